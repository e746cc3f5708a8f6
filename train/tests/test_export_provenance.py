"""export_recon.py's provenance of a model whose training ran in several steps (a continuation, or a
fine-tuning of an exported model): every step is named, so no run's steps read as the whole."""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from export_recon import checkpoint_choice, run_origin, trained_guided, machine_note  # noqa: E402


def write_run(folder, args, steps, minutes):
    folder.mkdir()
    (folder / 'summary.json').write_text(json.dumps({'args': args, 'steps': steps, 'minutes': minutes}))
    return str(folder / 'model.pt')


def test_a_run_from_a_random_draw_says_so():
    assert run_origin({'init': None}) == 'trained from scratch'


def test_a_chain_from_an_exported_model_names_every_step(tmp_path):
    (tmp_path / 'shipped.toml').write_text(
        'name = "m"\nprovenance = "trained from scratch, 11000 steps; benchmarks below on 76 other val windows"\n')
    middle = write_run(tmp_path / 'middle', {'init': str(tmp_path / 'shipped.onnx'), 'stages': [0.0, 1.0, 0.0]},
                       6000, 32.0)
    origin = run_origin({'init': middle})
    assert origin.startswith('fine-tuned from an exported model (trained from scratch, 11000 steps)')
    assert 'then 6000 steps (32 min), the instance head alone; then this run from their weights' in origin


def test_a_continuation_of_a_run_from_scratch_names_both(tmp_path):
    first = write_run(tmp_path / 'first', {'decouple': True}, 5400, 90.0)
    assert run_origin({'init': first}) == ('trained from scratch in two runs: 5400 steps (90 min) with --decouple, '
                                           'then this run from their weights')


def test_an_upsampling_carried_in_from_the_run_continued_counts_as_trained_with(tmp_path):
    first = write_run(tmp_path / 'first', {'guided': [0.06, 0.05]}, 6000, 32.0)
    assert trained_guided({'init': first})
    assert not trained_guided({'init': str(tmp_path / 'shipped.onnx')})
    assert not trained_guided({})


def test_a_snapshot_is_named_with_its_own_step_and_time(tmp_path):
    (tmp_path / 'log.csv').write_text('step,stage,seconds,loss\n1,2,0.0,1.0\n2000,2,600.0,0.5\n4000,2,1200.0,0.4\n')
    summary = {'best': {'step': 4000, 'minutes': 20.0, 'windows': 24}}
    assert checkpoint_choice(str(tmp_path / 'snapshot_2000.pt'), summary) == (
        2000, 10.0, 'picked among its snapshots by ARI on the val_selection windows')
    assert checkpoint_choice(str(tmp_path / 'model.pt'), summary) == (4000, 20.0, 'picked by ARI on 24 val windows')


def test_the_machine_seed_and_sessions_are_named_where_the_summary_has_them():
    assert machine_note({}) == ''
    note = machine_note({'cpu': 'AMD EPYC, avx512_bf16', 'seed': 0, 'sessions': 1})
    assert note == ' (AMD EPYC, avx512_bf16, seed 0)'
    assert machine_note({'cpu': None, 'seed': 3, 'sessions': 2}) == ' (seed 3, resumed over 2 sessions)'

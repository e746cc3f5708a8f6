"""groupforward's HDBSCAN against the Python `hdbscan` package (the reference implementation of
the algorithm) on the same seeded blobs, through `groupforward bench grouping`: the two labelings
agree (ARI >= 0.99) and ours recovers the blobs as well as the reference does."""

import csv
import subprocess
import sys


def test_hdbscan_agrees_with_the_python_reference(binary, tmp_path):
    out = tmp_path / 'grouping'
    subprocess.run([str(binary), 'bench', 'grouping', '--sizes', '2000,6000', '--out', str(out),
                    '--python', sys.executable], check=True,
                   capture_output=True, timeout=600)
    rows = list(csv.DictReader(open(out.with_suffix('.csv'))))
    assert [int(r['points']) for r in rows] == [2000, 6000]
    for row in rows:
        assert float(row['ari_rust_python']) >= 0.99, row
        assert float(row['ari_rust_truth']) >= float(row['ari_python_truth']) - 0.01, row
        assert int(row['rust_clusters']) == int(row['python_clusters']), row
    assert (out.with_suffix('.md')).read_text().count('\n| ') == 4, 'header, rule and one row per size'

//! `groupforward eval refer`: referring scored end to end. Writes `DIR/expressions.csv` (one row
//! per expression), `DIR/summary.json` and `DIR/summary.md`, and prints the table.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;
use std::sync::{Arc, Mutex};

use anyhow::{Context, Result};
use groupforward::window::WindowModels;
use groupforward_harness::eval::baseline::FeatureVoxels;
use groupforward_harness::eval::refer::{
    ask_scene, held_out_views, published_mask_iou, ReferRecord, Referrer, SceneTruth, Truth,
};
use groupforward_harness::eval::run::{record_scene, replay_scene_with};
use groupforward_harness::eval::score::TruthObject;
use groupforward_sim::referring::{observed_expressions, Expression, Relation, ViewPose};
use groupforward_sim::scene::SceneFile;
use groupforward_sim::simulation::Simulation;

use crate::sim::progress_bar;
use groupforward::config::Config;

/// A line of `--expressions`: the scene's name, the expression and its target object ids; the
/// rest of a `sim benchmark` record (relation, anchors, distractors, view) is optional.
#[derive(Debug, serde::Deserialize)]
struct ExpressionLine {
    scene: String,
    #[serde(alias = "expression")]
    text: String,
    targets: Vec<u16>,
    /// One of the benchmark's relation labels, or a user's own (scored as its own group).
    #[serde(default)]
    relation: Option<String>,
    #[serde(default)]
    anchors: Vec<u16>,
    #[serde(default)]
    distractors: usize,
    #[serde(default)]
    view: Option<ViewPose>,
}

/// A relation label the benchmark knows, if `label` is one.
fn known_relation(label: &str) -> Option<Relation> {
    serde_json::from_value(serde_json::Value::String(label.to_owned())).ok()
}

/// (scene, expression, the group it is scored in when not its relation's: `unlabelled` for a
/// line without a relation, the line's own label for one the benchmark does not know).
fn load_expressions(path: &Path) -> Result<Vec<(String, Expression, Option<String>)>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            let line: ExpressionLine = serde_json::from_str(l).with_context(|| {
                format!(
                    "{}:{}: expected {{\"scene\", \"text\", \"targets\"}}",
                    path.display(),
                    i + 1
                )
            })?;
            let mut targets = line.targets;
            targets.sort_unstable();
            let relation = line
                .relation
                .as_deref()
                .and_then(known_relation)
                .unwrap_or(Relation::Class);
            let group = match line.relation {
                None => Some("unlabelled".to_owned()),
                Some(label) if known_relation(&label).is_none() => Some(label),
                Some(_) => None,
            };
            let expression = Expression {
                text: line.text,
                relation,
                cardinality: targets.len(),
                targets,
                target_class: String::new(),
                anchors: line.anchors,
                distractors: line.distractors,
                view_dependent: line.view.is_some() || relation.view_dependent(),
                view: line.view,
            };
            Ok((line.scene, expression, group))
        })
        .collect()
}

/// Share of records with `f` true (0 for none).
fn rate(records: &[&ReferRecord], f: impl Fn(&ReferRecord) -> bool) -> f64 {
    if records.is_empty() {
        return 0.0;
    }
    records.iter().filter(|r| f(r)).count() as f64 / records.len() as f64
}

#[derive(Debug, Clone, serde::Serialize)]
struct Group {
    queries: usize,
    selection_accuracy: f64,
    topk_recall: f64,
    targets_in_map: f64,
    /// Over expressions whose targets all have instances in the map.
    accuracy_when_in_map: f64,
    /// Over those whose anchors are in the map too (both of "between" and of two hops, any one
    /// of the others): what the reasoner answers when the map holds everything it names.
    accuracy_when_anchors_in_map_too: f64,
    /// Over expressions with one target that is no refusal test: the answer's box against it.
    acc_at_25: f64,
    acc_at_50: f64,
    /// Over expressions whose targets some held-out view sees.
    referring_miou: f64,
}

fn group(records: &[&ReferRecord]) -> Group {
    let in_map: Vec<&ReferRecord> = records
        .iter()
        .copied()
        .filter(|r| r.targets_in_map)
        .collect();
    let grounded: Vec<&ReferRecord> = in_map
        .iter()
        .copied()
        .filter(|r| r.anchors_in_map)
        .collect();
    // Box accuracy is over expressions with one target to box: a refusal test has none (its
    // answer is right when it says what was not seen, which selection accuracy counts).
    let single: Vec<&ReferRecord> = records
        .iter()
        .copied()
        .filter(|r| r.targets.len() == 1 && r.truth != Truth::Refusal)
        .collect();
    Group {
        queries: records.len(),
        selection_accuracy: rate(records, |r| r.correct),
        topk_recall: rate(records, |r| r.topk_hit),
        targets_in_map: rate(records, |r| r.targets_in_map),
        accuracy_when_in_map: rate(&in_map, |r| r.correct),
        accuracy_when_anchors_in_map_too: rate(&grounded, |r| r.correct),
        acc_at_25: rate(&single, |r| r.iou >= 0.25),
        acc_at_50: rate(&single, |r| r.iou >= 0.5),
        referring_miou: {
            let ious: Vec<f64> = records.iter().filter_map(|r| r.mask_iou).collect();
            ious.iter().fold(0.0, |a, b| a + b) / ious.len().max(1) as f64
        },
    }
}

/// The benchmark's expressions of `file` by truth: decided over the objects the run observed (at
/// least [`crate::eval::MIN_OBJECT_PIXELS`] over the trajectory, as `eval map` scores them), the
/// refusal tests for objects never observed, and the old truth over every object.
fn benchmark_expressions(
    file: &SceneFile,
    objects: &[TruthObject],
) -> Result<Vec<(Expression, Truth)>> {
    let observed: Vec<u16> = objects
        .iter()
        .filter(|o| o.pixels >= crate::eval::MIN_OBJECT_PIXELS)
        .map(|o| o.id)
        .collect();
    let failed = |e: groupforward_sim::scene::SceneError| anyhow::anyhow!("{}: {e}", file.name);
    let benchmark = observed_expressions(file, &observed).map_err(failed)?;
    Ok(benchmark
        .answerable
        .into_iter()
        .map(|e| (e, Truth::Observed))
        .chain(benchmark.refusals.into_iter().map(|e| (e, Truth::Refusal)))
        .chain(
            benchmark
                .every_object
                .into_iter()
                .map(|e| (e, Truth::EveryObject)),
        )
        .collect())
}

pub fn eval_refer(
    files: &[SceneFile],
    config: &Config,
    expressions: Option<&Path>,
    baseline: bool,
    out: &Path,
) -> Result<()> {
    let mut models = WindowModels::load(&config.models, &config.semantics)
        .context("loading the models (`make setup` installs ONNX Runtime)")?;
    let encoder = models.text_encoder.take().map(|e| Arc::new(Mutex::new(e)));
    let given = expressions.map(load_expressions).transpose()?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let bar = progress_bar(files.len() as u64, "eval refer");
    let mut records = Vec::new();
    let mut baseline_rows = Vec::new();
    // Per scene, the published masks' mIoU (found objects, held-out views).
    let mut published = Vec::new();
    for file in files {
        bar.set_message(file.name.clone());
        let mut voxels = FeatureVoxels::default();
        let recorded = record_scene(file).with_context(|| format!("scene {}", file.name))?;
        let run =
            replay_scene_with(
                &recorded,
                config,
                &mut models,
                |frames, output, models| match models.semantic.as_mut().filter(|_| baseline) {
                    Some(semantic) => Ok(voxels.add_window(frames, output, semantic)?),
                    None => Ok(()),
                },
            )
            .with_context(|| format!("scene {}", file.name))?;
        let objects = run.objects.clone();
        let sim =
            Simulation::new(file.clone()).map_err(|e| anyhow::anyhow!("{}: {e}", file.name))?;
        // Masks are cut by the held-out view's depth only when the node was given depth.
        let with_depth = config.cameras.iter().any(|c| c.depth_topic.is_some());
        let views = held_out_views(&sim, &run.map, with_depth);
        let referrer = Referrer {
            vocabulary: models.vocabulary.clone(),
            encoder: encoder.clone(),
            section: config.refer.clone(),
        };
        let asked: Vec<(Expression, Truth)> = match &given {
            // A user's expressions are scored by the targets they give.
            Some(lines) => lines
                .iter()
                .filter(|(scene, _, _)| *scene == file.name)
                .map(|(_, e, _)| (e.clone(), Truth::Observed))
                .collect(),
            None => benchmark_expressions(file, &run.objects)?,
        };
        let truth = SceneTruth {
            objects: &run.objects,
            views: &views,
        };
        let shared = referrer.shared(run.map);
        published.extend(published_mask_iou(&shared, &run.objects, &views));
        let mut asked_records = ask_scene(&file.name, shared, truth, &asked);
        if let Some(lines) = &given {
            // A user's expression without a relation, or with a label of their own, is scored in
            // a group of its own.
            let groups = lines
                .iter()
                .filter(|(scene, _, _)| *scene == file.name)
                .map(|(_, _, group)| group);
            for (record, group) in asked_records.iter_mut().zip(groups) {
                if let Some(group) = group {
                    record.relation.clone_from(group);
                }
            }
        }
        if let (true, Some(vocabulary), Some(encoder)) = (baseline, &models.vocabulary, &encoder) {
            let named = voxels.named(vocabulary);
            let observed: Vec<ReferRecord> = asked_records
                .iter()
                .filter(|r| r.truth == Truth::Observed)
                .cloned()
                .collect();
            baseline_rows.extend(crate::eval_baseline::baseline_rows(
                &observed, &objects, &named, vocabulary, encoder,
            ));
        }
        records.extend(asked_records);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let published_miou =
        (!published.is_empty()).then(|| published.iter().sum::<f64>() / published.len() as f64);
    write_outputs(&records, published_miou, out)?;
    if baseline {
        crate::eval_baseline::write_baseline(&baseline_rows, out)?;
    }
    Ok(())
}

/// Whether a wrong answer chose only objects among the expression's targets: for a refusal
/// test, objects the trajectory saw too little of to count as observed.
fn answers_only_what_it_names(r: &ReferRecord) -> bool {
    !r.correct && !r.answered.is_empty() && r.answered.iter().all(|a| r.targets.contains(a))
}

fn write_outputs(records: &[ReferRecord], published_miou: Option<f64>, out: &Path) -> Result<()> {
    let mut csv = std::io::BufWriter::new(std::fs::File::create(out.join("expressions.csv"))?);
    writeln!(
        csv,
        "scene,truth,expression,relation,view_dependent,hard,targets,answered,correct,topk_hit,targets_in_map,anchors_in_map,iou,mask_iou,millis,reasoner,message"
    )?;
    let ids = |v: &[u16]| v.iter().map(u16::to_string).collect::<Vec<_>>().join(" ");
    for r in records {
        writeln!(
            csv,
            "{},{},\"{}\",{},{},{},{},{},{},{},{},{},{:.4},{},{:.3},{},\"{}\"",
            r.scene,
            r.truth.name(),
            r.expression.replace('"', "'"),
            r.relation,
            r.view_dependent,
            r.hard,
            ids(&r.targets),
            ids(&r.answered),
            r.correct,
            r.topk_hit,
            r.targets_in_map,
            r.anchors_in_map,
            r.iou,
            r.mask_iou.map_or(String::new(), |v| format!("{v:.4}")),
            r.millis,
            r.reasoner_used,
            r.message.replace('"', "'"),
        )?;
    }
    // The headline: what an observer can be asked (truth over the observed objects, and refusals
    // for the rest); the old truth over every object is its own row.
    let all: Vec<&ReferRecord> = records
        .iter()
        .filter(|r| r.truth != Truth::EveryObject)
        .collect();
    let of_truth = |truth: Truth| -> Vec<&ReferRecord> {
        records.iter().filter(|r| r.truth == truth).collect()
    };
    let mut by_relation: BTreeMap<&str, Vec<&ReferRecord>> = BTreeMap::new();
    for r in &all {
        by_relation.entry(r.relation.as_str()).or_default().push(r);
    }
    let split = |f: &dyn Fn(&ReferRecord) -> bool| -> Vec<&ReferRecord> {
        all.iter().copied().filter(|r| f(r)).collect()
    };
    let mut millis: Vec<f64> = records.iter().map(|r| r.millis).collect();
    millis.sort_by(f64::total_cmp);
    let percentile = |p: f64| {
        millis
            .get(((millis.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    let total = group(&all);
    // A refusal test answered with the very object(s) it names: the trajectory did see them, in
    // fewer pixels than the benchmark's line for "observed" (a box on a refrigerator's top).
    let refusal_tests = of_truth(Truth::Refusal);
    let answered_with_the_object = refusal_tests
        .iter()
        .filter(|r| answers_only_what_it_names(r))
        .count();
    let (seen, refusals, every) = (
        group(&of_truth(Truth::Observed)),
        group(&refusal_tests),
        group(&of_truth(Truth::EveryObject)),
    );
    let rows: Vec<(String, Group)> = [
        ("**all**".to_owned(), total.clone()),
        ("targets observed".to_owned(), seen.clone()),
        (
            "never observed (right: a refusal)".to_owned(),
            refusals.clone(),
        ),
        ("every object (old truth)".to_owned(), every.clone()),
        ("easy".to_owned(), group(&split(&|r| !r.hard))),
        ("hard".to_owned(), group(&split(&|r| r.hard))),
        (
            "view-dependent".to_owned(),
            group(&split(&|r| r.view_dependent)),
        ),
        (
            "view-independent".to_owned(),
            group(&split(&|r| !r.view_dependent)),
        ),
    ]
    .into_iter()
    .chain(
        by_relation
            .iter()
            .map(|(relation, rs)| ((*relation).to_owned(), group(rs))),
    )
    .collect();
    let json = serde_json::json!({
        "selection_accuracy": total.selection_accuracy,
        "topk_recall": total.topk_recall,
        "targets_in_map": total.targets_in_map,
        "accuracy_when_in_map": total.accuracy_when_in_map,
        "accuracy_when_anchors_in_map_too": total.accuracy_when_anchors_in_map_too,
        "acc_at_25": total.acc_at_25,
        "acc_at_50": total.acc_at_50,
        "referring_miou": total.referring_miou,
        "query_p50_ms": percentile(0.5),
        "query_p99_ms": percentile(0.99),
        "queries": all.len(),
        "published_masks_miou": published_miou,
        "targets_observed": seen,
        "refusals": refusals,
        "refusals_answered_with_the_object": answered_with_the_object,
        "every_object": every,
        "groups": rows.iter().map(|(name, g)| serde_json::json!({"group": name, "scores": g})).collect::<Vec<_>>(),
    });
    std::fs::write(
        out.join("summary.json"),
        serde_json::to_string_pretty(&json)?,
    )?;
    let mut table = String::from(
        "| expressions | queries | selection accuracy | top-K recall | targets in map | accuracy when targets in map | ... and anchors | Acc@0.25 | Acc@0.5 | referring mIoU |\n\
         | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
    );
    for (name, g) in &rows {
        table += &format!(
            "| {name} | {} | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.3} |\n",
            g.queries,
            100.0 * g.selection_accuracy,
            100.0 * g.topk_recall,
            100.0 * g.targets_in_map,
            100.0 * g.accuracy_when_in_map,
            100.0 * g.accuracy_when_anchors_in_map_too,
            100.0 * g.acc_at_25,
            100.0 * g.acc_at_50,
            g.referring_miou,
        );
    }
    table += &format!(
        "\nRefusal tests answered with the very object they name (seen, in fewer than the benchmark's {} pixels for \"observed\"): {answered_with_the_object} of {}.\n",
        crate::eval::MIN_OBJECT_PIXELS,
        refusal_tests.len()
    );
    std::fs::write(out.join("summary.md"), &table)?;
    print!("{table}");
    if let Some(miou) = published_miou {
        println!(
            "published masks (~/instance_masks: each listed instance that found an object, in held-out views at the sensor's resolution): mIoU {miou:.3}, mean over scenes"
        );
    }
    println!(
        "query latency (parse to response, through the service handler): p50 {:.1} ms, p99 {:.1} ms over {} queries; wrote {}",
        percentile(0.5),
        percentile(0.99),
        records.len(),
        out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_test_answered_with_the_object_it_names_is_told_apart() {
        let record = |answered: &[u16], correct: bool| ReferRecord {
            scene: "s".into(),
            truth: Truth::Refusal,
            expression: "the boxes on the refrigerator".into(),
            relation: "on".into(),
            view_dependent: false,
            hard: false,
            distractors: 0,
            targets: vec![7, 9],
            answered: answered.to_vec(),
            correct,
            topk_hit: false,
            targets_in_map: false,
            anchors_in_map: true,
            iou: 0.0,
            mask_iou: None,
            millis: 1.0,
            success: !correct,
            message: String::new(),
            reasoner_used: "builtin".into(),
        };
        assert!(answers_only_what_it_names(&record(&[7], false)));
        assert!(answers_only_what_it_names(&record(&[9, 7], false)));
        assert!(
            !answers_only_what_it_names(&record(&[2], false)),
            "another object"
        );
        assert!(
            !answers_only_what_it_names(&record(&[7, 0], false)),
            "and no object"
        );
        assert!(!answers_only_what_it_names(&record(&[], true)), "refused");
    }

    #[test]
    fn accuracy_in_the_map_is_reported_over_targets_and_over_targets_with_their_anchors() {
        // Right with everything in the map; wrong with the anchor missing; wrong with the target
        // missing: over targets in the map 1 of 2, with their anchors too 1 of 1.
        let record = |correct: bool, targets_in_map: bool, anchors_in_map: bool| ReferRecord {
            scene: "s".into(),
            truth: Truth::Observed,
            expression: "the chair closest to the lamp".into(),
            relation: "closest".into(),
            view_dependent: false,
            hard: false,
            distractors: 0,
            targets: vec![3],
            answered: vec![3],
            correct,
            topk_hit: correct,
            targets_in_map,
            anchors_in_map,
            iou: 0.0,
            mask_iou: None,
            millis: 1.0,
            success: true,
            message: String::new(),
            reasoner_used: "builtin".into(),
        };
        let records = [
            record(true, true, true),
            record(false, true, false),
            record(false, false, true),
        ];
        let g = group(&records.iter().collect::<Vec<_>>());
        assert_eq!(g.targets_in_map, 2.0 / 3.0);
        assert_eq!(g.accuracy_when_in_map, 0.5);
        assert_eq!(g.accuracy_when_anchors_in_map_too, 1.0);
    }

    #[test]
    fn box_accuracy_counts_the_boxes_of_single_targets_not_refusal_tests() {
        // An observed target boxed at IoU 0.6, one boxed at 0.3, a refusal test refused (right,
        // nothing to box): Acc@0.25 2 of 2, Acc@0.5 1 of 2, selection 2 of 3.
        let record = |truth: Truth, iou: f64, correct: bool| ReferRecord {
            scene: "s".into(),
            truth,
            expression: "the lamp".into(),
            relation: "class".into(),
            view_dependent: false,
            hard: false,
            distractors: 0,
            targets: vec![3],
            answered: if truth == Truth::Refusal {
                vec![]
            } else {
                vec![3]
            },
            correct,
            topk_hit: correct,
            targets_in_map: truth != Truth::Refusal,
            anchors_in_map: true,
            iou,
            mask_iou: None,
            millis: 1.0,
            success: truth != Truth::Refusal,
            message: String::new(),
            reasoner_used: "builtin".into(),
        };
        let records = [
            record(Truth::Observed, 0.6, true),
            record(Truth::Observed, 0.3, false),
            record(Truth::Refusal, 0.0, true),
        ];
        let g = group(&records.iter().collect::<Vec<_>>());
        assert_eq!((g.acc_at_25, g.acc_at_50), (1.0, 0.5));
        assert_eq!(g.selection_accuracy, 2.0 / 3.0);
    }

    #[test]
    fn a_label_the_benchmark_does_not_know_is_its_own_group_not_a_refused_file() {
        let dir = tempfile::tempdir().expect("a temporary directory");
        let path = dir.path().join("mine.jsonl");
        std::fs::write(
            &path,
            concat!(
                r#"{"scene": "s", "text": "the chair closest to the door", "targets": [3], "relation": "closest"}"#,
                "\n",
                r#"{"scene": "s", "text": "the chair", "targets": [2, 1]}"#,
                "\n\n",
                r#"{"scene": "s", "text": "the chair by the window", "targets": [1], "relation": "by_window"}"#,
                "\n",
            ),
        )
        .expect("write");
        let lines = load_expressions(&path).expect("the file loads");
        let groups: Vec<Option<&str>> = lines.iter().map(|l| l.2.as_deref()).collect();
        assert_eq!(groups, [None, Some("unlabelled"), Some("by_window")]);
        assert_eq!(lines[0].1.relation, Relation::Closest);
        assert_eq!(lines[1].1.targets, [1, 2]);
        assert_eq!(lines[2].1.relation, Relation::Class);
        // A line that is no expression record is refused, naming its line.
        std::fs::write(&path, "{\"scene\": \"s\", \"text\": \"the chair\"}\n").expect("write");
        let message = format!("{:#}", load_expressions(&path).unwrap_err());
        assert!(message.contains("mine.jsonl:1"), "{message}");
    }
}

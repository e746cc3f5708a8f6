//! `eval refer --baseline`: the ablation without instances beside the node, on the same
//! single-target expressions (ScanRefer's Acc@0.25 / 0.5 of the answer box), split by whether the
//! target has objects of its class around it. Writes `DIR/baseline.csv` and `DIR/baseline.md`.

use std::io::Write;
use std::path::Path;
use std::sync::{Arc, Mutex};

use anyhow::Result;
use groupforward::group::semantics::Vocabulary;
use groupforward::model::text::TextEncoder;
use groupforward::refer::parse::parse;
use groupforward_harness::eval::baseline::{concept_weights, NamedVoxels};
use groupforward_harness::eval::refer::ReferRecord;
use groupforward_harness::eval::score::TruthObject;

/// One single-target expression, answered by the node and by the baseline.
#[derive(Debug, Clone, serde::Serialize)]
pub struct BaselineRow {
    pub scene: String,
    pub expression: String,
    pub relation: String,
    pub distractors: usize,
    pub node_iou: f64,
    pub baseline_iou: f64,
}

/// The baseline's answers to the single-target expressions of `records` (one scene's).
pub fn baseline_rows(
    records: &[ReferRecord],
    objects: &[TruthObject],
    voxels: &NamedVoxels,
    vocabulary: &Vocabulary,
    encoder: &Arc<Mutex<TextEncoder>>,
) -> Vec<BaselineRow> {
    records
        .iter()
        .filter(|r| r.targets.len() == 1)
        .filter_map(|r| {
            let target = objects.iter().find(|o| o.id == r.targets[0])?;
            // The target phrase, as the node parses it; what the parser refuses, the baseline
            // cannot answer either.
            let baseline_iou = parse(&r.expression)
                .ok()
                .and_then(|q| encoder.lock().ok()?.embed(&q.target).ok())
                .and_then(|embedding| voxels.answer(&concept_weights(&embedding, vocabulary)))
                .map_or(0.0, |answer| answer.iou(&target.bbox));
            Some(BaselineRow {
                scene: r.scene.clone(),
                expression: r.expression.clone(),
                relation: r.relation.clone(),
                distractors: r.distractors,
                node_iou: r.iou,
                baseline_iou,
            })
        })
        .collect()
}

pub fn write_baseline(rows: &[BaselineRow], out: &Path) -> Result<serde_json::Value> {
    let mut csv = std::io::BufWriter::new(std::fs::File::create(out.join("baseline.csv"))?);
    writeln!(
        csv,
        "scene,expression,relation,distractors,node_iou,baseline_iou"
    )?;
    for r in rows {
        writeln!(
            csv,
            "{},\"{}\",{},{},{:.4},{:.4}",
            r.scene,
            r.expression.replace('"', "'"),
            r.relation,
            r.distractors,
            r.node_iou,
            r.baseline_iou
        )?;
    }
    csv.flush()?;
    type Keep = fn(&BaselineRow) -> bool;
    let groups: [(&str, Keep); 3] = [
        ("unique (no other object of the class)", |r| {
            r.distractors == 0
        }),
        ("multiple (same-class distractors)", |r| r.distractors > 0),
        ("all single-target", |_| true),
    ];
    let mut table = String::from(
        "| single-target expressions | count | node Acc@0.25 | baseline Acc@0.25 | node Acc@0.5 | baseline Acc@0.5 |\n\
         | --- | ---: | ---: | ---: | ---: | ---: |\n",
    );
    let mut json = Vec::new();
    for (name, keep) in groups {
        let kept: Vec<&BaselineRow> = rows.iter().filter(|r| keep(r)).collect();
        let share = |f: &dyn Fn(&BaselineRow) -> bool| {
            kept.iter().filter(|r| f(r)).count() as f64 / kept.len().max(1) as f64
        };
        let scores = [
            share(&|r| r.node_iou >= 0.25),
            share(&|r| r.baseline_iou >= 0.25),
            share(&|r| r.node_iou >= 0.5),
            share(&|r| r.baseline_iou >= 0.5),
        ];
        table.push_str(&format!(
            "| {name} | {} | {:.1}% | {:.1}% | {:.1}% | {:.1}% |\n",
            kept.len(),
            100.0 * scores[0],
            100.0 * scores[1],
            100.0 * scores[2],
            100.0 * scores[3]
        ));
        json.push(serde_json::json!({
            "group": name, "count": kept.len(),
            "node_acc_at_25": scores[0], "baseline_acc_at_25": scores[1],
            "node_acc_at_50": scores[2], "baseline_acc_at_50": scores[3],
        }));
    }
    std::fs::write(out.join("baseline.md"), &table)?;
    println!("\nWithout instances (semantic features lifted per 5 cm voxel, the target phrase's voxels boxed), against the node:\n\n{table}");
    Ok(serde_json::Value::Array(json))
}

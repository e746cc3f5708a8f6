//! `groupforward eval window` and `eval all` end to end in a fresh process, on one held-out
//! benchmark scene: every score is written, finite and in range, and the shipped models score what
//! a working model scores there (floors well under the measured values, far above what a broken
//! model or a broken lifting gives).

use std::process::Command;

/// `groupforward eval <args>` on held-out benchmark scene 10 into a fresh directory; it must
/// succeed.
fn eval(args: &[&str]) -> (tempfile::TempDir, std::process::Output) {
    let out = tempfile::tempdir().expect("a temporary directory");
    let run = Command::new(env!("CARGO_BIN_EXE_groupforward"))
        .arg("eval")
        .args(args)
        .args(["--first-index", "10", "--scenes", "1", "--out"])
        .arg(out.path())
        .output()
        .expect("the groupforward binary runs");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    (out, run)
}

fn value_of(header: &[&str], row: &[&str], name: &str) -> f64 {
    let at = header
        .iter()
        .position(|c| *c == name)
        .unwrap_or_else(|| panic!("no column {name}"));
    row[at].parse().unwrap_or_else(|e| panic!("{name}: {e}"))
}

#[test]
fn eval_window_scores_depth_instances_semantics_and_a_novel_view() {
    let (out, run) = eval(&["window"]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains("LPIPS is not computed"), "{stdout}");
    let csv = std::fs::read_to_string(out.path().join("windows.csv")).expect("windows.csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 2, "two windows a scene by default");
    let value = |row: &[&str], name: &str| value_of(&header, row, name);
    for row in &rows {
        // Measured on benchmark_00010: abs-rel 0.013, δ1 100%, ARI 0.955, semantic 86.8%,
        // PSNR 22.8 dB, SSIM 0.755 (means of its two windows).
        assert!(value(row, "depth_abs_rel") < 0.06, "{row:?}");
        assert!(value(row, "depth_delta1") > 0.9, "{row:?}");
        assert!(value(row, "ari") > 0.6, "{row:?}");
        assert!(value(row, "semantic_pixel_accuracy") > 0.6, "{row:?}");
        assert!(value(row, "novel_psnr") > 15.0, "{row:?}");
        let ssim = value(row, "novel_ssim");
        assert!((0.4..=1.0).contains(&ssim), "{row:?}");
        assert!((0.0..=1.0).contains(&value(row, "novel_semantic_pixel_accuracy")));
        assert!(value(row, "instances") >= 2.0);
        assert!(value(row, "object_coverage") > 0.6, "{row:?}");
    }
    // Where each object's pixels went: shares of one object that add up to one.
    let objects = std::fs::read_to_string(out.path().join("objects.csv")).expect("objects.csv");
    let mut lines = objects.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let mut sightings = 0;
    for line in lines {
        let row: Vec<&str> = line.split(',').collect();
        let share = |name: &str| value_of(&header, &row, name);
        let total = share("in_best") + share("split") + share("to_structure") + share("unassigned");
        assert!((total - 1.0).abs() < 1e-3, "{line}");
        assert!((0.0..=1.0).contains(&share("best_iou")), "{line}");
        sightings += 1;
    }
    assert!(sightings >= 4, "{objects}");
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.path().join("summary.json")).expect("summary.json"),
    )
    .expect("JSON");
    for key in ["source_semantic_miou", "novel_semantic_miou"] {
        let miou = summary[key].as_f64().unwrap_or_else(|| panic!("{key}"));
        assert!((0.0..=1.0).contains(&miou), "{key} {miou}");
    }
    assert_eq!(
        summary["models"]["reconstruction_sha256"]
            .as_str()
            .map(str::len),
        Some(64)
    );
}

#[test]
fn eval_all_runs_every_evaluation_on_the_same_scenes_and_gathers_their_figures() {
    let (out, _) = eval(&["all", "--windows", "1"]);
    for part in ["window", "map", "refer"] {
        assert!(
            out.path().join(part).join("summary.json").is_file(),
            "{part}"
        );
    }
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.path().join("summary.json")).expect("summary.json"),
    )
    .expect("JSON");
    assert_eq!(summary["scenes"][0], "benchmark_00010");
    let figure = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let recall = figure(&summary["map"]["summary"]["recall_at_25"]);
    let hash = summary["map"]["map_hashes"]["benchmark_00010"].as_str();
    assert_eq!(
        hash.map(str::len),
        Some(16),
        "{:?}",
        summary["map"]["map_hashes"]
    );
    assert!((0.0..=1.0).contains(&recall), "{recall}");
    assert!(figure(&summary["refer"]["queries"]) >= 1.0);
    // The scene's map from above: its objects and listed instances drawn.
    let picture = std::fs::read_to_string(out.path().join("map/maps/benchmark_00010.svg"))
        .expect("the scene's picture");
    assert!(
        picture.matches("class=\"object\"").count() >= 3,
        "{picture}"
    );
    assert!(picture.contains("class=\"instance\""));
    assert_eq!(figure(&summary["window"]["summary"]["windows"]), 1.0);
    // Every listed instance, with what it matched.
    let instances =
        std::fs::read_to_string(out.path().join("map/instances.csv")).expect("instances.csv");
    let mut lines = instances.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let outcome = header
        .iter()
        .position(|h| *h == "outcome")
        .expect("outcome");
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert!(!rows.is_empty(), "{instances}");
    for row in &rows {
        assert!(
            ["object", "duplicate", "unmatched"].contains(&row[outcome]),
            "{row:?}"
        );
    }
    let table = std::fs::read_to_string(out.path().join("summary.md")).expect("summary.md");
    assert_eq!(
        table.lines().filter(|l| l.starts_with("| window")).count(),
        6,
        "{table}"
    );
    assert!(!table.contains("NaN"), "{table}");
    // Each headline figure with its interval over scenes, and the per-scene counts a later run
    // is compared against.
    let map = &summary["map"];
    let interval = &map["intervals_95"]["recall_at_25"];
    assert_eq!(figure(&interval["value"]), recall);
    assert!(figure(&interval["low"]) <= recall && recall <= figure(&interval["high"]));
    assert!(map["scenes"][0]["counts"]["objects_scored"].as_u64() > Some(0));
}

#[test]
fn eval_map_against_an_earlier_run_gives_the_paired_difference_and_refuses_other_scenes() {
    let (first, _) = eval(&["map"]);
    the_objects_not_found_are_traced_to_a_stage(first.path());
    let against = first.path().to_str().expect("a UTF-8 path");
    // The same scene again: a run is deterministic, so every difference is zero.
    let (second, run) = eval(&["map", "--against", against]);
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(second.path().join("summary.json")).expect("summary.json"),
    )
    .expect("JSON");
    let difference = &summary["against"]["difference_95"];
    for name in ["recall_at_25", "recall_at_50", "mean_iou", "precision"] {
        for end in ["value", "low", "high"] {
            assert_eq!(difference[name][end].as_f64(), Some(0.0), "{difference}");
        }
    }
    let printed = String::from_utf8_lossy(&run.stdout);
    assert!(
        printed.contains("recall_at_25 +0.0 pts (+0.0 to +0.0, within the spread)"),
        "{printed}"
    );
    // A run over other scenes cannot be paired with this one: refused before any replay.
    let refused = std::process::Command::new(env!("CARGO_BIN_EXE_groupforward"))
        .args(["eval", "map", "--first-index", "11", "--scenes", "1"])
        .args(["--against", against, "--out"])
        .arg(second.path().join("other"))
        .output()
        .expect("the groupforward binary runs");
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("no scene `benchmark_00011`"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
}

/// Every scored object that `eval map` did not find names the stage that lost it, and the summary
/// counts them; the shares of its sighted pixels add up to one, those in no instance by stage too.
fn the_objects_not_found_are_traced_to_a_stage(out: &std::path::Path) {
    let objects = std::fs::read_to_string(out.join("objects.csv")).expect("objects.csv");
    let mut lines = objects.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let column = |name: &str| header.iter().position(|c| *c == name).expect(name);
    let (mut lost, mut sighted) = (0u64, 0);
    for line in lines {
        let row: Vec<&str> = line.split(',').collect();
        let (outcome, lost_at) = (row[column("outcome")], row[column("lost_at")]);
        match outcome {
            "found" | "not_seen" => assert_eq!(lost_at, "", "{line}"),
            _ => {
                assert!(["window", "fusion", "later"].contains(&lost_at), "{line}");
                lost += 1;
            }
        }
        if value_of(&header, &row, "window_sightings") > 0.0 {
            let share = |name: &str| value_of(&header, &row, name);
            let total =
                share("in_best") + share("split") + share("to_structure") + share("unassigned");
            assert!((total - 1.0).abs() < 2e-3, "{line}");
            // Every pixel in no instance was dropped by one named stage.
            let dropped: f64 = [
                "not_lifted",
                "noise",
                "edge",
                "speck",
                "support",
                "other_object",
            ]
            .iter()
            .map(|name| share(name))
            .sum();
            assert!((dropped - share("unassigned")).abs() < 4e-3, "{line}");
            sighted += 1;
        }
    }
    assert!(sighted >= 4, "{objects}");
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("summary.json")).expect("summary.json"),
    )
    .expect("JSON");
    let count = |key: &str| summary["summary"][key].as_u64().expect(key);
    assert_eq!(
        count("lost_in_windows") + count("lost_in_fusion") + count("lost_later"),
        lost
    );
    let found = summary["counts"]["found_25"].as_u64().expect("found_25");
    assert_eq!(count("objects_scored"), found + lost);
}

#[test]
fn the_baseline_without_instances_answers_the_same_single_target_expressions() {
    let (out, run) = eval(&["refer", "--baseline"]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains("Without instances"), "{stdout}");
    let csv = std::fs::read_to_string(out.path().join("baseline.csv")).expect("baseline.csv");
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    let asked = std::fs::read_to_string(out.path().join("expressions.csv")).expect("expressions");
    assert!(
        !rows.is_empty() && rows.len() < asked.lines().count(),
        "single-target ones only"
    );
    let mut baseline_found = 0;
    for row in &rows {
        let fields: Vec<&str> = row.rsplitn(3, ',').collect();
        let (baseline_iou, node_iou): (f64, f64) = (
            fields[0].parse().expect("baseline IoU"),
            fields[1].parse().expect("node IoU"),
        );
        assert!((0.0..=1.0).contains(&baseline_iou) && (0.0..=1.0).contains(&node_iou));
        baseline_found += usize::from(baseline_iou >= 0.25);
    }
    // The baseline finds some objects (it names unique ones as well as the node does).
    assert!(baseline_found >= 1, "{csv}");
    let table = std::fs::read_to_string(out.path().join("baseline.md")).expect("baseline.md");
    assert!(
        table.contains("| multiple (same-class distractors) |"),
        "{table}"
    );
}

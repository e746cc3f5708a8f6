//! `groupforward bench sweep --quick` end to end in a fresh process (the smoke setting CI runs;
//! its timings are not asserted: speed targets live in the benchmark's own output).

use std::process::Command;

#[test]
fn the_quick_sweep_writes_one_scored_and_timed_row_per_setting_and_the_pareto_chart() {
    let out = tempfile::tempdir().expect("a temporary directory");
    let run = Command::new(env!("CARGO_BIN_EXE_groupforward"))
        .args(["bench", "sweep", "--quick", "--out"])
        .arg(out.path())
        .output()
        .expect("the groupforward binary runs");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let csv = std::fs::read_to_string(out.path().join("sweep.csv")).expect("sweep.csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("a header").split(',').collect();
    let column = |name: &str| {
        header
            .iter()
            .position(|c| *c == name)
            .unwrap_or_else(|| panic!("no column {name} in {header:?}"))
    };
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let names: Vec<&str> = rows.iter().map(|r| r[column("setting")]).collect();
    assert_eq!(names, ["default", "views_2"]);
    let number = |row: &[&str], name: &str| -> f64 {
        row[column(name)]
            .parse()
            .unwrap_or_else(|e| panic!("{name}: {e}"))
    };
    for row in &rows {
        let (p50, p99) = (number(row, "window_p50_ms"), number(row, "window_p99_ms"));
        assert!(p50 > 0.0 && p50 <= p99 && p99.is_finite(), "{row:?}");
        // Every stage the table names was timed, within the windows it is part of.
        for stage in ["model", "lift", "group", "clean", "semantics", "fusion"] {
            let ms = number(row, &format!("{stage}_p50_ms"));
            assert!((0.0..=p99).contains(&ms), "{stage}: {ms} ms in {row:?}");
        }
        for rate in ["recall_at_25", "recall_at_50", "precision"] {
            let value = number(row, rate);
            assert!((0.0..=1.0).contains(&value), "{rate} {value}");
        }
        assert!(number(row, "objects_scored") >= 1.0);
    }
    // Windows do not overlap: two views a window give about twice the windows of four.
    let windows = |i: usize| number(&rows[i], "windows");
    assert!(
        windows(1) >= 2.0 * windows(0) - 1.0,
        "{} windows of 2 views against {} of 4",
        windows(1),
        windows(0)
    );
    let chart = std::fs::read_to_string(out.path().join("pareto.svg")).expect("pareto.svg");
    assert!(chart.starts_with("<svg"));
    for name in names {
        assert!(chart.contains(name), "{name} is not labelled in the chart");
    }
    let table = std::fs::read_to_string(out.path().join("sweep.md")).expect("sweep.md");
    assert!(table.contains("| default"));
}

#[test]
fn a_setting_the_sweep_does_not_know_is_refused_with_the_known_ones_named() {
    let out = tempfile::tempdir().expect("a temporary directory");
    let run = Command::new(env!("CARGO_BIN_EXE_groupforward"))
        .args([
            "bench",
            "sweep",
            "--only",
            "default,min_cluster_16",
            "--out",
        ])
        .arg(out.path())
        .output()
        .expect("the groupforward binary runs");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("no sweep setting \"min_cluster_16\""),
        "{stderr}"
    );
    assert!(stderr.contains("min_cluster_15"), "{stderr}");
    assert!(!out.path().join("sweep.csv").exists());
}

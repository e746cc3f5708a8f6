//! `bench soak`: runs [`groupforward_harness::soak`] and writes `summary.json` and a readable summary.

use std::path::Path;

use anyhow::{Context, Result};
use groupforward_harness::soak::{run_soak, SoakOptions, SoakReport};

pub fn soak(options: &SoakOptions, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let report = run_soak(options, &|phase| eprintln!("soak: {phase}"))?;
    let summary = out.join("summary.json");
    std::fs::write(&summary, serde_json::to_string_pretty(&report)?)?;
    print!("{}", describe(&report));
    println!("wrote {}", summary.display());
    Ok(())
}

fn describe(r: &SoakReport) -> String {
    let reasons = r
        .rejected_by_reason
        .iter()
        .map(|(reason, n)| format!("{reason} {n}"))
        .collect::<Vec<_>>()
        .join(", ");
    format!(
        "malformed: {} messages sent, {} counted ({reasons}); {} bad requests; panics {}\n\
         referring after the malformed traffic: {} ({} expressions)\n\
         VLM faults: {} of {} answered by the built-in reasoner and flagged{}\n\
         memory: {:.0} MB before, {:.0} MB after the malformed traffic, {:.0} MB peak in the flood, {:.0} MB at the end\n\
         flood: {:.0} s, {} frames from 2 cameras, {} dropped by the input queue (counted)\n\
         queries: {} sent, {} lost, p50 {:.0} ms, p99 {:.0} ms (the handler alone: p50 {:.0}, p99 {:.0} ms)\n\
         determinism: map hashes {} ({})\n",
        r.messages_sent,
        r.messages_counted,
        r.requests_sent,
        r.panics,
        if r.referring_same_after_malformed { "same answers" } else { "ANSWERS CHANGED" },
        r.referring_before.len(),
        r.vlm_faults_answered,
        r.vlm_faults_tried,
        if r.vlm_faults_failed.is_empty() {
            String::new()
        } else {
            format!(" (not: {})", r.vlm_faults_failed.join("; "))
        },
        r.rss_before_mb,
        r.rss_after_malformed_mb,
        r.rss_peak_flood_mb,
        r.rss_after_mb,
        r.flood_secs,
        r.flood_frames_published,
        r.flood_frames_dropped_by_queue,
        r.queries_sent,
        r.queries_lost,
        r.query_p50_ms,
        r.query_p99_ms,
        r.node_stages_after_flood.get("query").map_or(0.0, |t| t[0]),
        r.node_stages_after_flood.get("query").map_or(0.0, |t| t[1]),
        r.replay_hashes.join(" / "),
        if r.replay_hashes_equal { "equal" } else { "DIFFER" },
    )
}

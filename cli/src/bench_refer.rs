//! `groupforward bench refer`: referring query latency against maps of growing size, through the
//! `Refer` service's handler (parse, embed, retrieve, reason, and the response with the targets'
//! Gaussians and masks), with the shipped text encoder.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{Context, Result};
use groupforward::frame::WindowInstance;
use groupforward::graph::{FusionParams, SceneMap};
use groupforward::group::semantics::{
    default_vocabulary, Vocabulary, DEFAULT_SEMANTIC_TEMPERATURE,
};
use groupforward::model::text::TextEncoder;
use groupforward::node::services::{current_snapshot, refer_request, snapshot_due, Shared};
use groupforward_msgs::gf_msgs::ReferRequest;

use crate::bench_support::{bench_views, cube, line_chart};

/// Expressions over the default vocabulary, one per kind of reasoning.
const QUERIES: &[&str] = &[
    "the chair closest to the lamp",
    "the table farthest from the bed",
    "the biggest table",
    "all the boxes",
    "the red sofa",
    "the leftmost chair",
    "the lamp on the table",
    "the plant between the desk and the cabinet",
    "the thing you can sleep on",
    "the garbage can",
];

pub fn refer_bench(sizes: &[usize], rounds: usize, out: &Path) -> Result<()> {
    if let Some(parent) = out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let config = crate::eval::eval_config(&crate::eval_command::ModelArgs::default())?;
    groupforward::model::init_runtime(config.models.onnxruntime.as_deref())?;
    let mut encoder = TextEncoder::load(
        &config.models.text_encoder,
        &config.models.session_options(),
    )
    .context("loading the text encoder (`make setup` installs ONNX Runtime)")?;
    let phrases = default_vocabulary();
    let embeddings = phrases
        .iter()
        .map(|p| encoder.embed(p))
        .collect::<Result<Vec<_>, _>>()?;
    let vocabulary = Vocabulary {
        phrases: phrases.clone(),
        embeddings: embeddings.clone(),
        temperature: DEFAULT_SEMANTIC_TEMPERATURE,
        priors: groupforward::group::semantics::ClassPriors::builtin(),
    };
    let encoder = Arc::new(Mutex::new(encoder));
    let views = bench_views()?;
    let objects = phrases.len() - 1; // every phrase but `other`
    let mut csv = String::from(
        "instances,snapshot_ms,after_window_p50_ms,after_window_p99_ms,cold_p50_ms,warm_p50_ms,warm_p99_ms,decision_p50_ms,queries\n",
    );
    let mut md = format!(
        "Referring query latency through the `Refer` service handler ({} expressions x {rounds} rounds; 512 Gaussians per instance; {} threads). Cold: the first time each phrase is embedded; warm: phrases cached. Decision: parse to choice, without the response's clouds and masks (masks are cut by each view's 320 x 240 sensor depth). Snapshot: taking the changed map's snapshot, what a query pays that finds none being taken. After a window: a query right after the map changed, in the node (the output thread takes the new snapshot meanwhile and the query answers on the previous one, at most one window old).\n\n| instances | snapshot (ms) | after a window p50 / p99 (ms) | cold p50 (ms) | warm p50 (ms) | warm p99 (ms) | decision p50 (ms) |\n| ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
        QUERIES.len(),
        rayon::current_num_threads()
    );
    let (mut warm_series, mut p99_series, mut decision_series) =
        (Vec::new(), Vec::new(), Vec::new());
    for &n in sizes {
        let mut map = SceneMap::new(FusionParams::default());
        let instances = (0..n)
            .map(|k| {
                let mut gaussians = cube(glam::Vec3::new((k % 25) as f32, (k / 25) as f32, 0.5), 8);
                let hue = (k % 7) as f32 / 7.0;
                for c in &mut gaussians.colors {
                    *c = glam::Vec3::new(hue, 1.0 - hue, 0.5);
                }
                WindowInstance {
                    gaussians,
                    prototype: embeddings[k % objects].clone(),
                    support: 100,
                }
            })
            .collect();
        map.fuse(instances, &views, 0)?;
        let measured_views = crate::bench_support::sensor_depths(&map, &views);
        let mut shared = Shared {
            vocabulary: Some(vocabulary.clone()),
            text_encoder: Some(encoder.clone()),
            world_frame: "map".into(),
            ..Shared::default()
        };
        shared.set_map(map);
        shared.measured_views = measured_views;
        let shared = Mutex::new(shared);
        // What the first query after a window pays on top: the map snapshot.
        let started = Instant::now();
        let scene = current_snapshot(&shared).map_err(anyhow::Error::msg)?;
        let snapshot_ms = started.elapsed().as_secs_f64() * 1e3;
        // Cold: a fresh cache for this map size.
        if let Ok(mut e) = encoder.lock() {
            e.clear_cache();
        }
        let mut cold = Vec::new();
        let mut warm = Vec::new();
        let mut slowest = (0.0f64, "");
        let mut decision = Vec::new();
        for round in 0..=rounds {
            for q in QUERIES {
                let request = ReferRequest {
                    expression: (*q).into(),
                    ..ReferRequest::default()
                };
                let started = Instant::now();
                let response = refer_request(&shared, &request);
                let ms = started.elapsed().as_secs_f64() * 1e3;
                anyhow::ensure!(
                    response.success || !response.message.is_empty(),
                    "{q}: no answer and no reason"
                );
                if round == 0 {
                    cold.push(ms);
                } else {
                    warm.push(ms);
                    if ms > slowest.0 {
                        slowest = (ms, q);
                    }
                    let started = Instant::now();
                    let mut e = encoder.lock().map_err(|e| anyhow::anyhow!("{e}"))?;
                    let _ = groupforward::refer::answer(
                        &scene,
                        &mut *e,
                        &groupforward::refer::Request {
                            expression: (*q).into(),
                            ..Default::default()
                        },
                        &Default::default(),
                    );
                    decision.push(started.elapsed().as_secs_f64() * 1e3);
                }
            }
        }
        let mut after_window = after_a_window(&shared, rounds)?;
        let percentile = |v: &mut Vec<f64>, p: f64| {
            v.sort_by(f64::total_cmp);
            v[((v.len() as f64 - 1.0) * p).round() as usize]
        };
        let cold50 = percentile(&mut cold, 0.5);
        let (w50, w99) = (percentile(&mut warm, 0.5), percentile(&mut warm, 0.99));
        let d50 = percentile(&mut decision, 0.5);
        let (a50, a99) = (
            percentile(&mut after_window, 0.5),
            percentile(&mut after_window, 0.99),
        );
        warm_series.push((n as f64, w50));
        p99_series.push((n as f64, w99));
        decision_series.push((n as f64, d50));
        csv.push_str(&format!(
            "{n},{snapshot_ms:.3},{a50:.3},{a99:.3},{cold50:.3},{w50:.3},{w99:.3},{d50:.3},{}\n",
            warm.len()
        ));
        md.push_str(&format!(
            "| {n} | {snapshot_ms:.1} | {a50:.1} / {a99:.1} | {cold50:.1} | {w50:.1} | {w99:.1} | {d50:.2} |\n"
        ));
        eprintln!(
            "{n:>4} instances: warm p50 {w50:.1} ms, p99 {w99:.1} ms (slowest {:?} {:.1} ms), decision {d50:.2} ms, snapshot {snapshot_ms:.0} ms, after a window p50 {a50:.1} ms, p99 {a99:.1} ms",
            slowest.1, slowest.0
        );
    }
    md.push_str("\nReproduce: `groupforward bench refer`.\n");
    line_chart(
        &out.with_extension("svg"),
        "Referring query latency",
        "instances in the map",
        "milliseconds",
        &[
            ("service, warm p50", warm_series),
            ("service, warm p99", p99_series),
            ("decision p50", decision_series),
        ],
    )?;
    std::fs::write(out.with_extension("csv"), csv)?;
    std::fs::write(out.with_extension("md"), &md)?;
    print!("{md}");
    Ok(())
}

/// Latency of a query issued right after the map changed, as the running node meets it: the
/// output thread starts taking the new snapshot ([`snapshot_due`], then [`current_snapshot`] on
/// another thread) and the query, on the service's pool, answers on the previous one. `rounds`
/// times each expression, a map change before each.
fn after_a_window(shared: &Mutex<Shared>, rounds: usize) -> Result<Vec<f64>> {
    let lock = || shared.lock().map_err(|e| anyhow::anyhow!("{e}"));
    lock()?.snapshot_taker = true;
    let mut millis = Vec::new();
    for _ in 0..rounds {
        for q in QUERIES {
            {
                // A window changed the map: its messages are made and the snapshot is due.
                let mut s = lock()?;
                s.refresh_instances();
                snapshot_due(&mut s);
            }
            let request = ReferRequest {
                expression: (*q).into(),
                ..ReferRequest::default()
            };
            let ms = std::thread::scope(|scope| {
                let taker = scope.spawn(|| current_snapshot(shared));
                let started = Instant::now();
                let response = refer_request(shared, &request);
                let ms = started.elapsed().as_secs_f64() * 1e3;
                let taken = taker
                    .join()
                    .map_err(|_| anyhow::anyhow!("the snapshot thread panicked"))?;
                taken.map_err(anyhow::Error::msg)?;
                anyhow::ensure!(
                    response.success || !response.message.is_empty(),
                    "{q}: no answer and no reason"
                );
                Ok::<f64, anyhow::Error>(ms)
            })?;
            millis.push(ms);
        }
    }
    lock()?.snapshot_taker = false;
    Ok(millis)
}

//! `groupforward bench outputs`: what publishing the map costs. Per map size (instances x
//! Gaussians): refreshing the instance list (the window worker does it after every fused window),
//! the snapshot (shared with referring: built once per map change), and encoding every output
//! topic to CDR; beside the time of a real window pass (the demo scene through the shipped
//! models, same run, same machine), so the cost reads as a share of a window.

use std::path::Path;
use std::sync::Mutex;
use std::time::Instant;

use anyhow::Result;
use groupforward::frame::WindowInstance;
use groupforward::graph::{FusionParams, SceneMap};
use groupforward::node::outputs::encode;
use groupforward::node::services::{current_snapshot, Shared};
use groupforward::outputs::OutputsSection;

use crate::bench_support::{bench_views, cube};

/// Instances a window re-observes (and so changes) per round.
const WINDOW_INSTANCES: usize = 20;

pub fn outputs_bench(
    instances: &[usize],
    gaussians: &[usize],
    rounds: usize,
    out: &Path,
) -> Result<()> {
    if let Some(parent) = out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    // The denominator: window passes of the demo scene, model to map update.
    let config = crate::eval::eval_config(&crate::eval_command::ModelArgs::default())?;
    groupforward::model::init_runtime(config.models.onnxruntime.as_deref())?;
    let mut models = groupforward::window::WindowModels::load(&config.models, &config.semantics)?;
    let scene = groupforward_sim::scene::SceneFile::builtin("two_chairs")
        .ok_or_else(|| anyhow::anyhow!("the built-in two_chairs scene is missing"))?;
    let run = groupforward_harness::eval::run::run_scene(&scene, &config, &mut models)?;
    let stages = groupforward::timing::summarise(&run.window_times);
    let window_ms = stages
        .iter()
        .find(|s| s.stage == groupforward::timing::Stage::Window)
        .map_or(f64::NAN, |s| s.p50_ms);
    eprintln!(
        "window pass (two_chairs): {}",
        groupforward::timing::describe(&stages)
    );
    let views = bench_views()?;
    let section = OutputsSection::default();
    let mut csv = String::from(
        "instances,gaussians,list_ms,snapshot_ms,encode_ms,total_ms,bytes,window_ms,share\n",
    );
    let mut md = format!(
        "Publishing the map after a window that changed {WINDOW_INSTANCES} instances: per map size, the instance list refresh (boxes refitted for changed instances), the snapshot (shared with referring) and CDR encoding of every output topic (cloud within its {}-point budget; masks at a 320 × 240 sensor's resolution, cut by its depth); median of {rounds} rounds; {} threads. Share: of one window pass measured in the same run (two_chairs through the shipped models, p50 {window_ms:.0} ms).\n\n| instances | Gaussians | list (ms) | snapshot (ms) | encode (ms) | total (ms) | bytes | share of a window |\n| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
        section.cloud_max_points,
        rayon::current_num_threads()
    );
    for &n in instances {
        for &total in gaussians {
            let side = ((total / n) as f64).cbrt().round().max(1.0) as usize;
            let mut map = SceneMap::new(FusionParams {
                max_gaussians_per_instance: usize::MAX,
                ..FusionParams::default()
            });
            let window_instances = (0..n)
                .map(|k| WindowInstance {
                    gaussians: cube(glam::Vec3::new((k % 25) as f32, (k / 25) as f32, 0.5), side),
                    prototype: vec![1.0, (k % 7) as f32],
                    support: 100,
                })
                .collect();
            map.fuse(window_instances, &views, 0)?;
            let actual: usize = map.instances.iter().map(|i| i.gaussians.len()).sum();
            // The masks are cut by the depth a 320 × 240 sensor measured, as on a robot.
            let measured_views = crate::bench_support::sensor_depths(&map, &views);
            let mut shared = Shared {
                world_frame: "map".into(),
                ..Shared::default()
            };
            shared.set_map(map);
            shared.measured_views = measured_views;
            let shared = Mutex::new(shared);
            let (mut list, mut snapshot, mut encoding) = (Vec::new(), Vec::new(), Vec::new());
            let mut bytes = 0;
            for round in 0..rounds {
                // A window changed the map (it re-observed `WINDOW_INSTANCES` instances, which
                // moved a little): the worker refreshes the list, the publisher takes the
                // snapshot and encodes.
                let mut s = shared.lock().map_err(|e| anyhow::anyhow!("{e}"))?;
                let count = s.map.instances.len();
                for k in 0..WINDOW_INSTANCES.min(count) {
                    let instance = &mut s.map.instances[(round * WINDOW_INSTANCES + k) % count];
                    for m in &mut instance.gaussians.means {
                        m.z += 0.001;
                    }
                }
                let started = Instant::now();
                s.refresh_instances();
                list.push(started.elapsed().as_secs_f64() * 1e3);
                drop(s);
                let started = Instant::now();
                current_snapshot(&shared).map_err(anyhow::Error::msg)?;
                snapshot.push(started.elapsed().as_secs_f64() * 1e3);
                let started = Instant::now();
                let (encoded, _) = encode(&section, &shared, &mut Default::default())
                    .map_err(anyhow::Error::msg)?
                    .ok_or_else(|| anyhow::anyhow!("the map changed while encoding"))?;
                encoding.push(started.elapsed().as_secs_f64() * 1e3);
                bytes = encoded.len();
            }
            let median = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            let (l, s, e) = (
                median(&mut list),
                median(&mut snapshot),
                median(&mut encoding),
            );
            let all = l + s + e;
            let share = all / window_ms;
            csv.push_str(&format!(
                "{n},{actual},{l:.3},{s:.3},{e:.3},{all:.3},{bytes},{window_ms:.3},{share:.4}\n"
            ));
            md.push_str(&format!(
                "| {n} | {actual} | {l:.1} | {s:.1} | {e:.1} | {all:.1} | {bytes} | {:.1}% |\n",
                100.0 * share
            ));
            eprintln!(
                "{n:>4} instances, {actual:>8} Gaussians: list {l:.1} + snapshot {s:.1} + encode {e:.1} = {all:.1} ms ({:.1}% of a window), {bytes} bytes",
                100.0 * share
            );
        }
    }
    md.push_str("\nReproduce: `groupforward bench outputs`.\n");
    std::fs::write(out.with_extension("csv"), csv)?;
    std::fs::write(out.with_extension("md"), &md)?;
    print!("{md}");
    Ok(())
}

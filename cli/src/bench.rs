//! `groupforward bench ...`: measurements written as CSV and Markdown (and an SVG plot).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Subcommand;
use groupforward::group::blobs::blobs;
use groupforward::group::hdbscan::{hdbscan, HdbscanParams};
use groupforward::recon::metrics::adjusted_rand_index;

use crate::bench_support::{bench_views, cube, line_chart, percent_chart};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// HDBSCAN time and agreement against the Python `hdbscan` package, side by side on the same
    /// seeded 8-d blobs (sklearn's make_blobs recipe).
    Grouping {
        /// Numbers of points, comma separated.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "5000,10000,20000,50000,100000,200000"
        )]
        sizes: Vec<usize>,
        #[arg(long, default_value_t = 8)]
        dims: usize,
        #[arg(long, default_value_t = 12)]
        centers: usize,
        #[arg(long, default_value_t = 60)]
        min_cluster_size: usize,
        #[arg(long, default_value_t = 10)]
        min_samples: usize,
        /// Python with `hdbscan` installed (`make setup` puts it in .venv); `none` skips the
        /// reference.
        #[arg(long, default_value = ".venv/bin/python")]
        python: String,
        /// Output prefix: writes `<out>.csv` and `<out>.md`.
        #[arg(long, default_value = "target/bench/grouping")]
        out: PathBuf,
    },
    /// Fusion of one window into the persistent map, and the scene-graph update, against maps of
    /// growing size.
    Graph {
        /// Persistent instances in the map, comma separated.
        #[arg(long, value_delimiter = ',', default_value = "10,50,100,200,500")]
        instances: Vec<usize>,
        /// Instances in the fused window (re-observations of existing ones).
        #[arg(long, default_value_t = 20)]
        window: usize,
        #[arg(long, default_value = "target/bench/graph")]
        out: PathBuf,
    },
    /// Referring query latency through the `Refer` service handler against maps of growing
    /// size; writes `<out>.csv`, `<out>.md` and `<out>.svg`.
    Refer {
        /// Instances in the map, comma separated.
        #[arg(long, value_delimiter = ',', default_values_t = vec![25, 50, 100, 200, 400])]
        instances: Vec<usize>,
        /// Timed rounds over the expressions (after one cold round).
        #[arg(long, default_value_t = 5)]
        rounds: usize,
        #[arg(long, default_value = "target/bench/refer")]
        out: PathBuf,
    },
    /// What publishing the map costs: instance list, snapshot and every output topic encoded,
    /// against maps of growing size, as a share of a window pass; writes `<out>.csv`, `<out>.md`.
    Outputs {
        /// Instances in the map, comma separated.
        #[arg(long, value_delimiter = ',', default_values_t = vec![50, 500])]
        instances: Vec<usize>,
        /// Gaussians in the map (over all instances), comma separated.
        #[arg(long, value_delimiter = ',', default_values_t = vec![100_000, 1_000_000])]
        gaussians: Vec<usize>,
        #[arg(long, default_value_t = 3)]
        rounds: usize,
        #[arg(long, default_value = "target/bench/outputs")]
        out: PathBuf,
    },
    /// What accuracy costs in time: settings (views per window, HDBSCAN subsample and minimum
    /// cluster size, RGB-D or RGB model) each replaying the same recorded scenes, timed per
    /// stage and scored like `eval map`; writes `<out>/sweep.csv`, `sweep.md` and `pareto.svg`.
    Sweep {
        /// Two settings on one scene: a smoke test (CI runs it; its timings mean little).
        #[arg(long)]
        quick: bool,
        #[arg(long, default_value = "benchmark")]
        split: String,
        /// Scenes per setting (held out from every choice of settings: 10-29).
        #[arg(long, default_value_t = 10)]
        scenes: u64,
        #[arg(long, default_value_t = 10)]
        first_index: u64,
        /// Times every setting runs, the settings taking turns (timings pooled).
        #[arg(long, default_value_t = 1)]
        rounds: usize,
        /// Only these settings (comma-separated names, e.g. `default,min_cluster_15`): to confirm
        /// a few on more scenes.
        #[arg(long, value_delimiter = ',')]
        only: Vec<String>,
        #[arg(long, default_value = "target/bench/sweep")]
        out: PathBuf,
    },
    /// The node under hostile traffic and load (shipped models, two RGB-D cameras, one process
    /// over an embedded zenoh peer): malformed messages and requests, then both cameras flooding
    /// while referring queries come in, then the same bag twice through the stages; writes
    /// `<out>/summary.json`.
    Soak {
        /// CI size: 10^4 bad messages, 500 bad requests, a 15 s flood.
        #[arg(long)]
        quick: bool,
        #[arg(long, default_value_t = 100_000)]
        messages: usize,
        #[arg(long, default_value_t = 2_000)]
        requests: usize,
        #[arg(long, default_value_t = 300.0)]
        flood_secs: f64,
        /// Frames per second per camera during the flood.
        #[arg(long, default_value_t = 60.0)]
        camera_hz: f64,
        /// Referring queries per second during the flood.
        #[arg(long, default_value_t = 20.0)]
        query_hz: f64,
        #[arg(long, default_value_t = 34)]
        seed: u64,
        #[arg(long, default_value = "target/bench/soak")]
        out: PathBuf,
    },
    /// The map against random depth dropout: `eval map` on the same scenes with each level's
    /// `dropout:<p>` effect (0 = clean); writes `<out>.csv`, `<out>.md` and `<out>.svg`.
    Dropout {
        /// Probabilities of a depth pixel being dropped, comma separated.
        #[arg(long, value_delimiter = ',', default_value = "0,0.01,0.03,0.1,0.3")]
        levels: Vec<f64>,
        #[arg(long, default_value = "benchmark")]
        split: String,
        #[arg(long, default_value_t = 5)]
        scenes: u64,
        #[arg(long, default_value_t = 0)]
        first_index: u64,
        /// Reconstruction model manifest (default: the shipped RGB-D model).
        #[arg(long)]
        model: Option<PathBuf>,
        #[arg(long, default_value = "target/bench/dropout")]
        out: PathBuf,
    },
}

/// The map's scores at each dropout level, on the same scenes.
fn dropout_bench(
    levels: &[f64],
    files: &[groupforward_sim::scene::SceneFile],
    model: Option<PathBuf>,
    out: &Path,
) -> Result<()> {
    use groupforward_sim::effects::Preset;
    let config = crate::eval::eval_config(&crate::eval_command::ModelArgs::reconstruction(model))?;
    let mut models = groupforward::window::WindowModels::load(&config.models, &config.semantics)
        .context("loading the models (`make setup` installs ONNX Runtime)")?;
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let mut csv = String::from(
        "dropout,invalid_depth_fraction,recall_at_25,recall_at_50,precision,duplicate_rate,room_instances,objects_scored\n",
    );
    let mut md = String::from(
        "| dropout | invalid depth | recall@0.25 | recall@0.5 | precision | duplicates | room |\n| ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
    );
    let mut series: [(&str, Vec<(f64, f64)>); 3] = [
        ("recall@0.25", Vec::new()),
        ("recall@0.5", Vec::new()),
        ("precision", Vec::new()),
    ];
    for &level in levels {
        let preset = Preset::Dropout(level);
        let mut scenes = files.to_vec();
        for file in &mut scenes {
            file.apply_preset(preset);
        }
        let scored = crate::eval::score_scenes(&scenes, &config, &mut models, &preset.name())?;
        let s = scored.total.summary();
        let invalid = crate::eval::invalid_fraction(&scored.depth);
        csv.push_str(&format!(
            "{level},{invalid:.4},{:.4},{:.4},{:.4},{:.4},{},{}\n",
            s.recall_at_25,
            s.recall_at_50,
            s.precision,
            s.duplicate_rate,
            s.room_instances,
            s.objects_scored
        ));
        md.push_str(&format!(
            "| {:.0}% | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {} |\n",
            100.0 * level,
            100.0 * invalid,
            100.0 * s.recall_at_25,
            100.0 * s.recall_at_50,
            100.0 * s.precision,
            100.0 * s.duplicate_rate,
            s.room_instances
        ));
        for (i, value) in [s.recall_at_25, s.recall_at_50, s.precision]
            .into_iter()
            .enumerate()
        {
            series[i].1.push((100.0 * level, 100.0 * value));
        }
        eprintln!(
            "dropout {:.0}%: recall@0.25 {:.1}%, precision {:.1}%",
            100.0 * level,
            100.0 * s.recall_at_25,
            100.0 * s.precision
        );
    }
    md.push_str(&format!(
        "\n{} scenes; reproduce: `groupforward bench dropout`.\n",
        files.len()
    ));
    percent_chart(
        &out.with_extension("svg"),
        "The map against random depth dropout",
        "depth pixels dropped (%)",
        &series,
    )?;
    std::fs::write(out.with_extension("csv"), csv)?;
    std::fs::write(out.with_extension("md"), &md)?;
    print!("{md}");
    Ok(())
}

/// Fusion of one window and a scene-graph update against maps of `sizes` instances.
fn graph_bench(sizes: &[usize], window: usize, out: &Path) -> Result<()> {
    use groupforward::frame::WindowInstance;
    use groupforward::graph::{FusionParams, SceneMap};
    if let Some(parent) = out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    // Instances on a 1 m grid in the floor plane, 512 Gaussians each, 16-d prototypes.
    let place = |k: usize| glam::Vec3::new((k % 25) as f32, (k / 25) as f32, 0.5);
    let prototype = |k: usize| -> Vec<f32> {
        (0..16)
            .map(|c| if c == k % 16 { 1.0 } else { 0.0 })
            .collect()
    };

    let mut csv = String::from("instances,window,copy_ms,fuse_ms,graph_ms,edges\n");
    let (mut fuse_series, mut graph_series) = (Vec::new(), Vec::new());
    let mut md = format!(
        "Fusion of a {window}-instance window and a 4-keyframe scene-graph update (512 Gaussians per instance), {} threads, median of 5. Copy: the map copy the window worker fuses into (taken under the map lock).\n\n| instances | copy (ms) | fuse (ms) | graph (ms) | edges |\n| ---: | ---: | ---: | ---: | ---: |\n",
        rayon::current_num_threads()
    );
    for &n in sizes {
        let mut map = SceneMap::new(FusionParams::default());
        let views = bench_views()?;
        let initial = (0..n)
            .map(|k| WindowInstance {
                gaussians: cube(place(k), 8),
                prototype: prototype(k),
                support: 100,
            })
            .collect();
        map.fuse(initial, &views, 0)?;
        let mut copy_ms = Vec::new();
        let mut fuse_ms = Vec::new();
        let mut graph_ms = Vec::new();
        let mut edges = 0;
        for round in 0..5 {
            let shifted: Vec<WindowInstance> = (0..window.min(n))
                .map(|k| WindowInstance {
                    gaussians: cube(place(k) + glam::Vec3::splat(0.01), 8),
                    prototype: prototype(k),
                    support: 100,
                })
                .collect();
            let started = Instant::now();
            let mut trial = map.clone();
            copy_ms.push(started.elapsed().as_secs_f64() * 1e3);
            let started = Instant::now();
            trial.fuse(shifted, &views, round + 1)?;
            fuse_ms.push(started.elapsed().as_secs_f64() * 1e3);
            let started = Instant::now();
            let graph = trial.graph(4, f32::INFINITY)?;
            graph_ms.push(started.elapsed().as_secs_f64() * 1e3);
            edges = graph.edges.len();
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (c, f, g) = (
            median(&mut copy_ms),
            median(&mut fuse_ms),
            median(&mut graph_ms),
        );
        fuse_series.push((n as f64, f));
        graph_series.push((n as f64, g));
        csv.push_str(&format!("{n},{window},{c:.3},{f:.3},{g:.3},{edges}\n"));
        md.push_str(&format!("| {n} | {c:.2} | {f:.1} | {g:.1} | {edges} |\n"));
        eprintln!(
            "{n:>4} instances: copy {c:.2} ms, fuse {f:.1} ms, graph {g:.1} ms ({edges} edges)"
        );
    }
    md.push_str("\nReproduce: `groupforward bench graph`.\n");
    line_chart(
        &out.with_extension("svg"),
        &format!("Map update with a {window}-instance window"),
        "persistent instances",
        "milliseconds",
        &[
            ("fuse", fuse_series),
            ("scene graph (4 keyframes)", graph_series),
        ],
    )?;
    std::fs::write(out.with_extension("csv"), csv)?;
    std::fs::write(out.with_extension("md"), &md)?;
    print!("{md}");
    Ok(())
}

pub fn run(command: BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Grouping {
            sizes,
            dims,
            centers,
            min_cluster_size,
            min_samples,
            python,
            out,
        } => grouping(
            &sizes,
            dims,
            centers,
            min_cluster_size,
            min_samples,
            &python,
            &out,
        ),
        BenchCommand::Graph {
            instances,
            window,
            out,
        } => graph_bench(&instances, window, &out),
        BenchCommand::Refer {
            instances,
            rounds,
            out,
        } => crate::bench_refer::refer_bench(&instances, rounds, &out),
        BenchCommand::Outputs {
            instances,
            gaussians,
            rounds,
            out,
        } => crate::bench_outputs::outputs_bench(&instances, &gaussians, rounds, &out),
        BenchCommand::Sweep {
            quick,
            split,
            scenes,
            first_index,
            rounds,
            only,
            out,
        } => {
            let scenes = if quick { 1 } else { scenes };
            let settings = crate::bench_sweep::chosen_settings(quick, &only)?;
            let files = crate::eval::split_scenes(&split, first_index, scenes)?;
            let mut reproduce = format!(
                "groupforward bench sweep --split {split} --scenes {scenes} --first-index {first_index} --rounds {rounds}"
            );
            if quick {
                reproduce += " --quick";
            }
            if !only.is_empty() {
                reproduce += &format!(" --only {}", only.join(","));
            }
            crate::bench_sweep::sweep(&files, &settings, rounds, &reproduce, &out)
        }
        BenchCommand::Soak {
            quick,
            messages,
            requests,
            flood_secs,
            camera_hz,
            query_hz,
            seed,
            out,
        } => {
            let (messages, requests, flood_secs) = if quick {
                (10_000, 500, 15.0)
            } else {
                (messages, requests, flood_secs)
            };
            crate::bench_soak::soak(
                &groupforward_harness::soak::SoakOptions {
                    scene: groupforward_sim::scene::SceneFile::builtin("two_chairs").ok_or_else(
                        || anyhow::anyhow!("the built-in two_chairs scene is missing"),
                    )?,
                    bad_messages: messages,
                    bad_requests: requests,
                    flood_secs,
                    camera_hz,
                    query_hz,
                    seed,
                },
                &out,
            )
        }
        BenchCommand::Dropout {
            levels,
            split,
            scenes,
            first_index,
            model,
            out,
        } => {
            if let Some(bad) = levels.iter().find(|l| !(0.0..=1.0).contains(*l)) {
                bail!("dropout level {bad} is not a probability");
            }
            let files = crate::eval::split_scenes(&split, first_index, scenes)?;
            dropout_bench(&levels, &files, model, &out)
        }
    }
}

fn as_ari_labels(labels: &[i32]) -> Vec<u32> {
    labels.iter().map(|&l| (l + 1) as u32).collect()
}

struct Reference {
    seconds: f64,
    labels: Vec<i32>,
    version: String,
}

fn python_reference(
    python: &str,
    dir: &Path,
    points: &[f32],
    dims: usize,
    min_cluster_size: usize,
    min_samples: usize,
) -> Result<Reference> {
    let input = dir.join("points.f32");
    let output = dir.join("labels.i32");
    let bytes: Vec<u8> = points.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(&input, bytes)?;
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../node/benches/hdbscan_reference.py");
    let result = std::process::Command::new(python)
        .arg(&script)
        .arg(&input)
        .arg(dims.to_string())
        .arg(min_cluster_size.to_string())
        .arg(min_samples.to_string())
        .arg(&output)
        .output()
        .with_context(|| format!("running {python} {}", script.display()))?;
    if !result.status.success() {
        bail!(
            "the Python reference failed: {}",
            String::from_utf8_lossy(&result.stderr)
        );
    }
    let report: serde_json::Value = serde_json::from_slice(&result.stdout)?;
    let labels = std::fs::read(&output)?
        .chunks_exact(4)
        .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok(Reference {
        seconds: report["seconds"].as_f64().unwrap_or(f64::NAN),
        labels,
        version: report["version"].as_str().unwrap_or("?").to_owned(),
    })
}

fn grouping(
    sizes: &[usize],
    dims: usize,
    centers: usize,
    min_cluster_size: usize,
    min_samples: usize,
    python: &str,
    out: &Path,
) -> Result<()> {
    if let Some(parent) = out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let scratch = tempfile::tempdir()?;
    let params = HdbscanParams {
        min_cluster_size,
        min_samples,
        allow_single_cluster: false,
    };
    let threads = rayon::current_num_threads();
    let mut csv = String::from(
        "points,dims,clusters_true,rust_seconds,rust_clusters,rust_noise,python_seconds,python_clusters,python_noise,speedup,ari_rust_python,ari_rust_truth,ari_python_truth\n",
    );
    let mut md = format!(
        "HDBSCAN on {dims}-d blobs ({centers} centres, min_cluster_size {min_cluster_size}, min_samples {min_samples}), {threads} threads, best of two fits each.\n\n\
         | points | groupforward (s) | Python hdbscan (s) | speed-up | ARI vs Python | ARI vs truth (ours / Python) |\n\
         | ---: | ---: | ---: | ---: | ---: | ---: |\n"
    );
    let mut version = String::from("not run");
    let (mut rust_series, mut python_series) = (Vec::new(), Vec::new());
    for &n in sizes {
        let (points, truth) = blobs(n, dims, centers, 1.0, n as u64);
        // Best of two runs, as for the Python side.
        let mut rust_seconds = f64::INFINITY;
        let mut ours = None;
        for _ in 0..2 {
            let started = Instant::now();
            let result = hdbscan(&points, dims, &params)?;
            rust_seconds = rust_seconds.min(started.elapsed().as_secs_f64());
            ours = Some(result);
        }
        let ours = ours.context("no run")?;
        let rust_noise = ours.labels.iter().filter(|l| **l < 0).count();
        let ari_truth = adjusted_rand_index(&as_ari_labels(&ours.labels), &truth)?;
        let reference = if python == "none" {
            None
        } else {
            Some(python_reference(
                python,
                scratch.path(),
                &points,
                dims,
                min_cluster_size,
                min_samples,
            )?)
        };
        let (py_seconds, py_clusters, py_noise, ari_pair, ari_py_truth) = match &reference {
            Some(r) => {
                version = r.version.clone();
                (
                    r.seconds,
                    r.labels.iter().copied().max().unwrap_or(-1) + 1,
                    r.labels.iter().filter(|l| **l < 0).count(),
                    adjusted_rand_index(&as_ari_labels(&ours.labels), &as_ari_labels(&r.labels))?,
                    adjusted_rand_index(&as_ari_labels(&r.labels), &truth)?,
                )
            }
            None => (f64::NAN, -1, 0, f64::NAN, f64::NAN),
        };
        let speedup = py_seconds / rust_seconds;
        rust_series.push((n as f64, rust_seconds));
        python_series.push((n as f64, py_seconds));
        csv.push_str(&format!(
            "{n},{dims},{centers},{rust_seconds:.4},{},{rust_noise},{py_seconds:.4},{py_clusters},{py_noise},{speedup:.2},{ari_pair:.5},{ari_truth:.5},{ari_py_truth:.5}\n",
            ours.n_clusters
        ));
        md.push_str(&format!(
            "| {n} | {rust_seconds:.3} | {py_seconds:.3} | {speedup:.1}× | {ari_pair:.4} | {ari_truth:.4} / {ari_py_truth:.4} |\n"
        ));
        eprintln!(
            "{n:>7} points: groupforward {rust_seconds:.3} s ({} clusters, {rust_noise} noise), Python {py_seconds:.3} s ({py_clusters} clusters, {py_noise} noise), {speedup:.1}x, ARI {ari_pair:.4}",
            ours.n_clusters
        );
    }
    md.push_str(&format!(
        "\nPython hdbscan {version}. Reproduce: `groupforward bench grouping`.\n"
    ));
    let svg_path = out.with_extension("svg");
    line_chart(
        &svg_path,
        &format!("HDBSCAN on {dims}-d blobs, {threads} threads"),
        "points",
        "seconds",
        &[
            ("groupforward", rust_series),
            ("Python hdbscan", python_series),
        ],
    )?;
    let csv_path = out.with_extension("csv");
    let md_path = out.with_extension("md");
    std::fs::File::create(&csv_path)?.write_all(csv.as_bytes())?;
    std::fs::File::create(&md_path)?.write_all(md.as_bytes())?;
    print!("{md}");
    println!(
        "wrote {}, {} and {}",
        csv_path.display(),
        md_path.display(),
        svg_path.display()
    );
    Ok(())
}

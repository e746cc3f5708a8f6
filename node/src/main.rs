//! The `groupforward` command line: `run`, `replay`, `model-check`, `sim`, `demo`.

mod bench_cli;
mod sim_cli;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use groupforward::config::Config;
use groupforward::replay::{replay, ReplayOptions};
use groupforward::transport::{open_session, ZenohTransport};

#[derive(Debug, Parser)]
#[command(
    name = "groupforward",
    version,
    about = "Referable 3D scene node over zenoh / ROS 2"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Clone, clap::Args)]
struct ZenohArgs {
    /// Node config (YAML); defaults are used where it is silent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Zenoh endpoints to connect to, replacing the config's (repeatable).
    #[arg(long)]
    connect: Vec<String>,
    /// Zenoh endpoints to listen on, replacing the config's (repeatable).
    #[arg(long)]
    listen: Vec<String>,
}

impl ZenohArgs {
    fn load(&self) -> Result<Config> {
        let mut config = match &self.config {
            Some(path) => Config::load(path)?,
            None => Config::default(),
        };
        if !self.connect.is_empty() {
            config.zenoh.connect = self.connect.clone();
        }
        if !self.listen.is_empty() {
            config.zenoh.listen = self.listen.clone();
        }
        Ok(config)
    }
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the node: subscribe to the configured cameras and TF, publish status.
    Run {
        #[command(flatten)]
        zenoh: ZenohArgs,
        /// Stop after this many seconds (default: run until interrupted).
        #[arg(long)]
        duration_secs: Option<f64>,
    },
    /// Publish a rosbag2 MCAP bag (a .mcap file or a bag directory) over zenoh.
    Replay {
        bag: PathBuf,
        #[command(flatten)]
        zenoh: ZenohArgs,
        /// Playback speed factor; 0 publishes as fast as possible.
        #[arg(long, default_value_t = 1.0)]
        rate: f64,
        /// Play the bag again and again until interrupted.
        #[arg(long = "loop")]
        repeat: bool,
        /// Seconds to wait before publishing, so subscribers can connect.
        #[arg(long, default_value_t = 0.5)]
        delay_secs: f64,
    },
    /// Check an ONNX model against its manifest (names, shapes, types) and print its contract.
    ModelCheck {
        /// The model's manifest, `models/<name>.toml`.
        manifest: PathBuf,
        /// ONNX Runtime library to load (default: `ORT_DYLIB_PATH`, then the project's `.venv`).
        #[arg(long)]
        onnxruntime: Option<PathBuf>,
    },
    /// The simulator: render a scene, record a bag, write a training dataset or a benchmark set.
    Sim {
        #[command(subcommand)]
        command: sim_cli::SimCommand,
    },
    /// Measurements written as CSV and Markdown (grouping against Python hdbscan, ...).
    Bench {
        #[command(subcommand)]
        command: bench_cli::BenchCommand,
    },
    /// End-to-end demo in one process: the simulator records a scene as a bag, the bag is
    /// replayed over an embedded zenoh peer into the node, and the node is queried.
    Demo {
        /// A scene file (TOML) or a procedural scene `<split>:<index>` (default: the built-in
        /// `two_chairs` scene).
        #[arg(long)]
        scene: Option<String>,
        /// Replay speed factor of the recorded bag.
        #[arg(long, default_value_t = 2.0)]
        rate: f64,
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh=warn,ort=warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Run {
            zenoh,
            duration_secs,
        } => {
            let config = zenoh.load()?;
            let session = open_session(&config.zenoh).context("opening the zenoh session")?;
            let transport = ZenohTransport::new(
                session,
                config.zenoh.domain_id,
                &config.node.namespace,
                &config.node.name,
            )?;
            let shutdown = Arc::new(AtomicBool::new(false));
            if let Some(secs) = duration_secs {
                let stop = shutdown.clone();
                std::thread::spawn(move || {
                    std::thread::sleep(std::time::Duration::from_secs_f64(secs));
                    stop.store(true, Ordering::Relaxed);
                });
            }
            // Models are optional until their stages land: report what is usable, keep running.
            match groupforward::model::init_runtime(config.models.onnxruntime.as_deref()) {
                Ok(library) => tracing::info!("ONNX Runtime loaded from {}", library.display()),
                Err(e) => tracing::error!("models unavailable: {e}"),
            }
            let status = groupforward::node::run(&config, &transport, &shutdown)?;
            println!("{}", serde_json::to_string(&status)?);
        }
        Command::Replay {
            bag,
            zenoh,
            rate,
            repeat,
            delay_secs,
        } => {
            let config = zenoh.load()?;
            let session = open_session(&config.zenoh).context("opening the zenoh session")?;
            let transport =
                ZenohTransport::new(session, config.zenoh.domain_id, "/", "groupforward_replay")?;
            std::thread::sleep(std::time::Duration::from_secs_f64(delay_secs.max(0.0)));
            let options = ReplayOptions {
                rate,
                loops: if repeat { 0 } else { 1 },
                progress: true,
            };
            let summary = replay(&bag, &transport, options)
                .with_context(|| format!("replaying {}", bag.display()))?;
            eprintln!(
                "replayed {} messages in {:.2} s",
                summary.published,
                summary.elapsed.as_secs_f64()
            );
            for (topic, (count, reason)) in &summary.skipped {
                eprintln!("skipped {count} messages on {topic}: {reason}");
            }
        }
        Command::ModelCheck {
            manifest,
            onnxruntime,
        } => {
            let library = groupforward::model::init_runtime(onnxruntime.as_deref())?;
            let loaded = groupforward::model::manifest::Manifest::load(&manifest)?;
            let session = groupforward::model::open_session(
                &loaded.model_path(),
                &groupforward::model::SessionOptions::default(),
            )?;
            loaded.check(&session)?;
            println!(
                "{}: {} matches its manifest ({:?}{}; ONNX Runtime {})",
                manifest.display(),
                loaded.model_path().display(),
                loaded.kind,
                if loaded.fixture { ", test fixture" } else { "" },
                library.display()
            );
        }
        Command::Sim { command } => sim_cli::run(command)?,
        Command::Bench { command } => bench_cli::run(command)?,
        Command::Demo { scene, rate } => {
            let mut options = groupforward::demo::DemoOptions {
                rate,
                ..Default::default()
            };
            if let Some(spec) = scene {
                options.scene = sim_cli::load_scene(&spec)?;
            }
            let report = groupforward::demo::run_demo(&options).context("running the demo")?;
            print_report(&report);
        }
    }
    Ok(())
}

fn print_report(report: &groupforward::demo::DemoReport) {
    println!(
        "groupforward demo: sim scene -> rosbag2 bag -> replay over an embedded zenoh peer -> node"
    );
    println!(
        "  scene `{}`: recorded {} frames ({} dropped), {} messages incl. /gt/... ground truth; replayed {}",
        report.scene,
        report.recorded.frames,
        report.recorded.dropped,
        report.recorded.messages,
        report.replayed_messages
    );
    for camera in &report.status.cameras {
        println!(
            "  camera {:<8} received {:>4}  synced {:>4}  rejected {:>3}",
            camera.name, camera.frames_received, camera.frames_synced, camera.frames_rejected
        );
    }
    println!(
        "  tf: {} transforms accepted, {} rejected; {} malformed messages published on purpose",
        report.status.tf_received, report.status.tf_rejected, report.malformed_published
    );
    for rejection in &report.status.rejections {
        println!("  rejected {:>3} x {}", rejection.count, rejection.reason);
    }
    if report.instances.is_empty() {
        println!("  list_instances service answered: no instances (no reconstruction model loaded, see the log)");
    } else {
        println!(
            "  list_instances service answered: {} instances (persistent id, best name and score from the semantic model, box centre and size, Gaussians; nearest ground-truth object):",
            report.instances.len()
        );
        for instance in &report.instances {
            let p = &instance.pose.position;
            let nearest = report
                .objects
                .iter()
                .map(|(id, class, q)| {
                    let d = ((p.x - q[0]).powi(2) + (p.y - q[1]).powi(2)).sqrt();
                    (d, id, class)
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let nearest = nearest.map_or(String::new(), |(d, id, class)| {
                format!("#{id} {class} ({d:.2} m)")
            });
            let name = instance
                .hypotheses
                .first()
                .map_or("(unnamed)".to_owned(), |h| {
                    format!("{} {:.2}", h.class_id, h.score)
                });
            println!(
                "    {} {name:<18} at ({:.2}, {:.2}, {:.2}) size {:.2}x{:.2}x{:.2} m, {:>5} Gaussians; {nearest}",
                instance.id,
                p.x,
                p.y,
                p.z,
                instance.size.x,
                instance.size.y,
                instance.size.z,
                instance.point_count
            );
        }
    }
    println!("  ground truth ({} objects):", report.objects.len());
    for (id, class, p) in &report.objects {
        println!(
            "    #{id:<3} {class:<12} at ({:.2}, {:.2}, {:.2})",
            p[0], p[1], p[2]
        );
    }
    println!("  referring expressions generated from ground truth (one per relation type):");
    for e in &report.expressions {
        let view = e.view.map_or(String::new(), |v| {
            format!("  [seen from frame {}]", v.frame)
        });
        println!("    {:<48} -> {:?}{view}", e.text, e.targets);
    }
    match &report.vocabulary {
        Ok(matches) => {
            println!("  open vocabulary (all-MiniLM-L6-v2 int8 via ONNX Runtime), phrase -> sim class by name, description or affordance:");
            for (query, class, score) in matches {
                println!("    {query:<26} -> {class:<12} (cosine {score:.2})");
            }
        }
        Err(e) => println!("  text encoder unavailable: {e}"),
    }
    println!("  finished in {:.1} s", report.elapsed.as_secs_f64());
}

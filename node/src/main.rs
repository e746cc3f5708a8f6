//! The `groupforward` command line: `run`, `replay`, `demo`.

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
    /// Render one frame of a scene file: RGB, depth (16-bit mm), instance and class ids (16-bit) as
    /// PNGs, plus a side-by-side preview.
    SimRender {
        scene: PathBuf,
        /// Frame of the trajectory.
        #[arg(long, default_value_t = 0)]
        frame: usize,
        /// Output directory.
        #[arg(long, default_value = "sim_render")]
        out: PathBuf,
    },
    /// End-to-end demo in one process: simulated camera → node → status and services.
    Demo {
        /// Frames the simulated camera publishes.
        #[arg(long, default_value_t = 30)]
        frames: u64,
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh=warn")),
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
        Command::SimRender { scene, frame, out } => sim_render(&scene, frame, &out)?,
        Command::Demo { frames } => {
            let options = groupforward::demo::DemoOptions {
                frames,
                ..Default::default()
            };
            let report = groupforward::demo::run_demo(&options).context("running the demo")?;
            print_report(&report);
        }
    }
    Ok(())
}

fn sim_render(scene_path: &std::path::Path, frame: usize, out: &std::path::Path) -> Result<()> {
    use groupforward_sim::scene::{camera_pose, pinhole, SceneFile};
    let file = SceneFile::load(scene_path)?;
    let scene = file.build()?;
    let poses = file.robot_poses()?;
    let pose = poses
        .get(frame)
        .with_context(|| format!("the trajectory has {} frames", poses.len()))?;
    std::fs::create_dir_all(out)?;
    for camera in &file.cameras {
        let (rotation, position) = camera_pose(camera, pose);
        let view = groupforward_sim::render::render(&scene, &pinhole(camera), rotation, position);
        let (w, h) = (view.width, view.height);
        let rgb = image::RgbImage::from_raw(w, h, view.rgb.clone()).context("rgb size")?;
        let millimetres: Vec<u16> = view
            .depth
            .iter()
            .map(|d| (d * 1000.0).round().clamp(0.0, 65535.0) as u16)
            .collect();
        let depth = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, millimetres)
            .context("depth size")?;
        let instance =
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, view.instance.clone())
                .context("instance size")?;
        let class = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, view.class.clone())
            .context("class size")?;
        let stem = format!("{}_{frame:04}_{}", file.name, camera.name);
        rgb.save(out.join(format!("{stem}_rgb.png")))?;
        depth.save(out.join(format!("{stem}_depth_mm.png")))?;
        instance.save(out.join(format!("{stem}_instance.png")))?;
        class.save(out.join(format!("{stem}_class.png")))?;
        // Preview: RGB | depth (near bright) | instances in distinct colours.
        let max_depth = view.depth.iter().copied().fold(0.0f32, f32::max).max(1e-3);
        let mut preview = image::RgbImage::new(3 * w, h);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                preview.put_pixel(x, y, *rgb.get_pixel(x, y));
                let d = (255.0 * (1.0 - view.depth[i] / max_depth)) as u8;
                preview.put_pixel(w + x, y, image::Rgb([d, d, d]));
                let id = u32::from(view.instance[i]);
                let color = if id == 0 {
                    [0, 0, 0]
                } else {
                    [
                        (id * 97 % 200 + 55) as u8,
                        (id * 53 % 200 + 55) as u8,
                        (id * 151 % 200 + 55) as u8,
                    ]
                };
                preview.put_pixel(2 * w + x, y, image::Rgb(color));
            }
        }
        preview.save(out.join(format!("{stem}_preview.png")))?;
        println!(
            "wrote {}/{stem}_{{rgb,depth_mm,instance,class,preview}}.png",
            out.display()
        );
    }
    Ok(())
}

fn print_report(report: &groupforward::demo::DemoReport) {
    println!("groupforward demo: simulated camera -> node over an embedded zenoh peer");
    println!(
        "  published: {} frames (rgb8 + 32FC1 depth + CameraInfo + TF), {} malformed messages",
        report.frames_published, report.malformed_published
    );
    for camera in &report.status.cameras {
        println!(
            "  camera {:<8} received {:>4}  synced {:>4}  rejected {:>3}",
            camera.name, camera.frames_received, camera.frames_synced, camera.frames_rejected
        );
    }
    println!(
        "  tf: {} transforms accepted, {} rejected",
        report.status.tf_received, report.status.tf_rejected
    );
    for rejection in &report.status.rejections {
        println!("  rejected {:>3} x {}", rejection.count, rejection.reason);
    }
    println!(
        "  list_instances service answered: {} instances (grouping is not built yet)",
        report.instances
    );
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

//! `groupforward run`: the node on its middleware (a zenoh session, or native ROS 2 in a build
//! with the `ros2` feature) until interrupted (or for a set time).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{Context, Result};
use groupforward::node::open_transport;
use groupforward::record::{Recorder, RecordingTransport};

use crate::zenoh_args::ZenohArgs;

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    #[command(flatten)]
    zenoh: ZenohArgs,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long)]
    duration_secs: Option<f64>,
    /// Also write every topic the node publishes to a rosbag2 bag directory (MCAP +
    /// metadata.yaml), closed when the node stops (Ctrl-C, SIGTERM or --duration-secs).
    #[arg(long, value_name = "DIR")]
    record_outputs: Option<std::path::PathBuf>,
}

pub fn run(args: RunArgs) -> Result<()> {
    let config = args.zenoh.load()?;
    let transport = open_transport(&config).context("opening the node's transport")?;
    let transport = transport.as_ref();
    let shutdown = Arc::new(AtomicBool::new(false));
    if let Some(secs) = args.duration_secs {
        let stop = shutdown.clone();
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_secs_f64(secs));
            stop.store(true, Ordering::Relaxed);
        });
    }
    // Models are optional: report what is usable, keep running.
    match groupforward::model::init_runtime(config.models.onnxruntime.as_deref()) {
        Ok(library) => tracing::info!("ONNX Runtime loaded from {}", library.display()),
        Err(e) => tracing::error!("models unavailable: {e}"),
    }
    stop_on_signal(&shutdown);
    let status = match &args.record_outputs {
        Some(dir) => {
            let recorder = Recorder::create(dir)?;
            let recording = RecordingTransport {
                inner: transport,
                recorder: recorder.clone(),
            };
            let status = groupforward::node::run(&config, &recording, &shutdown)?;
            let messages = recorder.finish()?;
            tracing::info!("recorded {messages} messages to {}", dir.display());
            status
        }
        None => groupforward::node::run(&config, transport, &shutdown)?,
    };
    println!("{}", serde_json::to_string(&status)?);
    Ok(())
}

/// Ctrl-C or SIGTERM stop the node cleanly (the map and a recorded bag are closed), as a ROS
/// node stops under `ros2 launch`.
fn stop_on_signal(shutdown: &Arc<AtomicBool>) {
    let stop = shutdown.clone();
    std::thread::spawn(move || {
        let Ok(runtime) = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        else {
            return;
        };
        runtime.block_on(async {
            #[cfg(unix)]
            {
                use tokio::signal::unix::{signal, SignalKind};
                match signal(SignalKind::terminate()) {
                    Ok(mut terminate) => {
                        tokio::select! {
                            _ = tokio::signal::ctrl_c() => {}
                            _ = terminate.recv() => {}
                        }
                    }
                    Err(_) => {
                        let _ = tokio::signal::ctrl_c().await;
                    }
                }
            }
            #[cfg(not(unix))]
            {
                let _ = tokio::signal::ctrl_c().await;
            }
        });
        stop.store(true, Ordering::Relaxed);
    });
}

//! `groupforward run`: the node on a zenoh session until interrupted (or for a set time).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{Context, Result};
use groupforward::transport::{open_session, ZenohTransport};

use crate::zenoh_args::ZenohArgs;

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    #[command(flatten)]
    zenoh: ZenohArgs,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long)]
    duration_secs: Option<f64>,
}

pub fn run(args: RunArgs) -> Result<()> {
    let config = args.zenoh.load()?;
    let session = open_session(&config.zenoh).context("opening the zenoh session")?;
    let transport = ZenohTransport::new(
        session,
        config.zenoh.domain_id,
        &config.node.namespace,
        &config.node.name,
    )?;
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
    let status = groupforward::node::run(&config, &transport, &shutdown)?;
    println!("{}", serde_json::to_string(&status)?);
    Ok(())
}

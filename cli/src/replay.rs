//! `groupforward replay`: publish a rosbag2 MCAP bag as a live robot would, over zenoh or (a build
//! with the `ros2` feature, `--transport ros2`) into the ROS 2 graph.

use std::path::PathBuf;

use anyhow::{Context, Result};
use groupforward::node::open_transport;
use groupforward::replay::{replay, ReplayOptions};

use crate::zenoh_args::ZenohArgs;

#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
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
}

pub fn run(args: ReplayArgs) -> Result<()> {
    let mut config = args.zenoh.load()?;
    config.node.namespace = "/".into();
    config.node.name = "groupforward_replay".into();
    let transport = open_transport(&config).context("opening the transport")?;
    std::thread::sleep(std::time::Duration::from_secs_f64(args.delay_secs.max(0.0)));
    let options = ReplayOptions {
        rate: args.rate,
        loops: if args.repeat { 0 } else { 1 },
        progress: true,
    };
    let summary = replay(&args.bag, transport.as_ref(), options)
        .with_context(|| format!("replaying {}", args.bag.display()))?;
    eprintln!(
        "replayed {} messages in {:.2} s",
        summary.published,
        summary.elapsed.as_secs_f64()
    );
    for (topic, (count, reason)) in &summary.skipped {
        eprintln!("skipped {count} messages on {topic}: {reason}");
    }
    Ok(())
}

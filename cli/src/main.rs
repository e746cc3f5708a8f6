//! The `groupforward` command line: one file per subcommand; the library holds the stages and
//! the node, this binary wires them up.

mod bench;
mod bench_outputs;
mod bench_refer;
mod bench_soak;
mod bench_support;
mod bench_sweep;
mod demo;
mod eval;
mod eval_all;
mod eval_baseline;
mod eval_command;
mod eval_identity;
mod eval_refer;
mod eval_window;
mod model_check;
mod query;
mod replay;
mod run;
mod sim;
mod zenoh_args;

use anyhow::Result;
use clap::{Parser, Subcommand};

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

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the node: subscribe to the configured cameras and TF, build the instance map, serve it.
    Run(run::RunArgs),
    /// Ask a running node a referring question through its `Refer` service.
    Query(query::QueryArgs),
    /// Publish a rosbag2 MCAP bag (a .mcap file or a bag directory) over zenoh.
    Replay(replay::ReplayArgs),
    /// Check an ONNX model against its manifest (names, shapes, types) and print its contract.
    ModelCheck(model_check::ModelCheckArgs),
    /// The simulator: render a scene, record a bag, write a training dataset or a benchmark set.
    Sim {
        #[command(subcommand)]
        command: sim::SimCommand,
    },
    /// Measurements written as CSV and Markdown (grouping against Python hdbscan, ...).
    Bench {
        #[command(subcommand)]
        command: bench::BenchCommand,
    },
    /// Evaluations against the simulator's ground truth: `map`, `window`, `refer`, or `all`.
    Eval {
        #[command(subcommand)]
        command: eval_command::EvalCommand,
    },
    /// End-to-end demo in one process: the simulator records a scene as a bag, the bag is
    /// replayed over an embedded zenoh peer into the node, and the node is queried.
    Demo(demo::DemoArgs),
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    // The demo, eval and bench print summaries: node logs below WARN only with RUST_LOG.
    let default_filter = match cli.command {
        Command::Demo(_) | Command::Eval { .. } | Command::Bench { .. } | Command::Query(_) => {
            "warn,zenoh=warn,ort=warn"
        }
        _ => "info,zenoh=warn,ort=warn",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter)),
        )
        .with_writer(std::io::stderr)
        .init();
    match cli.command {
        Command::Run(args) => run::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Query(args) => query::run(args),
        Command::ModelCheck(args) => model_check::run(args),
        Command::Sim { command } => sim::run(command),
        Command::Bench { command } => bench::run(command),
        Command::Eval { command } => eval_command::run(command),
        Command::Demo(args) => demo::run(args),
    }
}

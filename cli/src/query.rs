//! `groupforward query "the chair closest to the lamp"`: ask a running node through its `Refer`
//! service over zenoh, as any ROS 2 client on rmw_zenoh would, and print the answer (exit status
//! 1 when the node answers with a refusal).

use std::time::Duration;

use anyhow::{Context, Result};
use groupforward::client::call_service;
use groupforward::transport::open_session;
use groupforward_msgs::gf_msgs::{ReferRequest, ReferResponse};
use groupforward_msgs::rmw_zenoh::resolve_name;
use groupforward_msgs::services::Refer;

use crate::zenoh_args::ZenohArgs;

#[derive(Debug, clap::Args)]
pub struct QueryArgs {
    /// The referring expression.
    expression: String,
    #[command(flatten)]
    zenoh: ZenohArgs,
    /// At most this many instances (0: as many as the expression asks for).
    #[arg(long, default_value_t = 0)]
    max_targets: u32,
    /// `builtin` or `vlm` (default: the node's).
    #[arg(long, default_value = "")]
    reasoner: String,
    /// Seconds to wait for the answer.
    #[arg(long, default_value_t = 10.0)]
    timeout_secs: f64,
}

pub fn run(args: QueryArgs) -> Result<()> {
    let config = args.zenoh.load()?;
    if config.transport == groupforward::transport::TransportKind::Ros2 {
        anyhow::bail!(
            "`query` asks over zenoh; on ROS 2 call the service: ros2 service call \
             /groupforward/refer groupforward_msgs/srv/Refer \"{{expression: 'the trash bin'}}\""
        );
    }
    let session = open_session(&config.zenoh).context("opening the zenoh session")?;
    let service = resolve_name(&config.node.namespace, &config.node.name, "~/refer")?;
    let request = ReferRequest {
        expression: args.expression.clone(),
        max_targets: args.max_targets,
        reasoner: args.reasoner,
        ..ReferRequest::default()
    };
    let answer: ReferResponse = call_service::<Refer>(
        &session,
        config.zenoh.domain_id,
        &service,
        &request,
        Duration::from_secs_f64(args.timeout_secs),
    )
    .with_context(|| format!("calling {service}"))?;
    print_answer(&args.expression, &answer);
    // Scripts can tell an answer from a refusal by the exit status.
    if !answer.success {
        std::process::exit(1);
    }
    Ok(())
}

/// The answer as a few readable lines.
pub fn print_answer(expression: &str, answer: &ReferResponse) {
    println!("{expression:?}");
    if !answer.success {
        println!("  no answer: {}", answer.message);
        return;
    }
    for ((id, confidence), b) in answer
        .instance_ids
        .iter()
        .zip(&answer.confidences)
        .zip(&answer.boxes)
    {
        let (c, s) = (&b.center.position, &b.size);
        println!(
            "  {id}  confidence {confidence:.2}  centre ({:.2}, {:.2}, {:.2}) m  size {:.2} x {:.2} x {:.2} m",
            c.x, c.y, c.z, s.x, s.y, s.z
        );
    }
    println!(
        "  {} target points, masks in {} views, reasoner {}",
        answer.target_cloud.width,
        answer.view_masks.len(),
        answer.reasoner_used
    );
    println!("  candidates:");
    for c in &answer.candidates {
        println!(
            "    {}  {:<12} score {:.2} (semantic {:.2}, geometric {:.2}, visibility {:.2})",
            c.id, c.label, c.score, c.semantic_score, c.geometric_score, c.visibility_score
        );
    }
    println!("  why: {}", answer.trace);
}

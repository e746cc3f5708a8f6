//! `groupforward demo`: the in-process demo ([`groupforward_harness::demo`]) on a scene, and its summary.

use anyhow::{Context, Result};
use groupforward::node::WINDOW_BUSY;
use groupforward::timing::{describe, Stage, StageSummary};
use groupforward_harness::demo::{run_demo, DemoOptions, DemoReport};
use groupforward_msgs::gf_msgs::StageTiming;
use groupforward_sim::effects::Preset;

use crate::sim::load_scene;

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// A scene file (TOML) or a procedural scene `<split>:<index>` (default: the built-in
    /// `two_chairs` scene).
    #[arg(long)]
    scene: Option<String>,
    /// Replay speed factor of the recorded bag: 1 is as the camera recorded it (a window every
    /// 0.4 s on `two_chairs`; a 2-core machine's window pass takes about 0.3 s). Faster rates drop
    /// windows that arrive while the pass is busy (counted in the status: window_dropped_busy).
    #[arg(long, default_value_t = 1.0)]
    rate: f64,
    /// Replace the scene's effects by a preset: `clean`, `realistic` (a consumer depth camera on
    /// a moving robot), `dropout:<p>`.
    #[arg(long)]
    effects: Option<String>,
    /// Also write every topic the node publishes to a rosbag2 bag directory (MCAP +
    /// metadata.yaml), e.g. to open the run in Foxglove.
    #[arg(long, value_name = "DIR")]
    record_outputs: Option<std::path::PathBuf>,
}

pub fn run(args: DemoArgs) -> Result<()> {
    let mut options = DemoOptions {
        rate: args.rate,
        record_outputs: args.record_outputs,
        ..Default::default()
    };
    if let Some(spec) = args.scene {
        options.scene = load_scene(&spec)?;
    }
    if let Some(name) = &args.effects {
        let preset = Preset::parse(name).map_err(anyhow::Error::msg)?;
        options.scene.apply_preset(preset);
    }
    let report = run_demo(&options).context("running the demo")?;
    print_report(&report);
    Ok(())
}

/// Where the node's time went, from its status message.
fn stages_line(stages: &[StageTiming]) -> Option<String> {
    let summaries: Vec<StageSummary> = stages
        .iter()
        .filter_map(|s| {
            Some(StageSummary {
                stage: Stage::from_name(&s.stage)?,
                count: s.count,
                last_ms: s.last_ms,
                p50_ms: s.p50_ms,
                p99_ms: s.p99_ms,
            })
        })
        .collect();
    (!summaries.is_empty())
        .then(|| format!("  time, window -> map update: {}", describe(&summaries)))
}

fn print_report(report: &DemoReport) {
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
        if camera.depth_pixels > 0 {
            println!(
                "  camera {:<8} depth: {} of {} pixels invalid ({:.1}%: no measurement, out of range or isolated), lifted only where the model's depth continues a measured neighbour, at its depth",
                camera.name,
                camera.depth_pixels_invalid,
                camera.depth_pixels,
                100.0 * camera.depth_pixels_invalid as f64 / camera.depth_pixels as f64
            );
        }
    }
    if let Some(line) = stages_line(&report.status.stages) {
        let dropped = report
            .status
            .rejections
            .iter()
            .find(|r| r.reason == WINDOW_BUSY)
            .map_or(0, |r| r.count);
        println!("{line}; {dropped} windows dropped while the pass was busy");
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
    let s = report.map_score.summary();
    let c = &report.map_score;
    println!(
        "  the list against ground truth (eval map's yardstick, 3D IoU of boxes): {} of {} objects found at IoU >= 0.25, {} at >= 0.5; {} of {} listed instances are objects, {} named right; {} room-sized",
        c.found_25,
        c.objects_scored,
        c.found_50,
        c.instances_true,
        c.instances_listed,
        c.names_correct,
        s.room_instances
    );
    println!("  ground truth ({} objects):", report.objects.len());
    for (id, class, p) in &report.objects {
        println!(
            "    #{id:<3} {class:<12} at ({:.2}, {:.2}, {:.2})",
            p[0], p[1], p[2]
        );
    }
    let right = report
        .answers
        .iter()
        .filter(|a| a.response.success && a.answered == a.expression.targets)
        .count();
    println!(
        "  refer service: {right} of {} expressions generated from ground truth (one per relation type) answered with exactly their objects (round trip incl. rendering and writing each answer's evidence bundle):",
        report.answers.len()
    );
    for a in &report.answers {
        let e = &a.expression;
        let view = e
            .view
            .map_or(String::new(), |v| format!(" [seen from frame {}]", v.frame));
        let verdict = if !a.response.success {
            format!("no answer: {}", a.response.message)
        } else {
            let ids: Vec<String> = a
                .response
                .instance_ids
                .iter()
                .zip(&a.answered)
                .map(|(id, object)| format!("{id} (#{object})"))
                .collect();
            let mark = if a.answered == e.targets {
                "right"
            } else {
                "wrong"
            };
            format!("{} {mark}", ids.join(", "))
        };
        println!(
            "    {:<44} truth {:?} -> {verdict}; {:.0} ms{view}",
            e.text, e.targets, a.millis
        );
    }
    let overview = report.answers.iter().find(|a| a.response.success).map(|a| {
        report.evidence_dir.join(format!(
            "{}_overview.png",
            groupforward::refer::evidence::stem(&a.expression.text)
        ))
    });
    if let Some(path) = overview.filter(|p| p.exists()) {
        println!(
            "  evidence the reasoner saw (candidates numbered, the answer outlined heavier): {}",
            path.display()
        );
    }
    print_published(&report.published, report.recorded_outputs);
    match &report.vocabulary {
        Ok(matches) => {
            println!("  open vocabulary (all-MiniLM-L6-v2 int8 via ONNX Runtime), phrase -> sim class by name, description or affordance:");
            for (query, class, score) in matches {
                println!("    {query:<26} -> {class:<12} (cosine {score:.2})");
            }
        }
        Err(e) => println!("  text encoder unavailable: {e}"),
    }
    match &report.saved_map {
        Ok((file, hash)) => println!(
            "  save_map service wrote {} (map content hash {hash})",
            file.display()
        ),
        Err(why) => println!("  save_map service failed: {why}"),
    }
    println!("  finished in {:.1} s", report.elapsed.as_secs_f64());
}

/// What a subscriber of the node's output topics received: one line per topic.
fn print_published(p: &groupforward_harness::demo::PublishedOutputs, recorded: Option<u64>) {
    println!(
        "  published topics, as a subscriber (RViz, a navigation stack) received them (map frame; messages, bytes; the last message):",
    );
    let traffic = |topic: &str| {
        let (messages, bytes) = p
            .traffic
            .get(&format!("/groupforward/{topic}"))
            .copied()
            .unwrap_or_default();
        format!(
            "~/{topic:<15} {messages:>3} msgs {:>8.1} kB",
            bytes as f64 / 1e3
        )
    };
    match &p.detections {
        Some(d) => println!(
            "    {} vision_msgs/Detection3DArray: {} detections (id, class hypotheses, oriented box)",
            traffic("instances"),
            d.detections.len()
        ),
        None => println!("    {} nothing received", traffic("instances")),
    }
    if let Some(a) = &p.instance_array {
        println!(
            "    {} groupforward_msgs/InstanceArray: {} instances ({} Gaussians)",
            traffic("instance_array"),
            a.instances.len(),
            a.instances
                .iter()
                .map(|i| u64::from(i.point_count))
                .sum::<u64>()
        );
    }
    if let Some(c) = &p.cloud {
        let ids: std::collections::BTreeSet<[u8; 4]> = c
            .data
            .chunks_exact(c.point_step.max(1) as usize)
            .filter_map(|point| point.get(16..20)?.try_into().ok())
            .collect();
        println!(
            "    {} sensor_msgs/PointCloud2: {} points of {} instances (x, y, z, rgb, instance_id)",
            traffic("instance_cloud"),
            c.width,
            ids.len()
        );
    }
    if !p.masks.is_empty() {
        let labelled: usize = p
            .masks
            .iter()
            .map(|m| m.mask.data.chunks_exact(2).filter(|v| v != &[0, 0]).count())
            .sum();
        let pixels: usize = p.masks.iter().map(|m| m.mask.data.len() / 2).sum();
        let cameras: std::collections::BTreeSet<&str> =
            p.masks.iter().map(|m| m.camera.as_str()).collect();
        println!(
            "    {} groupforward_msgs/InstanceMasks: one per view (mono16, cameras {:?}), {:.0}% of pixels on an instance",
            traffic("instance_masks"),
            cameras,
            100.0 * labelled as f64 / pixels.max(1) as f64
        );
    }
    if let Some(m) = &p.markers {
        use groupforward::outputs::{BOX_NAMESPACE, EDGE_NAMESPACE, LABEL_NAMESPACE};
        let added = |ns: &str| {
            m.markers
                .iter()
                .filter(|m| m.ns == ns && m.action == 0)
                .map(|m| m.points.len().max(1) / if ns == EDGE_NAMESPACE { 2 } else { 1 })
                .sum::<usize>()
        };
        println!(
            "    {} visualization_msgs/MarkerArray: {} boxes, {} labels, {} edge lines, {} deletions",
            traffic("markers"),
            added(BOX_NAMESPACE),
            added(LABEL_NAMESPACE),
            added(EDGE_NAMESPACE),
            m.markers.iter().filter(|m| m.action == 2).count()
        );
    }
    if let Some(g) = &p.scene_graph {
        println!(
            "    {} groupforward_msgs/SceneGraph: {} nodes, {} edges (also JSON: the scene_graph API)",
            traffic("scene_graph"),
            g.nodes.len(),
            g.edges.len()
        );
    }
    if let Some(messages) = recorded {
        println!("    recorded to a rosbag2 bag (--record-outputs): {messages} messages");
    }
}

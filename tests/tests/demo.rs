#![allow(clippy::unwrap_used)]
//! The demo end to end: a sim-recorded bag replayed over zenoh reaches the node frame for frame,
//! malformed input is counted, and the node answers the scene's referring expressions through its
//! `Refer` service; a subscriber of its output topics receives the same map.

use std::collections::BTreeSet;

use groupforward::refer::response::numeric_id;
use groupforward_harness::demo::{run_demo, DemoOptions};
use groupforward_msgs::visualization_msgs::Marker;

#[test]
fn the_demo_replays_a_sim_recorded_bag_into_the_node() {
    let mut options = DemoOptions {
        rate: 4.0,
        ..DemoOptions::default()
    };
    options.scene.cameras[0].width = 160;
    options.scene.cameras[0].height = 120;
    let report = run_demo(&options).unwrap();
    let camera = &report.status.cameras[0];
    let expected = (report.recorded.frames - report.recorded.dropped) as u64;
    assert_eq!(camera.frames_received, expected);
    assert_eq!(camera.frames_synced, expected);
    assert_eq!(camera.frames_rejected, 1, "the truncated image");
    assert_eq!(report.status.tf_rejected, 1, "the NaN transform");
    assert_eq!(report.replayed_messages, report.recorded.messages);
    assert_eq!(report.objects.len(), 5);
    // The worker computed keyframes' semantic features ahead of their windows, and the status
    // says where the time went.
    let stage = |name: &str| report.status.stages.iter().find(|s| s.stage == name);
    assert!(
        stage("keyframe").is_some_and(|s| s.count >= 1),
        "{:?}",
        report.status.stages
    );
    assert!(stage("window").is_some_and(|s| s.count >= 1 && s.p50_ms > 0.0));
    // The shipped reconstruction model ran: window passes produced persistent instances.
    assert!(!report.instances.is_empty());
    assert!(report
        .instances
        .iter()
        .all(|i| i.id.starts_with("inst_") && i.point_count > 0));
    // The shipped semantic model ran: every instance is named from the vocabulary, best first,
    // with softmax scores. Walls and floor (`other`) are structure, kept out of the object list,
    // and no listed box is room-sized.
    let vocabulary = groupforward::group::semantics::default_vocabulary();
    for instance in &report.instances {
        assert_eq!(instance.hypotheses.len(), 3, "{}", instance.id);
        assert!(instance
            .hypotheses
            .iter()
            .all(|h| vocabulary.contains(&h.class_id) && (0.0..=1.0).contains(&h.score)));
        assert!(instance
            .hypotheses
            .windows(2)
            .all(|w| w[0].score >= w[1].score));
        assert_ne!(
            instance.hypotheses[0].class_id,
            groupforward::group::semantics::OTHER_PHRASE,
            "{}",
            instance.id
        );
        assert!(
            instance.size.x * instance.size.y < 0.4 * 6.0 * 5.0,
            "{} is room-sized: {:?}",
            instance.id,
            instance.size
        );
    }
    // Scored as `eval map` scores a map: no room-sized instance, and objects found where they are
    // (at 160x120 and with windows dropped while the worker is busy, fewer than `eval map` finds).
    let score = report.map_score.summary();
    assert_eq!(score.room_instances, 0);
    assert!(report.map_score.found_25 >= 2, "{score:?}");
    // Referring questions went through the `Refer` service over zenoh: every one came back, with
    // the expression's instances (boxes, poses, Gaussians) or a reason; answers are closed-set
    // (only candidates) and carry every candidate's scores.
    assert!(report.answers.len() >= 5);
    let mut answered = 0;
    for a in &report.answers {
        let e = &a.expression;
        assert!(e
            .targets
            .iter()
            .all(|t| report.objects.iter().any(|o| o.0 == *t)));
        let r = &a.response;
        if !r.success {
            assert!(!r.message.is_empty(), "{}", e.text);
            continue;
        }
        answered += 1;
        assert_eq!(r.reasoner_used, "builtin");
        assert_eq!(r.boxes.len(), r.instance_ids.len());
        assert_eq!(r.poses.len(), r.instance_ids.len());
        assert!(r.target_cloud.width > 0, "{}", e.text);
        assert!(r
            .instance_ids
            .iter()
            .all(|id| r.candidates.iter().any(|c| &c.id == id)));
        assert!(r
            .candidates
            .iter()
            .all(|c| c.score.is_finite() && (0.0..=1.0).contains(&c.semantic_score)));
    }
    assert!(answered >= 3, "{answered} answers");

    // What a subscriber of the output topics received describes the same map, by the same ids.
    let p = &report.published;
    let listed: BTreeSet<&str> = report.instances.iter().map(|i| i.id.as_str()).collect();
    let detections = p.detections.as_ref().expect("~/instances received");
    assert_eq!(detections.header.frame_id, "map");
    let detected: BTreeSet<&str> = detections
        .detections
        .iter()
        .map(|d| d.id.as_str())
        .collect();
    assert_eq!(detected, listed);
    for d in &detections.detections {
        let listed = report.instances.iter().find(|i| i.id == d.id).unwrap();
        assert_eq!(d.bbox.center, listed.pose, "{}", d.id);
        assert_eq!(d.bbox.size, listed.size, "{}", d.id);
    }
    let array = p
        .instance_array
        .as_ref()
        .expect("~/instance_array received");
    assert_eq!(array.instances, report.instances);
    let numeric: BTreeSet<u32> = listed.iter().map(|id| numeric_id(id)).collect();
    let cloud = p.cloud.as_ref().expect("~/instance_cloud received");
    let total: u32 = report.instances.iter().map(|i| i.point_count).sum();
    assert_eq!(
        cloud.width, total,
        "every listed Gaussian, within the point budget"
    );
    let cloud_ids: BTreeSet<u32> = cloud
        .data
        .chunks_exact(cloud.point_step as usize)
        .map(|point| u32::from_le_bytes(point[16..20].try_into().unwrap()))
        .collect();
    assert_eq!(cloud_ids, numeric);
    let markers = p.markers.as_ref().expect("~/markers received");
    let boxes: BTreeSet<u32> = markers
        .markers
        .iter()
        .filter(|m| m.action == Marker::ADD && m.ns == "instances")
        .map(|m| m.id as u32)
        .collect();
    assert_eq!(boxes, numeric);
    let graph = p.scene_graph.as_ref().expect("~/scene_graph received");
    let nodes: BTreeSet<&str> = graph.nodes.iter().map(|n| n.id.as_str()).collect();
    assert_eq!(nodes, listed);
    // Masks: one per view of each window, from the configured camera, labelling listed ids only.
    assert!(p.masks.len() >= 4, "{} masks", p.masks.len());
    for mask in &p.masks {
        assert_eq!(mask.camera, "front");
        assert!(!mask.header.frame_id.is_empty());
        let largest = mask
            .mask
            .data
            .chunks_exact(2)
            .map(|v| u16::from_le_bytes([v[0], v[1]]) as usize)
            .max()
            .unwrap_or(0);
        assert!(largest <= mask.instance_ids.len());
    }
    let last = p.masks.last().unwrap();
    assert!(last
        .instance_ids
        .iter()
        .all(|id| listed.contains(id.as_str())));
    assert!(
        last.mask.data.iter().any(|b| *b != 0),
        "the last window's views show some instance"
    );
}

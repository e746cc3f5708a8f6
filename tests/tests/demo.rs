#![allow(clippy::unwrap_used)]
//! The demo end to end: a sim-recorded bag replayed over zenoh reaches the node frame for frame,
//! malformed input is counted, and the node answers the scene's referring expressions through its
//! `Refer` service.

use groupforward::demo::{run_demo, DemoOptions};

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
}

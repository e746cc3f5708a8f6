//! `bench soak` at CI size (issue 34): the node with the shipped models and two RGB-D cameras
//! answers nine scripted VLM faults with its built-in reasoner, takes 10⁴ seeded bad messages
//! and 1,000 bad requests over zenoh, then a 10 s flood of both cameras at 60 Hz with referring
//! queries at 20 Hz, and stays correct. Timings are reported by
//! `groupforward bench soak`, never asserted here.

use groupforward_harness::soak::{run_soak, SoakOptions};
use groupforward_sim::scene::SceneFile;

#[test]
fn the_node_counts_hostile_traffic_keeps_its_answers_and_loses_no_query_under_a_flood() {
    let options = SoakOptions {
        scene: SceneFile::builtin("two_chairs").expect("the built-in scene"),
        bad_messages: 10_000,
        bad_requests: 500,
        flood_secs: 10.0,
        camera_hz: 60.0,
        query_hz: 20.0,
        seed: 34,
    };
    let r = run_soak(&options, &|phase| println!("soak: {phase}")).expect("the soak runs");
    println!("{r:#?}");
    assert_eq!(r.panics, 0);
    assert_eq!(r.messages_sent, 10_000);
    assert_eq!(
        r.messages_counted, r.messages_sent,
        "{:?}",
        r.rejected_by_reason
    );
    assert!(r.rejected_by_reason.keys().all(|k| !k.is_empty()));
    assert!(!r.referring_before.is_empty());
    assert!(
        r.referring_before.iter().any(|ids| !ids.is_empty()),
        "the map answers something: {:?}",
        r.referring_before
    );
    assert!(
        r.referring_same_after_malformed,
        "{:?}",
        r.referring_after_malformed
    );
    // Memory back where it was: bad messages leave nothing behind.
    assert!(
        r.rss_after_malformed_mb <= r.rss_before_mb * 1.05,
        "{} MB after, {} MB before",
        r.rss_after_malformed_mb,
        r.rss_before_mb
    );
    assert!(
        r.flood_frames_published >= 600,
        "{}",
        r.flood_frames_published
    );
    assert!(r.queries_sent >= 50, "{}", r.queries_sent);
    assert_eq!(r.queries_lost, 0);
    assert!(r.replay_hashes_equal, "{:?}", r.replay_hashes);
    assert_eq!(r.vlm_faults_tried, 10);
    assert_eq!(
        r.vlm_faults_answered, r.vlm_faults_tried,
        "{:?}",
        r.vlm_faults_failed
    );
}

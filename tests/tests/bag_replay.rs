//! A bag written in memory is replayed over zenoh into a running node, which syncs every frame.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use std::collections::BTreeMap;
use std::io::Cursor;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use groupforward::client::{query_json, wait_for};
use groupforward::config::Config;
use groupforward::replay::{replay_buffers, ReplayOptions};
use groupforward::transport::ZenohSection;
use groupforward::transport::{open_session, ZenohTransport};
use groupforward_msgs::gf_msgs::NodeStatus;
use groupforward_sim::testcard::TestCard;

fn embedded_session() -> zenoh::Session {
    open_session(&ZenohSection {
        connect: Vec::new(),
        ..ZenohSection::default()
    })
    .unwrap()
}

/// Replay `bag` into a fresh node on its own session; once the node reports `frames` colour frames
/// (received or rejected), stop it and return its final status.
fn replay_into_node(bag: &[u8], frames: u64) -> NodeStatus {
    let session = embedded_session();
    let mut config = Config::default();
    config.status.period_secs = 0.1;
    let node_transport = ZenohTransport::new(session.clone(), 0, "/", "groupforward").unwrap();
    let shutdown = Arc::new(AtomicBool::new(false));
    let node = {
        let (config, shutdown) = (config.clone(), shutdown.clone());
        std::thread::spawn(move || groupforward::node::run(&config, &node_transport, &shutdown))
    };
    let key = format!("{}/status", config.api_prefix());
    wait_for("start", Duration::from_secs(10), || {
        query_json(&session, &key, Duration::from_millis(300)).ok()
    })
    .unwrap();
    let player = ZenohTransport::new(session.clone(), 0, "/", "player").unwrap();
    let options = ReplayOptions {
        rate: 8.0,
        loops: 1,
        progress: false,
    };
    let summary = replay_buffers(&["memory".into()], &[bag.to_vec()], &player, options).unwrap();
    assert!(summary.skipped.is_empty(), "{:?}", summary.skipped);
    wait_for("count every frame", Duration::from_secs(10), || {
        let json = query_json(&session, &key, Duration::from_millis(300)).ok()?;
        let status: NodeStatus = serde_json::from_value(json).ok()?;
        let camera = status.cameras.first()?;
        (camera.frames_received + camera.frames_rejected >= frames).then_some(())
    })
    .unwrap();
    shutdown.store(true, Ordering::Relaxed);
    node.join().unwrap().unwrap()
}

#[test]
fn replayed_bag_syncs_every_frame_and_twice_gives_the_same_counts() {
    let card = TestCard {
        width: 64,
        height: 48,
        ..TestCard::default()
    };
    let frames = 12;
    let bag = card.bag(frames, true).unwrap();
    let first = replay_into_node(&bag, frames);
    let camera = &first.cameras[0];
    assert_eq!(camera.frames_received, frames);
    assert_eq!(camera.frames_synced, frames);
    assert_eq!(camera.frames_rejected, 0, "{:?}", first.rejections);
    assert_eq!(first.tf_received, frames + 1);
    let second = replay_into_node(&bag, frames);
    let counts = |s: &NodeStatus| {
        let c = &s.cameras[0];
        (
            c.frames_received,
            c.frames_synced,
            c.frames_rejected,
            c.last_stamp,
            s.tf_received,
        )
    };
    assert_eq!(counts(&second), counts(&first));
}

#[test]
fn unknown_types_are_skipped_and_reported_and_corrupt_bags_fail_clearly() {
    let mut writer = mcap::Writer::new(Cursor::new(Vec::new())).unwrap();
    let schema = writer
        .add_schema("my_pkg/msg/Thing", "ros2msg", b"int32 x")
        .unwrap();
    let channel = writer
        .add_channel(schema, "/thing", "cdr", &BTreeMap::new())
        .unwrap();
    let header = mcap::records::MessageHeader {
        channel_id: channel,
        sequence: 1,
        log_time: 1,
        publish_time: 1,
    };
    writer
        .write_to_known_channel(&header, &[0, 1, 0, 0, 1, 0, 0, 0])
        .unwrap();
    writer.finish().unwrap();
    let bag = writer.into_inner().into_inner();
    let session = embedded_session();
    let player = ZenohTransport::new(session, 0, "/", "player").unwrap();
    let options = ReplayOptions {
        rate: 0.0,
        loops: 1,
        progress: false,
    };
    let summary = replay_buffers(&["m".into()], &[bag], &player, options).unwrap();
    assert_eq!(summary.published, 0);
    let (count, reason) = &summary.skipped["/thing"];
    assert_eq!(*count, 1);
    assert!(reason.contains("my_pkg/msg/Thing"), "{reason}");
    let corrupt = replay_buffers(
        &["bad".into()],
        &[b"not an mcap".to_vec()],
        &player,
        options,
    );
    assert!(corrupt
        .unwrap_err()
        .to_string()
        .contains("not a valid MCAP"));
}

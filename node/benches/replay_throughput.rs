//! Replay → node throughput: 640×480 rgb8 frames (with CameraInfo and TF) from an in-memory MCAP bag,
//! published over zenoh as fast as possible, through the node's subscriptions, queue, decode,
//! validation and stamp sync (`frames`), side by side with the same messages fed straight into the
//! pipeline (`ingest_only`). Reported as frames per second; compare with a 30 Hz camera.
//!
//! `cargo bench -p groupforward --bench replay_throughput`

#![allow(clippy::unwrap_used)] // benchmark setup

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use groupforward::config::Config;
use groupforward::ingest::Route;
use groupforward::node::{declare, InputQueue, Node, Shared};
use groupforward::replay::{replay_buffers, ReplayOptions};
use groupforward::transport::ZenohSection;
use groupforward::transport::{open_session, ZenohTransport};
use groupforward_sim::testcard::TestCard;

const FRAMES: u64 = 40;

fn replay_to_node(c: &mut Criterion) {
    let card = TestCard {
        width: 640,
        height: 480,
        ..TestCard::default()
    };
    let bag = card.bag(FRAMES, false).unwrap();
    let session = open_session(&ZenohSection {
        connect: Vec::new(),
        ..ZenohSection::default()
    })
    .unwrap();
    let mut config = Config::default();
    config.cameras[0].depth_topic = None;
    // Deep enough that a full-speed replay drops nothing: this measures processing, not the bound.
    config.ingest.queue_depth = 4 * (3 * FRAMES as usize + 1);
    config.ingest.pending_frames = FRAMES as usize;
    let node_transport = ZenohTransport::new(session.clone(), 0, "/", "groupforward").unwrap();
    let queue = Arc::new(InputQueue::new(config.ingest.queue_depth));
    declare(
        &config,
        &node_transport,
        &queue,
        &Arc::new(Mutex::new(Shared::default())),
    )
    .unwrap();
    let player = ZenohTransport::new(session.clone(), 0, "/", "player").unwrap();
    let options = ReplayOptions {
        rate: 0.0,
        loops: 1,
        progress: false,
    };

    let mut group = c.benchmark_group("replay_to_node_640x480_rgb8");
    group.throughput(Throughput::Elements(FRAMES));
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(20));
    group.bench_function("frames", |b| {
        b.iter_custom(|iterations| {
            let mut total = Duration::ZERO;
            for _ in 0..iterations {
                let mut node = Node::new(&config);
                let start = Instant::now();
                replay_buffers(
                    &["bench".into()],
                    std::slice::from_ref(&bag),
                    &player,
                    options,
                )
                .unwrap();
                let mut synced = 0;
                while synced < FRAMES as usize {
                    let (item, dropped) = queue.pop(Duration::from_secs(5));
                    assert!(dropped.is_empty(), "queue dropped input");
                    let (route, payload): (Route, Vec<u8>) = item.expect("replayed frames arrive");
                    synced += node.step(route, &payload).synced;
                }
                total += start.elapsed();
            }
            total
        })
    });
    // The same messages straight into the pipeline, no zenoh: the transport's share is the ratio.
    let routes: std::collections::HashMap<String, Route> =
        groupforward::ingest::Ingest::routes(&config.cameras, &config.tf)
            .into_iter()
            .collect();
    let messages: Vec<(Route, Vec<u8>)> = mcap::MessageStream::new(&bag)
        .unwrap()
        .map(|m| m.unwrap())
        .filter_map(|m| Some((*routes.get(&m.channel.topic)?, m.data.into_owned())))
        .collect();
    group.bench_function("ingest_only", |b| {
        b.iter(|| {
            let mut node = Node::new(&config);
            let synced: usize = messages.iter().map(|(r, p)| node.step(*r, p).synced).sum();
            assert_eq!(synced, FRAMES as usize);
        })
    });
    group.finish();
}

criterion_group!(benches, replay_to_node);
criterion_main!(benches);

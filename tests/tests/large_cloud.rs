#![allow(clippy::unwrap_used)]
//! A map's instance cloud is the largest message the node sends: 10⁶ points (20 MB) go from one
//! zenoh session to another over TCP, on the node's own output endpoint (lossless, rmw_zenoh key),
//! and arrive whole, byte for byte (rmw_zenoh lost large messages to congestion dropping, its
//! issue #696).

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::{Quat, Vec3};
use groupforward::config::Config;
use groupforward::node::outputs::OutputEndpoints;
use groupforward::recon::gaussians::Gaussians;
use groupforward::refer::response::instance_cloud;
use groupforward::transport::{open_session, Transport, ZenohMode, ZenohSection, ZenohTransport};
use groupforward_msgs::builtin_interfaces::Time;
use groupforward_msgs::cdr;
use groupforward_msgs::sensor_msgs::PointCloud2;

#[test]
fn a_million_point_instance_cloud_arrives_intact_over_tcp() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let node_session = open_session(&ZenohSection {
        mode: ZenohMode::Peer,
        listen: vec![endpoint.clone()],
        connect: Vec::new(),
        ..ZenohSection::default()
    })
    .unwrap();
    let viewer_session = open_session(&ZenohSection {
        mode: ZenohMode::Client,
        listen: Vec::new(),
        connect: vec![endpoint],
        ..ZenohSection::default()
    })
    .unwrap();
    let node = ZenohTransport::new(node_session, 0, "/", "groupforward").unwrap();
    let viewer = ZenohTransport::new(viewer_session, 0, "/", "viewer").unwrap();
    let outputs = OutputEndpoints::declare(&Config::default()).unwrap();
    let topic = outputs.instance_cloud.unwrap();
    assert!(topic.lossless);
    let received: Arc<Mutex<Vec<Vec<u8>>>> = Arc::default();
    let sink = received.clone();
    viewer
        .subscribe(
            &topic,
            Arc::new(move |payload| sink.lock().unwrap().push(payload)),
        )
        .unwrap();
    let publisher = node.advertise(&topic).unwrap();

    // 10⁶ points in four instances, on a grid.
    let mut instances = Vec::new();
    for k in 0..4 {
        let mut g = Gaussians::with_dims(0, 0);
        for i in 0..250_000u32 {
            g.push(
                Vec3::new(k as f32, (i % 500) as f32 * 0.01, (i / 500) as f32 * 0.01),
                1.0,
                Vec3::splat(0.01),
                Quat::IDENTITY,
                Vec3::new(0.2, 0.4, 0.6),
                &[],
                &[],
            );
        }
        instances.push((k + 1, g));
    }
    let items: Vec<(u32, &Gaussians)> = instances.iter().map(|(id, g)| (*id, g)).collect();
    let cloud = instance_cloud("map", Time::from_nanos(1), &items);
    assert_eq!(cloud.width, 1_000_000);
    let bytes = cdr::encode(&cloud).unwrap();
    assert!(bytes.len() > 20_000_000);

    // The subscriber's declaration takes a moment to reach the publisher's session: publish until
    // one arrives, then check it is whole.
    let deadline = Instant::now() + Duration::from_secs(30);
    while received.lock().unwrap().is_empty() {
        assert!(Instant::now() < deadline, "no cloud arrived");
        publisher.publish(&bytes).unwrap();
        std::thread::sleep(Duration::from_millis(300));
    }
    let first = received.lock().unwrap()[0].clone();
    assert_eq!(first.len(), bytes.len());
    assert!(first == bytes, "the cloud arrived altered");
    let decoded: PointCloud2 = cdr::decode(&first).unwrap();
    assert_eq!(decoded.width, 1_000_000);
    let last_id = u32::from_le_bytes(decoded.data[decoded.data.len() - 4..].try_into().unwrap());
    assert_eq!(last_id, 4);
}

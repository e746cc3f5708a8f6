//! The node: subscriptions feed a bounded drop-oldest queue, one loop runs ingest and cuts
//! keyframe windows, a worker thread runs window passes and fuses them into the map, and a status
//! report is published every period on `~/status` and the JSON API.
//!
//! - [`queue`]: the bounded input queue;
//! - [`status`]: ingest-side state and the status report;
//! - [`worker`]: the window worker (model passes, fusion);
//! - [`outputs`]: the thread that publishes the map's instances, cloud, masks, markers and graph;
//! - [`error`]: what can stop the node;
//! - [`services`]: shared state, services, the JSON API and their declaration;
//! - this file: [`run`], the loop that ties them together.

pub mod error;
pub mod limit;
pub mod outputs;
pub mod queue;
pub mod services;
pub mod status;
pub mod worker;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use groupforward_msgs::gf_msgs::NodeStatus;

use crate::config::Config;
use crate::graph::persist;
use crate::transport::{Transport, TransportKind};

pub use error::{NodeError, Result};
pub use queue::InputQueue;
pub use services::{declare, instance_messages, Declared, Shared};
pub use status::{Node, Step, WINDOW_BUSY};

/// The node's transport as `config` names it: a zenoh session, or (a build with the `ros2`
/// feature) an rcl node.
pub fn open_transport(config: &Config) -> crate::transport::Result<Box<dyn Transport>> {
    let (namespace, name) = (&config.node.namespace, &config.node.name);
    match config.transport {
        TransportKind::Zenoh => {
            let session = crate::transport::open_session(&config.zenoh)?;
            let transport = crate::transport::ZenohTransport::new(
                session,
                config.zenoh.domain_id,
                namespace,
                name,
            )?;
            Ok(Box::new(transport))
        }
        #[cfg(feature = "ros2")]
        TransportKind::Ros2 => Ok(Box::new(crate::transport::ros2::Ros2Transport::new(
            namespace, name,
        )?)),
        #[cfg(not(feature = "ros2"))]
        TransportKind::Ros2 => Err(crate::transport::TransportError::Ros2(
            "the config asks for `transport: ros2`, but this build has no ROS 2 transport: \
             build with `--features ros2` in a ROS 2 environment (`make ros2`)"
                .into(),
        )),
    }
}

/// How long the node, stopping, waits for the worker to take each last window.
const LAST_WINDOW_PATIENCE: Duration = Duration::from_secs(30);

/// Run the node on `transport` until `shutdown` is set; returns the last status.
pub fn run(
    config: &Config,
    transport: &dyn Transport,
    shutdown: &AtomicBool,
) -> Result<NodeStatus> {
    let queue = Arc::new(InputQueue::new(config.ingest.queue_depth));
    let mut initial = Shared {
        map_file: config.map.file.clone(),
        map_directory: Some(config.map.confining_directory()),
        hypotheses: config.semantics.hypotheses,
        refer: config.refer.clone(),
        world_frame: config.tf.world_frame.clone(),
        limiter: limit::RequestLimiter::new(config.node.max_requests_per_second),
        ..Shared::default()
    };
    if let Some(file) = config
        .map
        .file
        .as_deref()
        .filter(|_| config.map.restore_on_start)
    {
        let path = std::path::Path::new(file);
        if path.exists() {
            match persist::load(path, initial.map.params) {
                Ok(map) => {
                    tracing::info!("restored {} instances from {file}", map.instances.len());
                    initial.set_map(map);
                }
                Err(e) => {
                    tracing::error!("cannot restore the map from {file}: {e}; starting empty")
                }
            }
        }
    }
    let shared = Arc::new(Mutex::new(initial));
    let declared = declare(config, transport, &queue, &shared)?;
    let status_publisher = transport.advertise(&declared.status)?;
    let (stop_outputs, outputs_stopped) = std::sync::mpsc::sync_channel::<()>(1);
    let output_publisher = outputs::start_output_publisher(
        config,
        &outputs::OutputEndpoints::declare(config)?,
        transport,
        &shared,
        outputs_stopped,
    )?;
    if let Ok(mut s) = shared.lock() {
        s.snapshot_taker = output_publisher.is_some();
    }
    // Every interface is declared before the (slow) model load, so peers see the node at once.
    let (windows, worker) = worker::start_window_worker(config, &shared);
    let mut windows = windows;
    let mut model_gone = false;
    tracing::info!(
        subscriptions = declared.subscriptions.len(),
        json = %declared.json_prefix,
        "node `{}` running",
        config.node.name
    );
    let mut node = Node::new(config);
    let period = Duration::from_secs_f64(config.status.period_secs);
    let mut next_status = Instant::now() + period;
    let mut last = node.status(Instant::now());
    if let Ok(mut s) = shared.lock() {
        s.status = last.clone();
    }
    while !shutdown.load(Ordering::Relaxed) {
        let (item, dropped) = queue.pop(Duration::from_millis(20));
        node.record_dropped(&dropped);
        if let Some((route, payload)) = item {
            let step = node.step(route, &payload);
            if let Some(inbox) = &windows {
                let handed = step
                    .keyframes
                    .into_iter()
                    .filter(|_| config.window.features_ahead)
                    .map(|frame| inbox.send_keyframe(frame))
                    .chain(step.windows.into_iter().map(|window| {
                        // The worker is busy with the previous window: drop this one (counted)
                        // rather than stall ingest.
                        let sent = inbox.send_window(window);
                        if sent == Err(worker::NotSent::Busy) {
                            node.windows_dropped += 1;
                            tracing::debug!(
                                dropped = node.windows_dropped,
                                "window pass busy; window dropped"
                            );
                        }
                        sent
                    }))
                    .collect::<Vec<_>>();
                // A worker without a model has exited.
                model_gone = handed.contains(&Err(worker::NotSent::Gone));
            }
        }
        // A camera whose stream paused or ended with keyframes short of a window: map them now,
        // when the worker can take the window (it waits for nothing else to come).
        if let Some(inbox) = windows.as_ref().filter(|inbox| inbox.has_room()) {
            if let Some(window) = node.quiet_window(Instant::now()) {
                model_gone = inbox.send_window(window) == Err(worker::NotSent::Gone);
            }
        }
        if model_gone {
            windows = None;
            model_gone = false;
        }
        let now = Instant::now();
        if now >= next_status {
            next_status = now + period;
            last = status::publish_status(&mut node, now, status_publisher.as_ref(), &shared);
        }
    }
    // Drain what already arrived so a replay's last messages are counted.
    loop {
        let (item, dropped) = queue.pop(Duration::ZERO);
        node.record_dropped(&dropped);
        match item {
            Some((route, payload)) => {
                node.step(route, &payload);
            }
            None => break,
        }
    }
    // The keyframes still short of a window are mapped before the map is final.
    if let Some(inbox) = &windows {
        for window in node.pending_windows() {
            if inbox
                .send_window_waiting(window, LAST_WINDOW_PATIENCE)
                .is_err()
            {
                node.windows_dropped += 1;
            }
        }
    }
    // Let the worker finish the windows it has, then stop it.
    drop(windows);
    if let Some(worker) = worker {
        if worker.join().is_err() {
            tracing::error!("the window worker panicked");
        }
    }
    // The map is final: keep it for the next start, then the output publisher publishes it once
    // more and stops.
    if let Some(file) = config
        .map
        .file
        .as_deref()
        .filter(|_| config.map.save_on_exit)
    {
        let map = shared.lock().ok().map(|s| s.map.clone());
        match map.map(|map| persist::save(&map, std::path::Path::new(file))) {
            Some(Ok(())) => tracing::info!("map saved to {file}"),
            Some(Err(e)) => tracing::error!("cannot save the map to {file}: {e}"),
            None => tracing::error!("cannot save the map: its lock is poisoned"),
        }
    }
    drop(stop_outputs);
    if let Some(publisher) = output_publisher {
        if publisher.join().is_err() {
            tracing::error!("the output publisher panicked");
        }
    }
    if node.windows_dropped > 0 {
        tracing::info!(
            dropped = node.windows_dropped,
            "windows dropped while the model was busy"
        );
    }
    if !last.cameras.is_empty() || node.ingest.tf_received > 0 {
        last = status::publish_status(
            &mut node,
            Instant::now(),
            status_publisher.as_ref(),
            &shared,
        );
    }
    Ok(last)
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use groupforward_msgs::cdr;
    use groupforward_msgs::gf_msgs::{
        Instance, ListInstancesRequest, ListInstancesResponse, MapPathRequest, MapResultResponse,
    };
    use groupforward_msgs::sensor_msgs::Image;

    use super::*;
    use crate::graph::{persist, SceneMap};
    use crate::transport::MemoryTransport;

    /// Run the node on an in-memory bus and wait until it answers its JSON API.
    fn start(
        config: &Config,
    ) -> (
        Arc<MemoryTransport>,
        Arc<AtomicBool>,
        std::thread::JoinHandle<Result<NodeStatus>>,
    ) {
        let bus = MemoryTransport::new();
        let handle = bus.clone();
        let shutdown = Arc::new(AtomicBool::new(false));
        let runner = {
            let (config, shutdown) = (config.clone(), shutdown.clone());
            std::thread::spawn(move || run(&config, &handle, &shutdown))
        };
        let deadline = Instant::now() + Duration::from_secs(5);
        while bus.get_json("groupforward/default/status", b"").is_err() {
            assert!(Instant::now() < deadline, "node did not start");
            std::thread::sleep(Duration::from_millis(5));
        }
        (bus, shutdown, runner)
    }

    /// The node's status as its JSON API answers it.
    fn status_json(bus: &MemoryTransport) -> serde_json::Value {
        serde_json::from_str(&bus.get_json("groupforward/default/status", b"").unwrap()).unwrap()
    }

    /// `list_instances` with the default request, as a client calls it.
    fn list_instances(bus: &MemoryTransport) -> crate::transport::Result<Vec<u8>> {
        bus.call(
            "/groupforward/list_instances",
            &cdr::encode(&ListInstancesRequest::default()).unwrap(),
        )
    }

    #[cfg(not(feature = "ros2"))]
    #[test]
    fn asking_for_ros2_in_a_build_without_it_names_the_feature() {
        let config = Config {
            transport: crate::transport::TransportKind::Ros2,
            ..Config::default()
        };
        let error = super::open_transport(&config)
            .err()
            .expect("no ROS 2 in this build");
        assert!(error.to_string().contains("--features ros2"), "{error}");
        assert_eq!(
            "ros2".parse::<crate::transport::TransportKind>(),
            Ok(crate::transport::TransportKind::Ros2)
        );
        assert!("dds".parse::<crate::transport::TransportKind>().is_err());
    }

    #[test]
    fn run_counts_frames_serves_and_publishes_status_over_memory_transport() {
        let mut config = Config::default();
        config.cameras[0].depth_topic = None;
        config.status.period_secs = 0.05;
        let (bus, shutdown, runner) = start(&config);
        let image = Image {
            width: 2,
            height: 2,
            encoding: "rgb8".into(),
            step: 6,
            data: vec![0; 12],
            ..Default::default()
        };
        for _ in 0..3 {
            bus.inject("/camera/color/image_raw", &cdr::encode(&image).unwrap());
        }
        bus.inject("/camera/color/image_raw", b"garbage");
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            let json = status_json(&bus);
            if json["cameras"][0]["frames_received"] == 3
                && json["cameras"][0]["frames_rejected"] == 1
            {
                assert_eq!(json["rejections"][0]["reason"], "malformed_cdr");
                break;
            }
            assert!(
                Instant::now() < deadline,
                "status never showed the frames: {json}"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        let list = list_instances(&bus).unwrap();
        let list: ListInstancesResponse = cdr::decode(&list).unwrap();
        assert!(list.instances.is_empty());
        assert!(bus.call("/groupforward/list_instances", b"bad").is_err());
        assert!(bus.get_json("groupforward/default/nothing", b"").is_err());
        shutdown.store(true, Ordering::Relaxed);
        let last = runner.join().unwrap().unwrap();
        assert_eq!(last.cameras[0].frames_received, 3);
        let published = bus.published("/groupforward/status");
        assert!(!published.is_empty());
        let status: NodeStatus = cdr::decode(published.last().unwrap()).unwrap();
        assert_eq!(status.cameras[0].name, "front");
        // Every message the loop handled was timed as ingest; no window ran, so no window stage.
        let ingest = status.stages.iter().find(|s| s.stage == "ingest");
        let ingest = ingest.unwrap_or_else(|| panic!("no ingest timing in {:?}", status.stages));
        assert!(ingest.count >= 3, "{ingest:?}");
        assert!(ingest.p50_ms <= ingest.p99_ms && ingest.p99_ms.is_finite());
        assert!(status.stages.iter().all(|s| s.stage != "window"));
    }

    #[test]
    fn requests_beyond_the_node_s_rate_are_refused_with_the_reason_and_counted() {
        let mut config = Config::default();
        config.cameras[0].depth_topic = None;
        config.status.period_secs = 0.05;
        config.node.max_requests_per_second = 2.0;
        let (bus, shutdown, runner) = start(&config);
        let answers: Vec<_> = (0..20).map(|_| list_instances(&bus)).collect();
        let taken = answers.iter().filter(|a| a.is_ok()).count();
        // The burst (2), plus what refilled while the 20 calls ran (well under half a second).
        assert!((2..=3).contains(&taken), "{taken} taken");
        for refused in answers.iter().filter_map(|a| a.as_ref().err()) {
            assert!(
                refused.to_string().contains("request_rate_limited"),
                "{refused}"
            );
        }
        // The JSON API shares the bound; the status stays readable and counts the refusals.
        assert!(bus.get_json("groupforward/default/instances", b"").is_err());
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            let json = status_json(&bus);
            let limited = json["rejections"]
                .as_array()
                .and_then(|r| r.iter().find(|r| r["reason"] == "request_rate_limited"))
                .and_then(|r| r["count"].as_u64());
            if limited == Some((20 - taken + 1) as u64) {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "status never counted them: {json}"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        // The bucket refills at the rate: a request half a second later is taken.
        std::thread::sleep(Duration::from_millis(600));
        assert!(list_instances(&bus).is_ok());
        shutdown.store(true, Ordering::Relaxed);
        runner.join().unwrap().unwrap();
    }

    #[test]
    fn a_seeded_flood_of_bad_messages_and_requests_is_counted_and_the_node_keeps_serving() {
        use crate::ingest::test_messages::{hostile_message, HostileTarget};
        use rand::{Rng, SeedableRng};
        let mut config = Config::default();
        config.status.period_secs = 0.05;
        // Every bad request must reach its handler, not the rate bound.
        config.node.max_requests_per_second = 0.0;
        let (bus, shutdown, runner) = start(&config);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(34);
        let camera_topics = [
            "/camera/color/image_raw",
            "/camera/color/camera_info",
            "/camera/depth/image_raw",
        ];
        let (mut camera_bad, mut tf_bad) = (0u64, 0u64);
        const MESSAGES: usize = 20_000;
        for _ in 0..MESSAGES {
            let (target, payload) = hostile_message(&mut rng);
            let topic = match target {
                HostileTarget::Image => camera_topics[0],
                HostileTarget::CameraInfo => camera_topics[1],
                HostileTarget::Depth => camera_topics[2],
                HostileTarget::Tf => "/tf",
                HostileTarget::TfStatic => "/tf_static",
            };
            if target.is_tf() {
                tf_bad += 1;
            } else {
                camera_bad += 1;
            }
            bus.inject(topic, &payload);
        }
        // Every message is counted once, under a named reason (queue overflow included).
        let deadline = Instant::now() + Duration::from_secs(20);
        let status = loop {
            let json = status_json(&bus);
            let status: NodeStatus = serde_json::from_value(json).unwrap();
            let camera = &status.cameras[0];
            if camera.frames_rejected == camera_bad && status.tf_rejected == tf_bad {
                break status;
            }
            assert!(
                Instant::now() < deadline,
                "counted {} / {camera_bad} camera and {} / {tf_bad} tf rejections",
                camera.frames_rejected,
                status.tf_rejected
            );
            std::thread::sleep(Duration::from_millis(20));
        };
        assert_eq!(status.cameras[0].frames_received, 0);
        assert_eq!(status.tf_received, 0);
        let by_reason: u64 = status.rejections.iter().map(|r| r.count).sum();
        assert_eq!(by_reason, camera_bad + tf_bad, "{:?}", status.rejections);
        assert!(status.rejections.iter().all(|r| !r.reason.is_empty()));
        // Bad requests to every service and the JSON API: each an error, none a panic.
        let services = [
            "/groupforward/refer",
            "/groupforward/list_instances",
            "/groupforward/get_instance",
            "/groupforward/save_map",
            "/groupforward/load_map",
        ];
        for i in 0..2_000 {
            let bytes: Vec<u8> = (0..rng.random_range(0..64)).map(|_| rng.random()).collect();
            let mut request = vec![0xff, 0xff, 0, 0];
            request.extend(bytes);
            assert!(bus.call(services[i % services.len()], &request).is_err());
            let api = ["refer", "instances", "get_instance", "nothing"][i % 4];
            let _ = bus.get_json(&format!("groupforward/default/{api}"), &request);
        }
        // And it still serves: a good request is answered.
        let list = list_instances(&bus).unwrap();
        let _: ListInstancesResponse = cdr::decode(&list).unwrap();
        shutdown.store(true, Ordering::Relaxed);
        runner.join().expect("the node never panicked").unwrap();
    }

    /// A map with one instance: a small cube of Gaussians.
    fn one_instance_map() -> SceneMap {
        use crate::frame::WindowInstance;
        use crate::graph::FusionParams;
        use crate::recon::gaussians::Gaussians;
        let mut g = Gaussians::with_dims(0, 0);
        for i in 0..5 {
            for j in 0..5 {
                let p = glam::Vec3::new(2.0 + i as f32 * 0.05, j as f32 * 0.05, 0.5);
                g.push(
                    p,
                    0.9,
                    glam::Vec3::splat(0.02),
                    glam::Quat::IDENTITY,
                    glam::Vec3::ONE,
                    &[],
                    &[],
                );
            }
        }
        let mut map = SceneMap::new(FusionParams::default());
        map.fuse(
            vec![WindowInstance {
                gaussians: g,
                prototype: vec![1.0, 0.0],
                support: 25,
            }],
            &[],
            7,
        )
        .unwrap();
        map
    }

    /// `one_instance_map` and a second instance 3 m along x.
    fn two_instance_map() -> SceneMap {
        let mut two = one_instance_map();
        let mut far = two.instances[0].gaussians.clone();
        far.means.iter_mut().for_each(|m| m.x += 3.0);
        two.fuse(
            vec![crate::frame::WindowInstance {
                gaussians: far,
                prototype: vec![1.0, 0.0],
                support: 25,
            }],
            &[],
            9,
        )
        .unwrap();
        two
    }

    #[test]
    fn map_services_save_load_and_restore_on_start_keeping_the_map_on_errors() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("map.gfmap");
        persist::save(&one_instance_map(), &file).unwrap();
        let mut config = Config::default();
        config.map.file = Some(file.display().to_string());
        let (bus, shutdown, runner) = start(&config);
        let list = |bus: &MemoryTransport| -> Vec<Instance> {
            let reply = list_instances(bus).unwrap();
            cdr::decode::<ListInstancesResponse>(&reply)
                .unwrap()
                .instances
        };
        let call = |service: &str, path: &str| -> MapResultResponse {
            let request = cdr::encode(&MapPathRequest { path: path.into() }).unwrap();
            cdr::decode(&bus.call(service, &request).unwrap()).unwrap()
        };
        // Restored on start.
        let restored = list(&bus);
        assert_eq!(restored.len(), 1);
        assert_eq!(restored[0].id, "inst_000001");
        let expected = one_instance_map().instances[0].gaussians.len() as u32;
        assert_eq!(restored[0].point_count, expected);
        // Save elsewhere, then a corrupt file fails to load and changes nothing.
        let copy = dir.path().join("copy.gfmap");
        assert!(call("/groupforward/save_map", &copy.display().to_string()).success);
        let corrupt = dir.path().join("corrupt.gfmap");
        let mut bytes = std::fs::read(&copy).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle] ^= 1;
        std::fs::write(&corrupt, bytes).unwrap();
        let failed = call("/groupforward/load_map", &corrupt.display().to_string());
        assert!(
            !failed.success && failed.message.contains("corrupt"),
            "{failed:?}"
        );
        assert_eq!(list(&bus), restored);
        // Loading another map replaces the running one; loading the copy brings this one back.
        let mut other = one_instance_map();
        let mut far = other.instances[0].clone();
        far.gaussians.means.iter_mut().for_each(|m| m.x += 3.0);
        other
            .fuse(
                vec![crate::frame::WindowInstance {
                    gaussians: far.gaussians,
                    prototype: vec![1.0, 0.0],
                    support: 25,
                }],
                &[],
                9,
            )
            .unwrap();
        assert_eq!(other.instances.len(), 2);
        let other_file = dir.path().join("other.gfmap");
        persist::save(&other, &other_file).unwrap();
        let reply = call("/groupforward/load_map", &other_file.display().to_string());
        assert!(reply.success, "{reply:?}");
        let replaced = list(&bus);
        assert_eq!(replaced.len(), 2);
        assert_eq!(replaced[1].id, "inst_000002");
        assert_ne!(replaced, restored);
        // The configured file is the default path; the copy loads back to the same map.
        assert!(call("/groupforward/save_map", "").success);
        assert!(call("/groupforward/load_map", &copy.display().to_string()).success);
        assert_eq!(list(&bus), restored);
        assert!(bus.call("/groupforward/save_map", b"bad").is_err());
        shutdown.store(true, Ordering::Relaxed);
        runner.join().unwrap().unwrap();
    }

    #[test]
    fn the_map_is_saved_when_the_node_stops_and_restored_at_the_next_start() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("robot.gfmap");
        persist::save(&one_instance_map(), &file).unwrap();
        let two = two_instance_map();
        let two_file = dir.path().join("two.gfmap");
        persist::save(&two, &two_file).unwrap();
        let load = |bus: &MemoryTransport, path: &std::path::Path| {
            let request = cdr::encode(&MapPathRequest {
                path: path.display().to_string(),
            })
            .unwrap();
            let reply: MapResultResponse =
                cdr::decode(&bus.call("/groupforward/load_map", &request).unwrap()).unwrap();
            assert!(reply.success, "{reply:?}");
        };
        let mut config = Config::default();
        config.map.file = Some(file.display().to_string());
        // The robot's map changes while it runs (here: a map loaded into it), then it stops.
        let (bus, shutdown, runner) = start(&config);
        load(&bus, &two_file);
        shutdown.store(true, Ordering::Relaxed);
        runner.join().unwrap().unwrap();
        let saved = persist::load(&file, Default::default()).unwrap();
        assert_eq!(saved.instances.len(), 2, "the map at stop is on disk");
        // The next start restores it; with save_on_exit off, stopping leaves the file as it was.
        config.map.save_on_exit = false;
        let (bus, shutdown, runner) = start(&config);
        let reply = list_instances(&bus).unwrap();
        let listed: ListInstancesResponse = cdr::decode(&reply).unwrap();
        assert_eq!(listed.instances.len(), 2);
        let one_file = dir.path().join("one.gfmap");
        persist::save(&one_instance_map(), &one_file).unwrap();
        load(&bus, &one_file);
        shutdown.store(true, Ordering::Relaxed);
        runner.join().unwrap().unwrap();
        let kept = persist::load(&file, Default::default()).unwrap();
        assert_eq!(kept.instances.len(), 2);
    }

    /// Wait until the last message on `topic` satisfies `done`.
    fn last_published<T: serde::de::DeserializeOwned>(
        bus: &MemoryTransport,
        topic: &str,
        done: impl Fn(&T) -> bool,
    ) -> T {
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            if let Some(last) = bus.published(topic).last() {
                let message: T = cdr::decode(last).unwrap();
                if done(&message) {
                    return message;
                }
            }
            assert!(Instant::now() < deadline, "nothing fitting on {topic}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    #[test]
    fn the_map_is_published_on_its_topics_after_each_change_and_again_for_late_joiners() {
        use groupforward_msgs::gf_msgs::{InstanceArray, SceneGraph};
        use groupforward_msgs::sensor_msgs::PointCloud2;
        use groupforward_msgs::vision_msgs::Detection3DArray;
        use groupforward_msgs::visualization_msgs::{Marker, MarkerArray};
        let dir = tempfile::tempdir().unwrap();
        let one = dir.path().join("one.gfmap");
        persist::save(&one_instance_map(), &one).unwrap();
        let two = two_instance_map();
        let two_file = dir.path().join("two.gfmap");
        persist::save(&two, &two_file).unwrap();
        let mut config = Config::default();
        config.map.file = Some(one.display().to_string());
        config.outputs.republish_secs = 0.2;
        let (bus, shutdown, runner) = start(&config);

        // The restored map, on every topic, in the map frame.
        let detections: Detection3DArray =
            last_published(&bus, "/groupforward/instances", |d: &Detection3DArray| {
                d.detections.len() == 1
            });
        assert_eq!(detections.header.frame_id, "map");
        let detection = &detections.detections[0];
        assert_eq!(detection.id, "inst_000001");
        // The cube spans x 2.0..2.2, y 0..0.2 at z 0.5: its box centre is there.
        assert!((detection.bbox.center.position.x - 2.1).abs() < 0.02);
        assert!((detection.bbox.center.position.y - 0.1).abs() < 0.02);
        let array: InstanceArray =
            last_published(&bus, "/groupforward/instance_array", |_: &InstanceArray| {
                true
            });
        let gaussians = one_instance_map().instances[0].gaussians.len() as u32;
        assert_eq!(array.instances[0].point_count, gaussians);
        let cloud: PointCloud2 =
            last_published(&bus, "/groupforward/instance_cloud", |_: &PointCloud2| true);
        assert_eq!(cloud.width, gaussians);
        let ids: Vec<u32> = cloud
            .data
            .chunks_exact(cloud.point_step as usize)
            .map(|p| u32::from_le_bytes(p[16..20].try_into().unwrap()))
            .collect();
        assert!(ids.iter().all(|&id| id == 1), "{ids:?}");
        let graph: SceneGraph =
            last_published(&bus, "/groupforward/scene_graph", |_: &SceneGraph| true);
        assert_eq!(graph.nodes.len(), 1);
        let json: serde_json::Value = serde_json::from_str(
            &bus.get_json("groupforward/default/scene_graph", b"")
                .unwrap(),
        )
        .unwrap();
        assert_eq!(json["nodes"][0]["id"], "inst_000001");

        // Nothing changes: the same messages come again, for subscribers that join late.
        let before = bus.published("/groupforward/instances").len();
        std::thread::sleep(Duration::from_millis(600));
        assert!(bus.published("/groupforward/instances").len() > before);

        // A second instance appears, then leaves: its box and label are deleted.
        let request = |path: &std::path::Path| {
            cdr::encode(&MapPathRequest {
                path: path.display().to_string(),
            })
            .unwrap()
        };
        bus.call("/groupforward/load_map", &request(&two_file))
            .unwrap();
        last_published(&bus, "/groupforward/instances", |d: &Detection3DArray| {
            d.detections.len() == 2
        });
        let graph: SceneGraph =
            last_published(&bus, "/groupforward/scene_graph", |g: &SceneGraph| {
                g.nodes.len() == 2
            });
        assert_eq!(graph.edges.len(), 1, "3 m apart: within the edge distance");
        bus.call("/groupforward/load_map", &request(&one)).unwrap();
        let markers: MarkerArray =
            last_published(&bus, "/groupforward/markers", |m: &MarkerArray| {
                m.markers.iter().any(|m| m.action == Marker::DELETE)
            });
        let deleted: Vec<(&str, i32)> = markers
            .markers
            .iter()
            .filter(|m| m.action == Marker::DELETE)
            .map(|m| (m.ns.as_str(), m.id))
            .collect();
        // With one instance left there is no edge: the edge lines go too.
        assert_eq!(deleted, [("edges", 0), ("instances", 2), ("labels", 2)]);
        let kept = markers
            .markers
            .iter()
            .filter(|m| m.action == Marker::ADD)
            .count();
        assert_eq!(kept, 2, "one box and one label");
        shutdown.store(true, Ordering::Relaxed);
        runner.join().unwrap().unwrap();
    }
}

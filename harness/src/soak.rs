//! `groupforward bench soak`: the node under hostile traffic and load, in one process over an
//! embedded zenoh peer, as a robot would run it (shipped models, two RGB-D cameras).
//!
//! 1. A map is built from a sim scene's bag and the scene's referring expressions are asked.
//! 2. Malformed traffic: seeded bad messages to every subscription of both cameras and the
//!    transform topics, bad requests to every service and the JSON API, all over zenoh. Every
//!    message must be counted under a named reason; the expressions are asked again and must get
//!    the same answers; memory is read before and after.
//! 3. Flood: both cameras at `camera_hz` (the bag looped, restamped each loop) while a client asks
//!    referring queries at `query_hz`: latency, lost queries, queue drops, peak memory.
//! 4. Determinism: the bag through the node's stages twice (every window processed) gives one map
//!    hash. (A live replay drops windows while the worker is busy, so it cannot.)
//!
//! The node thread must end cleanly: a panic anywhere in it is counted.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use groupforward_msgs::gf_msgs::{NodeStatus, ReferRequest, ReferResponse};
use groupforward_msgs::rmw_zenoh::{self, Qos};
use groupforward_msgs::sensor_msgs::{CameraInfo, Image};
use groupforward_msgs::services::Refer;
use groupforward_msgs::tf2_msgs::TFMessage;
use groupforward_msgs::{cdr, RosMessage};
use groupforward_sim::record::{record_to_memory, CameraTopics, RecordOptions};
use groupforward_sim::scene::{CameraSpec, SceneFile};
use groupforward_sim::simulation::Simulation;
use rand::{Rng, SeedableRng};
use serde::Serialize;

use crate::demo::{embedded_node, DemoError};
use groupforward::client::{call_service, call_service_raw, query_json, wait_for};
use groupforward::config::Config;
use groupforward::ingest::test_messages::{hostile_message, HostileTarget};
use groupforward::ingest::CameraConfig;
use groupforward::refer::scripted_chat::{
    vlm_faults, ScriptedChatServer, FAULT_TIMEOUT_SECS, REFUSED_REASON,
};
use groupforward::transport::{Endpoint, Publisher, Transport, ZenohTransport};
use zenoh::Wait;

type Result<T> = std::result::Result<T, DemoError>;

/// What one soak run does.
#[derive(Debug, Clone)]
pub struct SoakOptions {
    pub scene: SceneFile,
    pub bad_messages: usize,
    pub bad_requests: usize,
    pub flood_secs: f64,
    /// Frames per second per camera during the flood.
    pub camera_hz: f64,
    /// Referring queries per second during the flood.
    pub query_hz: f64,
    pub seed: u64,
}

/// What a soak run measured (`DIR/summary.json`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct SoakReport {
    pub messages_sent: u64,
    pub requests_sent: u64,
    /// Bad messages the node's status counted, and under which reasons.
    pub messages_counted: u64,
    pub rejected_by_reason: BTreeMap<String, u64>,
    pub panics: u64,
    pub rss_before_mb: f64,
    pub rss_after_malformed_mb: f64,
    pub rss_peak_flood_mb: f64,
    pub rss_after_mb: f64,
    pub referring_before: Vec<Vec<String>>,
    pub referring_after_malformed: Vec<Vec<String>>,
    pub referring_same_after_malformed: bool,
    pub flood_secs: f64,
    pub flood_frames_published: u64,
    pub flood_frames_dropped_by_queue: u64,
    pub queries_sent: u64,
    pub queries_lost: u64,
    pub query_p50_ms: f64,
    pub query_p99_ms: f64,
    /// The node's own stage times at the end of the flood (p50 / p99 ms over its recent
    /// passes): `query` is the service handler alone, without transport and waiting.
    pub node_stages_after_flood: BTreeMap<String, [f64; 2]>,
    pub replay_hashes: Vec<String>,
    pub replay_hashes_equal: bool,
    /// Referring queries sent to a scripted VLM server failing in each way of
    /// [`vlm_faults`], then once more after it closed its port (connection refused), and those
    /// answered by the built-in reasoner with its own answer and the fault named in the trace.
    pub vlm_faults_tried: u64,
    pub vlm_faults_answered: u64,
    /// Faults not answered so, with what came back instead.
    pub vlm_faults_failed: Vec<String>,
}

/// Resident memory of this process in MB (Linux; 0 elsewhere).
pub fn rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let at = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[at.min(sorted.len() - 1)]
}

fn protocol(e: impl std::fmt::Display) -> DemoError {
    DemoError::Protocol(e.to_string())
}

/// The scene with a second camera, `rear`, on the robot (looking the same way: what matters here
/// is the load of two streams).
fn two_camera_scene(scene: &SceneFile) -> SceneFile {
    let mut scene = scene.clone();
    if let Some(first) = scene.cameras.first().cloned() {
        scene.cameras.truncate(1);
        scene.cameras.push(CameraSpec {
            name: "rear".into(),
            mount: [first.mount[0] - 0.2, first.mount[1], first.mount[2]],
            ..first
        });
    }
    scene
}

/// The node's camera sections for the sim's cameras (its topic names).
fn camera_sections(scene: &SceneFile) -> Vec<CameraConfig> {
    scene
        .cameras
        .iter()
        .map(|c| {
            let topics = CameraTopics::new(&c.name);
            CameraConfig {
                name: c.name.clone(),
                image_topic: topics.image,
                camera_info_topic: topics.camera_info,
                depth_topic: Some(topics.depth),
                ..CameraConfig::default()
            }
        })
        .collect()
}

/// A bag message the flood publishes again: its topic, its type, and its CDR payload.
struct Recorded {
    topic: String,
    type_name: String,
    payload: Vec<u8>,
}

fn read_bag(bag: &[u8]) -> Result<(Vec<Recorded>, i64)> {
    let mut out = Vec::new();
    let (mut first, mut last) = (i64::MAX, i64::MIN);
    for message in mcap::MessageStream::new(bag).map_err(protocol)? {
        let message = message.map_err(protocol)?;
        let topic = message.channel.topic.clone();
        if topic.starts_with("/gt") || topic.ends_with("/compressed") {
            continue;
        }
        let Some(schema) = message.channel.schema.as_ref() else {
            continue;
        };
        let log = message.log_time as i64;
        first = first.min(log);
        last = last.max(log);
        out.push(Recorded {
            topic,
            type_name: schema.name.clone(),
            payload: message.data.to_vec(),
        });
    }
    Ok((out, (last - first).max(0)))
}

/// `payload` with every header stamp moved by `offset_nanos` (images, camera info, transforms).
fn restamp(type_name: &str, payload: &[u8], offset_nanos: i64) -> Option<Vec<u8>> {
    use groupforward_msgs::builtin_interfaces::Time;
    let shift = |t: &mut Time| {
        let nanos = i64::from(t.sec) * 1_000_000_000 + i64::from(t.nanosec);
        *t = Time::from_nanos(nanos + offset_nanos);
    };
    match type_name {
        t if t == Image::TYPE_NAME => {
            let mut m: Image = cdr::decode(payload).ok()?;
            shift(&mut m.header.stamp);
            cdr::encode(&m).ok()
        }
        t if t == CameraInfo::TYPE_NAME => {
            let mut m: CameraInfo = cdr::decode(payload).ok()?;
            shift(&mut m.header.stamp);
            cdr::encode(&m).ok()
        }
        t if t == TFMessage::TYPE_NAME => {
            let mut m: TFMessage = cdr::decode(payload).ok()?;
            for transform in &mut m.transforms {
                shift(&mut transform.header.stamp);
            }
            cdr::encode(&m).ok()
        }
        _ => None,
    }
}

/// One publisher per topic, advertised on first use.
#[derive(Default)]
struct Publishers(BTreeMap<String, Box<dyn Publisher>>);

impl Publishers {
    fn publish(
        &mut self,
        rig: &ZenohTransport,
        topic: &str,
        type_name: &str,
        payload: &[u8],
    ) -> Result<()> {
        if !self.0.contains_key(topic) {
            let endpoint = Endpoint::new(topic, type_name, Qos::sensor_data())?;
            self.0.insert(topic.to_owned(), rig.advertise(&endpoint)?);
        }
        if let Some(p) = self.0.get(topic) {
            p.publish(payload)?;
        }
        Ok(())
    }
}

fn status(session: &zenoh::Session, key: &str) -> Option<NodeStatus> {
    let json = query_json(session, key, Duration::from_millis(500)).ok()?;
    serde_json::from_value(json).ok()
}

fn rejections(status: &NodeStatus) -> BTreeMap<String, u64> {
    let mut out = BTreeMap::new();
    for r in &status.rejections {
        *out.entry(r.reason.clone()).or_default() += r.count;
    }
    out
}

/// Ask a singular expression with `reasoner: vlm` once per fault of the scripted server; each
/// must come back answered by the built-in reasoner (its own ids) with the fault as the reason.
fn vlm_faults_phase(
    report: &mut SoakReport,
    vlm: &ScriptedChatServer,
    texts: &[String],
    ask: &dyn Fn(&str, &str) -> Result<ReferResponse>,
) {
    // A singular expression the built-in reasoner answers with one instance among two candidates
    // or more (the wrong-count fault answers two of them).
    let singular = |t: &str| {
        groupforward::refer::parse(t).is_ok_and(|q| q.count == groupforward::refer::Count::One)
    };
    let builtin = texts.iter().filter(|t| singular(t)).find_map(|t| {
        ask(t, "builtin")
            .ok()
            .filter(|r| r.instance_ids.len() == 1 && r.candidates.len() >= 2)
            .map(|r| (t.clone(), r))
    });
    let Some((text, builtin)) = builtin else {
        report
            .vlm_faults_failed
            .push("no singular expression with two candidates to ask".into());
        return;
    };
    let two = [
        builtin.candidates[0].id.as_str(),
        builtin.candidates[1].id.as_str(),
    ];
    let mut try_fault = |name: &str, reason: &str| {
        report.vlm_faults_tried += 1;
        match ask(&text, "vlm") {
            Ok(r)
                if r.reasoner_used == "fallback"
                    && r.trace.contains(reason)
                    && r.instance_ids == builtin.instance_ids =>
            {
                report.vlm_faults_answered += 1;
            }
            Ok(r) => report.vlm_faults_failed.push(format!(
                "{name}: {} {:?} ({})",
                r.reasoner_used, r.instance_ids, r.trace
            )),
            Err(e) => report
                .vlm_faults_failed
                .push(format!("{name}: no answer ({e})")),
        }
    };
    for fault in vlm_faults(&builtin.instance_ids[0], two) {
        vlm.push(fault.reply);
        try_fault(fault.name, fault.reason);
    }
    // Last, the server goes away: the connection is refused.
    vlm.close();
    try_fault("connection refused", REFUSED_REASON);
}

/// Run the soak; `progress` hears a line per phase.
pub fn run_soak(options: &SoakOptions, progress: &dyn Fn(&str)) -> Result<SoakReport> {
    let mut report = SoakReport::default();
    let scene = two_camera_scene(&options.scene);
    let mut config = Config::default();
    config.status.period_secs = 0.2;
    config.models = groupforward::model::ModelsSection::shipped_in(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models"),
    );
    config.cameras = camera_sections(&scene);
    // Bad requests must reach their decoders, not the rate bound (tested on its own).
    config.node.max_requests_per_second = 0.0;
    config.refer.evidence_dir = String::new();
    // The VLM the faults come from: its port is the node's endpoint from the start.
    let vlm = ScriptedChatServer::listen()
        .map_err(|e| DemoError::Protocol(format!("scripted VLM server: {e}")))?;
    config.refer.vlm.endpoint = vlm.url.clone();
    config.refer.vlm.model = "scripted".into();
    config.refer.vlm.timeout_secs = FAULT_TIMEOUT_SECS;
    let (session, node_transport) = embedded_node(&mut config)?;
    let domain = config.zenoh.domain_id;
    let shutdown = Arc::new(AtomicBool::new(false));
    let node_thread = {
        let (config, shutdown) = (config.clone(), shutdown.clone());
        std::thread::spawn(move || groupforward::node::run(&config, &node_transport, &shutdown))
    };
    let status_key = format!("{}/status", config.api_prefix());
    let timeout = Duration::from_secs(20);
    wait_for("start", timeout, || status(&session, &status_key))?;

    // 1. The map, and the referring answers on it.
    progress("recording the scene and building the map");
    let sim = Simulation::new(scene.clone()).map_err(|e| DemoError::Sim(e.to_string()))?;
    let (bag, recorded) = record_to_memory(&sim, &RecordOptions::default())
        .map_err(|e| DemoError::Sim(e.to_string()))?;
    let rig = ZenohTransport::new(session.clone(), domain, "/", "soak_rig")?;
    groupforward::replay::replay_buffers(
        &["soak.mcap".into()],
        std::slice::from_ref(&bag),
        &rig,
        groupforward::replay::ReplayOptions {
            rate: 1.0,
            loops: 1,
            progress: false,
        },
    )
    .map_err(protocol)?;
    let expected = (recorded.frames - recorded.dropped) as u64;
    wait_for("every frame", timeout, || {
        let s = status(&session, &status_key)?;
        s.cameras
            .iter()
            .all(|c| c.frames_received + c.frames_rejected >= expected)
            .then_some(())
    })?;
    // Let the worker finish the last window.
    std::thread::sleep(Duration::from_secs(2));
    let refer_service =
        rmw_zenoh::resolve_name(&config.node.namespace, &config.node.name, "~/refer")
            .map_err(groupforward::transport::TransportError::from)?;
    let mut expressions = groupforward_sim::referring::scene_expressions(&options.scene)
        .map_err(|e| DemoError::Sim(e.to_string()))?;
    let mut relations = std::collections::BTreeSet::new();
    expressions.retain(|e| relations.insert(e.relation));
    let texts: Vec<String> = expressions.into_iter().map(|e| e.text).collect();
    // `reasoner` "": the node's default.
    let ask = |text: &str, reasoner: &str| -> Result<ReferResponse> {
        call_service::<Refer>(
            &session,
            domain,
            &refer_service,
            &ReferRequest {
                expression: text.to_owned(),
                reasoner: reasoner.to_owned(),
                ..ReferRequest::default()
            },
            Duration::from_secs(5),
        )
        .map_err(DemoError::from)
    };
    let answers = |texts: &[String]| -> Vec<Vec<String>> {
        texts
            .iter()
            .map(|t| ask(t, "").map_or_else(|e| vec![format!("error: {e}")], |r| r.instance_ids))
            .collect()
    };
    report.referring_before = answers(&texts);
    progress("VLM faults");
    vlm_faults_phase(&mut report, &vlm, &texts, &ask);
    // After the faults: their scripted replies (one of 10 MB) are the soak's own memory.
    report.rss_before_mb = rss_mb();

    // 2. Malformed traffic over zenoh.
    progress(&format!(
        "{} bad messages and {} bad requests",
        options.bad_messages, options.bad_requests
    ));
    let before = status(&session, &status_key).unwrap_or_default();
    let counted_before: u64 = rejections(&before).values().sum();
    let mut publishers = Publishers::default();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(options.seed);
    for _ in 0..options.bad_messages {
        let (target, payload) = hostile_message(&mut rng);
        let camera = &config.cameras[rng.random_range(0..config.cameras.len())];
        let (topic, type_name) = match target {
            HostileTarget::Image => (camera.image_topic.clone(), Image::TYPE_NAME),
            HostileTarget::CameraInfo => (camera.camera_info_topic.clone(), CameraInfo::TYPE_NAME),
            HostileTarget::Depth => (
                camera.depth_topic.clone().unwrap_or_default(),
                Image::TYPE_NAME,
            ),
            HostileTarget::Tf => (config.tf.topic.clone(), TFMessage::TYPE_NAME),
            HostileTarget::TfStatic => (config.tf.static_topic.clone(), TFMessage::TYPE_NAME),
        };
        publishers.publish(&rig, &topic, type_name, &payload)?;
        report.messages_sent += 1;
    }
    let service = |name: &str| {
        rmw_zenoh::resolve_name(&config.node.namespace, &config.node.name, name)
            .map_err(groupforward::transport::TransportError::from)
    };
    let (refer, list, get, save, load) = (
        service("~/refer")?,
        service("~/list_instances")?,
        service("~/get_instance")?,
        service("~/save_map")?,
        service("~/load_map")?,
    );
    let wait = Duration::from_secs(2);
    for i in 0..options.bad_requests {
        let mut request = vec![0xff, 0xff, 0, 0];
        request.extend((0..rng.random_range(0..64)).map(|_| rng.random::<u8>()));
        let bytes = request.clone();
        use groupforward_msgs::services as srv;
        let _ = match i % 5 {
            0 => call_service_raw::<srv::Refer>(&session, domain, &refer, bytes, wait),
            1 => call_service_raw::<srv::ListInstances>(&session, domain, &list, bytes, wait),
            2 => call_service_raw::<srv::GetInstance>(&session, domain, &get, bytes, wait),
            3 => call_service_raw::<srv::SaveMap>(&session, domain, &save, bytes, wait),
            _ => call_service_raw::<srv::LoadMap>(&session, domain, &load, bytes, wait),
        };
        let api = ["refer", "instances", "get_instance", "nothing"][i % 4];
        let key = format!("{}/{api}", config.api_prefix());
        let _ = session
            .get(key)
            .payload(request)
            .timeout(Duration::from_secs(2))
            .wait()
            .map(|replies| while replies.recv().is_ok() {});
        report.requests_sent += 2;
    }
    let sent = report.messages_sent;
    let after = wait_for("every bad message counted", Duration::from_secs(60), || {
        let s = status(&session, &status_key)?;
        let counted: u64 = rejections(&s).values().sum::<u64>() - counted_before;
        (counted >= sent).then_some(s)
    })
    .unwrap_or_else(|_| status(&session, &status_key).unwrap_or_default());
    let mut by_reason = rejections(&after);
    for (reason, count) in rejections(&before) {
        if let Some(c) = by_reason.get_mut(&reason) {
            *c -= count;
        }
    }
    by_reason.retain(|_, c| *c > 0);
    report.messages_counted = by_reason.values().sum();
    report.rejected_by_reason = by_reason;
    report.referring_after_malformed = answers(&texts);
    report.referring_same_after_malformed =
        report.referring_after_malformed == report.referring_before;
    report.rss_after_malformed_mb = rss_mb();

    // 3. Flood: both cameras at `camera_hz`, queries at `query_hz`.
    progress(&format!(
        "flood: 2 cameras at {} Hz, queries at {} Hz for {} s",
        options.camera_hz, options.query_hz, options.flood_secs
    ));
    let (messages, span_nanos) = read_bag(&bag)?;
    let flood_before = status(&session, &status_key).unwrap_or_default();
    let stop = Arc::new(AtomicBool::new(false));
    let querying = {
        let (session, stop, texts) = (session.clone(), stop.clone(), texts.clone());
        let period = Duration::from_secs_f64(1.0 / options.query_hz.max(0.1));
        std::thread::spawn(move || {
            let (mut latencies, mut lost) = (Vec::new(), 0u64);
            let mut next = Instant::now();
            let mut i = 0usize;
            while !stop.load(Ordering::Relaxed) {
                let asked = Instant::now();
                let reply = call_service::<Refer>(
                    &session,
                    domain,
                    &refer_service,
                    &ReferRequest {
                        expression: texts
                            .get(i % texts.len().max(1))
                            .cloned()
                            .unwrap_or_default(),
                        ..ReferRequest::default()
                    },
                    Duration::from_secs(2),
                );
                match reply {
                    Ok(_) => latencies.push(asked.elapsed().as_secs_f64() * 1e3),
                    Err(_) => lost += 1,
                }
                i += 1;
                next += period;
                std::thread::sleep(next.saturating_duration_since(Instant::now()));
            }
            (latencies, lost)
        })
    };
    let started = Instant::now();
    // Frames of both cameras go out together: one bag frame per camera per tick.
    let tick = Duration::from_secs_f64(1.0 / options.camera_hz.max(1.0));
    let mut peak = rss_mb();
    let mut next = Instant::now();
    let mut lap = 0i64;
    'flood: loop {
        lap += 1;
        let offset = lap * (span_nanos + 1_000_000_000);
        for m in &messages {
            if started.elapsed().as_secs_f64() >= options.flood_secs {
                break 'flood;
            }
            if m.topic == config.tf.static_topic {
                continue;
            }
            let Some(payload) = restamp(&m.type_name, &m.payload, offset) else {
                continue;
            };
            publishers.publish(&rig, &m.topic, &m.type_name, &payload)?;
            if m.topic == config.cameras[0].image_topic {
                report.flood_frames_published += config.cameras.len() as u64;
                next += tick;
                std::thread::sleep(next.saturating_duration_since(Instant::now()));
                peak = peak.max(rss_mb());
            }
        }
    }
    stop.store(true, Ordering::Relaxed);
    let (mut latencies, lost) = querying.join().unwrap_or_default();
    report.flood_secs = started.elapsed().as_secs_f64();
    latencies.sort_by(f64::total_cmp);
    report.queries_sent = latencies.len() as u64 + lost;
    report.queries_lost = lost;
    report.query_p50_ms = percentile(&latencies, 0.5);
    report.query_p99_ms = percentile(&latencies, 0.99);
    let flood_after = status(&session, &status_key).unwrap_or_default();
    let overflow = |s: &NodeStatus| -> u64 {
        s.rejections
            .iter()
            .filter(|r| r.reason.contains("overflow"))
            .map(|r| r.count)
            .sum()
    };
    report.flood_frames_dropped_by_queue = overflow(&flood_after) - overflow(&flood_before);
    report.node_stages_after_flood = flood_after
        .stages
        .iter()
        .map(|t| (t.stage.clone(), [t.p50_ms, t.p99_ms]))
        .collect();
    report.rss_peak_flood_mb = peak;

    shutdown.store(true, Ordering::Relaxed);
    report.panics = match node_thread.join() {
        Ok(Ok(_)) => 0,
        Ok(Err(e)) => {
            tracing::error!("the node stopped with an error: {e}");
            0
        }
        Err(_) => 1,
    };
    report.rss_after_mb = rss_mb();

    // 4. Determinism: the same bag through the node's stages twice.
    progress("determinism: the scene's map twice");
    let eval_config = Config {
        models: config.models.clone(),
        ..Config::default()
    };
    let mut models =
        groupforward::window::WindowModels::load(&eval_config.models, &eval_config.semantics)
            .map_err(|e| DemoError::Protocol(e.to_string()))?;
    for _ in 0..2 {
        let run = crate::eval::run::run_scene(&options.scene, &eval_config, &mut models)
            .map_err(|e| DemoError::Protocol(e.to_string()))?;
        report
            .replay_hashes
            .push(groupforward::graph::persist::content_hash(&run.map));
    }
    report.replay_hashes_equal = report.replay_hashes.windows(2).all(|w| w[0] == w[1]);
    Ok(report)
}

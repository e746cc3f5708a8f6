//! `groupforward demo`: the whole node in one process over an embedded zenoh peer. The simulator
//! records a scene as a rosbag2 bag (what a robot records, plus ground truth on `/gt/...`), the
//! bag is replayed over zenoh exactly as `groupforward replay` would (rmw_zenoh keys, CDR,
//! attachments), the node ingests it, and the demo then asks the node what it saw through its
//! JSON API and its ROS 2 service, next to the scene's ground truth and the referring expressions
//! generated from it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use groupforward_msgs::geometry_msgs::Quaternion;
use groupforward_msgs::gf_msgs::{
    InstanceArray, InstanceMasks, ListInstancesRequest, ListInstancesResponse, MapPathRequest,
    MapResultResponse, NodeStatus, SceneGraph,
};
use groupforward_msgs::rmw_zenoh::{self, Qos};
use groupforward_msgs::sensor_msgs::Image;
use groupforward_msgs::sensor_msgs::PointCloud2;
use groupforward_msgs::services::{ListInstances, Refer, SaveMap};
use groupforward_msgs::tf2_msgs::TFMessage;
use groupforward_msgs::vision_msgs::Detection3DArray;
use groupforward_msgs::visualization_msgs::MarkerArray;
use groupforward_msgs::{cdr, RosMessage};
use groupforward_sim::record::{record_to_memory, RecordOptions, RecordSummary};
use groupforward_sim::referring::Expression;
use groupforward_sim::scene::SceneFile;
use groupforward_sim::simulation::Simulation;

use groupforward::client::{call_service, query_json, wait_for, ClientError};
use groupforward::config::Config;
use groupforward::transport::ZenohSection;
use groupforward::transport::{open_session, Endpoint, Transport, TransportError, ZenohTransport};

#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Node(#[from] groupforward::node::NodeError),
    #[error("{0}")]
    Protocol(String),
    #[error("simulator: {0}")]
    Sim(String),
    /// A call to the node failed or timed out ([`groupforward::client`]).
    #[error(transparent)]
    Client(#[from] ClientError),
}

pub type Result<T> = std::result::Result<T, DemoError>;

#[derive(Debug, Clone, PartialEq)]
pub struct DemoOptions {
    /// The scene the simulator records (default: the embedded `two_chairs` scene).
    pub scene: SceneFile,
    /// Replay speed factor of the recorded bag.
    pub rate: f64,
    /// Write everything the node publishes to this rosbag2 bag directory.
    pub record_outputs: Option<std::path::PathBuf>,
}

impl Default for DemoOptions {
    fn default() -> Self {
        Self {
            scene: SceneFile::builtin("two_chairs").unwrap_or_else(|| unreachable!()),
            rate: 1.0,
            record_outputs: None,
        }
    }
}

/// Free-form phrases the demo resolves to class names with the text encoder.
pub const DEMO_QUERIES: &[&str] = &[
    "garbage can",
    "where one can wash hands",
    "where the milk stays cold",
    "a place to sleep",
    "computer screen",
];

/// A phrase, the class name it is closest to, and their cosine similarity.
pub type VocabularyMatch = (String, String, f32);

/// Resolve `queries` to the closest class of the simulator's library (by name, description or
/// affordance) with the text encoder.
pub fn match_vocabulary(queries: &[&str]) -> std::result::Result<Vec<VocabularyMatch>, String> {
    use groupforward::model::text::{cosine, TextEncoder};
    groupforward::model::init_runtime(None).map_err(|e| e.to_string())?;
    let manifest =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/all-MiniLM-L6-v2.toml");
    let mut encoder = TextEncoder::load(&manifest, &groupforward::model::SessionOptions::default())
        .map_err(|e| e.to_string())?;
    // The vocabulary: the simulator library's class names.
    // Each class is known by its name, its description and its affordances ("wash hands"); a
    // phrase matches a class through the closest of these texts.
    let mut texts: Vec<(&'static str, Vec<f32>)> = Vec::new();
    for class in groupforward_sim::library::classes() {
        let phrases = [class.name, class.description]
            .into_iter()
            .chain(class.affordances.iter().copied());
        for phrase in phrases {
            texts.push((
                class.name,
                encoder.embed(phrase).map_err(|e| e.to_string())?,
            ));
        }
    }
    let mut matches = Vec::new();
    for query in queries {
        let q = encoder.embed(query).map_err(|e| e.to_string())?;
        let (best, score) = texts
            .iter()
            .map(|(name, e)| (*name, cosine(&q, e)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .ok_or("empty vocabulary")?;
        matches.push(((*query).to_owned(), best.to_owned(), score));
    }
    Ok(matches)
}

/// A referring expression generated from ground truth, the service's answer, and the objects
/// the answered instances' boxes name.
#[derive(Debug, Clone)]
pub struct DemoAnswer {
    pub expression: Expression,
    pub response: groupforward_msgs::gf_msgs::ReferResponse,
    pub answered: Vec<u16>,
    /// Round trip through zenoh.
    pub millis: f64,
}

/// One ground-truth object of the scene: instance id, class, position of its base.
pub type GroundTruthObject = (u16, String, [f64; 3]);

/// What the demo observed, all of it read back from the running node, with the scene's ground
/// truth next to it.
#[derive(Debug, Clone)]
pub struct DemoReport {
    pub scene: String,
    pub recorded: RecordSummary,
    pub replayed_messages: u64,
    pub status: NodeStatus,
    pub malformed_published: u64,
    /// What `list_instances` answered at the end.
    pub instances: Vec<groupforward_msgs::gf_msgs::Instance>,
    pub objects: Vec<GroundTruthObject>,
    /// A sample of the scene's generated referring expressions (one per relation type), asked
    /// through the `Refer` service.
    pub answers: Vec<DemoAnswer>,
    /// Where the answers' evidence bundles were written.
    pub evidence_dir: std::path::PathBuf,
    /// Open-vocabulary lookups, or why the text encoder could not run.
    pub vocabulary: std::result::Result<Vec<VocabularyMatch>, String>,
    /// The listed instances against the scene's objects, with `eval map`'s yardstick.
    pub map_score: crate::eval::score::Counts,
    /// What the node's output topics carried last, as a subscriber received it.
    pub published: PublishedOutputs,
    /// Messages written to the `record_outputs` bag, when one was asked for.
    pub recorded_outputs: Option<u64>,
    /// The map as `save_map` wrote it at the end, and its content hash (or why not).
    pub saved_map: std::result::Result<(std::path::PathBuf, String), String>,
    pub elapsed: Duration,
}

/// The last message of each output topic, decoded, as a subscriber of the running node saw it.
#[derive(Debug, Clone, Default)]
pub struct PublishedOutputs {
    pub detections: Option<Detection3DArray>,
    pub instance_array: Option<InstanceArray>,
    pub cloud: Option<PointCloud2>,
    /// Every mask message received (one per view of each published window).
    pub masks: Vec<InstanceMasks>,
    pub markers: Option<MarkerArray>,
    pub scene_graph: Option<SceneGraph>,
    /// Messages received over all output topics.
    pub messages: u64,
    /// Per topic name: messages and bytes received.
    pub traffic: std::collections::BTreeMap<String, (u64, u64)>,
}

/// Received payloads by topic name.
type Inbox = Arc<std::sync::Mutex<std::collections::HashMap<String, Vec<Vec<u8>>>>>;

/// Subscribe to every output topic of `endpoints` on `transport`, collecting payloads.
fn subscribe_outputs(
    transport: &dyn Transport,
    endpoints: &groupforward::node::outputs::OutputEndpoints,
) -> Result<Inbox> {
    let inbox: Inbox = Arc::default();
    for endpoint in endpoints.all() {
        let (inbox, name) = (inbox.clone(), endpoint.name.clone());
        transport.subscribe(
            endpoint,
            Arc::new(move |payload| {
                if let Ok(mut inbox) = inbox.lock() {
                    inbox.entry(name.clone()).or_default().push(payload);
                }
            }),
        )?;
    }
    Ok(inbox)
}

/// Decode what `inbox` holds (the last message of each topic; every mask message).
fn decode_outputs(
    inbox: &Inbox,
    endpoints: &groupforward::node::outputs::OutputEndpoints,
) -> PublishedOutputs {
    let Ok(inbox) = inbox.lock() else {
        return PublishedOutputs::default();
    };
    fn last<T: serde::de::DeserializeOwned>(
        inbox: &std::collections::HashMap<String, Vec<Vec<u8>>>,
        endpoint: &Option<Endpoint>,
    ) -> Option<T> {
        let payloads = inbox.get(&endpoint.as_ref()?.name)?;
        cdr::decode(payloads.last()?).ok()
    }
    PublishedOutputs {
        detections: last(&inbox, &endpoints.instances),
        instance_array: last(&inbox, &endpoints.instance_array),
        cloud: last(&inbox, &endpoints.instance_cloud),
        masks: endpoints
            .instance_masks
            .as_ref()
            .and_then(|e| inbox.get(&e.name))
            .map(|all| all.iter().filter_map(|p| cdr::decode(p).ok()).collect())
            .unwrap_or_default(),
        markers: last(&inbox, &endpoints.markers),
        scene_graph: last(&inbox, &endpoints.scene_graph),
        messages: inbox.values().map(|v| v.len() as u64).sum(),
        traffic: inbox
            .iter()
            .map(|(topic, all)| {
                let bytes = all.iter().map(|p| p.len() as u64).sum();
                (topic.clone(), (all.len() as u64, bytes))
            })
            .collect(),
    }
}

/// An embedded zenoh peer (no router to connect to) for `config`'s node: the session clients of
/// this process share, and the node's transport on it.
pub fn embedded_node(config: &mut Config) -> Result<(zenoh::Session, ZenohTransport)> {
    config.zenoh = ZenohSection {
        connect: Vec::new(),
        ..ZenohSection::default()
    };
    let session = open_session(&config.zenoh)?;
    let transport = ZenohTransport::new(
        session.clone(),
        config.zenoh.domain_id,
        &config.node.namespace,
        &config.node.name,
    )?;
    Ok((session, transport))
}

pub fn run_demo(options: &DemoOptions) -> Result<DemoReport> {
    let started = Instant::now();
    let mut config = Config::default();
    config.status.period_secs = 0.2;
    // The shipped models, wherever the demo is started from.
    config.models = groupforward::model::ModelsSection::shipped_in(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models"),
    );
    // Every answer's evidence bundle (PNG + JSON) lands here for a person to look at.
    let evidence_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map_or_else(
            || std::path::PathBuf::from("."),
            std::path::Path::to_path_buf,
        )
        .join("target/demo/evidence");
    let _ = std::fs::remove_dir_all(&evidence_dir);
    config.refer.evidence_dir = evidence_dir.display().to_string();
    // save_map writes the map beside the evidence, wherever the demo was started from.
    config.map.directory = evidence_dir.parent().map(|dir| dir.display().to_string());
    let (session, node_transport) = embedded_node(&mut config)?;
    let domain = config.zenoh.domain_id;
    // A subscriber of every output topic, as RViz or a navigation stack would be.
    let listener = ZenohTransport::new(session.clone(), domain, "/", "demo_listener")?;
    let output_endpoints = groupforward::node::outputs::OutputEndpoints::declare(&config)?;
    let inbox = subscribe_outputs(&listener, &output_endpoints)?;
    let shutdown = Arc::new(AtomicBool::new(false));
    let recorder = match &options.record_outputs {
        Some(dir) => Some(
            groupforward::record::Recorder::create(dir)
                .map_err(|e| DemoError::Protocol(e.to_string()))?,
        ),
        None => None,
    };
    let node_thread = {
        let (config, shutdown, recorder) = (config.clone(), shutdown.clone(), recorder.clone());
        std::thread::spawn(move || match recorder {
            Some(recorder) => {
                let recording = groupforward::record::RecordingTransport {
                    inner: &node_transport,
                    recorder,
                };
                groupforward::node::run(&config, &recording, &shutdown)
            }
            None => groupforward::node::run(&config, &node_transport, &shutdown),
        })
    };
    let status_key = format!("{}/status", config.api_prefix());
    let timeout = Duration::from_secs(10);
    wait_for("start", timeout, || {
        query_json(&session, &status_key, Duration::from_millis(500)).ok()
    })?;

    // The simulator records the scene; the bag is replayed into the node.
    let sim = Simulation::new(options.scene.clone()).map_err(|e| DemoError::Sim(e.to_string()))?;
    let (bag, recorded) = record_to_memory(&sim, &RecordOptions::default())
        .map_err(|e| DemoError::Sim(e.to_string()))?;
    let rig = ZenohTransport::new(session.clone(), domain, "/", "demo_replay")?;
    let replayed = groupforward::replay::replay_buffers(
        &[format!("{}.mcap", options.scene.name)],
        &[bag],
        &rig,
        groupforward::replay::ReplayOptions {
            rate: options.rate,
            loops: 1,
            progress: false,
        },
    )
    .map_err(|e| DemoError::Protocol(e.to_string()))?;

    // Bad input the node must reject and count while it keeps serving: a truncated image and a
    // transform with a NaN quaternion.
    let camera = &config.cameras[0];
    let advertise = |name: &str, type_name: &str| -> Result<_> {
        Ok(rig.advertise(&Endpoint::new(name, type_name, Qos::sensor_data())?)?)
    };
    let image_pub = advertise(&camera.image_topic, Image::TYPE_NAME)?;
    let tf_pub = advertise(&config.tf.topic, TFMessage::TYPE_NAME)?;
    let first = sim.frame(0);
    let view = first
        .views
        .first()
        .ok_or_else(|| DemoError::Sim("frame 0 of the scene is dropped".into()))?;
    let image = Image {
        header: Default::default(),
        height: view.truth.height,
        width: view.truth.width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: view.truth.width * 3,
        data: view.sensor_rgb().to_vec(),
    };
    let mut truncated = cdr::encode(&image).map_err(|e| DemoError::Protocol(e.to_string()))?;
    truncated.truncate(truncated.len() / 2);
    image_pub.publish(&truncated)?;
    let bad_tf = TFMessage {
        transforms: vec![groupforward_msgs::geometry_msgs::TransformStamped {
            header: groupforward_msgs::std_msgs::Header {
                stamp: Default::default(),
                frame_id: config.tf.world_frame.clone(),
            },
            child_frame_id: "base_link".into(),
            transform: groupforward_msgs::geometry_msgs::Transform {
                rotation: Quaternion {
                    x: f64::NAN,
                    y: 0.0,
                    z: 0.0,
                    w: 1.0,
                },
                ..Default::default()
            },
        }],
    };
    tf_pub.publish(&cdr::encode(&bad_tf).map_err(|e| DemoError::Protocol(e.to_string()))?)?;

    let expected = (recorded.frames - recorded.dropped) as u64;
    let status = wait_for("report every frame", timeout, || {
        let json = query_json(&session, &status_key, Duration::from_millis(500)).ok()?;
        let status: NodeStatus = serde_json::from_value(json).ok()?;
        let camera = status.cameras.first()?;
        let settled = camera.frames_received >= expected
            && camera.frames_rejected >= 1
            && status.tf_rejected >= 1;
        settled.then_some(status)
    })?;
    let list_service = rmw_zenoh::resolve_name(
        &config.node.namespace,
        &config.node.name,
        "~/list_instances",
    )
    .map_err(TransportError::from)?;
    let list = || {
        call_service::<ListInstances>(
            &session,
            domain,
            &list_service,
            &ListInstancesRequest::default(),
            timeout,
        )
        .map(|r: ListInstancesResponse| r.instances)
    };
    // The window worker may still be fusing the last window, and the keyframes short of a
    // window are mapped once the stream has been quiet for `flush_after_secs`: wait until the
    // list stays the same for longer than that.
    let mut instances = list()?;
    let settle_deadline = Instant::now() + timeout;
    let settle = Duration::try_from_secs_f64(config.window.flush_after_secs)
        .unwrap_or_default()
        .min(Duration::from_secs(5))
        + Duration::from_millis(600);
    loop {
        std::thread::sleep(settle);
        let again = list()?;
        let settled = again.len() == instances.len()
            && again
                .iter()
                .zip(&instances)
                .all(|(a, b)| a.id == b.id && a.point_count == b.point_count && a.pose == b.pose);
        instances = again;
        if settled || Instant::now() >= settle_deadline {
            break;
        }
    }
    // Referring questions through the `Refer` service, as a ROS 2 client would ask them: one
    // generated expression per relation type.
    let mut expressions = groupforward_sim::referring::scene_expressions(&options.scene)
        .map_err(|e| DemoError::Sim(e.to_string()))?;
    let mut seen = std::collections::BTreeSet::new();
    expressions.retain(|e| seen.insert(e.relation));
    let refer_service =
        rmw_zenoh::resolve_name(&config.node.namespace, &config.node.name, "~/refer")
            .map_err(TransportError::from)?;
    let truth = crate::eval::run::truth_objects(&sim.scene, |_| 1);
    let mut answers = Vec::new();
    for expression in &expressions {
        let asked = Instant::now();
        let response = call_service::<Refer>(
            &session,
            domain,
            &refer_service,
            &crate::eval::refer::request_for(expression),
            timeout,
        )?;
        let millis = asked.elapsed().as_secs_f64() * 1e3;
        let mut answered: Vec<u16> = response
            .boxes
            .iter()
            .map(|b| crate::eval::refer::matched_object(&crate::eval::refer::oriented(b), &truth).0)
            .collect();
        answered.sort_unstable();
        answered.dedup();
        answers.push(DemoAnswer {
            expression: expression.clone(),
            response,
            answered,
            millis,
        });
    }
    // The map as a client saves it, and its content hash (two runs that built the same map
    // print the same hash; the live node drops windows while busy, so two runs may not).
    let save_service =
        rmw_zenoh::resolve_name(&config.node.namespace, &config.node.name, "~/save_map")
            .map_err(TransportError::from)?;
    let map_file = evidence_dir
        .parent()
        .map_or_else(|| evidence_dir.clone(), std::path::Path::to_path_buf)
        .join("map.gfmap");
    let saved_map = call_service::<SaveMap>(
        &session,
        domain,
        &save_service,
        &MapPathRequest {
            path: map_file.display().to_string(),
        },
        timeout,
    )
    .map_err(|e| e.to_string())
    .and_then(|r: MapResultResponse| if r.success { Ok(()) } else { Err(r.message) })
    .and_then(|()| {
        groupforward::graph::persist::load(&map_file, groupforward::graph::FusionParams::default())
            .map_err(|e| e.to_string())
    })
    .map(|map| {
        (
            map_file.clone(),
            groupforward::graph::persist::content_hash(&map),
        )
    });
    // The status after the queries: where the time went, the queries included.
    let asked = answers.len() as u64;
    let read_status = || {
        let json = query_json(&session, &status_key, Duration::from_millis(500)).ok()?;
        serde_json::from_value::<NodeStatus>(json).ok()
    };
    let status = match wait_for("time the queries", timeout, || {
        let status = read_status()?;
        let timed = status.stages.iter().find(|s| s.stage == "query");
        timed.is_some_and(|s| s.count >= asked).then_some(status)
    }) {
        Ok(later) => later,
        // A node too busy to count every query in time still reports what it did since the
        // frames arrived (its windows above all): a newer status than the one from then.
        Err(_) => read_status().unwrap_or(status),
    };
    shutdown.store(true, Ordering::Relaxed);
    match node_thread.join() {
        Ok(result) => {
            result?;
        }
        Err(_) => return Err(DemoError::Protocol("the node thread panicked".into())),
    }
    let recorded_outputs = match &recorder {
        Some(recorder) => Some(
            recorder
                .finish()
                .map_err(|e| DemoError::Protocol(e.to_string()))?,
        ),
        None => None,
    };
    let classes = groupforward_sim::library::classes();
    let objects = sim
        .scene
        .objects
        .iter()
        .map(|o| {
            let class = classes
                .iter()
                .find(|c| c.id == o.class_id)
                .map_or("unknown", |c| c.name);
            (o.instance_id, class.to_owned(), o.position.to_array())
        })
        .collect();
    let map_score = score_listed(&sim, &instances, &options.scene);
    // The node published its final map while stopping; give the last messages time to arrive.
    // An earlier map's message can have as many detections, so wait for the listed boxes.
    let published = wait_for("publish its final map", timeout, || {
        let published = decode_outputs(&inbox, &output_endpoints);
        let arrived = published.detections.as_ref().is_some_and(|d| {
            d.detections.len() == instances.len()
                && d.detections.iter().all(|detection| {
                    instances.iter().any(|i| {
                        i.id == detection.id
                            && i.pose == detection.bbox.center
                            && i.size == detection.bbox.size
                    })
                })
        });
        arrived.then_some(published)
    })
    .unwrap_or_else(|_| decode_outputs(&inbox, &output_endpoints));
    Ok(DemoReport {
        scene: options.scene.name.clone(),
        recorded,
        replayed_messages: replayed.published,
        status,
        malformed_published: 2,
        instances,
        objects,
        answers,
        evidence_dir,
        vocabulary: match_vocabulary(DEMO_QUERIES),
        map_score,
        published,
        recorded_outputs,
        saved_map,
        elapsed: started.elapsed(),
    })
}

/// The instances `list_instances` answered, scored against the scene's objects as `eval map`
/// scores a map.
fn score_listed(
    sim: &Simulation,
    instances: &[groupforward_msgs::gf_msgs::Instance],
    scene: &SceneFile,
) -> crate::eval::score::Counts {
    use crate::eval::score::{score_map, ListedInstance};
    // Every object counts: the demo's orbit sees them all.
    let objects = crate::eval::run::truth_objects(&sim.scene, |_| 1);
    let listed: Vec<ListedInstance> = instances
        .iter()
        .map(|i| {
            let best = i.hypotheses.first();
            ListedInstance {
                id: i.id.clone(),
                name: best.map_or(String::new(), |h| h.class_id.clone()),
                name_score: best.map_or(0.0, |h| h.score),
                // The message does not say; the demo's score line does not use it.
                observations: 0,
                gaussians: i.point_count as usize,
                bbox: crate::eval::refer::instance_box(i),
            }
        })
        .collect();
    let room = scene.room.size;
    score_map(&scene.name, &objects, &listed, room[0] * room[1], 0).1
}

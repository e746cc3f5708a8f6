//! `groupforward demo`: the whole node in one process over an embedded zenoh peer. A simulated
//! camera publishes exactly what a robot would (rmw_zenoh keys, CDR, attachments), the node ingests
//! it, and the demo then asks the node what it saw through its JSON API and its ROS 2 service.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use groupforward_msgs::geometry_msgs::Quaternion;
use groupforward_msgs::gf_msgs::{ListInstancesRequest, ListInstancesResponse, NodeStatus};
use groupforward_msgs::rmw_zenoh::{self, Attachment, Qos};
use groupforward_msgs::sensor_msgs::{CameraInfo, Image};
use groupforward_msgs::services::ListInstances;
use groupforward_msgs::tf2_msgs::TFMessage;
use groupforward_msgs::{cdr, RosMessage, RosService};
use groupforward_sim::testcard::TestCard;
use zenoh::Wait;

use crate::config::{Config, ZenohSection};
use crate::transport::{open_session, Endpoint, Transport, TransportError, ZenohTransport};

#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Node(#[from] crate::node::NodeError),
    #[error("the node did not {0} within {1:?}")]
    Timeout(&'static str, Duration),
    #[error("{0}")]
    Protocol(String),
}

pub type Result<T> = std::result::Result<T, DemoError>;

#[derive(Debug, Clone, PartialEq)]
pub struct DemoOptions {
    pub frames: u64,
    pub rate_hz: f64,
    pub width: u32,
    pub height: u32,
}

impl Default for DemoOptions {
    fn default() -> Self {
        Self {
            frames: 30,
            rate_hz: 15.0,
            width: 320,
            height: 240,
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
    use crate::model::text::{cosine, TextEncoder};
    crate::model::init_runtime(None).map_err(|e| e.to_string())?;
    let manifest =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/all-MiniLM-L6-v2.toml");
    let mut encoder = TextEncoder::load(&manifest, &crate::model::SessionOptions::default())
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

/// What the demo observed, all of it read back from the running node.
#[derive(Debug, Clone)]
pub struct DemoReport {
    pub status: NodeStatus,
    pub frames_published: u64,
    pub malformed_published: u64,
    pub instances: usize,
    /// Open-vocabulary lookups, or why the text encoder could not run.
    pub vocabulary: std::result::Result<Vec<VocabularyMatch>, String>,
    pub elapsed: Duration,
}

/// The payload of the first reply to a get, or the error the replier sent.
fn first_reply(
    get: zenoh::session::SessionGetBuilder<'_, '_, zenoh::handlers::DefaultHandler>,
    what: &'static str,
    timeout: Duration,
) -> Result<Vec<u8>> {
    let replies = get
        .timeout(timeout)
        .wait()
        .map_err(|e| DemoError::Protocol(e.to_string()))?;
    let reply = replies
        .recv_timeout(timeout)
        .map_err(|e| DemoError::Protocol(e.to_string()))?
        .ok_or(DemoError::Timeout(what, timeout))?;
    match reply.result() {
        Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
        Err(e) => Err(DemoError::Protocol(format!(
            "{what}: error reply {}",
            String::from_utf8_lossy(&e.payload().to_bytes())
        ))),
    }
}

/// One JSON API request through zenoh.
pub fn query_json(
    session: &zenoh::Session,
    key: &str,
    timeout: Duration,
) -> Result<serde_json::Value> {
    let payload = first_reply(session.get(key), "answer the JSON API", timeout)?;
    serde_json::from_slice(&payload)
        .map_err(|e| DemoError::Protocol(format!("JSON API answered non-JSON: {e}")))
}

/// Call an rmw_zenoh service as a ROS 2 client would: a get on the service key with a CDR request
/// and an attachment.
pub fn call_service<S: RosService>(
    session: &zenoh::Session,
    domain_id: u32,
    service_name: &str,
    request: &S::Request,
    timeout: Duration,
) -> Result<S::Response> {
    let hash = groupforward_msgs::idl::type_hash(S::TYPE_NAME).map_err(TransportError::from)?;
    let key = rmw_zenoh::data_key(domain_id, service_name, S::TYPE_NAME, &hash)
        .map_err(TransportError::from)?;
    let attachment = Attachment {
        sequence_number: 1,
        source_timestamp: 0,
        source_gid: rmw_zenoh::gid_for_token(&key),
    };
    let payload = cdr::encode(request).map_err(|e| DemoError::Protocol(e.to_string()))?;
    let get = session
        .get(key)
        .payload(payload)
        .attachment(attachment.encode());
    let response = first_reply(get, "answer the service", timeout)?;
    cdr::decode(&response).map_err(|e| DemoError::Protocol(e.to_string()))
}

/// Poll `check` every 20 ms until it returns `Some`, or fail after `timeout`.
pub fn wait_for<T>(
    what: &'static str,
    timeout: Duration,
    mut check: impl FnMut() -> Option<T>,
) -> Result<T> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(value) = check() {
            return Ok(value);
        }
        if Instant::now() >= deadline {
            return Err(DemoError::Timeout(what, timeout));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

pub fn run_demo(options: &DemoOptions) -> Result<DemoReport> {
    let started = Instant::now();
    let mut config = Config::default();
    config.status.period_secs = 0.2;
    let embedded = ZenohSection {
        connect: Vec::new(),
        ..ZenohSection::default()
    };
    config.zenoh = embedded.clone();
    let session = open_session(&embedded)?;
    let domain = config.zenoh.domain_id;
    let node_transport = ZenohTransport::new(
        session.clone(),
        domain,
        &config.node.namespace,
        &config.node.name,
    )?;
    let shutdown = Arc::new(AtomicBool::new(false));
    let node_thread = {
        let (config, shutdown) = (config.clone(), shutdown.clone());
        std::thread::spawn(move || crate::node::run(&config, &node_transport, &shutdown))
    };
    let status_key = format!("{}/status", config.api_prefix());
    let timeout = Duration::from_secs(10);
    wait_for("start", timeout, || {
        query_json(&session, &status_key, Duration::from_millis(500)).ok()
    })?;

    let camera = &config.cameras[0];
    let card = TestCard {
        width: options.width,
        height: options.height,
        rate_hz: options.rate_hz,
        ..TestCard::default()
    };
    let rig = ZenohTransport::new(session.clone(), domain, "/", "demo_camera")?;
    let advertise = |name: &str, type_name: &str| -> Result<_> {
        Ok(rig.advertise(&Endpoint::new(name, type_name, Qos::sensor_data())?)?)
    };
    let image_pub = advertise(&camera.image_topic, Image::TYPE_NAME)?;
    let info_pub = advertise(&camera.camera_info_topic, CameraInfo::TYPE_NAME)?;
    let depth_topic = camera
        .depth_topic
        .clone()
        .unwrap_or_else(|| "/camera/depth/image_raw".into());
    let depth_pub = advertise(&depth_topic, Image::TYPE_NAME)?;
    let tf_pub = advertise(&config.tf.topic, TFMessage::TYPE_NAME)?;
    let tf_static_pub = advertise(&config.tf.static_topic, TFMessage::TYPE_NAME)?;
    let encode =
        |m: &dyn erased::Encode| m.encode().map_err(|e| DemoError::Protocol(e.to_string()));

    tf_static_pub.publish(&encode(&card.tf_static())?)?;
    let period = Duration::from_secs_f64(1.0 / options.rate_hz);
    for index in 0..options.frames {
        let frame = card.frame(index);
        tf_pub.publish(&encode(&frame.tf)?)?;
        info_pub.publish(&encode(&frame.camera_info)?)?;
        depth_pub.publish(&encode(&frame.depth)?)?;
        image_pub.publish(&encode(&frame.image)?)?;
        std::thread::sleep(period);
    }
    // Bad input the node must reject and count while it keeps serving: a truncated image and a
    // transform with a NaN quaternion.
    let mut truncated = encode(&card.image(0))?;
    truncated.truncate(truncated.len() / 2);
    image_pub.publish(&truncated)?;
    let mut bad_tf = card.tf(0);
    bad_tf.transforms[0].transform.rotation = Quaternion {
        x: f64::NAN,
        y: 0.0,
        z: 0.0,
        w: 1.0,
    };
    tf_pub.publish(&encode(&bad_tf)?)?;

    let expected = options.frames;
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
    let instances = call_service::<ListInstances>(
        &session,
        domain,
        &list_service,
        &ListInstancesRequest::default(),
        timeout,
    )?;
    let ListInstancesResponse { instances } = instances;
    shutdown.store(true, Ordering::Relaxed);
    match node_thread.join() {
        Ok(result) => {
            result?;
        }
        Err(_) => return Err(DemoError::Protocol("the node thread panicked".into())),
    }
    Ok(DemoReport {
        status,
        frames_published: options.frames,
        malformed_published: 2,
        instances: instances.len(),
        vocabulary: match_vocabulary(DEMO_QUERIES),
        elapsed: started.elapsed(),
    })
}

/// Object-safe encoding, so one closure can encode every message type.
mod erased {
    pub trait Encode {
        fn encode(&self) -> groupforward_msgs::cdr::Result<Vec<u8>>;
    }

    impl<T: serde::Serialize> Encode for T {
        fn encode(&self) -> groupforward_msgs::cdr::Result<Vec<u8>> {
            groupforward_msgs::cdr::encode(self)
        }
    }
}

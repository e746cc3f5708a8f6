//! Transport: moves serialized messages, nothing else.
//!
//! [`ZenohTransport`] speaks ROS 2's rmw_zenoh wire format (data keys with type hashes, liveliness
//! tokens for the node and each entity, an attachment on every sample and reply), so a ROS 2 system
//! on rmw_zenoh sees the node natively, and it serves a plain JSON API under
//! `groupforward/<namespace>/<name>` for non-ROS clients. [`MemoryTransport`] does the same in
//! process, for tests of the node loop without a network.

use std::collections::HashMap;
use std::sync::atomic::{AtomicI64, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use groupforward_msgs::rmw_zenoh::{
    self, gid_for_token, Attachment, EntityKind, NodeIdentity, Qos,
};
use zenoh::Wait;

use serde::{Deserialize, Serialize};

#[cfg(feature = "ros2")]
pub mod ros2;

/// ROS_DOMAIN_ID unless configured.
pub const DEFAULT_DOMAIN_ID: u32 = 0;

/// The middleware the node speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum TransportKind {
    /// zenoh, wire-compatible with ROS 2's rmw_zenoh, plus the JSON API.
    #[default]
    Zenoh,
    /// Native ROS 2 through rcl (r2r): a build with the `ros2` feature.
    Ros2,
}

impl std::str::FromStr for TransportKind {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        match s {
            "zenoh" => Ok(Self::Zenoh),
            "ros2" => Ok(Self::Ros2),
            other => Err(format!("unknown transport `{other}` (zenoh or ros2)")),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ZenohMode {
    #[default]
    Peer,
    Client,
    Router,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohSection {
    pub mode: ZenohMode,
    /// Endpoints to listen on, e.g. `tcp/0.0.0.0:7447`.
    pub listen: Vec<String>,
    /// Endpoints to connect to, e.g. the rmw_zenoh router `tcp/localhost:7447`.
    pub connect: Vec<String>,
    /// Off by default: robots on shared networks should not discover each other by accident.
    pub multicast_scouting: bool,
    /// ROS_DOMAIN_ID, the first chunk of every rmw_zenoh key.
    pub domain_id: u32,
    /// A zenoh JSON5 config file read first (the same format as rmw_zenoh's
    /// `ZENOH_SESSION_CONFIG_URI`): user / password authentication, access control (ACL), TLS,
    /// anything zenoh configures. `mode`, `listen`, `connect` and `multicast_scouting` above
    /// then override its values. `launch/zenoh_access_control.json5` is a commented example.
    pub config_file: Option<String>,
}

impl Default for ZenohSection {
    fn default() -> Self {
        Self {
            mode: ZenohMode::Peer,
            listen: Vec::new(),
            connect: vec!["tcp/localhost:7447".into()],
            multicast_scouting: false,
            domain_id: DEFAULT_DOMAIN_ID,
            config_file: None,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error("zenoh: {0}")]
    Zenoh(String),
    #[error("naming: {0}")]
    Naming(#[from] rmw_zenoh::NamingError),
    #[error("type hash: {0}")]
    TypeHash(#[from] groupforward_msgs::idl::IdlError),
    #[error("no service `{0}` is served")]
    NoService(String),
    #[error("service `{0}` failed: {1}")]
    Service(String, String),
    #[error("ROS 2: {0}")]
    Ros2(String),
}

pub type Result<T> = std::result::Result<T, TransportError>;

fn zerr(e: impl std::fmt::Display) -> TransportError {
    TransportError::Zenoh(e.to_string())
}

/// A topic or service endpoint: resolved name, ROS type and QoS.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Endpoint {
    /// Fully qualified name, e.g. `/groupforward/status`.
    pub name: String,
    /// `pkg/msg/Type` or `pkg/srv/Type`.
    pub type_name: String,
    pub type_hash: String,
    pub qos: Qos,
    /// A publisher waits for a congested network instead of dropping the message: for large,
    /// infrequent messages (the map's cloud) that a subscriber must not silently miss.
    pub lossless: bool,
}

impl Endpoint {
    /// An endpoint for an embedded type; its hash comes from the IDL.
    pub fn new(name: &str, type_name: &str, qos: Qos) -> Result<Self> {
        rmw_zenoh::validate_fqn(name)?;
        Ok(Self {
            name: name.to_owned(),
            type_name: type_name.to_owned(),
            type_hash: groupforward_msgs::idl::type_hash(type_name)?,
            qos,
            lossless: false,
        })
    }

    /// The same endpoint, published without dropping under congestion.
    pub fn lossless(self) -> Self {
        Self {
            lossless: true,
            ..self
        }
    }
}

/// Called with each received payload, on a transport thread: must be quick (push to a queue).
pub type Sink = Arc<dyn Fn(Vec<u8>) + Send + Sync>;
/// Answers a service request (CDR in, CDR out).
pub type ServiceHandler = Arc<dyn Fn(&[u8]) -> std::result::Result<Vec<u8>, String> + Send + Sync>;
/// Answers a JSON API request: (name after the prefix, request body) → JSON text.
pub type JsonHandler =
    Arc<dyn Fn(&str, &[u8]) -> std::result::Result<String, String> + Send + Sync>;

pub trait Publisher: Send + Sync {
    fn publish(&self, payload: &[u8]) -> Result<()>;
}

/// What the node needs from a middleware.
pub trait Transport: Send + Sync {
    fn subscribe(&self, topic: &Endpoint, sink: Sink) -> Result<()>;
    fn advertise(&self, topic: &Endpoint) -> Result<Box<dyn Publisher>>;
    fn serve(&self, service: &Endpoint, handler: ServiceHandler) -> Result<()>;
    /// Serve `<prefix>/<name>` for any name.
    fn serve_json(&self, prefix: &str, handler: JsonHandler) -> Result<()>;
}

fn now_nanos() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

/// 1, 10, 100, …: the counts at which a repeated failure is logged again.
fn is_power_of_ten(mut n: u64) -> bool {
    while n >= 10 && n % 10 == 0 {
        n /= 10;
    }
    n == 1
}

/// Log a failed service request. Hostile clients must not flood the log: the first failure and
/// every power of ten are logged, the rest at debug (the status counts them).
fn log_request_failure(failures: &AtomicU64, service: &str, message: &str) {
    let n = failures.fetch_add(1, Ordering::Relaxed) + 1;
    if is_power_of_ten(n) {
        tracing::warn!(service, failed = n, "request failed: {message}");
    } else {
        tracing::debug!(service, "request failed: {message}");
    }
}

/// Build a zenoh config from the node's zenoh section.
pub fn zenoh_config(section: &ZenohSection) -> Result<zenoh::Config> {
    let mut config = match &section.config_file {
        Some(path) => zenoh::Config::from_file(path)
            .map_err(|e| TransportError::Zenoh(format!("config file {path}: {e}")))?,
        None => zenoh::Config::default(),
    };
    let mode = match section.mode {
        ZenohMode::Peer => "peer",
        ZenohMode::Client => "client",
        ZenohMode::Router => "router",
    };
    let json = |v: serde_json::Value| v.to_string();
    config
        .insert_json5("mode", &json(serde_json::json!(mode)))
        .map_err(zerr)?;
    config
        .insert_json5("listen/endpoints", &json(serde_json::json!(section.listen)))
        .map_err(zerr)?;
    config
        .insert_json5(
            "connect/endpoints",
            &json(serde_json::json!(section.connect)),
        )
        .map_err(zerr)?;
    config
        .insert_json5(
            "scouting/multicast/enabled",
            &json(serde_json::json!(section.multicast_scouting)),
        )
        .map_err(zerr)?;
    Ok(config)
}

/// Open a zenoh session for `section`.
pub fn open_session(section: &ZenohSection) -> Result<zenoh::Session> {
    zenoh::open(zenoh_config(section)?).wait().map_err(zerr)
}

/// rmw_zenoh-compatible transport over one zenoh session.
pub struct ZenohTransport {
    session: zenoh::Session,
    node: NodeIdentity,
    next_entity_id: AtomicU32,
    /// Declared subscribers, queryables and tokens: dropping them undeclares them.
    keep_alive: Mutex<Vec<Box<dyn std::any::Any + Send>>>,
}

impl std::fmt::Debug for ZenohTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "ZenohTransport({}{})",
            self.node.namespace, self.node.name
        )
    }
}

impl ZenohTransport {
    /// Announce node `name` in `namespace` on `session` (its liveliness token is declared here).
    pub fn new(
        session: zenoh::Session,
        domain_id: u32,
        namespace: &str,
        name: &str,
    ) -> Result<Self> {
        let node = NodeIdentity {
            domain_id,
            zid: session.zid().to_string(),
            node_id: 0,
            namespace: namespace.to_owned(),
            name: name.to_owned(),
            enclave: "/".into(),
        };
        tracing::debug!(token = %node.node_token(), "liveliness token");
        let token = session
            .liveliness()
            .declare_token(node.node_token())
            .wait()
            .map_err(zerr)?;
        Ok(Self {
            session,
            node,
            next_entity_id: AtomicU32::new(10),
            keep_alive: Mutex::new(vec![Box::new(token)]),
        })
    }

    pub fn session(&self) -> &zenoh::Session {
        &self.session
    }

    /// Declare the liveliness token of a new entity; returns its gid.
    fn announce(&self, kind: EntityKind, endpoint: &Endpoint) -> Result<[u8; 16]> {
        let id = self.next_entity_id.fetch_add(1, Ordering::Relaxed);
        let token_key = self.node.entity_token(
            id,
            kind,
            &endpoint.name,
            &endpoint.type_name,
            &endpoint.type_hash,
            &endpoint.qos,
        )?;
        tracing::debug!(token = %token_key, "liveliness token");
        let token = self
            .session
            .liveliness()
            .declare_token(token_key.clone())
            .wait()
            .map_err(zerr)?;
        self.hold(token);
        Ok(gid_for_token(&token_key))
    }

    fn hold(&self, thing: impl std::any::Any + Send) {
        if let Ok(mut held) = self.keep_alive.lock() {
            held.push(Box::new(thing));
        }
    }

    fn data_key(&self, endpoint: &Endpoint) -> Result<String> {
        Ok(rmw_zenoh::data_key(
            self.node.domain_id,
            &endpoint.name,
            &endpoint.type_name,
            &endpoint.type_hash,
        )?)
    }
}

struct ZenohPublisher {
    publisher: zenoh::pubsub::Publisher<'static>,
    gid: [u8; 16],
    sequence: AtomicI64,
}

impl Publisher for ZenohPublisher {
    fn publish(&self, payload: &[u8]) -> Result<()> {
        let attachment = Attachment {
            sequence_number: self.sequence.fetch_add(1, Ordering::Relaxed) + 1,
            source_timestamp: now_nanos(),
            source_gid: self.gid,
        };
        self.publisher
            .put(payload.to_vec())
            .attachment(attachment.encode())
            .wait()
            .map_err(zerr)
    }
}

impl Transport for ZenohTransport {
    fn subscribe(&self, topic: &Endpoint, sink: Sink) -> Result<()> {
        // Any type hash: a publisher of another ROS distribution (or none) is still heard, and the
        // payload is validated when decoded.
        let key = rmw_zenoh::data_key(self.node.domain_id, &topic.name, &topic.type_name, "*")?;
        self.announce(EntityKind::Subscription, topic)?;
        tracing::debug!(%key, "subscribing");
        let subscriber = self
            .session
            .declare_subscriber(key)
            .callback(move |sample| sink(sample.payload().to_bytes().into_owned()))
            .wait()
            .map_err(zerr)?;
        self.hold(subscriber);
        Ok(())
    }

    fn advertise(&self, topic: &Endpoint) -> Result<Box<dyn Publisher>> {
        let key = self.data_key(topic)?;
        let gid = self.announce(EntityKind::Publisher, topic)?;
        tracing::debug!(%key, "publishing");
        let congestion = if topic.lossless {
            zenoh::qos::CongestionControl::Block
        } else {
            zenoh::qos::CongestionControl::Drop
        };
        let publisher = self
            .session
            .declare_publisher(key)
            .congestion_control(congestion)
            .wait()
            .map_err(zerr)?;
        Ok(Box::new(ZenohPublisher {
            publisher,
            gid,
            sequence: AtomicI64::new(0),
        }))
    }

    fn serve(&self, service: &Endpoint, handler: ServiceHandler) -> Result<()> {
        let key = self.data_key(service)?;
        self.announce(EntityKind::ServiceServer, service)?;
        tracing::debug!(%key, "serving");
        let name = service.name.clone();
        let failures = AtomicU64::new(0);
        let queryable = self
            .session
            .declare_queryable(key)
            .complete(true)
            .callback(move |query| {
                let request = query
                    .payload()
                    .map(|p| p.to_bytes().into_owned())
                    .unwrap_or_default();
                // The reply echoes the client's sequence number and gid so it can match it.
                let request_attachment = query
                    .attachment()
                    .and_then(|a| Attachment::decode(&a.to_bytes()).ok());
                let attachment = Attachment {
                    sequence_number: request_attachment.map_or(0, |a| a.sequence_number),
                    source_timestamp: now_nanos(),
                    source_gid: request_attachment.map_or([0; 16], |a| a.source_gid),
                };
                let result = match handler(&request) {
                    Ok(response) => query
                        .reply(query.key_expr().clone(), response)
                        .attachment(attachment.encode())
                        .wait(),
                    Err(message) => {
                        log_request_failure(&failures, &name, &message);
                        query.reply_err(message).wait()
                    }
                };
                if let Err(e) = result {
                    tracing::warn!(service = %name, "cannot send reply: {e}");
                }
            })
            .wait()
            .map_err(zerr)?;
        self.hold(queryable);
        Ok(())
    }

    fn serve_json(&self, prefix: &str, handler: JsonHandler) -> Result<()> {
        let prefix = prefix.trim_end_matches('/').to_owned();
        let key = format!("{prefix}/*");
        tracing::debug!(%key, "serving JSON API");
        let queryable = self
            .session
            .declare_queryable(key)
            .callback(move |query| {
                let name = query
                    .key_expr()
                    .as_str()
                    .strip_prefix(&prefix)
                    .unwrap_or("")
                    .trim_start_matches('/')
                    .to_owned();
                let body = query
                    .payload()
                    .map(|p| p.to_bytes().into_owned())
                    .unwrap_or_default();
                let result = match handler(&name, &body) {
                    Ok(json) => query
                        .reply(query.key_expr().clone(), json)
                        .encoding(zenoh::bytes::Encoding::APPLICATION_JSON)
                        .wait(),
                    Err(message) => query
                        .reply_err(serde_json::json!({ "error": message }).to_string())
                        .encoding(zenoh::bytes::Encoding::APPLICATION_JSON)
                        .wait(),
                };
                if let Err(e) = result {
                    tracing::warn!(api = %name, "cannot send reply: {e}");
                }
            })
            .wait()
            .map_err(zerr)?;
        self.hold(queryable);
        Ok(())
    }
}

/// In-process transport: publishing delivers to the sinks subscribed to the same name.
#[derive(Default)]
pub struct MemoryTransport {
    sinks: Mutex<HashMap<String, Vec<Sink>>>,
    services: Mutex<HashMap<String, ServiceHandler>>,
    json: Mutex<Vec<(String, JsonHandler)>>,
    published: Mutex<HashMap<String, Vec<Vec<u8>>>>,
}

impl std::fmt::Debug for MemoryTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("MemoryTransport")
    }
}

impl MemoryTransport {
    pub fn new() -> Arc<Self> {
        Arc::new(Self::default())
    }

    /// Deliver `payload` to every subscriber of `topic` (as another node would publish it).
    pub fn inject(&self, topic: &str, payload: &[u8]) {
        let sinks = self
            .sinks
            .lock()
            .map(|s| s.get(topic).cloned().unwrap_or_default())
            .unwrap_or_default();
        for sink in sinks {
            sink(payload.to_vec());
        }
    }

    /// Everything the node published on `topic`.
    pub fn published(&self, topic: &str) -> Vec<Vec<u8>> {
        self.published
            .lock()
            .map(|p| p.get(topic).cloned().unwrap_or_default())
            .unwrap_or_default()
    }

    /// Call a served service with a CDR request.
    pub fn call(&self, service: &str, request: &[u8]) -> Result<Vec<u8>> {
        let handler = self
            .services
            .lock()
            .ok()
            .and_then(|s| s.get(service).cloned())
            .ok_or_else(|| TransportError::NoService(service.to_owned()))?;
        handler(request).map_err(|e| TransportError::Service(service.to_owned(), e))
    }

    /// Query the JSON API at `key` (`<prefix>/<name>`).
    pub fn get_json(&self, key: &str, body: &[u8]) -> Result<String> {
        let handlers = self.json.lock().map(|j| j.clone()).unwrap_or_default();
        for (prefix, handler) in handlers {
            if let Some(name) = key.strip_prefix(&format!("{prefix}/")) {
                return handler(name, body).map_err(|e| TransportError::Service(key.to_owned(), e));
            }
        }
        Err(TransportError::NoService(key.to_owned()))
    }
}

struct MemoryPublisher {
    transport: Arc<MemoryTransport>,
    topic: String,
}

impl Publisher for MemoryPublisher {
    fn publish(&self, payload: &[u8]) -> Result<()> {
        if let Ok(mut published) = self.transport.published.lock() {
            published
                .entry(self.topic.clone())
                .or_default()
                .push(payload.to_vec());
        }
        self.transport.inject(&self.topic, payload);
        Ok(())
    }
}

impl Transport for Arc<MemoryTransport> {
    fn subscribe(&self, topic: &Endpoint, sink: Sink) -> Result<()> {
        if let Ok(mut sinks) = self.sinks.lock() {
            sinks.entry(topic.name.clone()).or_default().push(sink);
        }
        Ok(())
    }

    fn advertise(&self, topic: &Endpoint) -> Result<Box<dyn Publisher>> {
        Ok(Box::new(MemoryPublisher {
            transport: self.clone(),
            topic: topic.name.clone(),
        }))
    }

    fn serve(&self, service: &Endpoint, handler: ServiceHandler) -> Result<()> {
        if let Ok(mut services) = self.services.lock() {
            services.insert(service.name.clone(), handler);
        }
        Ok(())
    }

    fn serve_json(&self, prefix: &str, handler: JsonHandler) -> Result<()> {
        if let Ok(mut json) = self.json.lock() {
            json.push((prefix.trim_end_matches('/').to_owned(), handler));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeated_request_failures_are_logged_at_powers_of_ten_only() {
        let logged: Vec<u64> = (0..=20_000).filter(|&n| is_power_of_ten(n)).collect();
        assert_eq!(logged, [1, 10, 100, 1_000, 10_000]);
    }
}

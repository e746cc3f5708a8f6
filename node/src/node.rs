//! The node loop: subscriptions feed a bounded drop-oldest queue, one thread runs the pipeline
//! stages on it, and a status report is published every period on `~/status` and the JSON API.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use groupforward_msgs::gf_msgs::{
    CameraStatus, GetInstanceRequest, GetInstanceResponse, Instance, ListInstancesRequest,
    ListInstancesResponse, MapPathRequest, MapResultResponse, NodeStatus, RejectCount,
};
use groupforward_msgs::rmw_zenoh::{resolve_name, Qos};
use groupforward_msgs::services::{GetInstance, ListInstances, LoadMap, SaveMap};
use groupforward_msgs::vision_msgs::ObjectHypothesis;
use groupforward_msgs::{builtin_interfaces::Time, cdr, std_msgs::Header, RosMessage, RosService};

use crate::config::Config;
use crate::graph::{persist, SceneMap};
use crate::group::semantics::Vocabulary;
use crate::group::GroupingParams;
use crate::ingest::{Ingest, Reject, Rejection, Route, SyncedFrame};
use crate::model::reconstruction::ReconstructionModel;
use crate::model::semantic::SemanticModel;
use crate::model::text::TextEncoder;
use crate::transport::{Endpoint, Transport, TransportError};
use crate::window::{window_pass, Keyframes};

#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("naming: {0}")]
    Naming(#[from] groupforward_msgs::rmw_zenoh::NamingError),
}

pub type Result<T> = std::result::Result<T, NodeError>;

/// Bounded FIFO that drops the oldest entry when full and remembers what it dropped.
#[derive(Debug)]
pub struct InputQueue {
    state: Mutex<QueueState>,
    ready: Condvar,
    capacity: usize,
}

#[derive(Debug, Default)]
struct QueueState {
    items: VecDeque<(Route, Vec<u8>)>,
    dropped: Vec<Route>,
}

impl InputQueue {
    pub fn new(capacity: usize) -> Self {
        Self {
            state: Mutex::new(QueueState::default()),
            ready: Condvar::new(),
            capacity: capacity.max(1),
        }
    }

    pub fn push(&self, route: Route, payload: Vec<u8>) {
        let Ok(mut state) = self.state.lock() else {
            return;
        };
        if state.items.len() >= self.capacity {
            if let Some((old, _)) = state.items.pop_front() {
                state.dropped.push(old);
            }
        }
        state.items.push_back((route, payload));
        self.ready.notify_one();
    }

    /// The next item, waiting up to `timeout`; also returns the routes dropped since the last call.
    pub fn pop(&self, timeout: Duration) -> (Option<(Route, Vec<u8>)>, Vec<Route>) {
        let Ok(mut state) = self.state.lock() else {
            return (None, Vec::new());
        };
        if state.items.is_empty() {
            state = match self.ready.wait_timeout(state, timeout) {
                Ok((s, _)) => s,
                Err(_) => return (None, Vec::new()),
            };
        }
        let item = state.items.pop_front();
        (item, std::mem::take(&mut state.dropped))
    }
}

/// Frames kept per camera for the stages that land later (keyframes, window passes).
const RECENT_FRAMES_PER_CAMERA: usize = 4;

/// The node's pipeline state, driven by [`Node::step`] without any transport.
#[derive(Debug)]
pub struct Node {
    pub ingest: Ingest,
    started: Instant,
    recent: VecDeque<SyncedFrame>,
    period_start: Instant,
    period_received: Vec<u64>,
}

impl Node {
    pub fn new(config: &Config) -> Self {
        let ingest = Ingest::new(config);
        let cameras = ingest.camera_count();
        Self {
            ingest,
            started: Instant::now(),
            recent: VecDeque::new(),
            period_start: Instant::now(),
            period_received: vec![0; cameras],
        }
    }

    /// Process one message; returns how many frames completed.
    pub fn step(&mut self, route: Route, payload: &[u8]) -> usize {
        let _span = tracing::debug_span!("ingest", ?route).entered();
        let frames = self.ingest.handle(route, payload);
        let completed = frames.len();
        for frame in frames {
            self.recent.push_back(frame);
        }
        let cap = RECENT_FRAMES_PER_CAMERA * self.ingest.camera_count().max(1);
        while self.recent.len() > cap {
            self.recent.pop_front();
        }
        completed
    }

    /// The newest completed frames, oldest first.
    pub fn recent_frames(&self) -> impl DoubleEndedIterator<Item = &SyncedFrame> {
        self.recent.iter()
    }

    /// Count inputs the queue dropped before they were processed.
    pub fn record_dropped(&mut self, routes: &[Route]) {
        for route in routes {
            self.ingest.record_dropped(
                *route,
                &Rejection {
                    reason: Reject::QueueOverflow,
                    detail: "input queue full: the oldest message was dropped".into(),
                },
            );
        }
    }

    /// A status report; rates cover the time since the previous report.
    pub fn status(&mut self, now: Instant) -> NodeStatus {
        let period = now
            .duration_since(self.period_start)
            .as_secs_f64()
            .max(1e-9);
        let mut cameras = Vec::new();
        for (i, name) in self.ingest.camera_names().enumerate() {
            let Some(c) = self.ingest.camera_counters(i) else {
                continue;
            };
            let in_period = c.received - self.period_received.get(i).copied().unwrap_or(0);
            cameras.push(CameraStatus {
                name: name.to_owned(),
                frames_received: c.received,
                frames_synced: c.synced,
                frames_rejected: c.rejected,
                rate_hz: (in_period as f64 / period) as f32,
                last_stamp: Time::from_nanos(c.last_stamp_nanos),
            });
        }
        self.period_received = cameras.iter().map(|c| c.frames_received).collect();
        self.period_start = now;
        NodeStatus {
            header: Header {
                stamp: Time::from_nanos(wall_nanos()),
                frame_id: String::new(),
            },
            uptime_secs: now.duration_since(self.started).as_secs_f64(),
            cameras,
            tf_received: self.ingest.tf_received,
            tf_rejected: self.ingest.tf_rejected,
            rejections: self
                .ingest
                .rejections
                .iter()
                .map(|(reason, count)| RejectCount {
                    reason: reason.code().to_owned(),
                    count,
                })
                .collect(),
        }
    }
}

fn wall_nanos() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

/// State shared with service and JSON handlers, which run on transport threads.
#[derive(Debug, Default)]
pub struct Shared {
    pub status: NodeStatus,
    /// The persistent instance map (filled by window passes once the models land).
    pub map: SceneMap,
    /// `map` as messages, refreshed whenever the map changes.
    pub instances: Vec<Instance>,
    /// Default snapshot file (`map.file`).
    pub map_file: Option<String>,
    /// Names for instances (set once the text encoder has embedded `semantics.vocabulary`).
    pub vocabulary: Option<Vocabulary>,
    /// Hypotheses per instance message.
    pub hypotheses: usize,
}

fn time_of(nanos: i64) -> Time {
    Time::from_nanos(nanos)
}

/// The map's instances as `groupforward_msgs/Instance` (axis-aligned boxes in the map frame), named
/// by the `hypotheses` best phrases of `vocabulary` for their semantic prototype.
pub fn instance_messages(
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
    hypotheses: usize,
) -> Vec<Instance> {
    map.instances
        .iter()
        .map(|i| {
            let (lo, hi) = i.bounds();
            let (centre, size) = ((lo + hi) / 2.0, hi - lo);
            Instance {
                id: i.id.clone(),
                hypotheses: vocabulary
                    .map(|v| v.hypotheses(&i.prototype, hypotheses))
                    .unwrap_or_default()
                    .into_iter()
                    .map(|(class_id, score)| ObjectHypothesis {
                        class_id,
                        score: f64::from(score),
                    })
                    .collect(),
                pose: groupforward_msgs::geometry_msgs::Pose {
                    position: groupforward_msgs::geometry_msgs::Point {
                        x: f64::from(centre.x),
                        y: f64::from(centre.y),
                        z: f64::from(centre.z),
                    },
                    orientation: groupforward_msgs::geometry_msgs::Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: 0.0,
                        w: 1.0,
                    },
                },
                size: groupforward_msgs::geometry_msgs::Vector3 {
                    x: f64::from(size.x),
                    y: f64::from(size.y),
                    z: f64::from(size.z),
                },
                point_count: i.gaussians.len() as u32,
                confidence: i.confidence,
                first_seen: time_of(i.first_seen_nanos),
                last_seen: time_of(i.last_seen_nanos),
                ..Default::default()
            }
        })
        .collect()
}

impl Shared {
    /// Replace the map and refresh the instance messages.
    pub fn set_map(&mut self, map: SceneMap) {
        self.map = map;
        self.refresh_instances();
    }

    /// Rebuild the instance messages after the map changed in place.
    pub fn refresh_instances(&mut self) {
        self.instances = instance_messages(&self.map, self.vocabulary.as_ref(), self.hypotheses);
    }
}

fn map_path<'a>(shared: &'a Shared, requested: &'a str) -> std::result::Result<&'a str, String> {
    if !requested.is_empty() {
        return Ok(requested);
    }
    shared
        .map_file
        .as_deref()
        .ok_or_else(|| "no path given and no map.file configured".to_owned())
}

fn handle_save(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: MapPathRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    // Serialise under the lock, write outside it: a slow disk never stalls the node loop.
    let (path, bytes) = {
        let s = shared.lock().map_err(|e| e.to_string())?;
        let path = map_path(&s, &request.path).map(str::to_owned);
        (path, persist::to_bytes(&s.map))
    };
    let outcome = path.and_then(|path| {
        persist::write_atomically(std::path::Path::new(&path), &bytes)
            .map(|()| format!("saved {} bytes to {path}", bytes.len()))
            .map_err(|e| e.to_string())
    });
    map_result("save_map", outcome)
}

/// A SaveMap / LoadMap response; failures are logged too.
fn map_result(
    service: &str,
    outcome: std::result::Result<String, String>,
) -> std::result::Result<Vec<u8>, String> {
    let response = match outcome {
        Ok(message) => MapResultResponse {
            success: true,
            message,
        },
        Err(message) => {
            tracing::warn!("{service} failed: {message}");
            MapResultResponse {
                success: false,
                message,
            }
        }
    };
    cdr::encode(&response).map_err(|e| e.to_string())
}

fn handle_load(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: MapPathRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    let (path, params) = {
        let s = shared.lock().map_err(|e| e.to_string())?;
        (map_path(&s, &request.path).map(str::to_owned), s.map.params)
    };
    let loaded = path.and_then(|path| {
        persist::load(std::path::Path::new(&path), params)
            .map(|map| (path, map))
            .map_err(|e| e.to_string())
    });
    let outcome = match loaded {
        Ok((path, map)) => {
            let count = map.instances.len();
            shared.lock().map_err(|e| e.to_string())?.set_map(map);
            Ok(format!("loaded {count} instances from {path}"))
        }
        // The running map is untouched on any error.
        Err(message) => Err(message),
    };
    map_result("load_map", outcome)
}

fn handle_list(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: ListInstancesRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    let instances = shared
        .lock()
        .map_err(|e| e.to_string())?
        .instances
        .iter()
        .filter(|i| {
            request.label_filter.is_empty()
                || i.hypotheses
                    .first()
                    .is_some_and(|h| h.class_id.contains(&request.label_filter))
        })
        .cloned()
        .collect();
    cdr::encode(&ListInstancesResponse { instances }).map_err(|e| e.to_string())
}

fn handle_get(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: GetInstanceRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    let found = shared
        .lock()
        .map_err(|e| e.to_string())?
        .instances
        .iter()
        .find(|i| i.id == request.id)
        .cloned();
    let response = GetInstanceResponse {
        found: found.is_some(),
        instance: found.unwrap_or_default(),
        ..Default::default()
    };
    cdr::encode(&response).map_err(|e| e.to_string())
}

fn handle_json(shared: &Mutex<Shared>, name: &str) -> std::result::Result<String, String> {
    let shared = shared.lock().map_err(|e| e.to_string())?;
    let value = match name {
        "status" => serde_json::to_value(&shared.status),
        "instances" => serde_json::to_value(&shared.instances),
        other => {
            return Err(format!(
                "unknown API `{other}`; available: status, instances"
            ))
        }
    };
    value.map(|v| v.to_string()).map_err(|e| e.to_string())
}

/// The resolved names the node declares, for logs and docs.
#[derive(Debug, Clone)]
pub struct Declared {
    pub subscriptions: Vec<Endpoint>,
    pub status: Endpoint,
    pub services: Vec<Endpoint>,
    pub json_prefix: String,
}

/// Run the node on `transport` until `shutdown` is set; returns the last status.
pub fn run(
    config: &Config,
    transport: &dyn Transport,
    shutdown: &AtomicBool,
) -> Result<NodeStatus> {
    let queue = Arc::new(InputQueue::new(config.ingest.queue_depth));
    let mut initial = Shared {
        map_file: config.map.file.clone(),
        hypotheses: config.semantics.hypotheses,
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
    // Every interface is declared before the (slow) model load, so peers see the node at once.
    let (windows, worker) = start_window_worker(config, &shared);
    let mut windows = windows;
    let mut keyframes: std::collections::HashMap<String, Keyframes> = Default::default();
    let mut windows_dropped = 0u64;
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
            let completed = node.step(route, &payload);
            if let Some(windows) = &windows {
                let fresh: Vec<&SyncedFrame> = node.recent_frames().rev().take(completed).collect();
                for frame in fresh.into_iter().rev() {
                    let store = keyframes
                        .entry(frame.camera_name.clone())
                        .or_insert_with(|| Keyframes::new(config.window.clone()));
                    if store.offer(frame) {
                        if let Some(window) = store.take_window() {
                            // The worker is busy with the previous window: drop this one (counted)
                            // rather than stall ingest. A worker without a model has exited.
                            match windows.try_send(window) {
                                Ok(()) => {}
                                Err(std::sync::mpsc::TrySendError::Full(_)) => {
                                    windows_dropped += 1;
                                    tracing::debug!(
                                        windows_dropped,
                                        "window pass busy; window dropped"
                                    );
                                }
                                Err(std::sync::mpsc::TrySendError::Disconnected(_)) => {
                                    model_gone = true;
                                }
                            }
                        }
                    }
                }
            }
        }
        if model_gone {
            windows = None;
            model_gone = false;
        }
        let now = Instant::now();
        if now >= next_status {
            next_status = now + period;
            last = publish_status(&mut node, now, status_publisher.as_ref(), &shared);
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
    // Let the worker finish the windows it has, then stop it.
    drop(windows);
    if let Some(worker) = worker {
        if worker.join().is_err() {
            tracing::error!("the window worker panicked");
        }
    }
    if windows_dropped > 0 {
        tracing::info!(windows_dropped, "windows dropped while the model was busy");
    }
    if !last.cameras.is_empty() || node.ingest.tf_received > 0 {
        last = publish_status(
            &mut node,
            Instant::now(),
            status_publisher.as_ref(),
            &shared,
        );
    }
    Ok(last)
}

/// Load the reconstruction model and start the thread that runs window passes and fuses their
/// instances into the map. `None` when there is no usable model (logged; the node keeps serving).
fn start_window_worker(
    config: &Config,
    shared: &Arc<Mutex<Shared>>,
) -> (
    Option<std::sync::mpsc::SyncSender<Vec<SyncedFrame>>>,
    Option<std::thread::JoinHandle<()>>,
) {
    let Some(manifest) = config.models.reconstruction.as_ref() else {
        return (None, None);
    };
    if !manifest.exists() {
        tracing::warn!(
            "no reconstruction model at {}: no instances will be built",
            manifest.display()
        );
        return (None, None);
    }
    let options = crate::model::SessionOptions {
        provider: config.models.provider,
        intra_threads: config.models.threads,
    };
    let (sender, receiver) = std::sync::mpsc::sync_channel::<Vec<SyncedFrame>>(1);
    let shared = shared.clone();
    let grouping = GroupingParams::default();
    let (library, manifest) = (config.models.onnxruntime.clone(), manifest.clone());
    let models = config.models.clone();
    let semantics = config.semantics.clone();
    let worker = std::thread::spawn(move || {
        // Loaded here, not on the node loop: ingest and services run while the model loads.
        let mut model = match crate::model::init_runtime(library.as_deref())
            .and_then(|_| ReconstructionModel::load(&manifest, &options))
        {
            Ok(model) => model,
            Err(e) => {
                tracing::error!(
                    "reconstruction model unavailable: {e}; no instances will be built"
                );
                return;
            }
        };
        tracing::info!("reconstruction model {} loaded", manifest.display());
        let mut semantic = load_semantics(&models, &semantics, &options, &shared);
        while let Ok(frames) = receiver.recv() {
            let stamp = frames.last().map_or(0, |f| f.stamp_nanos);
            let started = Instant::now();
            match window_pass(&mut model, semantic.as_mut(), &frames, &grouping) {
                Ok(output) => {
                    if let Some(e) = &output.semantics_error {
                        tracing::warn!("window without semantics: {e}");
                    }
                    let Ok(mut s) = shared.lock() else { return };
                    let found = output.instances.len();
                    match s.map.fuse(output.instances, &output.views, stamp) {
                        Ok(report) => {
                            s.refresh_instances();
                            tracing::info!(
                                instances = found,
                                born = report.born,
                                merged = report.merged,
                                died = report.died,
                                total = s.map.instances.len(),
                                millis = started.elapsed().as_millis() as u64,
                                "window fused"
                            );
                        }
                        Err(e) => tracing::warn!("window not fused: {e}"),
                    }
                }
                Err(e) => tracing::warn!("window pass failed: {e}"),
            }
        }
    });
    (Some(sender), Some(worker))
}

/// Load the semantic model and embed the vocabulary with the text encoder (into `shared`). Either
/// may be missing or broken: the node then builds unnamed instances and says so once.
fn load_semantics(
    models: &crate::config::ModelsSection,
    semantics: &crate::config::SemanticsSection,
    options: &crate::model::SessionOptions,
    shared: &Mutex<Shared>,
) -> Option<SemanticModel> {
    let manifest = models.semantic.as_ref()?;
    if !manifest.exists() {
        tracing::warn!(
            "no semantic model at {}: instances will be unnamed",
            manifest.display()
        );
        return None;
    }
    let model = match SemanticModel::load(manifest, options) {
        Ok(model) => model,
        Err(e) => {
            tracing::error!("semantic model unavailable: {e}; instances will be unnamed");
            return None;
        }
    };
    let vocabulary = TextEncoder::load(&models.text_encoder, options).and_then(|mut encoder| {
        let embeddings = semantics
            .vocabulary
            .iter()
            .map(|phrase| encoder.embed(phrase))
            .collect::<crate::model::Result<Vec<_>>>()?;
        Ok(Vocabulary {
            phrases: semantics.vocabulary.clone(),
            embeddings,
            temperature: semantics.temperature,
        })
    });
    match vocabulary {
        Ok(vocabulary) => {
            if let Ok(mut s) = shared.lock() {
                s.vocabulary = Some(vocabulary);
                s.refresh_instances();
            }
        }
        Err(e) => tracing::error!("text encoder unavailable: {e}; instances will be unnamed"),
    }
    tracing::info!("semantic model {} loaded", manifest.display());
    Some(model)
}

fn publish_status(
    node: &mut Node,
    now: Instant,
    publisher: &dyn crate::transport::Publisher,
    shared: &Mutex<Shared>,
) -> NodeStatus {
    let status = node.status(now);
    match cdr::encode(&status) {
        Ok(bytes) => {
            if let Err(e) = publisher.publish(&bytes) {
                tracing::warn!("cannot publish status: {e}");
            }
        }
        Err(e) => tracing::warn!("cannot encode status: {e}"),
    }
    if let Ok(mut s) = shared.lock() {
        s.status = status.clone();
    }
    status
}

/// Subscribe to the inputs, and declare the status topic, services and JSON API.
pub fn declare(
    config: &Config,
    transport: &dyn Transport,
    queue: &Arc<InputQueue>,
    shared: &Arc<Mutex<Shared>>,
) -> Result<Declared> {
    let ns = &config.node.namespace;
    let name = &config.node.name;
    let mut subscriptions = Vec::new();
    for (topic, route) in Ingest::routes(config) {
        let qos = match route {
            Route::TfStatic => Qos {
                transient_local: true,
                depth: 1,
                ..Qos::default()
            },
            Route::Tf => Qos::default(),
            _ => Qos::sensor_data(),
        };
        let endpoint = Endpoint::new(&resolve_name(ns, name, &topic)?, route.type_name(), qos)?;
        let queue = queue.clone();
        transport.subscribe(
            &endpoint,
            Arc::new(move |payload| queue.push(route, payload)),
        )?;
        subscriptions.push(endpoint);
    }
    let status = Endpoint::new(
        &resolve_name(ns, name, "~/status")?,
        NodeStatus::TYPE_NAME,
        Qos::default(),
    )?;
    let list = Endpoint::new(
        &resolve_name(ns, name, "~/list_instances")?,
        ListInstances::TYPE_NAME,
        Qos::default(),
    )?;
    let get = Endpoint::new(
        &resolve_name(ns, name, "~/get_instance")?,
        GetInstance::TYPE_NAME,
        Qos::default(),
    )?;
    let save = Endpoint::new(
        &resolve_name(ns, name, "~/save_map")?,
        SaveMap::TYPE_NAME,
        Qos::default(),
    )?;
    let load = Endpoint::new(
        &resolve_name(ns, name, "~/load_map")?,
        LoadMap::TYPE_NAME,
        Qos::default(),
    )?;
    let s = shared.clone();
    transport.serve(&save, Arc::new(move |req| handle_save(&s, req)))?;
    let s = shared.clone();
    transport.serve(&load, Arc::new(move |req| handle_load(&s, req)))?;
    let s = shared.clone();
    transport.serve(&list, Arc::new(move |req| handle_list(&s, req)))?;
    let s = shared.clone();
    transport.serve(&get, Arc::new(move |req| handle_get(&s, req)))?;
    let prefix = config.api_prefix();
    let s = shared.clone();
    transport.serve_json(&prefix, Arc::new(move |api, _body| handle_json(&s, api)))?;
    Ok(Declared {
        subscriptions,
        status,
        services: vec![list, get, save, load],
        json_prefix: prefix,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::MemoryTransport;
    use groupforward_msgs::sensor_msgs::Image;

    #[test]
    fn queue_drops_oldest_and_reports_it() {
        let queue = InputQueue::new(2);
        queue.push(Route::Tf, vec![1]);
        queue.push(Route::Image(0), vec![2]);
        queue.push(Route::Tf, vec![3]);
        let (item, dropped) = queue.pop(Duration::ZERO);
        assert_eq!(item.unwrap().1, vec![2]);
        assert_eq!(dropped, vec![Route::Tf]);
        let (item, dropped) = queue.pop(Duration::ZERO);
        assert_eq!(item.unwrap().1, vec![3]);
        assert!(dropped.is_empty());
        assert!(queue.pop(Duration::from_millis(1)).0.is_none());
    }

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
            let json: serde_json::Value =
                serde_json::from_str(&bus.get_json("groupforward/default/status", b"").unwrap())
                    .unwrap();
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
        let list = bus
            .call(
                "/groupforward/list_instances",
                &cdr::encode(&ListInstancesRequest::default()).unwrap(),
            )
            .unwrap();
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
    }

    /// A map with one instance: a small cube of Gaussians.
    fn one_instance_map() -> SceneMap {
        use crate::graph::{FusionParams, WindowInstance};
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

    #[test]
    fn map_services_save_load_and_restore_on_start_keeping_the_map_on_errors() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("map.gfmap");
        persist::save(&one_instance_map(), &file).unwrap();
        let mut config = Config::default();
        config.map.file = Some(file.display().to_string());
        let (bus, shutdown, runner) = start(&config);
        let list = |bus: &MemoryTransport| -> Vec<Instance> {
            let reply = bus
                .call(
                    "/groupforward/list_instances",
                    &cdr::encode(&ListInstancesRequest::default()).unwrap(),
                )
                .unwrap();
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
        // The configured file is the default path; the copy loads back to the same map.
        assert!(call("/groupforward/save_map", "").success);
        assert!(call("/groupforward/load_map", &copy.display().to_string()).success);
        assert_eq!(list(&bus), restored);
        assert!(bus.call("/groupforward/save_map", b"bad").is_err());
        shutdown.store(true, Ordering::Relaxed);
        runner.join().unwrap().unwrap();
    }
}

//! What the node serves: the state shared with service handlers (the map and its instance
//! messages), the list / get / save / load services, the JSON API, and their declaration.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use glam::{DQuat, DVec3};
use groupforward_msgs::gf_msgs::{
    GetInstanceRequest, GetInstanceResponse, Instance, ListInstancesRequest, ListInstancesResponse,
    MapPathRequest, MapResultResponse, NodeStatus, ReferRequest, ReferResponse,
};
use groupforward_msgs::rmw_zenoh::{resolve_name, Qos};
use groupforward_msgs::services::{GetInstance, ListInstances, LoadMap, Refer, SaveMap};
use groupforward_msgs::vision_msgs::ObjectHypothesis;
use groupforward_msgs::{builtin_interfaces::Time, cdr, RosMessage, RosService};
use groupforward_relations::ViewPose;

use super::error::Result;
use super::queue::InputQueue;
use crate::config::Config;
use crate::frame::Keyframe;
use crate::graph::walls::object_list;
use crate::graph::{persist, Fitted, SceneMap};
use crate::group::semantics::Vocabulary;
use crate::ingest::{Ingest, Route};
use crate::model::text::TextEncoder;
use crate::outputs::ViewSource;
use crate::recon::boxes::OrientedBox;
use crate::recon::Rigid;
use crate::refer::{self, ReferScene, ReferSection};
use crate::timing::{Stage, StageClock};
use crate::transport::{Endpoint, Transport};

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
    /// Where request paths are confined (`map.directory`; `None`: anywhere).
    pub map_directory: Option<std::path::PathBuf>,
    /// Names for instances (set once the text encoder has embedded `semantics.vocabulary`).
    pub vocabulary: Option<Vocabulary>,
    /// Hypotheses per instance message.
    pub hypotheses: usize,
    /// Windows that built nothing: no view had valid depth.
    pub windows_skipped: u64,
    /// Windows fused while a `load_map` replaced the map, and so dropped.
    pub windows_superseded: u64,
    /// The bound on requests to the services and the JSON API, and the requests it refused.
    pub limiter: super::limit::RequestLimiter,
    pub requests_limited: u64,
    /// What referring queries read: a snapshot of `map`, taken by the first query or publication
    /// after the map changed (`refer_scene_generation` behind `map_generation`), so windows never
    /// pay for it.
    pub refer_scene: Arc<ReferScene>,
    pub refer_scene_generation: u64,
    /// The map generation whose snapshot the output thread is taking (or is about to, and when
    /// that was said): a query then answers on the previous snapshot, at most one map change
    /// old, instead of taking one itself (under a two-camera flood, queries taking it made the
    /// query p99 25 times its p50). Past [`SNAPSHOT_DUE_SECS`] a query takes it itself.
    pub refer_scene_building: Option<(u64, std::time::Instant)>,
    /// An output thread runs and takes the snapshot of every changed map.
    pub snapshot_taker: bool,
    /// Embeds query phrases (set with the vocabulary once the models load).
    pub text_encoder: Option<Arc<Mutex<TextEncoder>>>,
    pub refer: ReferSection,
    /// The map's frame (answers' clouds are expressed in it).
    pub world_frame: String,
    /// Bumped whenever the map changes (a fused window, load_map).
    pub map_generation: u64,
    /// The cameras and optical frames of the last window's views (masks are published in them).
    pub view_sources: Vec<ViewSource>,
    /// The last published scene graph as JSON (the `scene_graph` JSON API).
    pub scene_graph_json: Option<serde_json::Value>,
    /// Boxes of the listed instances, refitted only when their Gaussians change.
    pub boxes: BoxCache,
    /// Recent durations of the window, publishing and query stages (the status reports them).
    pub stages: StageClock,
}

fn time_of(nanos: i64) -> Time {
    Time::from_nanos(nanos)
}

/// The map's object list as `groupforward_msgs/Instance`: each instance's gravity-aligned box
/// (pose = centre and yaw about z, in the map frame; size along the box's axes), named by the
/// `hypotheses` best phrases of `vocabulary` for its semantic prototype. Structure (walls,
/// floor: prototypes named `other`) and small pieces named unsurely stay in the map and out of
/// the list (`Vocabulary::is_listed`).
pub fn instance_messages(
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
    hypotheses: usize,
) -> Vec<Instance> {
    instance_messages_cached(map, vocabulary, hypotheses, &mut BoxCache::default())
}

/// Fitted boxes by instance id, with the fingerprint of the Gaussians they were fitted to: a
/// window changes a few instances, so only those are fitted again.
#[derive(Debug, Clone, Default)]
pub struct BoxCache(HashMap<String, (Fingerprint, bool, Fitted)>);

/// Count and coordinate sums of an instance's Gaussians: changes whenever they change.
type Fingerprint = (usize, [u64; 3]);

fn fingerprint(g: &crate::recon::gaussians::Gaussians) -> Fingerprint {
    let sum = g.means.iter().fold([0.0f64; 3], |s, m| {
        [
            s[0] + f64::from(m.x),
            s[1] + f64::from(m.y),
            s[2] + f64::from(m.z),
        ]
    });
    (g.len(), sum.map(f64::to_bits))
}

/// As [`instance_messages`], fitting only the boxes of instances whose Gaussians changed since
/// `cache` saw them; `cache` keeps the boxes of the instances listed now.
pub fn instance_messages_cached(
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
    hypotheses: usize,
    cache: &mut BoxCache,
) -> Vec<Instance> {
    let mut fitted = HashMap::new();
    // The structure changes with every window: completion is redone, fitting is cached.
    let listed = object_list(map, vocabulary, |i, box_like| {
        let print = fingerprint(&i.gaussians);
        let b = match cache.0.get(&i.id) {
            Some((seen, was_box_like, b)) if (*seen, *was_box_like) == (print, box_like) => *b,
            _ => i.fitted(box_like),
        };
        fitted.insert(i.id.clone(), (print, box_like, b));
        b
    });
    let messages = listed
        .into_iter()
        .map(|(i, b)| Instance {
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
            pose: refer::response::box_pose(&b),
            size: groupforward_msgs::geometry_msgs::Vector3 {
                x: b.size.x,
                y: b.size.y,
                z: b.size.z,
            },
            point_count: i.gaussians.len() as u32,
            confidence: i.confidence,
            first_seen: time_of(i.first_seen_nanos),
            last_seen: time_of(i.last_seen_nanos),
            ..Default::default()
        })
        .collect();
    cache.0 = fitted;
    messages
}

impl Shared {
    /// Replace the map and refresh the instance messages.
    pub fn set_map(&mut self, map: SceneMap) {
        self.map = map;
        self.refresh_instances();
    }

    /// Install a map the worker fused outside the lock into a copy of generation `fused_from`,
    /// with its instance messages and boxes; refused (and counted) when the map was replaced
    /// meanwhile (`load_map`), whose content the copy does not hold.
    pub fn install_fused(
        &mut self,
        fused_from: u64,
        map: SceneMap,
        instances: Vec<Instance>,
        boxes: BoxCache,
    ) -> bool {
        if self.map_generation != fused_from {
            self.windows_superseded += 1;
            return false;
        }
        self.map = map;
        self.instances = instances;
        self.boxes = boxes;
        self.map_generation += 1;
        true
    }

    /// Rebuild the instance messages after the map changed in place; the referring snapshot is
    /// retaken by the next query.
    pub fn refresh_instances(&mut self) {
        self.instances = instance_messages_cached(
            &self.map,
            self.vocabulary.as_ref(),
            self.hypotheses,
            &mut self.boxes,
        );
        self.map_generation += 1;
    }
}

/// The referring snapshot of the current map: the stored one, or (after the map changed) a new
/// one, built from a copy of the map without holding the lock.
pub fn current_snapshot(shared: &Mutex<Shared>) -> std::result::Result<Arc<ReferScene>, String> {
    current_snapshot_and_generation(shared).map(|(scene, _)| scene)
}

/// How long a query relies on another thread taking the current map's snapshot.
pub const SNAPSHOT_DUE_SECS: f64 = 1.0;

/// What a referring query reads: [`current_snapshot`], except while the output thread is taking
/// the snapshot of the current map (it does at once after every map change): then the previous
/// one, at most one map change old, rather than a second copy taken alongside.
pub fn query_snapshot(shared: &Mutex<Shared>) -> std::result::Result<Arc<ReferScene>, String> {
    {
        let s = shared.lock().map_err(|e| e.to_string())?;
        let being_taken = s.refer_scene_building.is_some_and(|(generation, since)| {
            generation == s.map_generation && since.elapsed().as_secs_f64() < SNAPSHOT_DUE_SECS
        });
        if being_taken && s.refer_scene_generation > 0 {
            return Ok(s.refer_scene.clone());
        }
    }
    current_snapshot(shared)
}

/// Say that the output thread will take the changed map's snapshot (the worker, after a window).
pub fn snapshot_due(s: &mut Shared) {
    if s.snapshot_taker && s.refer_scene_generation != s.map_generation {
        s.refer_scene_building = Some((s.map_generation, std::time::Instant::now()));
    }
}

/// [`current_snapshot`] and the map generation it was taken of.
pub fn current_snapshot_and_generation(
    shared: &Mutex<Shared>,
) -> std::result::Result<(Arc<ReferScene>, u64), String> {
    let (map, vocabulary, generation, boxes) = {
        let mut s = shared.lock().map_err(|e| e.to_string())?;
        if s.refer_scene_generation == s.map_generation {
            return Ok((s.refer_scene.clone(), s.map_generation));
        }
        s.refer_scene_building = Some((s.map_generation, std::time::Instant::now()));
        // The listed instances' boxes were fitted when the map changed: reuse them.
        let boxes: HashMap<String, OrientedBox> = s
            .instances
            .iter()
            .map(|i| (i.id.clone(), refer::response::pose_box(&i.pose, &i.size)))
            .collect();
        (s.map.clone(), s.vocabulary.clone(), s.map_generation, boxes)
    };
    let built = ReferScene::build_with_boxes(map, vocabulary.as_ref(), &boxes);
    let mut s = shared.lock().map_err(|e| e.to_string())?;
    if s.refer_scene_building.is_some_and(|(g, _)| g == generation) {
        s.refer_scene_building = None;
    }
    let scene = Arc::new(built.map_err(|e| e.to_string())?);
    // Another query may have stored a newer one meanwhile: keep the newest.
    if generation >= s.refer_scene_generation {
        s.refer_scene = scene.clone();
        s.refer_scene_generation = generation;
    }
    Ok((scene, generation))
}

/// The file a `save_map` / `load_map` request names: `map.file` when it names none; inside
/// `map.directory` when one is configured (a path that would leave it is refused).
fn map_path(shared: &Shared, requested: &str) -> std::result::Result<String, String> {
    if requested.is_empty() {
        return shared
            .map_file
            .clone()
            .ok_or_else(|| "no path given and no map.file configured".to_owned());
    }
    let Some(directory) = &shared.map_directory else {
        return Ok(requested.to_owned());
    };
    let path = std::path::Path::new(requested);
    let escapes = path
        .components()
        .any(|c| matches!(c, std::path::Component::ParentDir));
    let inside = if path.is_absolute() {
        path.starts_with(directory).then(|| path.to_path_buf())
    } else {
        Some(directory.join(path))
    };
    match inside {
        Some(p) if !escapes => Ok(p.display().to_string()),
        _ => Err(format!(
            "`{requested}` is outside the map directory {} (map.directory)",
            directory.display()
        )),
    }
}

fn handle_save(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: MapPathRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    // Serialise under the lock, write outside it: a slow disk never stalls the node loop.
    let (path, bytes) = {
        let s = shared.lock().map_err(|e| e.to_string())?;
        let path = map_path(&s, &request.path);
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
        (map_path(&s, &request.path), s.map.params)
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

/// The view a request decides view-dependent words in: its pose when it gives one.
fn request_view(request: &ReferRequest) -> std::result::Result<Option<ViewPose>, String> {
    if !request.use_view_pose {
        return Ok(None);
    }
    let p = &request.view_pose;
    let rotation = DQuat::from_xyzw(
        p.orientation.x,
        p.orientation.y,
        p.orientation.z,
        p.orientation.w,
    );
    let position = DVec3::new(p.position.x, p.position.y, p.position.z);
    if !(position.is_finite() && rotation.is_finite()) || (rotation.length() - 1.0).abs() > 1e-3 {
        return Err("view_pose is not a finite pose with a unit quaternion".into());
    }
    Ok(Some(ViewPose::new(0, rotation.normalize(), position)))
}

/// The query to answer: the LLM's decomposition when `refer.llm_parse` is on and it validates,
/// else the rule parser's `rule`; with a note for the trace.
fn parse_query(
    expression: &str,
    rule: refer::Query,
    section: &ReferSection,
) -> (refer::Query, Option<String>) {
    if !section.llm_parse {
        return (rule, None);
    }
    match refer::vlm::VlmClient::new(&section.vlm).and_then(|client| client.parse(expression)) {
        Ok(query) => (query, Some("parsed by the LLM".into())),
        Err(e) => (rule, Some(format!("LLM parse failed ({e}): rule parser"))),
    }
}

/// Answer a referring request on the node's current snapshot (the service's work, CDR aside),
/// timed as the query stage.
pub fn refer_request(shared: &Mutex<Shared>, request: &ReferRequest) -> ReferResponse {
    let started = std::time::Instant::now();
    let response = answer_refer(shared, request);
    if let Ok(mut s) = shared.lock() {
        s.stages.record(Stage::Query, started.elapsed());
    }
    response
}

fn answer_refer(shared: &Mutex<Shared>, request: &ReferRequest) -> ReferResponse {
    let failure = |message: String| {
        // A question the map cannot answer is an answer, not a fault of the node.
        tracing::info!("refer {:?}: {message}", request.expression);
        ReferResponse {
            success: false,
            message,
            ..ReferResponse::default()
        }
    };
    // Bad input is refused first, whatever state the node is in.
    let rule = match refer::parse(&request.expression) {
        Ok(query) => query,
        Err(e) => return failure(refer::ReferError::from(e).to_string()),
    };
    let view = match request_view(request) {
        Ok(view) => view,
        Err(message) => return failure(message),
    };
    // Read what the query needs, then answer without holding the map's lock.
    let scene = match query_snapshot(shared) {
        Ok(scene) => scene,
        Err(e) => return failure(format!("no snapshot of the map: {e}")),
    };
    let (encoder, section, world_frame) = match shared.lock() {
        Ok(s) => (
            s.text_encoder.clone(),
            s.refer.clone(),
            s.world_frame.clone(),
        ),
        Err(e) => return failure(e.to_string()),
    };
    let Some(encoder) = encoder else {
        return failure("the text encoder is not loaded (yet): no phrase can be matched".into());
    };
    let reasoner = if request.reasoner.is_empty() {
        section.reasoner.as_str()
    } else {
        request.reasoner.as_str()
    };
    if !matches!(reasoner, "builtin" | "vlm") {
        return failure(format!(
            "unknown reasoner {reasoner:?}; use \"builtin\" or \"vlm\""
        ));
    }
    let answered = {
        let Ok(mut encoder) = encoder.lock() else {
            return failure("the text encoder's lock is poisoned".into());
        };
        let (query, parsed_by) = parse_query(&request.expression, rule, &section);
        refer::answer_query(
            &scene,
            &mut *encoder,
            query,
            &refer::Request {
                expression: request.expression.clone(),
                view,
                max_targets: request.max_targets as usize,
            },
            &section,
        )
        .map(|mut answer| {
            if let Some(note) = parsed_by {
                answer.trace = format!("{note}; {}", answer.trace);
            }
            answer
        })
    };
    let mut answer = match answered {
        Ok(answer) => answer,
        Err(e) => return failure(e.to_string()),
    };
    if reasoner == "vlm" || !section.evidence_dir.is_empty() {
        let all: Vec<(String, crate::recon::gaussians::Gaussians)> = scene
            .map
            .instances
            .iter()
            .map(|i| (i.id.clone(), i.gaussians.clone()))
            .collect();
        let images = if reasoner == "vlm" {
            section.vlm.max_images
        } else {
            1 + 3 * section.top_k
        };
        let evidence = refer::evidence::build(&scene, &answer, &all, images);
        if reasoner == "vlm" {
            let client = refer::vlm::VlmClient::new(&section.vlm);
            answer = refer::with_vlm(answer, client.as_ref().map_err(Clone::clone), &evidence);
        }
        if !section.evidence_dir.is_empty() {
            let stem = refer::evidence::stem(&request.expression);
            if let Err(e) = refer::evidence::write(
                std::path::Path::new(&section.evidence_dir),
                &stem,
                &evidence,
            ) {
                tracing::warn!("evidence not written to {}: {e}", section.evidence_dir);
            }
        }
    }
    // From the snapshot that chose them: consistent even if the live map moved on since.
    let gaussians: Vec<_> = answer
        .chosen
        .iter()
        .map(|c| scene.gaussians(&scene.nodes[c.index].id))
        .collect();
    let novel = view
        .zip(scene.keyframes.first())
        .map(|(v, latest)| Keyframe {
            stamp_nanos: latest.stamp_nanos,
            camera: latest.camera,
            world_from_camera: Rigid::new(
                DQuat::from_array(v.orientation),
                DVec3::from(v.position),
            ),
        });
    on_query_pool(|| {
        refer::response::response(&answer, &scene, &gaussians, &world_frame, novel.as_ref())
    })
}

/// Threads of the pool that renders answers' masks and clouds.
const QUERY_THREADS: usize = 2;

/// Run `work` on the queries' own rayon pool: in rayon's global pool an answer's renders queue
/// behind the window worker's HDBSCAN and the publisher's renders (query p99 4-6 times its
/// p50 under a two-camera flood). Without the pool (it failed to start), on the caller's.
fn on_query_pool<T: Send>(work: impl FnOnce() -> T + Send) -> T {
    static POOL: std::sync::OnceLock<Option<rayon::ThreadPool>> = std::sync::OnceLock::new();
    let pool = POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(QUERY_THREADS)
            .thread_name(|i| format!("gf-query-{i}"))
            .build()
            .map_err(|e| tracing::warn!("no query thread pool ({e}): answers share rayon's"))
            .ok()
    });
    match pool {
        Some(pool) => pool.install(work),
        None => work(),
    }
}

/// The reason a request over the bound is refused with (and the status counts it under).
pub const REQUEST_RATE_LIMITED: &str = "request_rate_limited";

/// Take a request under the node's bound on requests, or refuse it with the reason (counted).
pub fn admit(shared: &Mutex<Shared>) -> std::result::Result<(), String> {
    let mut s = shared
        .lock()
        .map_err(|_| "node state unavailable".to_owned())?;
    if s.limiter.admit(std::time::Instant::now()) {
        Ok(())
    } else {
        s.requests_limited += 1;
        Err(format!(
            "{REQUEST_RATE_LIMITED}: more requests than node.max_requests_per_second"
        ))
    }
}

/// The `Refer` service: CDR in, CDR out.
pub fn handle_refer(
    shared: &Mutex<Shared>,
    request: &[u8],
) -> std::result::Result<Vec<u8>, String> {
    let request: ReferRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    cdr::encode(&refer_request(shared, &request)).map_err(|e| e.to_string())
}

/// A referring answer as JSON: ids, confidences, boxes, candidates and the reasoning (clouds and
/// masks are the service's).
fn refer_json(
    shared: &Mutex<Shared>,
    body: &str,
) -> std::result::Result<serde_json::Value, String> {
    let body: serde_json::Value = serde_json::from_str(body).map_err(|e| {
        format!("the refer API takes JSON like {{\"expression\": \"the chair\"}}: {e}")
    })?;
    let expression = body["expression"]
        .as_str()
        .ok_or("the refer API needs a string `expression`")?;
    let request = ReferRequest {
        expression: expression.into(),
        max_targets: body["max_targets"].as_u64().unwrap_or(0) as u32,
        reasoner: body["reasoner"].as_str().unwrap_or("").into(),
        ..ReferRequest::default()
    };
    let r = refer_request(shared, &request);
    Ok(serde_json::json!({
        "success": r.success,
        "message": r.message,
        "instance_ids": r.instance_ids,
        "confidences": r.confidences,
        "boxes": r.boxes,
        "candidates": r.candidates,
        "reasoner_used": r.reasoner_used,
        "trace": r.trace,
        "target_points": r.target_cloud.width,
        "views_with_masks": r.view_masks.len(),
    }))
}

fn handle_json(
    shared: &Mutex<Shared>,
    name: &str,
    body: &str,
) -> std::result::Result<String, String> {
    if name == "refer" {
        return refer_json(shared, body).map(|v| v.to_string());
    }
    let shared = shared.lock().map_err(|e| e.to_string())?;
    let value = match name {
        "status" => serde_json::to_value(&shared.status),
        "instances" => serde_json::to_value(&shared.instances),
        "scene_graph" => Ok(shared
            .scene_graph_json
            .clone()
            .unwrap_or_else(|| serde_json::json!({"nodes": [], "edges": []}))),
        other => {
            return Err(format!(
                "unknown API `{other}`; available: status, instances, scene_graph, refer"
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
    for (topic, route) in Ingest::routes(&config.cameras, &config.tf) {
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
    let refer = Endpoint::new(
        &resolve_name(ns, name, "~/refer")?,
        Refer::TYPE_NAME,
        Qos::default(),
    )?;
    type Handler = fn(&Mutex<Shared>, &[u8]) -> std::result::Result<Vec<u8>, String>;
    let handlers: [(&Endpoint, Handler); 5] = [
        (&refer, handle_refer),
        (&save, handle_save),
        (&load, handle_load),
        (&list, handle_list),
        (&get, handle_get),
    ];
    for (endpoint, handle) in handlers {
        let s = shared.clone();
        transport.serve(
            endpoint,
            Arc::new(move |req| {
                admit(&s)?;
                handle(&s, req)
            }),
        )?;
    }
    let prefix = config.api_prefix();
    let s = shared.clone();
    transport.serve_json(
        &prefix,
        Arc::new(move |api, body| {
            // The status is a cached message: reading it costs nothing and is how a client
            // learns that it is being refused.
            if api != "status" {
                admit(&s)?;
            }
            handle_json(&s, api, &String::from_utf8_lossy(body))
        }),
    )?;
    Ok(Declared {
        subscriptions,
        status,
        services: vec![refer, list, get, save, load],
        json_prefix: prefix,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_query_answers_on_the_previous_snapshot_only_while_the_output_thread_takes_the_new_one() {
        let shared = Mutex::new(Shared::default());
        let lock = || shared.lock().unwrap_or_else(|e| panic!("{e}"));
        let snapshot = |f: fn(&Mutex<Shared>) -> std::result::Result<Arc<ReferScene>, String>| {
            f(&shared).unwrap_or_else(|e| panic!("{e}"))
        };
        lock().snapshot_taker = true;
        lock().set_map(SceneMap::default());
        let first = snapshot(current_snapshot);
        assert_eq!(lock().refer_scene_generation, 1);
        // A window changed the map and the output thread will take its snapshot: the query
        // does not wait for it.
        lock().refresh_instances();
        snapshot_due(&mut lock());
        assert!(Arc::ptr_eq(&snapshot(query_snapshot), &first));
        assert_eq!(lock().refer_scene_generation, 1);
        // The output thread took it: the query reads the new one.
        let taken = snapshot(current_snapshot);
        assert!(lock().refer_scene_building.is_none());
        assert!(Arc::ptr_eq(&snapshot(query_snapshot), &taken));
        assert!(!Arc::ptr_eq(&taken, &first));
        // Promised too long ago (a stalled output thread): the query takes it itself.
        lock().refresh_instances();
        snapshot_due(&mut lock());
        if let Some((_, since)) = lock().refer_scene_building.as_mut() {
            *since -= std::time::Duration::from_secs_f64(SNAPSHOT_DUE_SECS + 0.5);
        }
        assert!(!Arc::ptr_eq(&snapshot(query_snapshot), &taken));
        let current = |s: &Shared| s.refer_scene_generation == s.map_generation;
        assert!(current(&lock()));
        // No output thread: nothing is promised, and a query after a change takes it.
        lock().snapshot_taker = false;
        lock().refresh_instances();
        snapshot_due(&mut lock());
        assert!(lock().refer_scene_building.is_none());
        snapshot(query_snapshot);
        assert!(current(&lock()));
    }

    #[test]
    fn a_window_fused_outside_the_lock_is_installed_unless_load_map_replaced_the_map_meanwhile() {
        let mut s = Shared::default();
        s.set_map(SceneMap::default());
        // The worker copies the map at generation 1 and fuses one instance into the copy.
        let copied_at = s.map_generation;
        let fused = vec![named("inst_000001", "chair")];
        assert!(s.install_fused(
            copied_at,
            SceneMap::default(),
            fused.clone(),
            BoxCache::default()
        ));
        assert_eq!(s.map_generation, copied_at + 1);
        assert_eq!(s.instances.len(), 1);
        // The next window copies generation 2, but a load_map replaces the map before it is
        // installed: the window is dropped and counted, the loaded map stays.
        let copied_at = s.map_generation;
        s.set_map(SceneMap::default());
        let loaded = s.map_generation;
        assert!(!s.install_fused(copied_at, SceneMap::default(), fused, BoxCache::default()));
        assert_eq!((s.map_generation, s.windows_superseded), (loaded, 1));
        assert!(
            s.instances.is_empty(),
            "the loaded (empty) map's list stays"
        );
    }

    #[test]
    fn answers_render_on_their_own_threads_while_rayons_global_pool_is_busy() {
        use rayon::prelude::*;
        use std::sync::atomic::{AtomicBool, Ordering};
        let release = AtomicBool::new(false);
        let busy = AtomicBool::new(false);
        // Held at most this long, so a render queued behind them fails the test, not hangs it.
        let started = std::time::Instant::now();
        let held = std::time::Duration::from_secs(3);
        std::thread::scope(|scope| {
            // The window worker's HDBSCAN: every global-pool thread held until released.
            scope.spawn(|| {
                (0..rayon::current_num_threads() * 4)
                    .into_par_iter()
                    .for_each(|_| {
                        busy.store(true, Ordering::Release);
                        while !release.load(Ordering::Acquire) && started.elapsed() < held {
                            std::thread::yield_now();
                        }
                    });
            });
            while !busy.load(Ordering::Acquire) {
                std::thread::yield_now();
            }
            // An answer's parallel render still runs, on the query pool's threads.
            let names: Vec<String> = on_query_pool(|| {
                (0..8)
                    .into_par_iter()
                    .map(|_| std::thread::current().name().unwrap_or("").to_owned())
                    .collect()
            });
            release.store(true, Ordering::Release);
            assert!(
                started.elapsed() < held,
                "the render waited for the global pool"
            );
            assert!(
                names.iter().all(|n| n.starts_with("gf-query-")),
                "{names:?}"
            );
        });
    }

    fn named(id: &str, best: &str) -> Instance {
        Instance {
            id: id.into(),
            hypotheses: vec![
                ObjectHypothesis {
                    class_id: best.into(),
                    score: 0.7,
                },
                ObjectHypothesis {
                    class_id: "table".into(),
                    score: 0.2,
                },
            ],
            ..Default::default()
        }
    }

    #[test]
    fn map_paths_stay_inside_the_configured_directory() {
        let mut s = Shared {
            map_file: Some("/var/robot/map.gfmap".into()),
            ..Shared::default()
        };
        // No directory: any path, as before; an empty request names map.file.
        assert_eq!(map_path(&s, "../x.gfmap").unwrap(), "../x.gfmap");
        assert_eq!(map_path(&s, "").unwrap(), "/var/robot/map.gfmap");
        s.map_directory = Some("/data/maps".into());
        assert_eq!(
            map_path(&s, "kitchen.gfmap").unwrap(),
            "/data/maps/kitchen.gfmap"
        );
        assert_eq!(
            map_path(&s, "/data/maps/a/b.gfmap").unwrap(),
            "/data/maps/a/b.gfmap"
        );
        for outside in [
            "../etc/passwd",
            "a/../../x.gfmap",
            "/etc/x.gfmap",
            "/data/mapsx/y.gfmap",
            "/data/maps/../z.gfmap",
        ] {
            let refused = map_path(&s, outside).unwrap_err();
            assert!(
                refused.contains("outside the map directory"),
                "{outside}: {refused}"
            );
        }
        assert_eq!(map_path(&s, "").unwrap(), "/var/robot/map.gfmap");
    }

    #[test]
    fn cached_boxes_are_refitted_exactly_where_the_gaussians_changed() {
        use crate::frame::WindowInstance;
        use crate::graph::FusionParams;
        let cube = |x: f32| {
            let mut g = crate::recon::gaussians::Gaussians::with_dims(0, 0);
            for i in 0..27 {
                let offset = glam::Vec3::new((i % 3) as f32, (i / 3 % 3) as f32, (i / 9) as f32);
                g.push(
                    glam::Vec3::new(x, 0.0, 0.5) + offset * 0.1,
                    0.9,
                    glam::Vec3::splat(0.02),
                    glam::Quat::IDENTITY,
                    glam::Vec3::ONE,
                    &[],
                    &[],
                );
            }
            g
        };
        let mut map = SceneMap::new(FusionParams::default());
        let window = (0..3)
            .map(|k| WindowInstance {
                gaussians: cube(2.0 * k as f32),
                prototype: vec![1.0, k as f32],
                support: 27,
            })
            .collect();
        map.fuse(window, &[], 1).unwrap();
        let mut cache = BoxCache::default();
        let first = instance_messages_cached(&map, None, 3, &mut cache);
        assert_eq!(first, instance_messages(&map, None, 3));
        // The middle instance moves by a metre; the others stay.
        for m in &mut map.instances[1].gaussians.means {
            m.x += 1.0;
        }
        let second = instance_messages_cached(&map, None, 3, &mut cache);
        assert_eq!(second, instance_messages(&map, None, 3), "no stale box");
        assert!((second[1].pose.position.x - first[1].pose.position.x - 1.0).abs() < 1e-6);
        assert_eq!(second[0], first[0]);
        assert_eq!(second[2], first[2]);
        // An instance that left the map leaves the cache.
        map.instances.remove(2);
        instance_messages_cached(&map, None, 3, &mut cache);
        assert_eq!(cache.0.len(), 2);
    }

    fn shared() -> Mutex<Shared> {
        Mutex::new(Shared {
            instances: vec![
                named("inst_000001", "chair"),
                named("inst_000002", "armchair"),
                named("inst_000003", "lamp"),
            ],
            ..Shared::default()
        })
    }

    fn list(shared: &Mutex<Shared>, filter: &str) -> Vec<String> {
        let request = cdr::encode(&ListInstancesRequest {
            label_filter: filter.into(),
        })
        .unwrap();
        let reply: ListInstancesResponse =
            cdr::decode(&handle_list(shared, &request).unwrap()).unwrap();
        reply.instances.into_iter().map(|i| i.id).collect()
    }

    #[test]
    fn list_filters_by_the_best_label_only() {
        let shared = shared();
        assert_eq!(list(&shared, "").len(), 3);
        // A substring of the best hypothesis: both chairs; `table` is only a second hypothesis.
        assert_eq!(list(&shared, "chair"), ["inst_000001", "inst_000002"]);
        assert_eq!(list(&shared, "lamp"), ["inst_000003"]);
        assert!(list(&shared, "table").is_empty());
    }

    #[test]
    fn get_finds_by_id_and_says_when_it_does_not() {
        let shared = shared();
        let get = |id: &str| -> GetInstanceResponse {
            let request = cdr::encode(&GetInstanceRequest { id: id.into() }).unwrap();
            cdr::decode(&handle_get(&shared, &request).unwrap()).unwrap()
        };
        let found = get("inst_000003");
        assert!(found.found);
        assert_eq!(found.instance.hypotheses[0].class_id, "lamp");
        let missing = get("inst_000042");
        assert!(!missing.found);
        assert!(missing.instance.id.is_empty());
        assert!(handle_get(&shared, b"garbage").is_err());
    }

    #[test]
    fn the_json_api_serves_instances_and_status_and_names_what_it_serves() {
        let shared = shared();
        let instances: serde_json::Value =
            serde_json::from_str(&handle_json(&shared, "instances", "").unwrap()).unwrap();
        let ids: Vec<&str> = instances
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i["id"].as_str().unwrap())
            .collect();
        assert_eq!(ids, ["inst_000001", "inst_000002", "inst_000003"]);
        assert_eq!(instances[2]["hypotheses"][0]["class_id"], "lamp");
        let status: serde_json::Value =
            serde_json::from_str(&handle_json(&shared, "status", "").unwrap()).unwrap();
        assert!(status["cameras"].is_array());
        let unknown = handle_json(&shared, "graph", "").unwrap_err();
        assert!(
            unknown.contains("status, instances, scene_graph, refer"),
            "{unknown}"
        );
    }
}

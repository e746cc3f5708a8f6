//! The state the node shares with its service and JSON handlers (which run on transport
//! threads): the map, its instance messages with their boxes cached, and the snapshots referring
//! answers on.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use groupforward_msgs::builtin_interfaces::Time;
use groupforward_msgs::gf_msgs::{Instance, NodeStatus};
use groupforward_msgs::vision_msgs::ObjectHypothesis;

use crate::frame::MeasuredDepth;
use crate::graph::{Fitted, SceneMap};
use crate::group::semantics::Vocabulary;
use crate::model::text::TextEncoder;
use crate::observations::Observations;
use crate::outputs::ViewSource;
use crate::refer::scene::{query_list, QueryList};
use crate::refer::{self, ReferScene, ReferSection};
use crate::timing::StageClock;

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
    pub limiter: super::super::limit::RequestLimiter,
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
    /// The last window's views' sensor depth (answers' masks are cut by it).
    pub measured_views: Vec<Arc<MeasuredDepth>>,
    /// The camera's pictures of each instance (the VLM's evidence shows them).
    pub observations: Observations,
    /// The last published scene graph as JSON (the `scene_graph` JSON API).
    pub scene_graph_json: Option<serde_json::Value>,
    /// Boxes of the listed instances, refitted only when their Gaussians change.
    pub boxes: BoxCache,
    /// The object list of `map` as queries read it, made with `instances` (the snapshot takes
    /// it rather than listing the map again).
    pub query_list: Arc<QueryList>,
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
pub struct BoxCache(pub(super) HashMap<String, (Fingerprint, bool, Fitted)>);

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
    object_lists_cached(map, vocabulary, hypotheses, cache).0
}

/// The instance messages ([`instance_messages_cached`]) and the object list queries read
/// ([`QueryList`]: the same boxes, and the tentative candidates), from one listing of `map`.
pub fn object_lists_cached(
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
    hypotheses: usize,
    cache: &mut BoxCache,
) -> (Vec<Instance>, QueryList) {
    let mut fitted = HashMap::new();
    // The structure changes with every window: completion is redone, fitting is cached.
    let listed = query_list(map, vocabulary, |i, box_like| {
        let print = fingerprint(&i.gaussians);
        let b = match cache.0.get(&i.id) {
            Some((seen, was_box_like, b)) if (*seen, *was_box_like) == (print, box_like) => *b,
            _ => i.fitted(box_like),
        };
        fitted.insert(i.id.clone(), (print, box_like, b));
        b
    });
    // In the map's order, as the object list is; tentative candidates are not published.
    let messages = map
        .instances
        .iter()
        .filter_map(|i| match listed.get(&i.id) {
            Some((b, names, false)) => Some((i, *b, names)),
            _ => None,
        })
        .map(|(i, b, names)| Instance {
            id: i.id.clone(),
            hypotheses: vocabulary
                .map(|v| v.ranked(names, hypotheses))
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
    (messages, listed)
}

impl Shared {
    /// Replace the map and refresh the instance messages.
    pub fn set_map(&mut self, map: SceneMap) {
        self.map = map;
        // What was seen of the map it replaces is not of this one (ids are reused).
        self.measured_views.clear();
        self.observations = Observations::default();
        self.refresh_instances();
    }

    /// Install a map the worker fused outside the lock into a copy of generation `fused_from`,
    /// with its instance messages and boxes; refused (and counted) when the map was replaced
    /// meanwhile (`load_map`), whose content the copy does not hold.
    pub fn install_fused(
        &mut self,
        fused_from: u64,
        map: SceneMap,
        (instances, query_list): (Vec<Instance>, QueryList),
        boxes: BoxCache,
    ) -> bool {
        if self.map_generation != fused_from {
            self.windows_superseded += 1;
            return false;
        }
        self.map = map;
        self.instances = instances;
        self.query_list = Arc::new(query_list);
        self.boxes = boxes;
        self.map_generation += 1;
        true
    }

    /// Rebuild the instance messages after the map changed in place; the referring snapshot is
    /// retaken by the next query.
    pub fn refresh_instances(&mut self) {
        let (instances, query_list) = object_lists_cached(
            &self.map,
            self.vocabulary.as_ref(),
            self.hypotheses,
            &mut self.boxes,
        );
        self.instances = instances;
        self.query_list = Arc::new(query_list);
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
    let (map, vocabulary, generation, listed, (measured, observations)) = {
        let mut s = shared.lock().map_err(|e| e.to_string())?;
        if s.refer_scene_generation == s.map_generation {
            return Ok((s.refer_scene.clone(), s.map_generation));
        }
        s.refer_scene_building = Some((s.map_generation, std::time::Instant::now()));
        let seen = (s.measured_views.clone(), s.observations.clone());
        (
            s.map.clone(),
            s.vocabulary.clone(),
            s.map_generation,
            // Listed when the map changed, with the instance messages: answers carry the
            // published boxes, and the snapshot does not list the map again.
            s.query_list.clone(),
            seen,
        )
    };
    let listed = Arc::unwrap_or_clone(listed);
    let built = ReferScene::build_listed(map, vocabulary.as_ref(), listed).map(|scene| {
        scene
            .with_measured(&measured)
            .with_observations(observations)
    });
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

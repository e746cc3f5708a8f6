//! The output publisher: a thread that, after the map changed (at most `outputs.max_rate_hz`),
//! encodes the map's messages from the referring snapshot and publishes them, and publishes the
//! last ones again every `outputs.republish_secs` for subscribers that join late. Encoding runs
//! off the node loop and off the window worker; taking the snapshot here also means the first
//! query after a window finds it ready.

use std::collections::BTreeSet;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use groupforward_msgs::gf_msgs::{InstanceArray, InstanceMasks, SceneGraph};
use groupforward_msgs::rmw_zenoh::{resolve_name, Qos};
use groupforward_msgs::sensor_msgs::PointCloud2;
use groupforward_msgs::vision_msgs::Detection3DArray;
use groupforward_msgs::visualization_msgs::MarkerArray;
use groupforward_msgs::{cdr, RosMessage};

use super::error::Result;
use super::services::{current_snapshot, current_snapshot_and_generation, Shared};
use crate::config::Config;
use crate::outputs::{self, OutputsSection};
use crate::timing::Stage;
use crate::transport::{Endpoint, Publisher, Transport};

/// The output topics the configuration switches on, resolved.
#[derive(Debug, Clone, Default)]
pub struct OutputEndpoints {
    pub instances: Option<Endpoint>,
    pub instance_array: Option<Endpoint>,
    pub instance_cloud: Option<Endpoint>,
    pub instance_masks: Option<Endpoint>,
    pub markers: Option<Endpoint>,
    pub scene_graph: Option<Endpoint>,
}

impl OutputEndpoints {
    pub fn declare(config: &Config) -> Result<Self> {
        let (ns, name) = (&config.node.namespace, &config.node.name);
        let o = &config.outputs;
        // Reliable, depth 1: each message replaces the previous one.
        let qos = Qos {
            depth: 1,
            ..Qos::default()
        };
        let endpoint = |topic: &str, type_name: &str| -> Result<Option<Endpoint>> {
            if topic.is_empty() {
                return Ok(None);
            }
            // Lossless: a late map message is better than a lost one (rmw_zenoh's issue #696 lost
            // large messages to congestion dropping).
            Ok(Some(
                Endpoint::new(&resolve_name(ns, name, topic)?, type_name, qos)?.lossless(),
            ))
        };
        Ok(Self {
            instances: endpoint(&o.instances, Detection3DArray::TYPE_NAME)?,
            instance_array: endpoint(&o.instance_array, InstanceArray::TYPE_NAME)?,
            instance_cloud: endpoint(&o.instance_cloud, PointCloud2::TYPE_NAME)?,
            instance_masks: endpoint(&o.instance_masks, InstanceMasks::TYPE_NAME)?,
            markers: endpoint(&o.markers, MarkerArray::TYPE_NAME)?,
            scene_graph: endpoint(&o.scene_graph, SceneGraph::TYPE_NAME)?,
        })
    }

    pub fn all(&self) -> Vec<&Endpoint> {
        [
            &self.instances,
            &self.instance_array,
            &self.instance_cloud,
            &self.instance_masks,
            &self.markers,
            &self.scene_graph,
        ]
        .into_iter()
        .flatten()
        .collect()
    }
}

type Advertised = Option<Box<dyn Publisher>>;

/// The advertised publishers, one per switched-on output.
struct Publishers {
    instances: Advertised,
    instance_array: Advertised,
    instance_cloud: Advertised,
    instance_masks: Advertised,
    markers: Advertised,
    scene_graph: Advertised,
}

/// One publication: every message already serialized, kept for republishing.
#[derive(Debug, Default)]
pub struct Encoded {
    pub instances: Vec<u8>,
    pub instance_array: Vec<u8>,
    pub instance_cloud: Vec<u8>,
    pub instance_masks: Vec<Vec<u8>>,
    pub markers: Vec<u8>,
    pub scene_graph: Vec<u8>,
}

impl Encoded {
    /// Bytes over all messages.
    pub fn len(&self) -> usize {
        self.instances.len()
            + self.instance_array.len()
            + self.instance_cloud.len()
            + self.instance_masks.iter().map(Vec::len).sum::<usize>()
            + self.markers.len()
            + self.scene_graph.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Publishers {
    fn publish(&self, encoded: &Encoded) {
        let send = |publisher: &Advertised, what: &str, bytes: &[u8]| {
            if let Some(p) = publisher {
                if let Err(e) = p.publish(bytes) {
                    tracing::warn!("cannot publish {what}: {e}");
                }
            }
        };
        send(&self.instances, "instances", &encoded.instances);
        send(
            &self.instance_array,
            "instance array",
            &encoded.instance_array,
        );
        send(
            &self.instance_cloud,
            "instance cloud",
            &encoded.instance_cloud,
        );
        for mask in &encoded.instance_masks {
            send(&self.instance_masks, "instance masks", mask);
        }
        send(&self.markers, "markers", &encoded.markers);
        send(&self.scene_graph, "scene graph", &encoded.scene_graph);
    }
}

/// Advertise the outputs and start the thread; it stops when `stop` is dropped or sends.
pub(super) fn start_output_publisher(
    config: &Config,
    endpoints: &OutputEndpoints,
    transport: &dyn Transport,
    shared: &Arc<Mutex<Shared>>,
    stop: Receiver<()>,
) -> Result<Option<JoinHandle<()>>> {
    let advertise = |e: &Option<Endpoint>| -> Result<Advertised> {
        Ok(match e {
            Some(e) => Some(transport.advertise(e)?),
            None => None,
        })
    };
    let publishers = Publishers {
        instances: advertise(&endpoints.instances)?,
        instance_array: advertise(&endpoints.instance_array)?,
        instance_cloud: advertise(&endpoints.instance_cloud)?,
        instance_masks: advertise(&endpoints.instance_masks)?,
        markers: advertise(&endpoints.markers)?,
        scene_graph: advertise(&endpoints.scene_graph)?,
    };
    let section = config.outputs.clone();
    let shared = shared.clone();
    Ok(Some(std::thread::spawn(move || {
        publish_loop(&section, &publishers, &shared, &stop)
    })))
}

fn publish_loop(
    section: &OutputsSection,
    publishers: &Publishers,
    shared: &Mutex<Shared>,
    stop: &Receiver<()>,
) {
    let min_interval = Duration::from_secs_f64(1.0 / section.max_rate_hz);
    let republish =
        (section.republish_secs > 0.0).then(|| Duration::from_secs_f64(section.republish_secs));
    // Nothing published yet: the first turn publishes the map as it is (empty at a cold start,
    // which tells a viewer there are no objects yet).
    let mut published_generation = u64::MAX;
    let mut last_publish: Option<Instant> = None;
    let mut encoded: Option<Encoded> = None;
    let mut listed_before: BTreeSet<String> = BTreeSet::new();
    loop {
        // On stop, one last turn without the rate limit: the final map is published.
        let stopping = match stop.recv_timeout(Duration::from_millis(50)) {
            Err(RecvTimeoutError::Timeout) => false,
            Ok(()) | Err(RecvTimeoutError::Disconnected) => true,
        };
        let now = Instant::now();
        if !stopping && last_publish.is_some_and(|t| now - t < min_interval) {
            // Publishing waits for its rate; the referring snapshot of a changed map does not, so
            // queries find it taken (see `query_snapshot`; an unchanged map's costs a lock).
            if let Err(e) = current_snapshot(shared) {
                tracing::warn!("cannot take the map's snapshot: {e}");
            }
            continue;
        }
        let generation = shared.lock().map(|s| s.map_generation).unwrap_or(0);
        if generation != published_generation {
            match encode(section, shared, &mut listed_before) {
                Ok(Some((fresh, at))) => {
                    publishers.publish(&fresh);
                    if let Ok(mut s) = shared.lock() {
                        s.stages.record(Stage::Publish, now.elapsed());
                    }
                    encoded = Some(fresh);
                    published_generation = at;
                    last_publish = Some(now);
                }
                // The map moved on while encoding: the next turn takes the newer one.
                Ok(None) => {}
                Err(e) => {
                    tracing::warn!("cannot encode the map's outputs: {e}");
                    published_generation = generation;
                    last_publish = Some(now);
                }
            }
        } else if let (Some(every), Some(last), Some(previous)) =
            (republish, last_publish, encoded.as_ref())
        {
            if now - last >= every {
                publishers.publish(previous);
                last_publish = Some(now);
            }
        }
        if stopping {
            break;
        }
    }
}

/// Encode every output from one snapshot (taking it if the map changed since the last one);
/// `None` when the instance list and the snapshot are of different map generations (a window
/// landed in between). `listed_before` (ids of the previous publication) gets this one's.
pub fn encode(
    section: &OutputsSection,
    shared: &Mutex<Shared>,
    listed_before: &mut BTreeSet<String>,
) -> std::result::Result<Option<(Encoded, u64)>, String> {
    let (scene, generation) = current_snapshot_and_generation(shared)?;
    let (instances, world_frame, sources) = {
        let s = shared.lock().map_err(|e| e.to_string())?;
        if s.map_generation != generation {
            return Ok(None);
        }
        (
            s.instances.clone(),
            s.world_frame.clone(),
            s.view_sources.clone(),
        )
    };
    let header = outputs::map_header(&scene, &world_frame);
    let listed: BTreeSet<String> = instances.iter().map(|i| i.id.clone()).collect();
    let gone: Vec<String> = listed_before.difference(&listed).cloned().collect();
    let graph = outputs::scene_graph(&header, &scene, &instances);
    let json = outputs::scene_graph_json(&graph);
    let bytes = |e: groupforward_msgs::cdr::CdrError| e.to_string();
    let encoded = Encoded {
        instances: cdr::encode(&outputs::detections(&header, &instances)).map_err(bytes)?,
        instance_array: cdr::encode(&outputs::instance_array(&header, &instances))
            .map_err(bytes)?,
        instance_cloud: cdr::encode(&outputs::cloud(
            &header,
            &scene,
            &instances,
            section.cloud_max_points,
        ))
        .map_err(bytes)?,
        instance_masks: outputs::masks(&scene, &instances, &sources)
            .iter()
            .map(cdr::encode)
            .collect::<std::result::Result<_, _>>()
            .map_err(bytes)?,
        markers: cdr::encode(&outputs::markers(&header, &instances, &gone, &graph))
            .map_err(bytes)?,
        scene_graph: cdr::encode(&graph).map_err(bytes)?,
    };
    *listed_before = listed;
    if let Ok(mut s) = shared.lock() {
        s.scene_graph_json = Some(json);
    }
    Ok(Some((encoded, generation)))
}

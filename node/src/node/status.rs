//! The node's ingest-side state ([`Node`]: ingest plus the frames it completed) and the status
//! report it publishes every period.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::Instant;

use groupforward_msgs::gf_msgs::{CameraStatus, NodeStatus, RejectCount, StageTiming};
use groupforward_msgs::{builtin_interfaces::Time, cdr, std_msgs::Header};

use super::services::Shared;
use crate::config::Config;
use crate::frame::SyncedFrame;
use crate::ingest::{Ingest, Reject, Rejection, Route};
use crate::timing::{Stage, StageClock, StageSummary};
use crate::transport::Publisher;
use crate::window::{Keyframes, WindowSection};

/// What one message did to the node's state.
#[derive(Debug, Default)]
pub struct Step {
    /// Frames that completed (colour, camera info, depth and pose all there).
    pub synced: usize,
    /// Frames kept as keyframes, oldest first (their semantic features can be computed before
    /// their window is complete).
    pub keyframes: Vec<SyncedFrame>,
    /// Keyframe windows that became complete, oldest first: each is one model pass.
    pub windows: Vec<Vec<SyncedFrame>>,
}

/// The node's pipeline state up to the window pass (ingest, keyframes), driven by [`Node::step`]
/// without any transport: the node loop and `groupforward eval` feed it alike.
#[derive(Debug)]
pub struct Node {
    pub ingest: Ingest,
    window: WindowSection,
    /// By camera name, so several cameras' waiting windows come in a fixed order.
    keyframes: BTreeMap<String, Keyframes>,
    started: Instant,
    period_start: Instant,
    period_received: Vec<u64>,
    /// Recent ingest durations (one per message).
    pub stages: StageClock,
    /// Keyframe windows dropped because the window pass was still busy with the previous one.
    pub windows_dropped: u64,
}

impl Node {
    pub fn new(config: &Config) -> Self {
        let ingest = Ingest::new(&config.cameras, &config.tf, &config.ingest);
        let cameras = ingest.camera_count();
        Self {
            ingest,
            window: config.window.clone(),
            keyframes: BTreeMap::new(),
            started: Instant::now(),
            period_start: Instant::now(),
            period_received: vec![0; cameras],
            stages: StageClock::default(),
            windows_dropped: 0,
        }
    }

    /// Process one message: ingest it, offer the frames it completed as keyframes, and return
    /// the windows that became complete.
    pub fn step(&mut self, route: Route, payload: &[u8]) -> Step {
        let _span = tracing::debug_span!("ingest", ?route).entered();
        let started = std::time::Instant::now();
        let frames = self.ingest.handle(route, payload);
        let mut step = Step {
            synced: frames.len(),
            ..Step::default()
        };
        for frame in frames {
            let store = self
                .keyframes
                .entry(frame.camera_name.clone())
                .or_insert_with(|| Keyframes::new(self.window.clone()));
            if store.offer(&frame) {
                match store.take_window() {
                    // The window's newest frame is computed in the window itself.
                    Some(window) => step.windows.push(window),
                    None => step.keyframes.extend(store.newest().cloned()),
                }
            }
        }
        self.stages.record(Stage::Ingest, started.elapsed());
        step
    }

    /// The window of the keyframes still waiting for one of the first camera (by name) whose
    /// stream has been quiet for `window.flush_after_secs` at `now`
    /// ([`Keyframes::take_quiet_window`]).
    pub fn quiet_window(&mut self, now: Instant) -> Option<Vec<SyncedFrame>> {
        self.keyframes
            .values_mut()
            .find_map(|store| store.take_quiet_window(now))
    }

    /// Windows of every camera's keyframes still waiting for one: the stream ended.
    pub fn pending_windows(&mut self) -> Vec<Vec<SyncedFrame>> {
        self.keyframes
            .values_mut()
            .filter_map(Keyframes::take_pending_window)
            .collect()
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
                depth_pixels: c.depth.pixels,
                depth_pixels_invalid: c.depth.invalid(),
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
            stages: self.stages.summary().iter().map(stage_timing).collect(),
        }
    }
}

fn stage_timing(s: &StageSummary) -> StageTiming {
    StageTiming {
        stage: s.stage.name().to_owned(),
        count: s.count,
        last_ms: s.last_ms,
        p50_ms: s.p50_ms,
        p99_ms: s.p99_ms,
    }
}

pub(super) fn wall_nanos() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

/// The status's reason code for windows dropped while the window pass was busy.
pub const WINDOW_BUSY: &str = "window_dropped_busy";

/// The status's reason code for windows that built nothing because no view had valid depth.
pub const WINDOW_WITHOUT_DEPTH: &str = "window_without_valid_depth";
/// The status's reason code for windows fused while `load_map` replaced the map.
pub const WINDOW_SUPERSEDED: &str = "window_superseded_by_load_map";

pub(super) fn publish_status(
    node: &mut Node,
    now: Instant,
    publisher: &dyn Publisher,
    shared: &Mutex<Shared>,
) -> NodeStatus {
    let mut status = node.status(now);
    if node.windows_dropped > 0 {
        status.rejections.push(RejectCount {
            reason: WINDOW_BUSY.to_owned(),
            count: node.windows_dropped,
        });
    }
    if let Ok(s) = shared.lock() {
        if s.windows_skipped > 0 {
            status.rejections.push(RejectCount {
                reason: WINDOW_WITHOUT_DEPTH.to_owned(),
                count: s.windows_skipped,
            });
        }
        if s.windows_superseded > 0 {
            status.rejections.push(RejectCount {
                reason: WINDOW_SUPERSEDED.to_owned(),
                count: s.windows_superseded,
            });
        }
        if s.requests_limited > 0 {
            status.rejections.push(RejectCount {
                reason: super::services::REQUEST_RATE_LIMITED.to_owned(),
                count: s.requests_limited,
            });
        }
        // Ingest runs on the node loop; the other stages on the worker, publisher and service
        // threads. One list in data-flow order.
        let mut summaries = node.stages.summary();
        summaries.extend(s.stages.summary());
        summaries.sort_by_key(|t| t.stage);
        status.stages = summaries.iter().map(stage_timing).collect();
    }
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

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::node::queue::InputQueue;

    #[test]
    fn messages_the_full_queue_dropped_are_counted_and_reported() {
        let mut config = Config::default();
        config.cameras[0].depth_topic = None;
        let mut node = Node::new(&config);
        let queue = InputQueue::new(1);
        queue.push(Route::Image(0), vec![1]);
        queue.push(Route::Tf, vec![2]);
        queue.push(Route::Image(0), vec![3]);
        let (item, dropped) = queue.pop(Duration::ZERO);
        assert_eq!(item.map(|(route, _)| route), Some(Route::Image(0)));
        node.record_dropped(&dropped);
        assert_eq!(node.ingest.rejections.count(Reject::QueueOverflow), 2);
        assert_eq!(node.ingest.tf_rejected, 1);
        let status = node.status(Instant::now());
        assert_eq!(status.cameras[0].frames_rejected, 1);
        assert_eq!(status.rejections.len(), 1);
        assert_eq!(status.rejections[0].reason, "queue_overflow");
        assert_eq!(status.rejections[0].count, 2);
    }

    #[test]
    fn windows_dropped_while_the_pass_was_busy_and_stage_times_are_in_the_published_status() {
        use crate::timing::{Stage, StageTimes};
        use crate::transport::{Endpoint, MemoryTransport, Transport};
        use groupforward_msgs::RosMessage;
        let config = Config::default();
        let mut node = Node::new(&config);
        node.windows_dropped = 3;
        node.stages
            .record(Stage::Ingest, Duration::from_micros(200));
        let shared = Mutex::new(Shared::default());
        let mut times = StageTimes::default();
        times.0.push((Stage::Model, Duration::from_millis(80)));
        times.0.push((Stage::Window, Duration::from_millis(250)));
        shared.lock().unwrap().stages.record_all(&times);
        let bus = MemoryTransport::new();
        let endpoint = Endpoint::new(
            "/groupforward/status",
            NodeStatus::TYPE_NAME,
            Default::default(),
        )
        .unwrap();
        let publisher = bus.advertise(&endpoint).unwrap();
        publish_status(&mut node, Instant::now(), publisher.as_ref(), &shared);
        let status: NodeStatus = cdr::decode(&bus.published("/groupforward/status")[0]).unwrap();
        let busy = status.rejections.iter().find(|r| r.reason == WINDOW_BUSY);
        assert_eq!(busy.map(|r| r.count), Some(3));
        // Ingest (node loop) and the worker's stages in one list, in data-flow order.
        let stages: Vec<&str> = status.stages.iter().map(|s| s.stage.as_str()).collect();
        assert_eq!(stages, ["ingest", "model", "window"]);
        assert!((status.stages[1].p50_ms - 80.0).abs() < 1e-9);
        assert_eq!(shared.lock().unwrap().status, status);
    }
}

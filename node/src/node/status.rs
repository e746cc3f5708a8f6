//! The node's ingest-side state ([`Node`]: ingest plus the frames it completed) and the status
//! report it publishes every period.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::Instant;

use groupforward_msgs::gf_msgs::{CameraStatus, NodeStatus, RejectCount};
use groupforward_msgs::{builtin_interfaces::Time, cdr, std_msgs::Header};

use super::services::Shared;
use crate::config::Config;
use crate::frame::SyncedFrame;
use crate::ingest::{Ingest, Reject, Rejection, Route};
use crate::transport::Publisher;

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
        let ingest = Ingest::new(&config.cameras, &config.tf, &config.ingest);
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

pub(super) fn wall_nanos() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

pub(super) fn publish_status(
    node: &mut Node,
    now: Instant,
    publisher: &dyn Publisher,
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
}

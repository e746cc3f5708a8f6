//! Keyframe selection for one camera: which synced frames become keyframes, and when they form
//! a window (enough fresh ones, or the stream paused or ended).

use std::collections::VecDeque;

use super::WindowSection;
use crate::exposure::ExposureTracker;
use crate::frame::SyncedFrame;

/// Keyframes of one camera.
#[derive(Debug, Default)]
pub struct Keyframes {
    pub params: WindowSection,
    frames: VecDeque<SyncedFrame>,
    /// Keyframes added since the last window was taken.
    fresh: usize,
    exposure: ExposureTracker,
    /// When the last frame was offered (wall clock): how long the stream has been quiet.
    last_offer: Option<std::time::Instant>,
}

impl Keyframes {
    pub fn new(params: WindowSection) -> Self {
        Self {
            params,
            ..Self::default()
        }
    }

    /// Keep `frame` if it is a keyframe; returns whether it was.
    pub fn offer(&mut self, frame: &SyncedFrame) -> bool {
        self.last_offer = Some(std::time::Instant::now());
        let p = &self.params;
        let keep = match self.frames.back() {
            None => true,
            Some(last) => {
                let moved = (frame.world_from_camera.translation
                    - last.world_from_camera.translation)
                    .length();
                let turned = frame
                    .world_from_camera
                    .rotation
                    .angle_between(last.world_from_camera.rotation)
                    .to_degrees();
                let waited = (frame.stamp_nanos - last.stamp_nanos) as f64 / 1e9;
                moved >= p.min_translation_m
                    || turned >= p.min_rotation_deg
                    || waited >= p.max_interval_secs
            }
        };
        if keep {
            let mut kept = frame.clone();
            if p.exposure_compensation {
                self.exposure.compensate(&mut kept, self.frames.back());
            }
            self.frames.push_back(kept);
            self.fresh += 1;
            while self.frames.len() > p.max_keyframes.max(p.views) {
                self.frames.pop_front();
            }
        }
        keep
    }

    /// The newest keyframe as kept (exposure compensated).
    pub fn newest(&self) -> Option<&SyncedFrame> {
        self.frames.back()
    }

    /// The next window once `views` new keyframes have arrived since the last one (windows do
    /// not overlap, so every keyframe is seen once at this pace).
    pub fn take_window(&mut self) -> Option<Vec<SyncedFrame>> {
        let views = self.params.views.clamp(2, 24);
        if self.fresh < views || self.frames.len() < views {
            return None;
        }
        Some(self.newest_window(views))
    }

    /// The window of the keyframes still waiting for one, whatever their number: the newest
    /// `views` keyframes (some already in the previous window). `None` when none waits or fewer
    /// than `views` keyframes were ever kept (a model pass takes exactly `views`).
    pub fn take_pending_window(&mut self) -> Option<Vec<SyncedFrame>> {
        let views = self.params.views.clamp(2, 24);
        if self.fresh == 0 || self.frames.len() < views {
            return None;
        }
        Some(self.newest_window(views))
    }

    /// [`Self::take_pending_window`] once no frame was offered for `flush_after_secs` before
    /// `now` (never when that is 0 or less).
    pub fn take_quiet_window(&mut self, now: std::time::Instant) -> Option<Vec<SyncedFrame>> {
        let after = self.params.flush_after_secs;
        let quiet = self
            .last_offer
            .is_some_and(|last| now.saturating_duration_since(last).as_secs_f64() >= after);
        if after > 0.0 && quiet {
            self.take_pending_window()
        } else {
            None
        }
    }

    fn newest_window(&mut self, views: usize) -> Vec<SyncedFrame> {
        self.fresh = 0;
        self.frames
            .iter()
            .skip(self.frames.len() - views)
            .cloned()
            .collect()
    }
}

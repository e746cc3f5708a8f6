//! The window worker: a thread that loads the models, computes each keyframe's semantic features
//! when it is otherwise idle, runs a window pass for each window the node loop hands it, and fuses
//! the window's instances into the shared map.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use super::services::Shared;
use crate::config::Config;
use crate::frame::{Keyframe, MeasuredDepth, SyncedFrame, WindowView};
use crate::graph::FusionReport;
use crate::observations::{Observations, ObservedView};
use crate::outputs::ViewSource;
use crate::timing::Stage;
use crate::window::WindowModels;

/// Keyframes waiting for their features at most (more are left to their window pass). They
/// wait only while a window pass runs (a second at most at the camera's keyframe rate), and each
/// holds its full-resolution colour and depth.
const KEYFRAMES_WAITING: usize = 8;

enum Work {
    Keyframe(Box<SyncedFrame>),
    Window(Vec<SyncedFrame>),
}

/// What the node loop hands the worker.
#[derive(Debug)]
pub(super) struct WorkerInbox {
    sender: SyncSender<Work>,
    windows_waiting: Arc<AtomicUsize>,
    keyframes_waiting: Arc<AtomicUsize>,
}

/// Why a window was not handed over.
#[derive(Debug, PartialEq, Eq)]
pub(super) enum NotSent {
    /// A window is already waiting behind the one being processed.
    Busy,
    /// The worker has exited (its model failed to load).
    Gone,
}

impl WorkerInbox {
    /// Hand over a window; one waits at most (behind the one being processed), so a busy worker
    /// means the window is dropped rather than ingest stalling.
    pub(super) fn send_window(&self, window: Vec<SyncedFrame>) -> Result<(), NotSent> {
        if self.windows_waiting.load(Ordering::Acquire) >= 1 {
            return Err(NotSent::Busy);
        }
        self.windows_waiting.fetch_add(1, Ordering::AcqRel);
        self.sender.try_send(Work::Window(window)).map_err(|e| {
            self.windows_waiting.fetch_sub(1, Ordering::AcqRel);
            match e {
                TrySendError::Full(_) => NotSent::Busy,
                TrySendError::Disconnected(_) => NotSent::Gone,
            }
        })
    }

    /// Whether a window handed over now would be taken (none is waiting).
    pub(super) fn has_room(&self) -> bool {
        self.windows_waiting.load(Ordering::Acquire) == 0
    }

    /// Hand over a window, waiting while one is already waiting: for the last windows when the
    /// node stops, which must not be dropped. Waits `patience` at most (a worker that died with
    /// a window waiting never makes room).
    pub(super) fn send_window_waiting(
        &self,
        window: Vec<SyncedFrame>,
        patience: std::time::Duration,
    ) -> Result<(), NotSent> {
        let deadline = std::time::Instant::now() + patience;
        while !self.has_room() && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        self.send_window(window)
    }

    /// Hand over a keyframe for its features ahead of its window; skipped (the window computes
    /// them) when too many wait already.
    pub(super) fn send_keyframe(&self, frame: SyncedFrame) -> Result<(), NotSent> {
        if self.keyframes_waiting.load(Ordering::Acquire) >= KEYFRAMES_WAITING {
            return Ok(());
        }
        self.keyframes_waiting.fetch_add(1, Ordering::AcqRel);
        match self.sender.try_send(Work::Keyframe(Box::new(frame))) {
            Ok(()) => Ok(()),
            Err(e) => {
                self.keyframes_waiting.fetch_sub(1, Ordering::AcqRel);
                match e {
                    TrySendError::Full(_) => Ok(()),
                    TrySendError::Disconnected(_) => Err(NotSent::Gone),
                }
            }
        }
    }
}

/// Start the thread that loads the models, runs window passes and fuses their instances into the
/// map. `None` when no reconstruction model is configured or its file is missing (logged; the node
/// keeps serving).
pub(super) fn start_window_worker(
    config: &Config,
    shared: &Arc<Mutex<Shared>>,
) -> (Option<WorkerInbox>, Option<JoinHandle<()>>) {
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
    // Room for every waiting keyframe and the one waiting window: the counters bound the rest.
    let (sender, receiver) = sync_channel::<Work>(KEYFRAMES_WAITING + 1);
    let inbox = WorkerInbox {
        sender,
        windows_waiting: Arc::new(AtomicUsize::new(0)),
        keyframes_waiting: Arc::new(AtomicUsize::new(0)),
    };
    let (windows_waiting, keyframes_waiting) = (
        inbox.windows_waiting.clone(),
        inbox.keyframes_waiting.clone(),
    );
    let shared = shared.clone();
    let (models, semantics) = (config.models.clone(), config.semantics.clone());
    let views = config.window.views;
    let worker = std::thread::spawn(move || {
        // Loaded here, not on the node loop: ingest and services run while the models load.
        let mut models = match WindowModels::load(&models, &semantics) {
            Ok(models) => models,
            Err(e) => {
                tracing::error!(
                    "reconstruction model unavailable: {e}; no instances will be built"
                );
                return;
            }
        };
        models.set_views(views);
        if let Ok(mut s) = shared.lock() {
            s.vocabulary = models.vocabulary.clone();
            s.text_encoder = models.text_encoder.take().map(|e| Arc::new(Mutex::new(e)));
            s.refresh_instances();
        }
        while let Some(mut frames) = next_window(
            &receiver,
            &windows_waiting,
            &keyframes_waiting,
            &mut models,
            &shared,
        ) {
            let stamp = frames.last().map_or(0, |f| f.stamp_nanos);
            match models.pass(&frames) {
                Ok(mut output) => {
                    if let Some(reason) = &output.skipped {
                        tracing::warn!("window skipped: {reason}");
                        if let Ok(mut s) = shared.lock() {
                            s.windows_skipped += 1;
                        }
                        continue;
                    }
                    if let Some(e) = &output.semantics_error {
                        tracing::warn!("window without semantics: {e}");
                    }
                    let sources: Vec<ViewSource> = frames
                        .iter()
                        .map(|f| ViewSource {
                            stamp_nanos: f.stamp_nanos,
                            camera: f.camera_name.clone(),
                            frame_id: f.frame_id.clone(),
                        })
                        .collect();
                    // The views' sensor depth, kept for the masks of answers in them.
                    let measured = measured_depths(&mut frames, &output.views);
                    // Fused into a copy without the lock (queries, publishing and services
                    // go on meanwhile), then swapped in unless the map was replaced meanwhile.
                    let Ok((mut map, generation, mut boxes, hypotheses, mut observations)) =
                        shared.lock().map(|s| {
                            (
                                s.map.clone(),
                                s.map_generation,
                                s.boxes.clone(),
                                s.hypotheses,
                                s.observations.clone(),
                            )
                        })
                    else {
                        return;
                    };
                    let found = output.instances.len();
                    let pixel_instances = std::mem::take(&mut output.pixel_instances);
                    let mut times = output.times;
                    let fused = times.time(Stage::Fusion, || {
                        models.fuse(&mut map, output.instances, &output.views, stamp)
                    });
                    match fused {
                        Ok(report) => {
                            keep_observations(
                                &mut observations,
                                &frames,
                                &output.views,
                                &pixel_instances,
                                &report,
                            );
                            let live: rustc_hash::FxHashSet<&str> =
                                map.instances.iter().map(|i| i.id.as_str()).collect();
                            observations.retain(|id| live.contains(id));
                            let lists = times.time(Stage::List, || {
                                super::services::object_lists_cached(
                                    &map,
                                    models.vocabulary.as_ref(),
                                    hypotheses,
                                    &mut boxes,
                                )
                            });
                            let Ok(mut s) = shared.lock() else { return };
                            if !s.install_fused(generation, map, lists, boxes) {
                                tracing::warn!(
                                    "window not fused: load_map replaced the map meanwhile"
                                );
                                continue;
                            }
                            s.view_sources = sources;
                            s.measured_views = measured;
                            s.observations = observations;
                            super::services::snapshot_due(&mut s);
                            let millis = times.total().as_millis() as u64;
                            times.0.push((Stage::Window, times.total()));
                            s.stages.record_all(&times);
                            tracing::info!(
                                instances = found,
                                born = report.born,
                                merged = report.merged,
                                died = report.died,
                                total = s.map.instances.len(),
                                millis,
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
    (Some(inbox), Some(worker))
}

/// Wait for the next window, computing the features of the keyframes that arrive before it;
/// `None` when the node loop has gone.
fn next_window(
    receiver: &Receiver<Work>,
    windows_waiting: &AtomicUsize,
    keyframes_waiting: &AtomicUsize,
    models: &mut WindowModels,
    shared: &Mutex<Shared>,
) -> Option<Vec<SyncedFrame>> {
    loop {
        match receiver.recv().ok()? {
            Work::Window(frames) => {
                windows_waiting.fetch_sub(1, Ordering::AcqRel);
                return Some(frames);
            }
            Work::Keyframe(frame) => {
                keyframes_waiting.fetch_sub(1, Ordering::AcqRel);
                if let Some(took) = models.prepare(&frame) {
                    if let Ok(mut s) = shared.lock() {
                        s.stages.record(Stage::Keyframe, took);
                    }
                }
            }
        }
    }
}

/// The views' sensor depth, taken from the frames (registered to the colour camera, as the
/// ingest checks), kept for the masks of answers in them.
fn measured_depths(frames: &mut [SyncedFrame], views: &[WindowView]) -> Vec<Arc<MeasuredDepth>> {
    frames
        .iter_mut()
        .zip(views)
        .filter_map(|(f, v)| {
            let depth = f
                .depth
                .take()
                .filter(|d| (d.width, d.height) == (f.camera.width, f.camera.height))?;
            Some(Arc::new(MeasuredDepth::new(
                Keyframe {
                    stamp_nanos: f.stamp_nanos,
                    camera: f.camera,
                    world_from_camera: f.world_from_camera,
                },
                depth.metres,
                v.depth_noise_at_1m,
            )))
        })
        .collect()
}

/// Keep the camera's pictures of the window's instances (`pixel_instances`: per model pixel,
/// view-major, its window instance), under the persistent ids fusion gave them.
fn keep_observations(
    observations: &mut Observations,
    frames: &[SyncedFrame],
    views: &[WindowView],
    pixel_instances: &[i32],
    report: &FusionReport,
) {
    observations.follow_folds(&report.absorbed);
    let mut start = 0;
    let mut observed = Vec::new();
    for (frame, view) in frames.iter().zip(views) {
        let (width, height) = (
            view.keyframe.camera.width as usize,
            view.keyframe.camera.height as usize,
        );
        let Some(pixels) = pixel_instances.get(start..start + width * height) else {
            break;
        };
        start += width * height;
        let owners = pixels
            .iter()
            .map(|&k| {
                usize::try_from(k)
                    .ok()
                    .and_then(|k| report.assigned.get(k))
                    .map(String::as_str)
            })
            .collect();
        observed.push(ObservedView {
            frame,
            width,
            height,
            owners,
        });
    }
    observations.add_views(&observed);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::RgbImage;
    use crate::recon::camera::Camera;
    use crate::recon::Rigid;

    fn frame(stamp_nanos: i64) -> SyncedFrame {
        SyncedFrame {
            camera_name: "front".into(),
            stamp_nanos,
            frame_id: "camera".into(),
            rgb: RgbImage {
                width: 1,
                height: 1,
                data: vec![0; 3],
            },
            depth: None,
            camera: Camera::from_fov(1, 1, 1.0).unwrap_or_else(|e| panic!("{e}")),
            world_from_camera: Rigid::default(),
        }
    }

    fn inbox() -> (WorkerInbox, Receiver<Work>) {
        let (sender, receiver) = sync_channel::<Work>(KEYFRAMES_WAITING + 1);
        let inbox = WorkerInbox {
            sender,
            windows_waiting: Arc::new(AtomicUsize::new(0)),
            keyframes_waiting: Arc::new(AtomicUsize::new(0)),
        };
        (inbox, receiver)
    }

    #[test]
    fn one_window_waits_and_keyframes_never_take_its_place() {
        let (inbox, receiver) = inbox();
        for stamp in 0..(KEYFRAMES_WAITING as i64 + 5) {
            assert_eq!(inbox.send_keyframe(frame(stamp)), Ok(()));
        }
        assert_eq!(
            inbox.keyframes_waiting.load(Ordering::Acquire),
            KEYFRAMES_WAITING,
            "keyframes beyond the bound are left to their window"
        );
        assert_eq!(inbox.send_window(vec![frame(100)]), Ok(()));
        assert_eq!(inbox.send_window(vec![frame(200)]), Err(NotSent::Busy));
        // The worker takes the keyframes, then the window: a new window may wait again.
        let mut keyframes = 0;
        loop {
            match receiver.recv().unwrap_or_else(|e| panic!("{e}")) {
                Work::Keyframe(_) => {
                    keyframes += 1;
                    inbox.keyframes_waiting.fetch_sub(1, Ordering::AcqRel);
                }
                Work::Window(frames) => {
                    assert_eq!(frames[0].stamp_nanos, 100);
                    inbox.windows_waiting.fetch_sub(1, Ordering::AcqRel);
                    break;
                }
            }
        }
        assert_eq!(keyframes, KEYFRAMES_WAITING);
        assert_eq!(inbox.send_window(vec![frame(300)]), Ok(()));
        drop(receiver);
        assert_eq!(inbox.send_keyframe(frame(400)), Err(NotSent::Gone));
    }
}

//! The window worker: a thread that loads the models, runs a window pass for each window the
//! node loop hands it, and fuses the window's instances into the shared map.

use std::sync::mpsc::{sync_channel, SyncSender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use super::services::Shared;
use crate::config::Config;
use crate::frame::SyncedFrame;
use crate::outputs::ViewSource;
use crate::timing::Stage;
use crate::window::WindowModels;

/// Start the thread that loads the models, runs window passes and fuses their instances into the
/// map. `None` when no reconstruction model is configured or its file is missing (logged; the node
/// keeps serving).
pub(super) fn start_window_worker(
    config: &Config,
    shared: &Arc<Mutex<Shared>>,
) -> (Option<SyncSender<Vec<SyncedFrame>>>, Option<JoinHandle<()>>) {
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
    let (sender, receiver) = sync_channel::<Vec<SyncedFrame>>(1);
    let shared = shared.clone();
    let (models, semantics) = (config.models.clone(), config.semantics.clone());
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
        if let Ok(mut s) = shared.lock() {
            s.vocabulary = models.vocabulary.clone();
            s.text_encoder = models.text_encoder.take().map(|e| Arc::new(Mutex::new(e)));
            s.refresh_instances();
        }
        while let Ok(frames) = receiver.recv() {
            let stamp = frames.last().map_or(0, |f| f.stamp_nanos);
            match models.pass(&frames) {
                Ok(output) => {
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
                    let Ok(mut s) = shared.lock() else { return };
                    let found = output.instances.len();
                    let mut times = output.times;
                    let fused = times.time(Stage::Fusion, || {
                        s.map.fuse(output.instances, &output.views, stamp)
                    });
                    match fused {
                        Ok(report) => {
                            s.view_sources = sources;
                            times.time(Stage::List, || s.refresh_instances());
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
    (Some(sender), Some(worker))
}

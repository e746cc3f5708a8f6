//! The window worker: a thread that loads the models, runs a window pass for each window the
//! node loop hands it, and fuses the window's instances into the shared map.

use std::sync::mpsc::{sync_channel, SyncSender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use super::services::Shared;
use crate::config::Config;
use crate::frame::SyncedFrame;
use crate::group::semantics::{SemanticsSection, Vocabulary};
use crate::group::GroupingParams;
use crate::model::reconstruction::ReconstructionModel;
use crate::model::semantic::SemanticModel;
use crate::model::text::TextEncoder;
use crate::model::{ModelsSection, SessionOptions};
use crate::window::window_pass;

/// Load the reconstruction model and start the thread that runs window passes and fuses their
/// instances into the map. `None` when there is no usable model (logged; the node keeps serving).
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
    let options = SessionOptions {
        provider: config.models.provider,
        intra_threads: config.models.threads,
    };
    let (sender, receiver) = sync_channel::<Vec<SyncedFrame>>(1);
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
    models: &ModelsSection,
    semantics: &SemanticsSection,
    options: &SessionOptions,
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

//! The models a window pass runs on, loaded from the config: the reconstruction model, and the
//! semantic model with the vocabulary the text encoder embedded; and how fusion asks that
//! vocabulary about kinds and sizes.

use super::features::FeatureCache;
use super::{pass_with_cache, WindowError, WindowOutput};
use crate::frame::{SyncedFrame, WindowInstance, WindowView};
use crate::graph::{FusionReport, GraphError, Kinds, SceneMap};
use crate::group::semantics::{KindMemo, SemanticsSection, Vocabulary};
use crate::group::GroupingParams;
use crate::model::reconstruction::ReconstructionModel;
use crate::model::semantic::SemanticModel;
use crate::model::text::TextEncoder;
use crate::model::{ModelError, ModelsSection};

/// What a window pass runs on: the reconstruction model, and (optional) the semantic model with
/// the vocabulary embedded by the text encoder that names instances.
#[derive(Debug)]
pub struct WindowModels {
    pub reconstruction: ReconstructionModel,
    pub semantic: Option<SemanticModel>,
    pub vocabulary: Option<Vocabulary>,
    /// The text encoder that embedded the vocabulary, kept for referring queries' phrases.
    pub text_encoder: Option<TextEncoder>,
    pub grouping: GroupingParams,
    /// Semantic features of keyframes computed on arrival ([`WindowModels::prepare`]).
    pub features: FeatureCache,
}

impl WindowModels {
    /// Load the models `models` names. The reconstruction model is required; the semantic model
    /// and the text encoder may be missing or broken: instances are then unnamed (logged once).
    pub fn load(models: &ModelsSection, semantics: &SemanticsSection) -> Result<Self, ModelError> {
        let options = models.session_options();
        crate::model::init_runtime(models.onnxruntime.as_deref())?;
        let manifest = models
            .reconstruction
            .as_ref()
            .ok_or_else(|| ModelError::Input("no reconstruction model configured".into()))?;
        let reconstruction = ReconstructionModel::load(manifest, &options)?;
        tracing::info!("reconstruction model {} loaded", manifest.display());
        let semantic = match models.semantic.as_ref() {
            None => None,
            Some(path) if !path.exists() => {
                tracing::warn!(
                    "no semantic model at {}: instances will be unnamed",
                    path.display()
                );
                None
            }
            Some(path) => match SemanticModel::load(path, &options) {
                Ok(model) => {
                    tracing::info!("semantic model {} loaded", path.display());
                    Some(model)
                }
                Err(e) => {
                    tracing::error!("semantic model unavailable: {e}; instances will be unnamed");
                    None
                }
            },
        };
        let mut text_encoder = None;
        let vocabulary = semantic.as_ref().and_then(|_| {
            let embedded =
                TextEncoder::load(&models.text_encoder, &options).and_then(|mut encoder| {
                    let embeddings = semantics
                        .vocabulary
                        .iter()
                        .map(|phrase| encoder.embed(phrase))
                        .collect::<crate::model::Result<Vec<_>>>()?;
                    text_encoder = Some(encoder);
                    let priors = semantics
                        .class_priors()
                        .map_err(|e| ModelError::Input(e.to_string()))?;
                    Ok(Vocabulary {
                        phrases: semantics.vocabulary.clone(),
                        embeddings,
                        temperature: semantics.temperature,
                        priors,
                    })
                });
            embedded
                .map_err(|e| {
                    tracing::error!("text encoder unavailable: {e}; instances will be unnamed")
                })
                .ok()
        });
        Ok(Self {
            reconstruction,
            semantic,
            vocabulary,
            text_encoder,
            grouping: GroupingParams::default(),
            features: FeatureCache::default(),
        })
    }

    /// Keep computed-ahead features for windows of `views` views (2–24, as windows take them).
    pub fn set_views(&mut self, views: usize) {
        let views = views.clamp(2, 24);
        if self.features.capacity != views {
            self.features = FeatureCache::with_capacity(views);
        }
    }

    /// Compute a keyframe's semantic features ahead of its window (when the worker would
    /// otherwise wait), so the window pass only pools them. Returns the time it took, `None` when
    /// there is no semantic model, the features are cached already, or the model failed (the
    /// window then computes them, and reports the failure).
    pub fn prepare(&mut self, frame: &SyncedFrame) -> Option<std::time::Duration> {
        self.features
            .prepare(self.semantic.as_mut()?, self.vocabulary.as_ref(), frame)
    }

    /// Fuse a window's instances into `map`; with a vocabulary, fragments of one object (touching,
    /// alike, named alike) fold together afterwards ([`SceneMap::fold_fragments`]).
    pub fn fuse(
        &self,
        map: &mut SceneMap,
        instances: Vec<WindowInstance>,
        views: &[WindowView],
        stamp_nanos: i64,
    ) -> Result<FusionReport, GraphError> {
        match &self.vocabulary {
            Some(v) => map.fuse_named(instances, views, stamp_nanos, KindMemo::new(v)),
            None => map.fuse(instances, views, stamp_nanos),
        }
    }

    /// One window pass over `frames`.
    pub fn pass(&mut self, frames: &[SyncedFrame]) -> Result<WindowOutput, WindowError> {
        pass_with_cache(
            &mut self.reconstruction,
            self.semantic.as_mut().map(|m| (m, &mut self.features)),
            self.vocabulary.as_ref(),
            frames,
            &self.grouping,
        )
    }
}

/// The vocabulary as fusion asks it: kinds by best name, sizes by the name's largest side and
/// typical length.
impl Kinds for KindMemo<'_> {
    fn same_kind(&self, a: &[f32], b: &[f32]) -> bool {
        KindMemo::same_kind(self, a, b)
    }

    fn largest_side(&self, prototype: &[f32]) -> Option<f64> {
        self.best_phrase(prototype)
            .and_then(|name| self.priors().largest_side(&name))
    }

    fn typical_length(&self, prototype: &[f32]) -> Option<f64> {
        self.best_phrase(prototype)
            .and_then(|name| self.priors().typical_length(&name))
    }

    fn typical_depth(&self, prototype: &[f32]) -> Option<f64> {
        self.best_phrase(prototype)
            .and_then(|name| self.priors().typical_depth(&name))
    }
}

//! The paper's ablation without instance embeddings (LSM / Uni3R style): no grouping and no
//! instances. Every pixel the node lifts keeps its semantic-model feature, pooled into 5 cm voxels
//! over the replay; a query's target phrase selects the voxels that are more likely than not what
//! it names, and the answer is the box around them. It answers with the same models, depth and
//! poses as the node, so the difference to the node's answers is what instances (and the
//! relations and counts they allow) buy.

use glam::{DVec2, Vec3};
use rustc_hash::FxHashMap;

use groupforward::frame::SyncedFrame;
use groupforward::group::semantics::Vocabulary;
use groupforward::model::semantic::SemanticModel;
use groupforward::model::ModelError;
use groupforward::recon::boxes::{OrientedBox, DEFAULT_TRIM};
use groupforward::refer::concepts::spread;
use groupforward::window::WindowOutput;

/// Voxel edge (m): about a pixel's footprint at 3 m at the model resolution.
pub const VOXEL_M: f64 = 0.05;

/// A voxel is selected when the query's concept has at least this probability there.
pub const SELECT_PROBABILITY: f32 = 0.5;

#[derive(Debug, Clone, Default)]
struct Cell {
    position_sum: glam::DVec3,
    feature_sum: Vec<f32>,
    count: u32,
}

/// Semantic features lifted to 3D and pooled per voxel: the baseline's whole scene model.
#[derive(Debug, Clone, Default)]
pub struct FeatureVoxels {
    cells: FxHashMap<(i64, i64, i64), Cell>,
}

/// The voxels' centres of mass and their distributions over the vocabulary, computed once for
/// all queries of a scene.
#[derive(Debug, Clone, Default)]
pub struct NamedVoxels {
    pub centres: Vec<Vec3>,
    pub probabilities: Vec<Vec<f32>>,
}

impl FeatureVoxels {
    /// Lift every pixel of `output`'s views that has valid depth (as the node lifts them), with
    /// the semantic feature the model gives its image there.
    pub fn add_window(
        &mut self,
        frames: &[SyncedFrame],
        output: &WindowOutput,
        semantic: &mut SemanticModel,
    ) -> Result<(), ModelError> {
        for (frame, view) in frames.iter().zip(&output.views) {
            let features = semantic.features(&frame.rgb)?;
            let camera = view.keyframe.camera;
            let (w, h) = (camera.width as usize, camera.height as usize);
            for (i, &depth) in view.depth.iter().enumerate() {
                if !(depth.is_finite() && depth > 0.0) {
                    continue;
                }
                let (x, y) = (i % w, i / w);
                let point = view.keyframe.world_from_camera.transform_point(
                    camera.unproject(DVec2::new(x as f64, y as f64), f64::from(depth)),
                );
                let fx = (x * features.width / w).min(features.width - 1);
                let fy = (y * features.height / h).min(features.height - 1);
                let feature = features.at(fy * features.width + fx);
                let key = (
                    (point.x / VOXEL_M).floor() as i64,
                    (point.y / VOXEL_M).floor() as i64,
                    (point.z / VOXEL_M).floor() as i64,
                );
                let cell = self.cells.entry(key).or_default();
                if cell.feature_sum.is_empty() {
                    cell.feature_sum = vec![0.0; feature.len()];
                }
                cell.feature_sum
                    .iter_mut()
                    .zip(&feature)
                    .for_each(|(s, v)| *s += v);
                cell.position_sum += point;
                cell.count += 1;
            }
        }
        Ok(())
    }

    /// Name every voxel over `vocabulary` (its mean feature's softmax over the phrases).
    pub fn named(&self, vocabulary: &Vocabulary) -> NamedVoxels {
        let mut named = NamedVoxels::default();
        for cell in self.cells.values() {
            let probabilities = vocabulary.probabilities(&cell.feature_sum);
            if probabilities.is_empty() {
                continue;
            }
            named
                .centres
                .push((cell.position_sum / f64::from(cell.count)).as_vec3());
            named.probabilities.push(probabilities);
        }
        named
    }
}

/// `phrase`'s embedding spread over the vocabulary, as referring's concept scores spread it.
pub fn concept_weights(embedding: &[f32], vocabulary: &Vocabulary) -> Vec<f32> {
    spread(
        embedding,
        &vocabulary.phrases,
        &vocabulary.embeddings,
        vocabulary.temperature,
    )
}

impl NamedVoxels {
    /// The baseline's answer to a concept: the box around the voxels more likely than not of it
    /// (2% trimmed per axis, as instance boxes are); `None` when no voxel is.
    pub fn answer(&self, weights: &[f32]) -> Option<OrientedBox> {
        let selected: Vec<Vec3> = self
            .centres
            .iter()
            .zip(&self.probabilities)
            .filter(|(_, p)| {
                p.iter().zip(weights).map(|(p, w)| p * w).sum::<f32>() >= SELECT_PROBABILITY
            })
            .map(|(c, _)| *c)
            .collect();
        (!selected.is_empty()).then(|| OrientedBox::fit(&selected, DEFAULT_TRIM))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_answer_boxes_the_voxels_of_the_concept_and_nothing_else() {
        let named = NamedVoxels {
            centres: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(5.0, 5.0, 0.0),
            ],
            probabilities: vec![vec![0.9, 0.1], vec![0.6, 0.4], vec![0.2, 0.8]],
        };
        let first = named
            .answer(&[1.0, 0.0])
            .expect("two voxels of the first phrase");
        assert!(
            (first.centre.x - 0.5).abs() < 1e-6 && first.centre.y.abs() < 1e-6,
            "{first:?}"
        );
        let second = named.answer(&[0.0, 1.0]).expect("one voxel of the second");
        assert!((second.centre.x - 5.0).abs() < 1e-6);
        // Weight split evenly: only the voxel above one half on the mix.
        assert!(named.answer(&[0.0, 0.0]).is_none());
    }
}

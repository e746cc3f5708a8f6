//! Semantic scores: how well an instance fits a concept phrase. The phrase is embedded by the
//! text encoder and spread over the vocabulary by text similarity (a softmax of cosine / τ), and
//! an instance's score is that spread weighted by the instance's own distribution over the same
//! phrases: Σ_j p(phrase_j | phrase) p(phrase_j | instance). Synonyms ("garbage can") and
//! function phrases ("wash hands") land on the phrases they mean with no table from words to
//! classes; the structure phrase `other` never takes weight (a query never asks for walls).

use crate::group::semantics::{softmax, OTHER_PHRASE};
use crate::model::text::cosine;

use super::scene::{ReferNode, ReferScene};

/// A phrase's `embedding` spread over `phrases` (with their `embeddings`): the softmax of its
/// cosines / `temperature`, `other` (structure) never taking weight; all zero when only `other`
/// is there.
pub fn spread(
    embedding: &[f32],
    phrases: &[String],
    embeddings: &[Vec<f32>],
    temperature: f32,
) -> Vec<f32> {
    spread_with_functions(embedding, phrases, embeddings, &[], temperature)
}

/// [`spread`], where a phrase's cosine is the best of its own and those of what one does with
/// its objects (`functions[j]`: the embeddings of phrase j's functions; missing: none).
pub fn spread_with_functions(
    embedding: &[f32],
    phrases: &[String],
    embeddings: &[Vec<f32>],
    functions: &[Vec<Vec<f32>>],
    temperature: f32,
) -> Vec<f32> {
    let cosines: Vec<f32> = phrases
        .iter()
        .zip(embeddings)
        .enumerate()
        .map(|(j, (p, e))| {
            if p == OTHER_PHRASE {
                return f32::NEG_INFINITY;
            }
            let own = cosine(embedding, e);
            functions
                .get(j)
                .into_iter()
                .flatten()
                .map(|f| cosine(embedding, f))
                .filter(|c| c.is_finite())
                .fold(own, f32::max)
        })
        .collect();
    if cosines.iter().any(|c| c.is_finite()) {
        softmax(&cosines, temperature)
    } else {
        vec![0.0; cosines.len()]
    }
}

/// A concept phrase spread over a scene's vocabulary.
#[derive(Debug, Clone, PartialEq)]
pub struct Concept {
    pub phrase: String,
    /// Over the scene's phrases.
    pub weights: Vec<f32>,
}

impl Concept {
    /// `embedding`: the text encoder's embedding of `phrase`.
    pub fn new(phrase: &str, embedding: &[f32], scene: &ReferScene, temperature: f32) -> Self {
        Self {
            phrase: phrase.to_owned(),
            weights: spread(embedding, &scene.phrases, &scene.embeddings, temperature),
        }
    }

    /// A function phrase ("wash hands"): spread over the phrases by the nearer of each phrase and
    /// what one does with its objects (`functions`: per phrase, its functions' embeddings).
    pub fn for_function(
        phrase: &str,
        embedding: &[f32],
        scene: &ReferScene,
        functions: &[Vec<Vec<f32>>],
        temperature: f32,
    ) -> Self {
        Self {
            phrase: phrase.to_owned(),
            weights: spread_with_functions(
                embedding,
                &scene.phrases,
                &scene.embeddings,
                functions,
                temperature,
            ),
        }
    }

    /// How well `node` fits this concept, in [0, 1] (0 for an instance without semantics).
    pub fn score(&self, node: &ReferNode) -> f32 {
        node.names
            .iter()
            .zip(&self.weights)
            .map(|(p, w)| p * w)
            .sum::<f32>()
            .clamp(0.0, 1.0)
    }

    /// How plausible it is that `node` is what this concept names, against its own best name: the
    /// largest p(phrase | node) / max p(· | node) over the phrases the concept stands for (those
    /// with at least half its largest weight), in [0, 1]. A toilet whose names hold a trace of sink
    /// scores that trace's share for "sink"; a refrigerator the map calls cabinet a little more
    /// surely keeps most of its share for "fridge". `phrases`: the scene's, to leave `other` out of
    /// the best name. 0 for an instance without object names.
    pub fn name_share(&self, node: &ReferNode, phrases: &[String]) -> f32 {
        let best_name = node
            .names
            .iter()
            .zip(phrases)
            .filter(|(_, p)| p.as_str() != OTHER_PHRASE)
            .map(|(v, _)| *v)
            .fold(0.0, f32::max);
        let top_weight = self.weights.iter().copied().fold(0.0, f32::max);
        // f32::max folds past NaN, so both are finite here.
        if best_name <= 0.0 || top_weight <= 0.0 {
            return 0.0;
        }
        node.names
            .iter()
            .zip(&self.weights)
            .filter(|(_, w)| **w >= 0.5 * top_weight)
            .map(|(p, _)| p / best_name)
            .fold(0.0, f32::max)
            .clamp(0.0, 1.0)
    }

    /// The phrase of the vocabulary this concept leans on most, with its weight.
    pub fn nearest_phrase<'a>(&self, scene: &'a ReferScene) -> Option<(&'a str, f32)> {
        self.weights
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, w)| (scene.phrases[i].as_str(), *w))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> ReferScene {
        ReferScene {
            phrases: vec!["chair".into(), "sofa".into(), "other".into()],
            embeddings: vec![
                vec![1.0, 0.0, 0.0],
                vec![0.0, 1.0, 0.0],
                vec![0.0, 0.0, 1.0],
            ],
            ..ReferScene::default()
        }
    }

    #[test]
    fn a_concept_between_two_phrases_leans_on_the_nearer_and_never_on_other() {
        let scene = scene();
        let couch = Concept::new("couch", &[0.3, 0.9, 0.9], &scene, 0.05);
        assert!(couch.weights[1] > 0.99, "{:?}", couch.weights);
        assert_eq!(couch.weights[2], 0.0);
        assert_eq!(couch.nearest_phrase(&scene).map(|p| p.0), Some("sofa"));
    }

    #[test]
    fn zero_embeddings_and_unnamed_instances_score_zero_not_nan() {
        let scene = scene();
        let nothing = Concept::new("", &[0.0, 0.0, 0.0], &scene, 0.05);
        assert!(nothing.weights.iter().all(|w| w.is_finite()));
        let unnamed = named(Vec::new());
        assert_eq!(nothing.score(&unnamed), 0.0);
        // A vocabulary of only `other`: no weight anywhere, finite.
        let only_other = ReferScene {
            phrases: vec!["other".into()],
            embeddings: vec![vec![1.0]],
            ..ReferScene::default()
        };
        let c = Concept::new("wall", &[1.0], &only_other, 1e-9);
        assert_eq!(c.weights, [0.0]);
    }

    fn named(names: Vec<f32>) -> ReferNode {
        ReferNode {
            id: "inst_000001".into(),
            names,
            label: String::new(),
            bbox: crate::recon::boxes::OrientedBox::from_bounds(
                glam::DVec3::ZERO,
                glam::DVec3::ONE,
            ),
            lo: glam::DVec3::ZERO,
            hi: glam::DVec3::ONE,
            color: [0.5; 3],
            visibility: 0.0,
            confidence: 0.5,
            gaussians: 0,
            tentative: false,
        }
    }

    #[test]
    fn a_trace_of_a_name_is_a_small_share_and_a_close_second_name_a_large_one() {
        let scene = scene();
        let sofa = Concept::new("sofa", &[0.0, 1.0, 0.0], &scene, 0.05);
        // A chair with a trace of sofa, most of the rest structure: the trace against the chair.
        let chair = named(vec![0.6, 0.06, 0.34]);
        let share = sofa.name_share(&chair, &scene.phrases);
        assert!((share - 0.1).abs() < 1e-3, "{share}");
        // Named chair a little more surely than sofa: sofa keeps most of its share.
        let unsure = named(vec![0.45, 0.4, 0.15]);
        assert!(sofa.name_share(&unsure, &scene.phrases) > 0.85);
        // `other` is never the best name: an instance mostly structure, sofa its best object name.
        let mostly_structure = named(vec![0.05, 0.2, 0.75]);
        assert_eq!(sofa.name_share(&mostly_structure, &scene.phrases), 1.0);
    }

    #[test]
    fn a_concept_over_two_phrases_fits_a_sure_instance_of_either() {
        let scene = scene();
        // "something to sit on", between chair and sofa and leaning to chair: a sure chair and a
        // sure sofa both fit it fully, not only the phrase it leans on most.
        let sit = Concept::new("sit", &[1.0, 0.98, 0.0], &scene, 0.05);
        assert!(sit.weights[0] > sit.weights[1] && sit.weights[1] > 0.5 * sit.weights[0]);
        let chair = named(vec![0.95, 0.01, 0.04]);
        assert_eq!(sit.name_share(&chair, &scene.phrases), 1.0);
        let sofa = named(vec![0.01, 0.95, 0.04]);
        assert_eq!(sit.name_share(&sofa, &scene.phrases), 1.0);
    }

    #[test]
    fn name_shares_of_unnamed_instances_and_empty_concepts_are_zero_not_nan() {
        let scene = scene();
        let sofa = Concept::new("sofa", &[0.0, 1.0, 0.0], &scene, 0.05);
        assert_eq!(sofa.name_share(&named(Vec::new()), &scene.phrases), 0.0);
        assert_eq!(
            sofa.name_share(&named(vec![0.0, 0.0, 1.0]), &scene.phrases),
            0.0
        );
        let nothing = Concept::new("", &[0.0, 0.0, 0.0], &scene, 1e-9);
        let share = nothing.name_share(&named(vec![0.5, 0.5, 0.0]), &scene.phrases);
        assert!(share.is_finite() && (0.0..=1.0).contains(&share), "{share}");
    }

    #[test]
    fn a_function_phrase_finds_the_class_whose_function_it_names() {
        let scene = scene();
        // "lie down on" reads closer to the chair's name than to the sofa's, but the sofa lists
        // it among its functions; zero and missing function embeddings change nothing.
        let lie_down = [0.8, 0.6, 0.0];
        let by_name = Concept::new("lie down on", &lie_down, &scene, 0.05);
        assert_eq!(by_name.nearest_phrase(&scene).map(|p| p.0), Some("chair"));
        let functions = vec![Vec::new(), vec![vec![0.8, 0.6, 0.0]]];
        let by_function = Concept::for_function("lie down on", &lie_down, &scene, &functions, 0.05);
        assert_eq!(
            by_function.nearest_phrase(&scene).map(|p| p.0),
            Some("sofa")
        );
        assert!(by_function.weights.iter().all(|w| w.is_finite()));
        assert_eq!(by_function.weights[2], 0.0);
        // A zero function embedding lowers nothing, and no functions change nothing.
        let zero = vec![vec![vec![0.0, 0.0, 0.0]], Vec::new()];
        let with_zero = Concept::for_function("lie down on", &lie_down, &scene, &zero, 0.05);
        assert_eq!(with_zero, by_name);
        let none = Concept::for_function("lie down on", &lie_down, &scene, &[], 0.05);
        assert_eq!(none, by_name);
    }
}

//! Referring (RSRF, DESIGN §5.7): an expression in, the instances it means out, with every
//! candidate's scores and the reasoning that chose them. One file per step:
//!
//! - [`parse`]: expression → target concept, cardinality, attributes, relation, anchors;
//! - [`scene`]: the map snapshot queries read (names, boxes, colours, visibility, keyframes);
//! - [`concepts`]: semantic scores of a phrase against the instances;
//! - [`retrieve`]: semantic, geometric and visibility scores; the top K;
//! - [`reasoner`]: the built-in graph reasoner over the candidates.

pub mod concepts;
pub mod parse;
pub mod reasoner;
pub mod response;
pub mod retrieve;
pub mod scene;
#[cfg(test)]
mod tests;

use groupforward_sim::referring::ViewPose;
use serde::{Deserialize, Serialize};

use concepts::Concept;
pub use parse::{parse, Count, ParseError, Query, Relation, Superlative};
pub use reasoner::{Decision, ReasonError};
pub use retrieve::{Scored, DEFAULT_TOP_K};
pub use scene::{ReferNode, ReferScene};

/// The `refer` section of the node's config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReferSection {
    /// Candidates kept for the reasoner (K).
    pub top_k: usize,
    /// τ of the softmax that spreads a concept phrase over the vocabulary (text cosines).
    pub concept_temperature: f32,
}

impl Default for ReferSection {
    fn default() -> Self {
        Self {
            top_k: DEFAULT_TOP_K,
            concept_temperature: 0.05,
        }
    }
}

/// Something that embeds phrases in the prototypes' space (the text encoder; a table in tests).
pub trait Embed {
    fn embed(&mut self, phrase: &str) -> Result<Vec<f32>, String>;
}

impl Embed for crate::model::text::TextEncoder {
    fn embed(&mut self, phrase: &str) -> Result<Vec<f32>, String> {
        crate::model::text::TextEncoder::embed(self, phrase).map_err(|e| e.to_string())
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReferError {
    #[error("cannot parse the expression: {0}")]
    Parse(#[from] ParseError),
    #[error("the map has no instances yet")]
    EmptyMap,
    #[error("the map's instances have no semantics (no semantic model or text encoder)")]
    NoSemantics,
    #[error("text encoder: {0}")]
    Embed(String),
    #[error(transparent)]
    Reason(#[from] ReasonError),
}

/// A referring request.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Request {
    pub expression: String,
    /// The view view-dependent relations are decided in (else the newest keyframe).
    pub view: Option<ViewPose>,
    /// 0: as many as the expression asks for.
    pub max_targets: usize,
}

/// One candidate as the answer reports it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CandidateReport {
    pub id: String,
    pub label: String,
    pub score: f32,
    pub semantic: f32,
    pub geometric: f32,
    pub visibility: f32,
}

/// An answer: the chosen instances (indices into the snapshot's nodes) and how they were found.
#[derive(Debug, Clone, PartialEq)]
pub struct Answer {
    pub query: Query,
    pub chosen: Vec<reasoner::Choice>,
    pub candidates: Vec<CandidateReport>,
    pub reasoner_used: String,
    pub trace: String,
    /// The view that decided view-dependent words.
    pub view: Option<ViewPose>,
}

/// The newest keyframe of `scene` as a view.
pub fn latest_view(scene: &ReferScene) -> Option<ViewPose> {
    scene.keyframes.first().map(|k| {
        ViewPose::new(
            0,
            k.world_from_camera.rotation,
            k.world_from_camera.translation,
        )
    })
}

/// Answer `request` on `scene` with the built-in reasoner.
pub fn answer(
    scene: &ReferScene,
    embed: &mut dyn Embed,
    request: &Request,
    section: &ReferSection,
) -> Result<Answer, ReferError> {
    let query = parse(&request.expression)?;
    if scene.nodes.is_empty() {
        return Err(ReferError::EmptyMap);
    }
    if scene.phrases.is_empty() || scene.nodes.iter().all(|n| n.names.is_empty()) {
        return Err(ReferError::NoSemantics);
    }
    let mut concept = |phrase: &str| -> Result<Concept, ReferError> {
        let embedding = embed.embed(phrase).map_err(ReferError::Embed)?;
        Ok(Concept::new(
            phrase,
            &embedding,
            scene,
            section.concept_temperature,
        ))
    };
    let target = concept(&query.target)?;
    let anchors = query
        .anchors
        .iter()
        .map(|a| concept(a))
        .collect::<Result<Vec<_>, _>>()?;
    let view = request.view.or_else(|| latest_view(scene));
    let retrieval = retrieve::retrieve(
        scene,
        &query,
        &target,
        &anchors,
        view.as_ref(),
        section.top_k,
    );
    let decision = reasoner::reason(
        scene,
        &query,
        &retrieval,
        view.as_ref(),
        request.max_targets,
    )?;
    let nearest = target
        .nearest_phrase(scene)
        .map(|(p, w)| format!("{:?} reads as {p:?} ({w:.2}); ", query.target))
        .unwrap_or_default();
    let mut trace = nearest + &decision.trace;
    if let Some(shortfall) = &decision.shortfall {
        trace += &format!("; {shortfall}");
    }
    Ok(Answer {
        candidates: retrieval
            .candidates
            .iter()
            .map(|c| {
                let node = &scene.nodes[c.index];
                CandidateReport {
                    id: node.id.clone(),
                    label: node.label.clone(),
                    score: c.score,
                    semantic: c.semantic,
                    geometric: c.geometric,
                    visibility: c.visibility,
                }
            })
            .collect(),
        chosen: decision.chosen,
        reasoner_used: "builtin".into(),
        trace,
        view: query.view_dependent().then_some(view).flatten(),
        query,
    })
}

//! Referring (RSRF, ARCHITECTURE.md §2): an expression in, the instances it means out, with every
//! candidate's scores and the reasoning that chose them. One file per step:
//!
//! - [`parse`]: expression → target concept, cardinality, attributes, relation, anchors;
//! - [`scene`]: the map snapshot queries read (names, boxes, colours, visibility, keyframes);
//! - [`concepts`]: semantic scores of a phrase against the instances;
//! - [`retrieve`]: semantic, geometric and visibility scores; the top K;
//! - [`reasoner`]: the built-in graph reasoner over the candidates.

pub mod concepts;
pub mod evidence;
pub mod masks;
pub mod parse;
pub mod reasoner;
pub mod response;
pub mod retrieve;
pub mod scene;
pub mod scripted_chat;
#[cfg(test)]
mod tests;
pub mod vlm;

use groupforward_relations::ViewPose;
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
    /// The reasoner a request with none named gets: `builtin` or `vlm`.
    pub reasoner: String,
    /// The VLM behind an OpenAI-compatible server.
    pub vlm: vlm::VlmSection,
    /// Write each answer's evidence bundle (PNG + JSON) here ("" = not written).
    pub evidence_dir: String,
    /// Decompose expressions with the LLM behind `vlm.endpoint` (validated against the parser's
    /// schema; the rule parser answers whenever it fails, and the trace says so).
    pub llm_parse: bool,
}

impl Default for ReferSection {
    fn default() -> Self {
        Self {
            top_k: DEFAULT_TOP_K,
            concept_temperature: 0.05,
            reasoner: "builtin".into(),
            vlm: vlm::VlmSection::default(),
            evidence_dir: String::new(),
            llm_parse: false,
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
    /// Index into the snapshot's nodes.
    pub index: usize,
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
    /// What the asker should know about the answer (the reasoner's [`reasoner::Decision::note`]).
    pub note: Option<String>,
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
    answer_query(scene, embed, parse(&request.expression)?, request, section)
}

/// The concept of a function phrase ("wash hands"): the vocabulary's phrases scored by the nearer
/// of each one and what one does with its objects (the vocabulary file's `functions`, embedded by
/// the same text encoder; its cache keeps them after the first query).
fn function_concept(
    scene: &ReferScene,
    embed: &mut dyn Embed,
    phrase: &str,
    temperature: f32,
) -> Result<Concept, ReferError> {
    let embedding = embed.embed(phrase).map_err(ReferError::Embed)?;
    let functions = scene
        .functions
        .iter()
        .map(|of_phrase| {
            of_phrase
                .iter()
                .map(|f| embed.embed(f).map_err(ReferError::Embed))
                .collect::<Result<Vec<_>, _>>()
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Concept::for_function(
        phrase,
        &embedding,
        scene,
        &functions,
        temperature,
    ))
}

/// A two-hop anchor answered first, by the same steps: the instances it chose as the anchor
/// list, and a trace line saying so. Its failures are the query's ("no bed has been seen to
/// relate to").
fn answer_anchor(
    scene: &ReferScene,
    embed: &mut dyn Embed,
    anchor: &Query,
    request: &Request,
    section: &ReferSection,
) -> Result<(retrieve::AnchorList, String), ReferError> {
    let inner = Request {
        max_targets: 0,
        ..request.clone()
    };
    let answer = answer_query(scene, embed, anchor.clone(), &inner, section)?;
    let list: retrieve::AnchorList = answer
        .chosen
        .iter()
        .map(|c| (c.index, c.confidence.clamp(f32::MIN_POSITIVE, 1.0)))
        .collect();
    let ids: Vec<&str> = list.iter().map(|a| scene.nodes[a.0].id.as_str()).collect();
    let trace = format!(
        "anchor {:?} answered first: {}; ",
        anchor.text,
        ids.join(", ")
    );
    Ok((list, trace))
}

/// Answer an already parsed `query` (the rule parser's or a validated LLM decomposition).
pub fn answer_query(
    scene: &ReferScene,
    embed: &mut dyn Embed,
    query: Query,
    request: &Request,
    section: &ReferSection,
) -> Result<Answer, ReferError> {
    if scene.nodes.is_empty() {
        return Err(ReferError::EmptyMap);
    }
    if scene.phrases.is_empty() || scene.nodes.iter().all(|n| n.names.is_empty()) {
        return Err(ReferError::NoSemantics);
    }
    let target = if query.function {
        function_concept(scene, embed, &query.target, section.concept_temperature)?
    } else {
        let embedding = embed.embed(&query.target).map_err(ReferError::Embed)?;
        Concept::new(
            &query.target,
            &embedding,
            scene,
            section.concept_temperature,
        )
    };
    let mut concept = |phrase: &str| -> Result<Concept, ReferError> {
        let embedding = embed.embed(phrase).map_err(ReferError::Embed)?;
        Ok(Concept::new(
            phrase,
            &embedding,
            scene,
            section.concept_temperature,
        ))
    };
    let view = request.view.or_else(|| latest_view(scene));
    // A two-hop anchor phrase that finds nothing leaves the relation unchecked (`unresolved`).
    let (anchor_lists, anchor_trace, unresolved) = match &query.anchor_query {
        Some(anchor) => match answer_anchor(scene, embed, anchor, request, section) {
            Ok((list, trace)) => (vec![list], trace, None),
            Err(ReferError::Reason(
                refusal @ (ReasonError::NoAnchor(_) | ReasonError::NoTarget(_)),
            )) => {
                let trace = format!("anchor {:?} found nothing: {refusal}; ", anchor.text);
                (Vec::new(), trace, Some(refusal))
            }
            Err(e) => return Err(e),
        },
        None => {
            let anchors = query
                .anchors
                .iter()
                .map(|a| concept(a))
                .collect::<Result<Vec<_>, _>>()?;
            (retrieve::anchor_lists(scene, &anchors), String::new(), None)
        }
    };
    let retrieval = retrieve::retrieve(
        scene,
        &query,
        &target,
        anchor_lists,
        view.as_ref(),
        section.top_k,
    );
    let mut decision = match unresolved {
        Some(refusal) => reasoner::without_anchor(scene, &query, &retrieval, refusal)?,
        None => reasoner::reason(
            scene,
            &query,
            &retrieval,
            view.as_ref(),
            request.max_targets,
        )?,
    };
    decision.note = with_tentative_note(scene, &decision.chosen, decision.note);
    let nearest = target
        .nearest_phrase(scene)
        .map(|(p, w)| format!("{:?} reads as {p:?} ({w:.2}); ", query.target))
        .unwrap_or_default();
    let mut trace = anchor_trace + &nearest + &decision.trace;
    if let Some(note) = &decision.note {
        trace += &format!("; {note}");
    }
    Ok(Answer {
        candidates: retrieval
            .candidates
            .iter()
            .map(|c| {
                let node = &scene.nodes[c.index];
                CandidateReport {
                    index: c.index,
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
        note: decision.note,
        reasoner_used: "builtin".into(),
        trace,
        view: query.view_dependent().then_some(view).flatten(),
        query,
    })
}

/// `note`, with a line naming the chosen instances that are tentative candidates (small pieces
/// seen by one window or named unsurely; [`scene::ReferNode::tentative`]): the asker should know
/// the map has not confirmed them.
fn with_tentative_note(
    scene: &ReferScene,
    chosen: &[reasoner::Choice],
    note: Option<String>,
) -> Option<String> {
    let tentative: Vec<&str> = chosen
        .iter()
        .map(|c| &scene.nodes[c.index])
        .filter(|n| n.tentative)
        .map(|n| n.id.as_str())
        .collect();
    if tentative.is_empty() {
        return note;
    }
    let line = format!(
        "{} not yet confirmed (small, seen by one window or named unsurely)",
        tentative.join(", ")
    );
    Some(match note {
        Some(note) => format!("{note}; {line}"),
        None => line,
    })
}

/// Let the VLM decide among `answer`'s candidates from `evidence`; on any failure the built-in
/// reasoner's choice stands and the answer says why (`reasoner_used: "fallback"`).
pub fn with_vlm(
    mut answer: Answer,
    client: Result<&vlm::VlmClient, vlm::VlmError>,
    evidence: &evidence::Evidence,
) -> Answer {
    let ids: Vec<String> = answer.candidates.iter().map(|c| c.id.clone()).collect();
    let chosen = client
        .and_then(|client| client.choose(&answer.query.text, answer.query.count, evidence, &ids));
    match chosen {
        Ok(choice) => {
            answer.chosen = choice
                .ids
                .iter()
                .filter_map(|id| answer.candidates.iter().find(|c| &c.id == id))
                .map(|c| reasoner::Choice {
                    index: c.index,
                    confidence: c.score,
                })
                .collect();
            answer.reasoner_used = "vlm".into();
            // The note was about the built-in reasoner's choice.
            answer.note = None;
            answer.trace = format!("VLM: {}; built-in: {}", choice.reason, answer.trace);
        }
        Err(e) => {
            answer.reasoner_used = "fallback".into();
            answer.trace = format!("{e}: the built-in reasoner answered; {}", answer.trace);
        }
    }
    answer
}

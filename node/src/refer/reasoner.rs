//! The built-in graph reasoner (default, deterministic): among the retrieved candidates only, the
//! instances that fit the target concept are ranked by what the expression asks (the relation's
//! Sr3D margin to the best anchors, the superlative's key, the colour's distance, else the
//! semantic score) and as many as the expression's cardinality are chosen.

use groupforward_relations::{Geometry, ViewPose};

use super::parse::{Count, Query, Relation};
use super::retrieve::{
    color_distance, color_rgb, geometries, relation_margin, superlative_key, Retrieval, Scored,
    MIN_SEMANTIC,
};
use super::scene::ReferScene;

/// Boxes overlapping at least this much (3D IoU) are one object.
pub const DUPLICATE_IOU: f64 = 0.25;

/// One chosen instance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Choice {
    /// Index into the scene's nodes.
    pub index: usize,
    pub confidence: f32,
}

/// A reasoner's decision.
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    pub chosen: Vec<Choice>,
    /// Why, in words (candidate keys and the rule applied).
    pub trace: String,
    /// What the asker should know about the answer: fewer instances fit than were asked for
    /// ("both chairs" with one chair in the map), or a relation that could not be checked.
    pub note: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReasonError {
    /// What was asked for and has not been seen ([`unseen`]).
    #[error("{0}")]
    NoTarget(String),
    #[error("no {0} has been seen to relate to")]
    NoAnchor(String),
    #[error("{0} needs a viewpoint and the map has no keyframe yet")]
    NoView(String),
}

/// The candidates that fit the target concept: at least half the best semantic score.
pub fn fitting(candidates: &[Scored]) -> Vec<Scored> {
    let best = candidates.iter().map(|c| c.semantic).fold(0.0, f32::max);
    candidates
        .iter()
        .filter(|c| c.semantic >= MIN_SEMANTIC && c.semantic >= 0.5 * best)
        .copied()
        .collect()
}

/// What a query asks for that nothing in the map fits, as a refusal says it: "no lamp has been
/// seen", "nothing that one can water has been seen".
pub fn unseen(query: &Query) -> String {
    if query.function {
        format!("nothing that one can {} has been seen", query.target)
    } else {
        format!("no {} has been seen", query.target)
    }
}

/// Decide among `retrieval`'s candidates.
pub fn reason(
    scene: &ReferScene,
    query: &Query,
    retrieval: &Retrieval,
    view: Option<&ViewPose>,
    max_targets: usize,
) -> Result<Decision, ReasonError> {
    let fit = fitting(&retrieval.candidates);
    if fit.is_empty() {
        return Err(ReasonError::NoTarget(unseen(query)));
    }
    if query.view_dependent() && view.is_none() {
        return Err(ReasonError::NoView(query.text.clone()));
    }
    let geometries: Vec<Geometry> = geometries(scene);
    let mut trace = format!(
        "{} of {} candidates fit {:?}",
        fit.len(),
        retrieval.candidates.len(),
        query.target
    );
    // (candidate, key, holds): larger keys win; `holds` says the relation is satisfied outright.
    let mut keyed: Vec<(Scored, f64, bool)> = Vec::new();
    if let Some(relation) = query.relation {
        let anchors = &retrieval.anchors;
        let first = anchors.first().filter(|l| !l.is_empty());
        let Some(first) = first else {
            let missing = query.anchors.first().cloned().unwrap_or_default();
            return only_fit(scene, query, &fit, ReasonError::NoAnchor(missing));
        };
        for c in &fit {
            let t = &geometries[c.index];
            let margin = match relation {
                Relation::Between => {
                    let pair = between_pair(anchors, c.index);
                    match pair {
                        Some((a, b)) => {
                            relation_margin(relation, t, &geometries[a], Some(&geometries[b]), view)
                        }
                        None => {
                            let missing = unseen_anchors(query, anchors);
                            return only_fit(scene, query, &fit, ReasonError::NoAnchor(missing));
                        }
                    }
                }
                // Support relations hold with any instance of the anchor concept.
                Relation::On | Relation::Supporting | Relation::Above | Relation::Below => first
                    .iter()
                    .filter(|a| a.0 != c.index)
                    .map(|a| relation_margin(relation, t, &geometries[a.0], None, view))
                    .fold(f64::NEG_INFINITY, f64::max),
                // Others are about the anchor: the best fit of its concept.
                _ => match first.iter().find(|a| a.0 != c.index) {
                    Some(a) => relation_margin(relation, t, &geometries[a.0], None, view),
                    None => f64::NEG_INFINITY,
                },
            };
            let holds =
                !matches!(relation, Relation::Closest | Relation::Farthest) && margin >= 0.0;
            keyed.push((*c, margin, holds));
        }
        let anchor_ids: Vec<&str> = first
            .iter()
            .take(3)
            .map(|a| scene.nodes[a.0].id.as_str())
            .collect();
        trace += &format!(
            "; {relation:?} to {:?} (anchors {})",
            query.anchors,
            anchor_ids.join(", ")
        );
    } else if let Some(s) = query.superlative {
        for c in &fit {
            keyed.push((*c, superlative_key(s, &geometries[c.index], view), false));
        }
        trace += &format!("; {s:?}");
    } else if let Some(named) = query.color.as_deref().and_then(color_rgb) {
        for c in &fit {
            let node = &scene.nodes[c.index];
            keyed.push((*c, -color_distance(node.color, named), false));
        }
        trace += &format!("; colour {:?}", query.color.as_deref().unwrap_or(""));
    } else {
        for c in &fit {
            keyed.push((*c, f64::from(c.semantic), false));
        }
    }
    keyed.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.index.cmp(&b.0.index)));
    let keys: Vec<String> = keyed
        .iter()
        .map(|(c, k, _)| format!("{}={k:.2}", scene.nodes[c.index].id))
        .collect();
    trace += &format!("; keys {}", keys.join(" "));
    // Two instances whose boxes overlap this much are one object seen twice (a duplicate in the
    // map): when several are asked for, they are different objects.
    if query.count != Count::One {
        keyed = distinct(scene, keyed, |k| k.0.index);
    }
    let wanted = match query.count {
        Count::One => 1,
        Count::Exactly(n) => n,
        Count::All => {
            let holding = keyed.iter().filter(|k| k.2).count();
            if query.relation.is_some() && holding > 0 {
                holding
            } else if query.relation.is_some() {
                1
            } else {
                keyed.len()
            }
        }
    };
    let wanted = if max_targets > 0 {
        wanted.min(max_targets)
    } else {
        wanted
    };
    let note = (keyed.len() < wanted).then(|| {
        format!(
            "asked for {wanted}, {} instance(s) fit {:?}",
            keyed.len(),
            query.target
        )
    });
    // Confidence: the candidate's score, discounted when the runner-up's key is close.
    let chosen: Vec<Choice> = keyed
        .iter()
        .take(wanted)
        .enumerate()
        .map(|(rank, (c, key, _))| {
            let next = keyed.get(wanted.max(rank + 1)).map(|n| n.1);
            let clarity = next.map_or(1.0, |n| {
                let gap = (key - n) as f32;
                1.0 / (1.0 + (-gap / 0.1).exp())
            });
            Choice {
                index: c.index,
                confidence: (c.score.max(c.semantic) * clarity).clamp(0.0, 1.0),
            }
        })
        .collect();
    Ok(Decision {
        chosen,
        trace,
        note,
    })
}

/// The anchors of "between" that no instance stands for, as a refusal names them ("lamp",
/// "chair and lamp"); when each has one but they are the same instance, the pair ("between the
/// two desks" with one desk seen) or the second apart from the first.
fn unseen_anchors(query: &Query, anchors: &[super::retrieve::AnchorList]) -> String {
    let missing: Vec<&str> = query
        .anchors
        .iter()
        .enumerate()
        .filter(|(i, _)| anchors.get(*i).is_none_or(|l| l.is_empty()))
        .map(|(_, a)| a.as_str())
        .collect();
    if missing.is_empty() {
        match query.anchors.as_slice() {
            [a, b] if a != b => format!("{b} apart from the {a}"),
            _ => format!(
                "pair of {}",
                query.anchors.last().map_or("", String::as_str)
            ),
        }
    } else {
        missing.join(" and ")
    }
}

/// `items` with each object once, in order: an item whose instance's box overlaps an earlier
/// one's by [`DUPLICATE_IOU`] is that object seen twice (a duplicate in the map).
fn distinct<T>(scene: &ReferScene, items: Vec<T>, index: impl Fn(&T) -> usize) -> Vec<T> {
    let mut kept: Vec<T> = Vec::new();
    for item in items {
        let b = &scene.nodes[index(&item)].bbox;
        if !kept
            .iter()
            .any(|k| scene.nodes[index(k)].bbox.iou(b) >= DUPLICATE_IOU)
        {
            kept.push(item);
        }
    }
    kept
}

/// An anchor the map lacks leaves the relation unchecked; when one object alone fits the target
/// ("the desk closest to the lamp" with one desk seen and no lamp), that object is the answer
/// whatever the relation says, as it would be with the anchor seen, and the answer says the
/// relation went unchecked. Otherwise the relation would have to choose: `refusal`.
fn only_fit(
    scene: &ReferScene,
    query: &Query,
    fit: &[Scored],
    refusal: ReasonError,
) -> Result<Decision, ReasonError> {
    if query.count != Count::One {
        return Err(refusal);
    }
    let objects = distinct(scene, fit.to_vec(), |c| c.index);
    let [only] = objects.as_slice() else {
        return Err(refusal);
    };
    Ok(Decision {
        chosen: vec![Choice {
            index: only.index,
            // Half: the description was only half checked.
            confidence: (0.5 * only.score.max(only.semantic)).clamp(0.0, 1.0),
        }],
        trace: format!(
            "the only {:?} seen ({}); {refusal}",
            query.target, scene.nodes[only.index].id
        ),
        note: Some(format!(
            "{refusal}, so the relation was not checked: the only {} seen",
            query.target
        )),
    })
}

/// A query whose two-hop anchor phrase found nothing (`refusal`, the inner answer's): the target
/// alone decides when one object fits it ([`only_fit`]), else the inner refusal stands.
pub fn without_anchor(
    scene: &ReferScene,
    query: &Query,
    retrieval: &Retrieval,
    refusal: ReasonError,
) -> Result<Decision, ReasonError> {
    let fit = fitting(&retrieval.candidates);
    if fit.is_empty() {
        return Err(ReasonError::NoTarget(unseen(query)));
    }
    only_fit(scene, query, &fit, refusal)
}

/// The two anchors of "between" for candidate `t`: the best of each anchor concept, or the two
/// best of one concept ("between the two chairs").
fn between_pair(anchors: &[super::retrieve::AnchorList], t: usize) -> Option<(usize, usize)> {
    let first: Vec<usize> = anchors
        .first()?
        .iter()
        .map(|a| a.0)
        .filter(|&a| a != t)
        .collect();
    let second: Vec<usize> = anchors
        .get(1)?
        .iter()
        .map(|a| a.0)
        .filter(|&a| a != t)
        .collect();
    let a = *first.first()?;
    let b = *second.iter().find(|&&b| b != a)?;
    Some((a, b))
}

//! The templates: each method adds every unambiguous expression of one kind to the builder.

use super::relations::{
    above_margin, bearing, between_margin, color_distance, color_name, front_margin, left_margin,
    on_margin, plural, Expression, Geometry, PairMargin, Relation, ViewPose, BETWEEN_CLEARANCE_M,
    CLOSEST_GAP_M, DEPTH_GAP_M, DIRECTION_MARGIN_DEG, SIZE_RATIO, VERTICAL_SEPARATION_M,
};
use crate::library;

/// The distance relations and their words.
const DISTANCE_WORDS: [(Relation, &str); 2] = [
    (Relation::Closest, "closest to"),
    (Relation::Farthest, "farthest from"),
];

/// A superlative: relation, word, key, required gap in the key, and whether the largest wins.
type Superlative = (Relation, &'static str, fn(&Geometry) -> f64, f64, bool);

pub(super) struct Builder<'a> {
    pub(super) objects: &'a [Geometry],
    pub(super) out: Vec<Expression>,
}

impl<'a> Builder<'a> {
    pub(super) fn of_class(&self, class: &str) -> Vec<&'a Geometry> {
        self.objects.iter().filter(|o| o.class == class).collect()
    }

    pub(super) fn classes(&self) -> Vec<&'static str> {
        let mut classes: Vec<&'static str> = self.objects.iter().map(|o| o.class).collect();
        classes.sort_unstable();
        classes.dedup();
        classes
    }

    pub(super) fn unique(&self, class: &str) -> Option<&'a Geometry> {
        match self.of_class(class)[..] {
            [only] => Some(only),
            _ => None,
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn push(
        &mut self,
        text: String,
        relation: Relation,
        mut targets: Vec<u16>,
        target_class: &str,
        anchors: Vec<u16>,
        view: Option<ViewPose>,
    ) {
        targets.sort_unstable();
        let same_class = if target_class.is_empty() {
            0
        } else {
            self.of_class(target_class).len()
        };
        self.out.push(Expression {
            text,
            relation,
            cardinality: targets.len(),
            distractors: same_class.saturating_sub(targets.len()),
            targets,
            target_class: target_class.into(),
            anchors,
            view_dependent: relation.view_dependent(),
            view,
        });
    }

    /// Instances of `class` split by a margin: those at or above `+margin` and whether every
    /// other one is at or below `-margin` (clearly failing).
    pub(super) fn clear_split(
        candidates: &[&Geometry],
        margin: impl Fn(&Geometry) -> f64,
        threshold: f64,
    ) -> Option<Vec<u16>> {
        let mut yes = Vec::new();
        for c in candidates {
            let m = margin(c);
            if m >= 0.0 {
                yes.push(c.id);
            } else if m > -threshold {
                // Neither clearly in nor clearly out: ambiguous.
                return None;
            }
        }
        (!yes.is_empty()).then_some(yes)
    }

    pub(super) fn class_and_cardinality(&mut self) {
        for class in self.classes() {
            let all = self.of_class(class);
            let ids: Vec<u16> = all.iter().map(|o| o.id).collect();
            let text = match all.len() {
                1 => format!("the {class}"),
                2 => format!("both {}", plural(class)),
                _ => format!("all the {}", plural(class)),
            };
            self.push(text, Relation::Class, ids, class, Vec::new(), None);
        }
    }

    pub(super) fn distance_relations(&mut self) {
        for target_class in self.classes() {
            let candidates = self.of_class(target_class);
            if candidates.len() < 2 {
                continue;
            }
            for anchor_class in self.classes() {
                let Some(anchor) = self.unique(anchor_class).cloned() else {
                    continue;
                };
                if anchor_class == target_class {
                    continue;
                }
                for (relation, words) in DISTANCE_WORDS {
                    if let Some(target) = distance_pick(&candidates, &anchor, relation) {
                        self.push(
                            format!("the {target_class} {words} the {anchor_class}"),
                            relation,
                            vec![target.id],
                            target_class,
                            vec![anchor.id],
                            None,
                        );
                    }
                }
            }
        }
    }

    /// Two hops: "the T closest to the A farthest from the Z". A has several instances, so the
    /// inner phrase picks one, by its distance to the only Z; both hops clear Sr3D's gap. One Z
    /// (the first in class order that picks an A unambiguously) and one phrase per pair of T and A.
    pub(super) fn two_hops(&mut self) {
        let classes = self.classes();
        for &anchor_class in &classes {
            let anchors = self.of_class(anchor_class);
            if anchors.len() < 2 {
                continue;
            }
            let inner = classes.iter().find_map(|&far_class| {
                let far = self.unique(far_class)?;
                DISTANCE_WORDS.iter().find_map(|&(relation, words)| {
                    let picked = distance_pick(&anchors, far, relation)?;
                    Some((
                        picked,
                        format!("the {anchor_class} {words} the {far_class}"),
                        far.id,
                    ))
                })
            });
            let Some((anchor, inner_text, far_id)) = inner else {
                continue;
            };
            for &target_class in &classes {
                let candidates = self.of_class(target_class);
                if target_class == anchor_class || candidates.len() < 2 {
                    continue;
                }
                // One phrase per pair of classes (closest first), so two hops do not crowd the
                // benchmark's other kinds.
                let outer = DISTANCE_WORDS.iter().find_map(|&(relation, words)| {
                    distance_pick(&candidates, anchor, relation).map(|t| (t, words))
                });
                if let Some((target, words)) = outer {
                    self.push(
                        format!("the {target_class} {words} {inner_text}"),
                        Relation::TwoHop,
                        vec![target.id],
                        target_class,
                        vec![anchor.id, far_id],
                        None,
                    );
                }
            }
        }
    }

    /// Relations to any instance of an anchor class: on, supporting, above, below.
    pub(super) fn support_relations(&mut self) {
        for target_class in self.classes() {
            for anchor_class in self.classes() {
                if anchor_class == target_class {
                    continue;
                }
                let candidates = self.of_class(target_class);
                let anchors = self.of_class(anchor_class);
                let best = |f: &dyn Fn(&Geometry, &Geometry) -> f64, t: &Geometry| {
                    anchors
                        .iter()
                        .map(|a| f(t, a))
                        .fold(f64::NEG_INFINITY, f64::max)
                };
                let on = |t: &Geometry, a: &Geometry| on_margin(t, a);
                let supporting = |t: &Geometry, a: &Geometry| on_margin(a, t);
                let above = |t: &Geometry, a: &Geometry| above_margin(t, a);
                let below = |t: &Geometry, a: &Geometry| above_margin(a, t);
                let cases: [(Relation, &PairMargin, String); 4] = [
                    (
                        Relation::On,
                        &on,
                        format!("the {target_class} on the {anchor_class}"),
                    ),
                    (
                        Relation::Supporting,
                        &supporting,
                        format!("the {target_class} with a {anchor_class} on it"),
                    ),
                    (
                        Relation::Above,
                        &above,
                        format!("the {target_class} above the {anchor_class}"),
                    ),
                    (
                        Relation::Below,
                        &below,
                        format!("the {target_class} below the {anchor_class}"),
                    ),
                ];
                let mut found = Vec::new();
                for (relation, f, text) in cases {
                    let split = Self::clear_split(&candidates, |t| best(f, t), 0.1);
                    if let Some(targets) = split {
                        let anchor_ids: Vec<u16> = anchors
                            .iter()
                            .filter(|a| {
                                targets.iter().any(|id| {
                                    candidates.iter().any(|t| t.id == *id && f(t, a) >= 0.0)
                                })
                            })
                            .map(|a| a.id)
                            .collect();
                        found.push((text, relation, targets, anchor_ids));
                    }
                }
                for (text, relation, targets, anchor_ids) in found {
                    let text = if targets.len() > 1 {
                        text.replacen(
                            &format!("the {target_class}"),
                            &format!("the {}", plural(target_class)),
                            1,
                        )
                    } else {
                        text
                    };
                    self.push(text, relation, targets, target_class, anchor_ids, None);
                }
            }
        }
    }

    pub(super) fn between(&mut self) {
        let classes = self.classes();
        for (i, a_class) in classes.iter().enumerate() {
            for b_class in &classes[i..] {
                let (a, b) = if a_class == b_class {
                    match self.of_class(a_class)[..] {
                        [a, b] => (a.clone(), b.clone()),
                        _ => continue,
                    }
                } else {
                    match (self.unique(a_class), self.unique(b_class)) {
                        (Some(a), Some(b)) => (a.clone(), b.clone()),
                        _ => continue,
                    }
                };
                let anchors = if a_class == b_class {
                    format!("the two {}", plural(a_class))
                } else {
                    format!("the {a_class} and the {b_class}")
                };
                for target_class in self.classes() {
                    if target_class == *a_class || target_class == *b_class {
                        continue;
                    }
                    let candidates = self.of_class(target_class);
                    let split = Self::clear_split(
                        &candidates,
                        |t| between_margin(t, &a, &b),
                        BETWEEN_CLEARANCE_M,
                    );
                    if let Some(targets) = split.filter(|t| t.len() == 1) {
                        self.push(
                            format!("the {target_class} between {anchors}"),
                            Relation::Between,
                            targets,
                            target_class,
                            vec![a.id, b.id],
                            None,
                        );
                    }
                }
            }
        }
    }

    pub(super) fn superlatives(&mut self) {
        for class in self.classes() {
            let candidates = self.of_class(class);
            if candidates.len() < 2 {
                continue;
            }
            let cases: [Superlative; 5] = [
                (
                    Relation::Biggest,
                    "biggest",
                    |g| g.volume().ln(),
                    SIZE_RATIO.ln(),
                    true,
                ),
                (
                    Relation::Smallest,
                    "smallest",
                    |g| g.volume().ln(),
                    SIZE_RATIO.ln(),
                    false,
                ),
                (
                    Relation::Tallest,
                    "tallest",
                    Geometry::height,
                    VERTICAL_SEPARATION_M,
                    true,
                ),
                (
                    Relation::Highest,
                    "highest",
                    |g| g.hi.z,
                    VERTICAL_SEPARATION_M,
                    true,
                ),
                (
                    Relation::Lowest,
                    "lowest",
                    |g| g.lo.z,
                    VERTICAL_SEPARATION_M,
                    false,
                ),
            ];
            for (relation, word, key, gap, largest) in cases {
                let mut values: Vec<(f64, u16)> = candidates
                    .iter()
                    .map(|c| (if largest { key(c) } else { -key(c) }, c.id))
                    .collect();
                values.sort_by(|a, b| b.0.total_cmp(&a.0));
                if values[0].0 - values[1].0 >= gap {
                    self.push(
                        format!("the {word} {class}"),
                        relation,
                        vec![values[0].1],
                        class,
                        Vec::new(),
                        None,
                    );
                }
            }
        }
    }

    pub(super) fn colors(&mut self) {
        for class in self.classes() {
            let candidates = self.of_class(class);
            if candidates.len() < 2 {
                continue;
            }
            for t in &candidates {
                let name = color_name(t.color);
                let clear = candidates.iter().all(|o| {
                    o.id == t.id
                        || (color_name(o.color) != name && color_distance(o.color, t.color) >= 0.15)
                });
                if clear {
                    self.push(
                        format!("the {name} {class}"),
                        Relation::Color,
                        vec![t.id],
                        class,
                        Vec::new(),
                        None,
                    );
                }
            }
        }
    }

    pub(super) fn functions(&mut self) {
        let classes = library::classes();
        let mut affordances: Vec<&'static str> = classes
            .iter()
            .flat_map(|c| c.affordances.iter().copied())
            .collect();
        affordances.sort_unstable();
        affordances.dedup();
        for affordance in affordances {
            let targets: Vec<u16> = self
                .objects
                .iter()
                .filter(|o| {
                    classes
                        .iter()
                        .any(|c| c.name == o.class && c.affordances.contains(&affordance))
                })
                .map(|o| o.id)
                .collect();
            let text = match targets.len() {
                0 => continue,
                1 => format!("the thing you can {affordance}"),
                _ => format!("all the things you can {affordance}"),
            };
            self.push(text, Relation::Function, targets, "", Vec::new(), None);
        }
    }

    /// View-dependent relations and superlatives, decided in `view`, among objects whose centre
    /// the view sees.
    pub(super) fn view_relations(&mut self, view: ViewPose, half_fov_deg: f64) {
        let visible = |g: &Geometry| {
            let (b, z) = bearing(&view, g.center());
            z > 0.3 && b.abs() < half_fov_deg
        };
        for target_class in self.classes() {
            let candidates: Vec<&Geometry> = self.of_class(target_class);
            if candidates.len() < 2 || !candidates.iter().all(|c| visible(c)) {
                continue;
            }
            // Leftmost / rightmost.
            let mut bearings: Vec<(f64, u16)> = candidates
                .iter()
                .map(|c| (bearing(&view, c.center()).0, c.id))
                .collect();
            bearings.sort_by(|a, b| a.0.total_cmp(&b.0));
            let n = bearings.len();
            if bearings[1].0 - bearings[0].0 >= DIRECTION_MARGIN_DEG {
                let text = format!("the leftmost {target_class}");
                self.push(
                    text,
                    Relation::Leftmost,
                    vec![bearings[0].1],
                    target_class,
                    Vec::new(),
                    Some(view),
                );
            }
            if bearings[n - 1].0 - bearings[n - 2].0 >= DIRECTION_MARGIN_DEG {
                let text = format!("the rightmost {target_class}");
                self.push(
                    text,
                    Relation::Rightmost,
                    vec![bearings[n - 1].1],
                    target_class,
                    Vec::new(),
                    Some(view),
                );
            }
            for anchor_class in self.classes() {
                if anchor_class == target_class {
                    continue;
                }
                let Some(anchor) = self.unique(anchor_class).cloned() else {
                    continue;
                };
                if !visible(&anchor) {
                    continue;
                }
                let cases: [(Relation, String, f64); 4] = [
                    (
                        Relation::Left,
                        format!("the {target_class} to the left of the {anchor_class}"),
                        DIRECTION_MARGIN_DEG,
                    ),
                    (
                        Relation::Right,
                        format!("the {target_class} to the right of the {anchor_class}"),
                        DIRECTION_MARGIN_DEG,
                    ),
                    (
                        Relation::Front,
                        format!("the {target_class} in front of the {anchor_class}"),
                        DEPTH_GAP_M,
                    ),
                    (
                        Relation::Behind,
                        format!("the {target_class} behind the {anchor_class}"),
                        DEPTH_GAP_M,
                    ),
                ];
                for (relation, text, threshold) in cases {
                    let margin = |t: &Geometry| match relation {
                        Relation::Left => left_margin(&view, t, &anchor),
                        Relation::Right => {
                            -left_margin(&view, t, &anchor) - 2.0 * DIRECTION_MARGIN_DEG
                        }
                        Relation::Front => front_margin(&view, t, &anchor),
                        _ => front_margin(&view, &anchor, t),
                    };
                    let split = Self::clear_split(&candidates, margin, threshold);
                    if let Some(targets) = split.filter(|t| t.len() == 1) {
                        self.push(
                            text,
                            relation,
                            targets,
                            target_class,
                            vec![anchor.id],
                            Some(view),
                        );
                    }
                }
            }
        }
    }
}

/// The one of `candidates` closest to (or farthest from) `anchor`, when the runner-up is at
/// least Sr3D's gap behind; never `anchor` itself.
fn distance_pick<'g>(
    candidates: &[&'g Geometry],
    anchor: &Geometry,
    relation: Relation,
) -> Option<&'g Geometry> {
    let mut by_distance: Vec<(f64, &'g Geometry)> = candidates
        .iter()
        .filter(|c| c.id != anchor.id)
        .map(|c| ((c.center() - anchor.center()).length(), *c))
        .collect();
    if by_distance.len() < 2 {
        return None;
    }
    by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
    if relation == Relation::Farthest {
        by_distance.reverse();
    }
    ((by_distance[0].0 - by_distance[1].0).abs() >= CLOSEST_GAP_M).then_some(by_distance[0].1)
}

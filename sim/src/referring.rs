//! Referring expressions generated from ground truth, for benchmark sets.
//!
//! Templates cover every relation of the Sr3D taxonomy the node answers (closest / farthest,
//! above / below, on / supporting, left / right / front / behind in a named view, between),
//! superlatives, colour attributes, function phrases and plural cardinality. An expression is
//! kept only if exactly its targets satisfy it with a margin, using the thresholds ReferIt3D's
//! Sr3D generator uses: a 0.2 m gap for closest / farthest, 0.06 m vertical separation for above
//! / below, support touching within 0.15 m, 0.3 m clearance for between, 10° for view-dependent
//! directions. Every other object of the target's class must clearly fail.

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::library;
use crate::render::{PlacedObject, Scene};

/// Sr3D's thresholds.
pub const CLOSEST_GAP_M: f64 = 0.2;
pub const VERTICAL_SEPARATION_M: f64 = 0.06;
pub const SUPPORT_CONTACT_M: f64 = 0.15;
pub const BETWEEN_CLEARANCE_M: f64 = 0.3;
pub const DIRECTION_MARGIN_DEG: f64 = 10.0;
/// Superlatives of size need the biggest to be this many times the runner-up's volume.
pub const SIZE_RATIO: f64 = 1.25;
/// Front / behind need this much depth difference in the view (metres).
pub const DEPTH_GAP_M: f64 = 0.3;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Relation {
    /// "the trash bin" (the only one), or "all the chairs" (cardinality > 1).
    Class,
    Closest,
    Farthest,
    Above,
    Below,
    On,
    Supporting,
    Left,
    Right,
    Front,
    Behind,
    Between,
    Biggest,
    Smallest,
    Tallest,
    Highest,
    Lowest,
    Leftmost,
    Rightmost,
    Color,
    Function,
}

impl Relation {
    pub fn view_dependent(self) -> bool {
        matches!(
            self,
            Relation::Left
                | Relation::Right
                | Relation::Front
                | Relation::Behind
                | Relation::Leftmost
                | Relation::Rightmost
        )
    }
}

/// The viewpoint a view-dependent expression is decided in: `world_from_camera` of the rig's
/// first camera at a trajectory frame (REP-103 optical frame), as the Refer service's `view_pose`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ViewPose {
    pub frame: usize,
    pub position: [f64; 3],
    /// x, y, z, w.
    pub orientation: [f64; 4],
}

impl ViewPose {
    pub fn new(frame: usize, rotation: DQuat, position: DVec3) -> Self {
        Self {
            frame,
            position: position.to_array(),
            orientation: rotation.to_array(),
        }
    }

    /// A world point in this camera's frame.
    fn in_camera(&self, p: DVec3) -> DVec3 {
        let rotation = DQuat::from_array(self.orientation);
        rotation.inverse() * (p - DVec3::from(self.position))
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Expression {
    pub text: String,
    pub relation: Relation,
    /// Instance ids the expression means (sorted); `cardinality` = their number.
    pub targets: Vec<u16>,
    pub cardinality: usize,
    /// The targets' class ("" for function phrases, which name no class).
    pub target_class: String,
    /// Instances of the anchor classes the relation is about.
    pub anchors: Vec<u16>,
    /// Objects of the target's class that are not targets (ReferIt3D "hard": more than 2).
    pub distractors: usize,
    pub view_dependent: bool,
    pub view: Option<ViewPose>,
}

/// The geometry of one object as relations see it.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    pub id: u16,
    pub class: &'static str,
    pub lo: DVec3,
    pub hi: DVec3,
    pub color: [f32; 3],
}

impl Geometry {
    pub fn new(object: &PlacedObject) -> Self {
        let (lo, hi) = object.bounds();
        let class = library::classes()
            .into_iter()
            .find(|c| c.id == object.class_id)
            .map_or("object", |c| c.name);
        Self {
            id: object.instance_id,
            class,
            lo,
            hi,
            color: object.color,
        }
    }

    pub fn center(&self) -> DVec3 {
        (self.lo + self.hi) / 2.0
    }

    pub fn volume(&self) -> f64 {
        let s = self.hi - self.lo;
        s.x * s.y * s.z
    }

    pub fn height(&self) -> f64 {
        self.hi.z - self.lo.z
    }

    /// Overlap of the two footprints (xy), metres; negative: the gap between them.
    fn footprint_overlap(&self, other: &Geometry) -> f64 {
        let x = self.hi.x.min(other.hi.x) - self.lo.x.max(other.lo.x);
        let y = self.hi.y.min(other.hi.y) - self.lo.y.max(other.lo.y);
        x.min(y)
    }
}

/// Margin (metres) by which `t` stands on `a`: positive when `t`'s footprint centre lies on
/// `a`'s footprint and `t`'s base is within `a`'s height range (or touching its top within
/// 0.15 m), off the floor.
pub fn on_margin(t: &Geometry, a: &Geometry) -> f64 {
    let c = t.center();
    let inside = (c.x - a.lo.x)
        .min(a.hi.x - c.x)
        .min(c.y - a.lo.y)
        .min(a.hi.y - c.y);
    let base = t.lo.z;
    let vertical = (base - a.lo.z).min(a.hi.z + SUPPORT_CONTACT_M - base);
    inside.min(vertical).min(base - 0.05)
}

/// Margin by which `t` is above `a`: footprints overlap, `t`'s base at or over `a`'s top (within
/// the contact tolerance) and its centre at least 0.06 m higher.
pub fn above_margin(t: &Geometry, a: &Geometry) -> f64 {
    let overlap = t.footprint_overlap(a);
    let base = t.lo.z - (a.hi.z - SUPPORT_CONTACT_M);
    let separation = t.center().z - a.center().z - VERTICAL_SEPARATION_M;
    overlap.min(base).min(separation)
}

/// Horizontal bearing (degrees, positive to the right) and depth of a point in a view.
fn bearing(view: &ViewPose, p: DVec3) -> (f64, f64) {
    let c = view.in_camera(p);
    (c.x.atan2(c.z).to_degrees(), c.z)
}

/// Margin (degrees) by which `t` is left of `a` in `view`.
pub fn left_margin(view: &ViewPose, t: &Geometry, a: &Geometry) -> f64 {
    let (bt, _) = bearing(view, t.center());
    let (ba, _) = bearing(view, a.center());
    ba - bt - DIRECTION_MARGIN_DEG
}

/// Margin (metres) by which `t` is in front of `a` (nearer the viewer, roughly in line).
pub fn front_margin(view: &ViewPose, t: &Geometry, a: &Geometry) -> f64 {
    let (bt, zt) = bearing(view, t.center());
    let (ba, za) = bearing(view, a.center());
    let in_line = (25.0 - (bt - ba).abs()) / 25.0 * DEPTH_GAP_M;
    (za - zt - DEPTH_GAP_M).min(in_line)
}

/// Margin (metres) by which `t` lies between `a` and `b` (in the floor plane): inside the
/// corridor joining their centres, half a metre wide each side, away from its ends.
pub fn between_margin(t: &Geometry, a: &Geometry, b: &Geometry) -> f64 {
    let flat = |v: DVec3| DVec3::new(v.x, v.y, 0.0);
    let (pa, pb, pt) = (flat(a.center()), flat(b.center()), flat(t.center()));
    let ab = pb - pa;
    let length = ab.length();
    if length < 1e-6 {
        return f64::NEG_INFINITY;
    }
    let s = (pt - pa).dot(ab) / (length * length);
    let along = (s.min(1.0 - s) - 0.15) * length;
    let across = 0.5 - (pt - (pa + s * ab)).length();
    along.min(across)
}

/// The nearest colour name of an RGB triple.
pub fn color_name(color: [f32; 3]) -> &'static str {
    const PALETTE: &[(&str, [f32; 3])] = &[
        ("red", [0.8, 0.15, 0.15]),
        ("orange", [0.9, 0.5, 0.15]),
        ("yellow", [0.9, 0.85, 0.3]),
        ("green", [0.2, 0.6, 0.25]),
        ("blue", [0.2, 0.3, 0.75]),
        ("purple", [0.5, 0.25, 0.6]),
        ("brown", [0.5, 0.32, 0.18]),
        ("black", [0.08, 0.08, 0.1]),
        ("white", [0.93, 0.93, 0.93]),
        ("grey", [0.5, 0.5, 0.5]),
        ("beige", [0.85, 0.78, 0.6]),
    ];
    let distance = |c: &[f32; 3]| {
        c.iter()
            .zip(color)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f32>()
    };
    PALETTE
        .iter()
        .min_by(|a, b| distance(&a.1).total_cmp(&distance(&b.1)))
        .map_or("grey", |p| p.0)
}

pub fn plural(class: &str) -> String {
    match class {
        "box" => "boxes".into(),
        "bookshelf" => "bookshelves".into(),
        other => format!("{other}s"),
    }
}

fn color_distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
}

/// A margin of `t` with respect to an anchor.
type PairMargin = dyn Fn(&Geometry, &Geometry) -> f64;

/// A superlative: relation, word, key, required gap in the key, and whether the largest wins.
type Superlative = (Relation, &'static str, fn(&Geometry) -> f64, f64, bool);

struct Builder<'a> {
    objects: &'a [Geometry],
    out: Vec<Expression>,
}

impl<'a> Builder<'a> {
    fn of_class(&self, class: &str) -> Vec<&'a Geometry> {
        self.objects.iter().filter(|o| o.class == class).collect()
    }

    fn classes(&self) -> Vec<&'static str> {
        let mut classes: Vec<&'static str> = self.objects.iter().map(|o| o.class).collect();
        classes.sort_unstable();
        classes.dedup();
        classes
    }

    fn unique(&self, class: &str) -> Option<&'a Geometry> {
        match self.of_class(class)[..] {
            [only] => Some(only),
            _ => None,
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn push(
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
    fn clear_split(
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

    fn class_and_cardinality(&mut self) {
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

    fn distance_relations(&mut self) {
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
                let mut by_distance: Vec<(f64, u16)> = candidates
                    .iter()
                    .map(|c| ((c.center() - anchor.center()).length(), c.id))
                    .collect();
                by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
                let n = by_distance.len();
                if by_distance[1].0 - by_distance[0].0 >= CLOSEST_GAP_M {
                    self.push(
                        format!("the {target_class} closest to the {anchor_class}"),
                        Relation::Closest,
                        vec![by_distance[0].1],
                        target_class,
                        vec![anchor.id],
                        None,
                    );
                }
                if by_distance[n - 1].0 - by_distance[n - 2].0 >= CLOSEST_GAP_M {
                    self.push(
                        format!("the {target_class} farthest from the {anchor_class}"),
                        Relation::Farthest,
                        vec![by_distance[n - 1].1],
                        target_class,
                        vec![anchor.id],
                        None,
                    );
                }
            }
        }
    }

    /// Relations to any instance of an anchor class: on, supporting, above, below.
    fn support_relations(&mut self) {
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

    fn between(&mut self) {
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

    fn superlatives(&mut self) {
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

    fn colors(&mut self) {
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

    fn functions(&mut self) {
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
    fn view_relations(&mut self, view: ViewPose, half_fov_deg: f64) {
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

/// Every unambiguous expression of `scene`; view-dependent ones in each of `views`
/// (`half_fov_deg`: half the horizontal field of view).
pub fn generate(scene: &Scene, views: &[ViewPose], half_fov_deg: f64) -> Vec<Expression> {
    let objects: Vec<Geometry> = scene.objects.iter().map(Geometry::new).collect();
    let mut builder = Builder {
        objects: &objects,
        out: Vec::new(),
    };
    builder.class_and_cardinality();
    builder.distance_relations();
    builder.support_relations();
    builder.between();
    builder.superlatives();
    builder.colors();
    builder.functions();
    for view in views {
        builder.view_relations(*view, half_fov_deg);
    }
    builder.out
}

/// The viewpoints of a scene's benchmark: the first camera every `every` frames of the trajectory.
pub fn trajectory_views(file: &crate::scene::SceneFile, every: usize) -> Vec<ViewPose> {
    let Ok(poses) = file.robot_poses() else {
        return Vec::new();
    };
    let Some(camera) = file.cameras.first() else {
        return Vec::new();
    };
    poses
        .iter()
        .enumerate()
        .step_by(every.max(1))
        .map(|(frame, pose)| {
            let (rotation, position) = crate::scene::camera_pose(camera, pose);
            ViewPose::new(frame, rotation, position)
        })
        .collect()
}

/// A scene's benchmark expressions: view-independent ones once, view-dependent ones in views
/// every 20 frames.
pub fn scene_expressions(
    file: &crate::scene::SceneFile,
) -> Result<Vec<Expression>, crate::scene::SceneError> {
    let scene = file.build()?;
    let half_fov = file.cameras.first().map_or(45.0, |c| c.fov_x_deg / 2.0);
    Ok(generate(&scene, &trajectory_views(file, 20), half_fov))
}

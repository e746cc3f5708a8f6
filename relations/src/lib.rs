//! groupforward-relations: what a referring expression's relation and colour words mean, as
//! geometry. The node's reasoner decides "the chair left of the table" with these margins, and the
//! simulator's benchmark generator keeps an expression only when its targets satisfy them: both
//! must agree, so both depend on this crate and neither on the other.
//!
//! Objects are axis-aligned boxes ([`Geometry`]); view-dependent relations are decided in a
//! [`ViewPose`]. The thresholds are the ones ReferIt3D's Sr3D generator uses.

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

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
    /// "the table closest to the chair farthest from the bed": a distance relation to an anchor
    /// that is itself picked by one.
    TwoHop,
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

/// The geometry of one object as relations see it.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    pub id: u16,
    pub class: &'static str,
    /// Axis-aligned bounds: where the object is.
    pub lo: DVec3,
    pub hi: DVec3,
    /// Its size along its own axes (m): how big it is. The bounds of a turned object are larger
    /// than it: a round plant's box turned by 45° has bounds of twice its footprint, so the
    /// bounds' volume made one of two alike plants "the biggest" by its yaw alone.
    pub extent: DVec3,
    pub color: [f32; 3],
}

impl Geometry {
    pub fn center(&self) -> DVec3 {
        (self.lo + self.hi) / 2.0
    }

    /// The object's own volume ([`Geometry::extent`]), not its bounds'.
    pub fn volume(&self) -> f64 {
        self.extent.x * self.extent.y * self.extent.z
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
pub fn bearing(view: &ViewPose, p: DVec3) -> (f64, f64) {
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

/// Colour names and the RGB (0-1) they stand for: what colour words mean to the generator and the
/// node's reasoner.
pub const COLOR_PALETTE: &[(&str, [f32; 3])] = &[
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

/// The nearest colour name of an RGB triple.
pub fn color_name(color: [f32; 3]) -> &'static str {
    let distance = |c: &[f32; 3]| {
        c.iter()
            .zip(color)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f32>()
    };
    COLOR_PALETTE
        .iter()
        .min_by(|a, b| distance(&a.1).total_cmp(&distance(&b.1)))
        .map_or("grey", |p| p.0)
}

/// Euclidean distance of two RGB triples (0-1).
pub fn color_distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
}

/// A margin of `t` with respect to an anchor.
pub type PairMargin = dyn Fn(&Geometry, &Geometry) -> f64;

#[cfg(test)]
mod tests {
    use super::*;

    fn cube(id: u16, centre: DVec3, half: f64) -> Geometry {
        Geometry {
            id,
            class: "box",
            lo: centre - DVec3::splat(half),
            hi: centre + DVec3::splat(half),
            extent: DVec3::splat(2.0 * half),
            color: [0.5, 0.5, 0.5],
        }
    }

    #[test]
    fn every_palette_colour_is_named_by_its_own_name() {
        for (name, rgb) in COLOR_PALETTE {
            assert_eq!(color_name(*rgb), *name);
        }
    }

    #[test]
    fn between_two_anchors_at_one_place_holds_for_nothing_and_stays_ordered() {
        let a = cube(0, DVec3::new(1.0, 1.0, 0.5), 0.2);
        let t = cube(1, DVec3::new(1.0, 1.0, 0.5), 0.1);
        let margin = between_margin(&t, &a, &a);
        assert!(margin < 0.0 && !margin.is_nan());
    }

    #[test]
    fn a_turned_object_is_no_bigger_than_its_twin() {
        // Two 0.4 m plants, the second turned by 45°: its bounds are 0.57 m wide.
        let plant = cube(0, DVec3::ZERO, 0.2);
        let half = 0.2 * std::f64::consts::SQRT_2;
        let turned = Geometry {
            lo: DVec3::new(-half, -half, -0.2),
            hi: DVec3::new(half, half, 0.2),
            ..cube(1, DVec3::ZERO, 0.2)
        };
        let bounds = |g: &Geometry| (g.hi - g.lo).x * (g.hi - g.lo).y * (g.hi - g.lo).z;
        assert!(bounds(&turned) > 1.9 * bounds(&plant));
        assert!((turned.volume() - plant.volume()).abs() < 1e-12);
    }

    #[test]
    fn a_box_on_a_table_is_on_it_and_above_it_and_the_table_is_neither() {
        let table = Geometry {
            id: 0,
            class: "table",
            lo: DVec3::new(0.0, 0.0, 0.0),
            hi: DVec3::new(1.2, 0.8, 0.75),
            extent: DVec3::new(1.2, 0.8, 0.75),
            color: [0.5, 0.32, 0.18],
        };
        let box_on_top = cube(1, DVec3::new(0.6, 0.4, 0.85), 0.1);
        assert!(on_margin(&box_on_top, &table) > 0.0);
        assert!(above_margin(&box_on_top, &table) > 0.0);
        assert!(on_margin(&table, &box_on_top) < 0.0);
        assert!(above_margin(&table, &box_on_top) < 0.0);
    }

    #[test]
    fn left_and_front_are_decided_in_the_view() {
        // A camera at the origin looking along world +y (optical z), optical x = world +x.
        let rotation = DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2);
        let view = ViewPose::new(0, rotation, DVec3::ZERO);
        let left = cube(0, DVec3::new(-1.0, 3.0, 0.0), 0.1);
        let right = cube(1, DVec3::new(1.0, 3.0, 0.0), 0.1);
        assert!(left_margin(&view, &left, &right) > 0.0);
        assert!(left_margin(&view, &right, &left) < 0.0);
        let near = cube(2, DVec3::new(0.0, 2.0, 0.0), 0.1);
        let far = cube(3, DVec3::new(0.0, 4.0, 0.0), 0.1);
        assert!(front_margin(&view, &near, &far) > 0.0);
        assert!(front_margin(&view, &far, &near) < 0.0);
    }
}

//! Boxes of furniture seen from one side only. A depth camera sees the front of a cabinet that
//! stands against a wall, never its sides when it stands in a row or a corner, and never its back:
//! the points are one vertical surface and the fitted box is a few millimetres deep, although the
//! object fills the space back to the wall. A navigation stack that plans around such a box drives
//! into the cabinet's volume, and a 3D IoU against the object is near zero.
//!
//! The completion is geometric, not a size prior: a box that is a vertical surface standing on the
//! floor, with the room's structure (the map's walls) forming a plane parallel to it within
//! [`MAX_BACK_M`] on one side, is extended back to that plane. The wall behind the object itself is
//! hidden by it, so the plane is read from the wall around it (beside and above the surface).

use glam::{DVec2, DVec3, Vec3};

use super::{Instance, SceneMap};
use crate::group::cleaning::floor_height;
use crate::group::semantics::Vocabulary;
use crate::recon::boxes::OrientedBox;

/// A box thinner than this along one horizontal axis is a surface seen from one side.
pub const SLAB_M: f64 = 0.05;
/// The surface's width and height at least: smaller pieces are not the front of furniture.
pub const MIN_FACE_M: f64 = 0.2;
/// Farthest wall a surface is completed back to (deeper furniture is rare; a wall farther away
/// is more likely across free space).
pub const MAX_BACK_M: f64 = 1.0;
/// The surface's bottom within this of the floor: furniture stands there, while a screen on a
/// desk or a picture has no volume down to the wall.
pub const ON_FLOOR_M: f64 = 0.15;
/// How far beside the surface, and above it, wall points are read.
const BESIDE_M: f64 = 0.6;
/// Depth bins of the plane search.
const BIN_M: f64 = 0.02;
/// A plane needs this many structure points in its bin (±1), and this share of the side's.
const MIN_PLANE_POINTS: usize = 15;
const MIN_PLANE_SHARE: f64 = 0.3;

/// The map's structure (walls, floor, ceiling) as the completion reads it.
#[derive(Debug, Clone, Default)]
pub struct Walls {
    points: Vec<Vec3>,
    floor: Option<f32>,
}

impl Walls {
    /// The structure of `map`: the Gaussians of the instances `is_structure` picks.
    pub fn of_map(map: &SceneMap, is_structure: impl Fn(&Instance) -> bool) -> Self {
        Self::new(
            map.instances
                .iter()
                .filter(|i| is_structure(i))
                .flat_map(|i| i.gaussians.means.iter().copied())
                .collect(),
        )
    }

    /// From the Gaussians' centres of the map's structure instances.
    pub fn new(points: Vec<Vec3>) -> Self {
        let points: Vec<Vec3> = points.into_iter().filter(|p| p.is_finite()).collect();
        let floor = floor_height(&points);
        Self { points, floor }
    }

    /// `fitted` completed back to the wall behind it when it is a vertical surface standing on
    /// the floor in front of a wall; otherwise `fitted` as it is.
    pub fn complete(&self, fitted: OrientedBox) -> OrientedBox {
        let Some(floor) = self.floor else {
            return fitted;
        };
        let size = fitted.size;
        let bottom = fitted.centre.z - size.z / 2.0;
        let top = fitted.centre.z + size.z / 2.0;
        let on_floor = bottom <= f64::from(floor) + ON_FLOOR_M;
        if !(fitted.centre.is_finite() && is_surface(&fitted) && on_floor) {
            return fitted;
        }
        let (c, s) = (fitted.yaw.cos(), fitted.yaw.sin());
        let (x_axis, y_axis) = (DVec2::new(c, s), DVec2::new(-s, c));
        // The thin axis is the surface's normal, the other its width.
        let thin_along_x = size.x < SLAB_M;
        let (normal, along, thin, width) = if thin_along_x {
            (x_axis, y_axis, size.x, size.y)
        } else {
            (y_axis, x_axis, size.y, size.x)
        };
        let centre = fitted.centre.truncate();
        // Signed distances from the surface's mid-plane of the structure points beside and above
        // it (the floor and points far to the side left out).
        let mut ahead = Vec::new();
        let mut behind = Vec::new();
        for p in &self.points {
            let z = f64::from(p.z);
            if z < bottom + ON_FLOOR_M || z > top + BESIDE_M {
                continue;
            }
            let d = p.truncate().as_dvec2() - centre;
            if d.dot(along).abs() > width / 2.0 + BESIDE_M {
                continue;
            }
            let depth = d.dot(normal);
            if depth.abs() > thin / 2.0 + BIN_M && depth.abs() <= MAX_BACK_M {
                if depth > 0.0 {
                    ahead.push(depth);
                } else {
                    behind.push(-depth);
                }
            }
        }
        // The nearer side that holds a wall plane; the object fills the space back to it.
        let wall = [(1.0, plane_depth(&ahead)), (-1.0, plane_depth(&behind))]
            .into_iter()
            .filter_map(|(sign, depth)| depth.map(|d| (sign, d)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        let Some((sign, depth)) = wall else {
            return fitted;
        };
        // Front face at -thin/2 (away from the wall), back at the wall: along `sign * normal`.
        let extent = depth + thin / 2.0;
        let shift = sign * (depth - thin / 2.0) / 2.0;
        let moved = centre + normal * shift;
        let mut completed = fitted;
        completed.centre = DVec3::new(moved.x, moved.y, fitted.centre.z);
        if thin_along_x {
            completed.size.x = extent;
        } else {
            completed.size.y = extent;
        }
        completed
    }
}

/// Whether `fitted` is a vertical surface seen from one side (thin along one horizontal axis):
/// the only boxes [`Walls::complete`] may change, so callers build [`Walls`] only for them.
pub fn is_surface(fitted: &OrientedBox) -> bool {
    let s = fitted.size;
    s.is_finite()
        && s.z >= MIN_FACE_M
        && ((s.x < SLAB_M && s.y >= MIN_FACE_M) || (s.y < SLAB_M && s.x >= MIN_FACE_M))
}

/// The box an instance publishes: `fitted`, or for a surface seen from one side the box back to
/// the wall behind it ([`Walls::complete`]; `walls` is built from `map` at the first surface).
pub fn published_box(
    fitted: OrientedBox,
    walls: &std::cell::OnceCell<Walls>,
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
) -> OrientedBox {
    if !is_surface(&fitted) {
        return fitted;
    }
    walls
        .get_or_init(|| {
            Walls::of_map(map, |i| {
                vocabulary.is_some_and(|v| v.is_structure(&i.prototype))
            })
        })
        .complete(fitted)
}

/// Depth of a plane parallel to the surface among `depths` (one side's structure points): the
/// fullest 2 cm bin with its neighbours when it holds enough of them, refined to their median.
fn plane_depth(depths: &[f64]) -> Option<f64> {
    if depths.len() < MIN_PLANE_POINTS {
        return None;
    }
    let bins = (MAX_BACK_M / BIN_M).ceil() as usize + 1;
    let mut counts = vec![0usize; bins];
    let bin_of = |d: f64| ((d / BIN_M) as usize).min(bins - 1);
    for &d in depths {
        counts[bin_of(d)] += 1;
    }
    let near = |b: usize| {
        counts[b.saturating_sub(1)..(b + 2).min(bins)]
            .iter()
            .sum::<usize>()
    };
    let peak = (0..bins).max_by_key(|&b| (near(b), std::cmp::Reverse(b)))?;
    let held = near(peak);
    if held < MIN_PLANE_POINTS || (held as f64) < MIN_PLANE_SHARE * depths.len() as f64 {
        return None;
    }
    let mut on_plane: Vec<f64> = depths
        .iter()
        .copied()
        .filter(|&d| bin_of(d).abs_diff(peak) <= 1)
        .collect();
    let middle = on_plane.len() / 2;
    let (_, median, _) = on_plane.select_nth_unstable_by(middle, f64::total_cmp);
    Some(*median)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on the rectangle x in [x0, x1], y = y, z in [z0, z1] (a wall patch or a cabinet's
    /// front), every 4 cm.
    fn wall_y(y: f32, (x0, x1): (f32, f32), (z0, z1): (f32, f32)) -> Vec<Vec3> {
        let mut points = Vec::new();
        let mut x = x0;
        while x <= x1 {
            let mut z = z0;
            while z <= z1 {
                points.push(Vec3::new(x, y, z));
                z += 0.04;
            }
            x += 0.04;
        }
        points
    }

    fn floor() -> Vec<Vec3> {
        let mut points = Vec::new();
        for i in 0..100 {
            for j in 0..100 {
                points.push(Vec3::new(i as f32 * 0.05, j as f32 * 0.05, 0.0));
            }
        }
        points
    }

    /// A room's floor and its wall at y = 0, except where a cabinet 0.8 m wide (x 2–2.8) and
    /// 1.8 m tall hides it.
    fn room_with_a_hidden_wall() -> Walls {
        let mut points = floor();
        points.extend(wall_y(0.0, (0.0, 2.0), (0.0, 2.6)));
        points.extend(wall_y(0.0, (2.8, 5.0), (0.0, 2.6)));
        points.extend(wall_y(0.0, (2.0, 2.8), (1.8, 2.6)));
        Walls::new(points)
    }

    fn front_face(y: f32) -> OrientedBox {
        OrientedBox::fit(&wall_y(y, (2.0, 2.8), (0.0, 1.8)), 0.0)
    }

    #[test]
    fn a_cabinet_seen_only_from_the_front_is_completed_back_to_the_wall_behind_it() {
        let walls = room_with_a_hidden_wall();
        let fitted = front_face(0.5);
        let thin = fitted.size.x.min(fitted.size.y);
        assert!(thin < 0.01, "a surface: {fitted:?}");
        let completed = walls.complete(fitted);
        let (lo, hi) = (
            completed.centre - completed.size / 2.0,
            completed.centre + completed.size / 2.0,
        );
        // Canonical yaw 0 or a quarter turn: read the extent along world y either way.
        let depth = if completed.yaw.abs() < 1e-6 {
            (lo.y, hi.y)
        } else {
            (
                completed.centre.y - completed.size.x / 2.0,
                completed.centre.y + completed.size.x / 2.0,
            )
        };
        assert!(
            (depth.0 - 0.0).abs() < 0.03 && (depth.1 - 0.5).abs() < 0.03,
            "{completed:?}"
        );
        assert!(
            (hi.z - 1.8).abs() < 0.05 && lo.z.abs() < 0.05,
            "height kept: {completed:?}"
        );
        assert!(completed.iou(&fitted) < 0.1, "a different box");
        assert!(completed.centre.is_finite() && completed.size.is_finite());
    }

    #[test]
    fn a_surface_far_from_any_wall_a_raised_one_and_a_solid_box_keep_their_fitted_boxes() {
        let walls = room_with_a_hidden_wall();
        // 1.5 m in front of the wall: beyond MAX_BACK_M.
        let free = front_face(1.5);
        assert_eq!(walls.complete(free), free);
        // A screen on a desk: its bottom 0.75 m above the floor.
        let screen = OrientedBox::fit(&wall_y(0.4, (2.0, 2.6), (0.75, 1.15)), 0.0);
        assert_eq!(walls.complete(screen), screen);
        // A box with depth is what it is.
        let mut solid = wall_y(0.4, (2.0, 2.6), (0.0, 0.8));
        solid.extend(wall_y(0.7, (2.0, 2.6), (0.0, 0.8)));
        let solid = OrientedBox::fit(&solid, 0.0);
        assert_eq!(walls.complete(solid), solid);
    }

    #[test]
    fn without_structure_or_with_degenerate_input_boxes_stay_finite_and_unchanged() {
        let empty = Walls::new(Vec::new());
        let fitted = front_face(0.5);
        assert_eq!(empty.complete(fitted), fitted);
        let walls = Walls::new(vec![Vec3::NAN, Vec3::splat(f32::INFINITY)]);
        assert_eq!(walls.complete(fitted), fitted);
        let walls = room_with_a_hidden_wall();
        for degenerate in [
            OrientedBox::fit(&[], 0.0),
            OrientedBox::fit(&[Vec3::new(2.0, 0.5, 0.0)], 0.0),
            // A surface of zero width: no face to complete.
            OrientedBox::fit(&wall_y(0.5, (2.0, 2.0), (0.0, 1.8)), 0.0),
        ] {
            let completed = walls.complete(degenerate);
            assert!(
                completed == degenerate
                    || (completed.centre.is_finite() && completed.size.is_finite()),
                "{degenerate:?} -> {completed:?}"
            );
        }
    }
}

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

use glam::{DVec2, Vec3};

use super::{amodal, Instance, SceneMap};
use crate::group::cleaning::floor_height;
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
pub const ON_FLOOR_M: f64 = 0.2;
/// A horizontal surface this close to the floor is the floor.
pub const FLOOR_PATCH_M: f64 = 0.05;
/// A box whose top is at most this far above the floor is the floor (a patch of it thickened by
/// noise, or the feet of furniture beside it), whatever it is named: no object of the
/// vocabulary is that low (the lowest top in 200 training rooms is a box's, 0.26 m up; a test
/// checks it).
pub const FLOOR_TOP_M: f64 = 0.12;
/// A raised horizontal surface with its top between these heights above the floor is a
/// worktop (table, desk, bed, counter), completed down to the floor; higher ones are shelves.
pub const MIN_WORKTOP_M: f64 = 0.3;
pub const MAX_WORKTOP_M: f64 = 1.2;
/// A vertical surface whose wall points lie within this of its own plane is in the wall.
const IN_PLANE_M: f64 = 0.03;
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

    /// The floor's height, when the structure shows one.
    pub fn floor(&self) -> Option<f32> {
        self.floor
    }

    /// From the Gaussians' centres of the map's structure instances.
    pub fn new(points: Vec<Vec3>) -> Self {
        let points: Vec<Vec3> = points.into_iter().filter(|p| p.is_finite()).collect();
        let floor = floor_height(&points);
        Self { points, floor }
    }

    /// The structure points over `placed`, at most [`BESIDE_M`] above its top and within `reach`
    /// of its centre horizontally, brought down to its mid-height: the wall a piece of furniture
    /// stands against is hidden behind it at its own height and seen above it, as
    /// [`Walls::wall_towards`] reads it.
    pub fn over(&self, placed: &OrientedBox, reach: f32) -> impl Iterator<Item = Vec3> + '_ {
        let (_, top) = z_range(placed);
        let (low, high) = (top as f32, (top + BESIDE_M) as f32);
        let centre = placed.centre.as_vec3();
        self.points
            .iter()
            .filter(move |p| {
                p.z > low
                    && p.z <= high
                    && (p.x - centre.x).abs() <= reach
                    && (p.y - centre.y).abs() <= reach
            })
            .map(move |p| Vec3::new(p.x, p.y, centre.z))
    }

    /// Where a box thin along some axis (a surface seen from one side) belongs: `None` when it
    /// is the room's own surface (a patch lying on the floor or anything whose top is within
    /// [`FLOOR_TOP_M`] of it, or a vertical patch in the plane
    /// of the wall around it: a visible face flush with a wall is that wall, as a face an
    /// object turns to a wall is hidden); a horizontal surface raised to worktop height is
    /// completed down to the floor (a table or bed top whose legs or sides the camera grouped
    /// apart or never saw: furniture stands on the floor); a vertical surface standing on the
    /// floor is completed back to the wall behind it ([`Walls::complete`]); otherwise `fitted`.
    pub fn place(&self, fitted: OrientedBox) -> Option<OrientedBox> {
        let Some(floor) = self.floor.map(f64::from) else {
            return Some(fitted);
        };
        let size = fitted.size;
        if !(fitted.centre.is_finite() && size.is_finite()) {
            return Some(fitted);
        }
        let (bottom, top) = z_range(&fitted);
        if top - floor <= FLOOR_TOP_M {
            return None;
        }
        if size.z < SLAB_M {
            if (fitted.centre.z - floor).abs() <= FLOOR_PATCH_M {
                return None;
            }
            let raised = bottom - floor;
            if size.x >= MIN_FACE_M
                && size.y >= MIN_FACE_M
                && (MIN_WORKTOP_M..=MAX_WORKTOP_M).contains(&(top - floor))
                && raised > 0.0
            {
                let mut supported = fitted;
                supported.size.z = top - floor;
                supported.centre.z = (top + floor) / 2.0;
                return Some(supported);
            }
            return Some(fitted);
        }
        if size.x.min(size.y) >= SLAB_M {
            return Some(fitted);
        }
        // A face with a wall plane parallel behind it stands in front of that wall (its own
        // plane may still hold structure: a fridge's door the semantic model calls wall). The
        // plane is searched once, for both questions.
        let wall = self.wall_behind(&fitted);
        if wall.is_none() && self.in_wall_plane(&fitted) {
            return None;
        }
        Some(if self.completes(&fitted) {
            complete_to_wall(fitted, wall)
        } else {
            fitted
        })
    }

    /// Whether the vertical surface `fitted` (thin along one horizontal axis) lies in the plane
    /// of the structure around it: the fullest plane among the wall points beside, above and
    /// below it (within [`MAX_BACK_M`] either side) is its own.
    fn in_wall_plane(&self, fitted: &OrientedBox) -> bool {
        let Some(floor) = self.floor.map(f64::from) else {
            return false;
        };
        let (bottom, top) = z_range(fitted);
        let low = (floor + ON_FLOOR_M).max(bottom - BESIDE_M);
        let (_, thin, depths) = self.depths_beside(fitted, (low, top + BESIDE_M));
        let near: Vec<f64> = depths
            .into_iter()
            .map(f64::abs)
            .filter(|d| *d <= MAX_BACK_M)
            .collect();
        let in_plane = near
            .iter()
            .filter(|d| **d <= thin / 2.0 + IN_PLANE_M)
            .count();
        in_plane >= MIN_PLANE_POINTS && (in_plane as f64) >= MIN_PLANE_SHARE * near.len() as f64
    }

    /// Signed distances from the vertical surface `fitted`'s mid-plane, along its normal, of the
    /// structure points at heights within `heights` and beside it (within [`BESIDE_M`] of its
    /// width), with the normal and the surface's thickness.
    fn depths_beside(
        &self,
        fitted: &OrientedBox,
        (low, high): (f64, f64),
    ) -> (DVec2, f64, Vec<f64>) {
        let (normal, along, thin, width) = face_frame(fitted);
        let centre = fitted.centre.truncate();
        let depths = self
            .points
            .iter()
            .filter(|p| (low..=high).contains(&f64::from(p.z)))
            .map(|p| p.truncate().as_dvec2() - centre)
            .filter(|d| d.dot(along).abs() <= width / 2.0 + BESIDE_M)
            .map(|d| d.dot(normal))
            .collect();
        (normal, thin, depths)
    }

    /// The nearest wall plane parallel to the vertical surface `fitted` (thin along one
    /// horizontal axis) within [`MAX_BACK_M`] on either side of it, read from the structure
    /// points beside and above it (the floor and points far to the side left out): the surface's
    /// normal, and the side (+1 along the normal, -1 against it) and distance of the plane.
    fn wall_behind(&self, fitted: &OrientedBox) -> Option<(DVec2, (f64, f64))> {
        let (bottom, top) = z_range(fitted);
        let (normal, thin, depths) =
            self.depths_beside(fitted, (bottom + ON_FLOOR_M, top + BESIDE_M));
        let off_plane = |d: f64| d > thin / 2.0 + BIN_M && d <= MAX_BACK_M;
        let ahead: Vec<f64> = depths.iter().copied().filter(|&d| off_plane(d)).collect();
        let behind: Vec<f64> = depths
            .iter()
            .map(|d| -d)
            .filter(|&d| off_plane(d))
            .collect();
        // The nearer side that holds a wall plane.
        [(1.0, plane_depth(&ahead)), (-1.0, plane_depth(&behind))]
            .into_iter()
            .filter_map(|(sign, depth)| depth.map(|d| (sign, d)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|wall| (normal, wall))
    }

    /// The distance from the vertical surface `fitted` (thin along one horizontal axis) to a wall
    /// plane parallel to it on the side `towards` points to, within [`MAX_BACK_M`], read as
    /// [`Walls::wall_behind`] reads it (structure beside and above the surface).
    pub fn wall_towards(&self, fitted: &OrientedBox, towards: DVec2) -> Option<f64> {
        let (bottom, top) = z_range(fitted);
        let (normal, thin, depths) =
            self.depths_beside(fitted, (bottom + ON_FLOOR_M, top + BESIDE_M));
        let side = normal.dot(towards).signum();
        let beyond: Vec<f64> = depths
            .into_iter()
            .map(|d| d * side)
            .filter(|&d| d > thin / 2.0 + BIN_M && d <= MAX_BACK_M)
            .collect();
        plane_depth(&beyond)
    }

    /// `fitted` completed back to the wall behind it when it is a vertical surface standing on
    /// the floor in front of a wall; otherwise `fitted` as it is.
    pub fn complete(&self, fitted: OrientedBox) -> OrientedBox {
        if !self.completes(&fitted) {
            return fitted;
        }
        let wall = self.wall_behind(&fitted);
        complete_to_wall(fitted, wall)
    }

    /// Whether [`Walls::complete`] may change `fitted`: a vertical surface standing on the floor.
    fn completes(&self, fitted: &OrientedBox) -> bool {
        self.floor.is_some_and(|floor| {
            let on_floor = z_range(fitted).0 <= f64::from(floor) + ON_FLOOR_M;
            fitted.centre.is_finite() && is_surface(fitted) && on_floor
        })
    }
}

/// `fitted` extended back to `wall` ([`Walls::wall_behind`] of it), or as it is without one.
fn complete_to_wall(fitted: OrientedBox, wall: Option<(DVec2, (f64, f64))>) -> OrientedBox {
    // The object fills the space back to the nearer wall plane.
    let Some((normal, (sign, depth))) = wall else {
        return fitted;
    };
    let thin = fitted.size.x.min(fitted.size.y);
    // Front face at -thin/2 (away from the wall), back at the wall: along `sign * normal`.
    let shift = sign * (depth - thin / 2.0) / 2.0;
    amodal::deepened(fitted, normal * shift, depth + thin / 2.0)
}

/// A box's bottom and top heights.
fn z_range(b: &OrientedBox) -> (f64, f64) {
    (b.centre.z - b.size.z / 2.0, b.centre.z + b.size.z / 2.0)
}

/// A box's frame on the ground as a vertical surface: its normal (the thinner horizontal axis),
/// the axis along it, and its thickness and width.
fn face_frame(fitted: &OrientedBox) -> (DVec2, DVec2, f64, f64) {
    let (c, s) = (fitted.yaw.cos(), fitted.yaw.sin());
    let (x_axis, y_axis) = (DVec2::new(c, s), DVec2::new(-s, c));
    let size = fitted.size;
    if size.x <= size.y {
        (x_axis, y_axis, size.x, size.y)
    } else {
        (y_axis, x_axis, size.y, size.x)
    }
}

/// Whether `fitted` is a vertical surface seen from one side (thin along one horizontal axis):
/// the only boxes [`Walls::complete`] may change.
pub fn is_surface(fitted: &OrientedBox) -> bool {
    let s = fitted.size;
    s.is_finite()
        && s.z >= MIN_FACE_M
        && ((s.x < SLAB_M && s.y >= MIN_FACE_M) || (s.y < SLAB_M && s.x >= MIN_FACE_M))
}

/// Whether `fitted` is thin along some axis: a surface seen from one side, the only boxes
/// [`Walls::place`] may change or call structure, so callers build [`Walls`] only for them.
pub fn is_thin(fitted: &OrientedBox) -> bool {
    let s = fitted.size;
    s.is_finite() && s.min_element() < SLAB_M
}

/// Whether `fitted` is low enough that its top could lie within [`FLOOR_TOP_M`] of the floor
/// (depth noise may draw its bottom as far below the floor): the other boxes
/// [`Walls::place`] may call structure.
pub fn is_low(fitted: &OrientedBox) -> bool {
    fitted.size.z.is_finite() && fitted.size.z <= 2.0 * FLOOR_TOP_M
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
    // The listing's completions are tested here, beside the walls they complete against.
    use crate::graph::listing::{object_list, seen_from_one_side};
    use crate::group::semantics::{ClassPriors, Vocabulary};

    /// Points every 4 cm over the rectangle [a0, a1] × [b0, b1], placed by `at`.
    fn grid(
        (a0, a1): (f32, f32),
        (b0, b1): (f32, f32),
        at: impl Fn(f32, f32) -> Vec3,
    ) -> Vec<Vec3> {
        let mut points = Vec::new();
        let mut a = a0;
        while a <= a1 {
            let mut b = b0;
            while b <= b1 {
                points.push(at(a, b));
                b += 0.04;
            }
            a += 0.04;
        }
        points
    }

    /// Points on the rectangle x in [x0, x1], y = y, z in [z0, z1] (a wall patch or a cabinet's
    /// front), every 4 cm.
    fn wall_y(y: f32, x: (f32, f32), z: (f32, f32)) -> Vec<Vec3> {
        grid(x, z, |x, z| Vec3::new(x, y, z))
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

    /// An instance of `points` named by `prototype`, seen from `viewpoint` through range noise
    /// `sigma` (0: a clean camera).
    fn instance_of(id: &str, points: &[Vec3], prototype: [f32; 3], sigma: f32) -> Instance {
        Instance {
            viewpoint: Some(Vec3::new(2.4, 3.5, 1.2)),
            viewpoint_weight: 1.0,
            range_noise_m: sigma,
            range_noise_weight: f32::from(sigma > 0.0),
            ..Instance::of_points(id, points, &prototype)
        }
    }

    #[test]
    fn a_face_seen_through_range_noise_is_completed_from_its_surface_and_a_round_object_keeps_its_points_box(
    ) {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let vocabulary = Vocabulary {
            phrases: vec!["cabinet".into(), "plant".into(), "other".into()],
            embeddings: vec![
                vec![1.0, 0.0, 0.0],
                vec![0.0, 1.0, 0.0],
                vec![0.0, 0.0, 1.0],
            ],
            temperature: 0.05,
            priors: crate::group::semantics::ClassPriors::builtin(),
        };
        let sigma = 0.06;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let noise = Normal::new(0.0f32, sigma).unwrap();
        // The room of the hidden wall; a cabinet's front at y = 0.5 measured three times along
        // y; a plant (a ball of 0.2 m radius) in the open, its near side measured the same way.
        let mut structure = floor();
        structure.extend(wall_y(0.0, (0.0, 2.0), (0.0, 2.6)));
        structure.extend(wall_y(0.0, (2.8, 5.0), (0.0, 2.6)));
        structure.extend(wall_y(0.0, (2.0, 2.8), (1.8, 2.6)));
        // A face at y = 0.5 over `x` and `z`, measured three times along y.
        let mut measured_face = |x: (f32, f32), z: (f32, f32)| -> Vec<Vec3> {
            (0..3)
                .flat_map(|_| wall_y(0.5, x, z))
                .map(|p| p + Vec3::Y * noise.sample(&mut rng))
                .collect()
        };
        let front = measured_face((2.0, 2.8), (0.0, 1.8));
        // And a flat face named by a name with no typical depth (a bin's near side, which the
        // noise made flat), standing before the wall too.
        let flat_bin = measured_face((3.4, 3.8), (0.0, 0.6));
        let mut ball = Vec::new();
        for _ in 0..3 {
            for i in 0..24 {
                for k in 1..12 {
                    let (a, b) = (i as f32 * std::f32::consts::PI / 24.0, k as f32 * 0.26);
                    let on = Vec3::new(a.cos() * b.sin(), a.sin() * b.sin(), b.cos()) * 0.2;
                    ball.push(Vec3::new(1.0, 2.0, 0.6) + on + Vec3::Y * noise.sample(&mut rng));
                }
            }
        }
        let map = SceneMap {
            instances: vec![
                instance_of("room", &structure, [0.0, 0.0, 1.0], 0.0),
                instance_of("cabinet", &front, [1.0, 0.0, 0.0], sigma),
                instance_of("plant", &ball, [0.0, 1.0, 0.0], sigma),
                instance_of("flat", &flat_bin, [0.0, 1.0, 0.0], sigma),
            ],
            ..SceneMap::default()
        };
        let with_surfaces = object_list(&map, Some(&vocabulary), |i, box_like| i.fitted(box_like));
        let points_only = object_list(&map, Some(&vocabulary), |i, _| i.oriented_box().into());
        let thin = |b: &OrientedBox| b.size.x.min(b.size.y);
        assert_eq!((with_surfaces.len(), points_only.len()), (3, 3));
        let (cabinet, cabinet_points) = (with_surfaces[0].bbox, points_only[0].bbox);
        // The noisy slab is too deep for a face and stays as deep as the noise ...
        assert!(
            (0.15..0.4).contains(&thin(&cabinet_points)),
            "{cabinet_points:?}"
        );
        // ... while its surface is completed back to the wall: y from 0 to about 0.5.
        assert!((thin(&cabinet) - 0.5).abs() < 0.08, "{cabinet:?}");
        assert!((cabinet.centre.y - 0.25).abs() < 0.06, "{cabinet:?}");
        assert!(cabinet.centre.is_finite() && cabinet.size.is_finite());
        // The plant's box is its points' box: no completion, no plane fitted over it; so is
        // the flat face of a name with no typical depth (no furniture a face stands for).
        assert_eq!(with_surfaces[1].bbox, points_only[1].bbox);
        assert_eq!(with_surfaces[2].bbox, points_only[2].bbox);
        assert!(
            thin(&with_surfaces[2].bbox) < 0.4,
            "{:?}",
            with_surfaces[2].bbox
        );
    }

    #[test]
    fn a_face_completed_away_from_the_viewer_never_goes_through_the_wall_behind_it() {
        // The room of the hidden wall (y = 0); the viewer at y = 3.5 (instance_of). Faces 0.45 m
        // wide, 0.5 to 0.9 m up (a chair's backrest seen over a table), named chair (typical
        // depth 0.45 m, none in the training rooms shallower than 0.38 m).
        let walls = room_with_a_hidden_wall();
        let backrest = |y: f32| {
            instance_of(
                "chair",
                &wall_y(y, (2.2, 2.65), (0.5, 0.9)),
                [1.0, 0.0, 0.0],
                0.0,
            )
        };
        // The box's extent along world y (any yaw).
        let extent_y = |b: &OrientedBox| {
            let half = (b.yaw.sin().abs() * b.size.x + b.yaw.cos().abs() * b.size.y) / 2.0;
            (b.centre.y - half, b.centre.y + half)
        };
        let complete = |y: f32| {
            let instance = backrest(y);
            let face = instance.oriented_box();
            let priors = ClassPriors::builtin();
            seen_from_one_side(face, &instance, Some(("chair", &priors)), || &walls)
        };
        // 1.5 m out in the room: the chair lies behind its face, 0.45 m deep.
        let (near, far) = extent_y(&complete(1.5));
        assert!(
            (near - 1.05).abs() < 0.02 && (far - 1.5).abs() < 0.02,
            "{near} {far}"
        );
        // 0.3 m from the wall: no chair fits behind it, so the face is the chair's back and the
        // seat is on the viewer's side.
        let (near, far) = extent_y(&complete(0.3));
        assert!(
            (near - 0.3).abs() < 0.02 && (far - 0.75).abs() < 0.02,
            "{near} {far}"
        );
        // 0.4 m from the wall: a chair as shallow as the shallowest fills the space to the wall.
        let (near, far) = extent_y(&complete(0.4));
        assert!(
            near.abs() < 0.02 && (far - 0.4).abs() < 0.02,
            "{near} {far}"
        );
        // Without a name with a depth, the face is what it is.
        let instance = backrest(0.3);
        let face = instance.oriented_box();
        assert_eq!(
            seen_from_one_side(
                face,
                &instance,
                Some(("lamp", &ClassPriors::builtin())),
                || &walls
            ),
            face
        );
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

    /// Points on the horizontal rectangle x in [x0, x1], y in [y0, y1] at height z, every 4 cm.
    fn top(z: f32, x: (f32, f32), y: (f32, f32)) -> Vec<Vec3> {
        grid(x, y, |x, y| Vec3::new(x, y, z))
    }

    #[test]
    fn a_table_top_seen_without_its_legs_stands_on_the_floor() {
        let walls = room_with_a_hidden_wall();
        let fitted = OrientedBox::fit(&top(0.75, (1.0, 2.2), (1.0, 1.8)), 0.0);
        assert!(fitted.size.z < 0.01, "a surface: {fitted:?}");
        let placed = walls.place(fitted).expect("an object");
        let (lo, hi) = (
            placed.centre - placed.size / 2.0,
            placed.centre + placed.size / 2.0,
        );
        assert!(
            lo.z.abs() < 0.02 && (hi.z - 0.75).abs() < 0.02,
            "{placed:?}"
        );
        assert!(
            (placed.footprint_area() - fitted.footprint_area()).abs() < 1e-9,
            "the footprint kept: {placed:?}"
        );
        // A shelf board above worktop height and a board a few centimetres up (a rug, a mat)
        // stay what was seen.
        for z in [1.6, 0.15] {
            let fitted = OrientedBox::fit(&top(z, (1.0, 2.2), (1.0, 1.8)), 0.0);
            assert_eq!(walls.place(fitted), Some(fitted), "at {z} m");
        }
    }

    #[test]
    fn patches_of_the_floor_and_of_a_wall_s_plane_are_the_room_not_objects() {
        let walls = room_with_a_hidden_wall();
        let on_floor = OrientedBox::fit(&top(0.01, (1.0, 2.2), (1.0, 1.8)), 0.0);
        assert_eq!(walls.place(on_floor), None);
        // A piece of the wall at y = 0 (beside the cabinet), named as an object.
        let wall_piece = OrientedBox::fit(&wall_y(0.005, (3.2, 3.8), (0.8, 1.6)), 0.0);
        assert!(is_thin(&wall_piece));
        assert_eq!(walls.place(wall_piece), None);
        // The cabinet's front half a metre out is an object, completed back to the wall.
        let front = front_face(0.5);
        assert_eq!(walls.place(front), Some(walls.complete(front)));
        assert_ne!(walls.complete(front), front);
        // A fridge half a metre out whose upper door the semantic model calls wall: its plane
        // holds structure, but a wall stands parallel behind it, so it is furniture.
        // The wall is seen only in a strip beside it, so the door dominates its surroundings.
        let mut points = floor();
        points.extend(wall_y(0.0, (1.6, 2.0), (0.0, 2.6)));
        points.extend(wall_y(0.5, (2.0, 2.8), (1.0, 1.8)));
        let door_as_wall = Walls::new(points);
        let lower_door = OrientedBox::fit(&wall_y(0.5, (2.0, 2.8), (0.0, 0.96)), 0.0);
        let placed = door_as_wall.place(lower_door).expect("furniture");
        assert!(
            placed.size.x.min(placed.size.y) > 0.45,
            "completed: {placed:?}"
        );
        // A patch of the floor 9 cm thick (noise, or a chair's feet on it), named as an
        // object, is the floor; a box on the floor 0.25 m tall is an object.
        let thick_patch = OrientedBox::fit(
            &[
                top(0.0, (1.0, 1.8), (1.0, 1.75)),
                top(0.087, (1.0, 1.8), (1.0, 1.75)),
            ]
            .concat(),
            0.0,
        );
        assert!(!is_thin(&thick_patch) && is_low(&thick_patch));
        assert_eq!(walls.place(thick_patch), None);
        let low_box = OrientedBox::fit(
            &[
                top(0.0, (1.0, 1.4), (1.0, 1.3)),
                top(0.25, (1.0, 1.4), (1.0, 1.3)),
            ]
            .concat(),
            0.0,
        );
        assert_eq!(walls.place(low_box), Some(low_box));
        // A box with depth is never the room's, even on the floor against the wall.
        let mut solid = wall_y(0.02, (3.2, 3.8), (0.0, 0.8));
        solid.extend(wall_y(0.4, (3.2, 3.8), (0.0, 0.8)));
        let solid = OrientedBox::fit(&solid, 0.0);
        assert!(!is_thin(&solid));
        assert_eq!(walls.place(solid), Some(solid));
    }

    #[test]
    fn without_structure_or_with_degenerate_input_boxes_stay_finite_and_unchanged() {
        let empty = Walls::new(Vec::new());
        let fitted = front_face(0.5);
        assert_eq!(empty.complete(fitted), fitted);
        // Without a floor nothing is known of the room: every box is an object, as fitted.
        let table_top = OrientedBox::fit(&top(0.75, (1.0, 2.2), (1.0, 1.8)), 0.0);
        assert_eq!(empty.place(table_top), Some(table_top));
        assert_eq!(empty.place(fitted), Some(fitted));
        let walls = Walls::new(vec![Vec3::NAN, Vec3::splat(f32::INFINITY)]);
        assert_eq!(walls.complete(fitted), fitted);
        let walls = room_with_a_hidden_wall();
        for degenerate in [
            OrientedBox::fit(&[], 0.0),
            OrientedBox::fit(&[Vec3::new(2.0, 0.5, 0.0)], 0.0),
            // A surface of zero width: no face to complete.
            OrientedBox::fit(&wall_y(0.5, (2.0, 2.0), (0.0, 1.8)), 0.0),
        ] {
            let placed = walls.place(degenerate);
            assert!(
                placed.is_none_or(|b| b.centre.is_finite() && b.size.is_finite()),
                "{degenerate:?} -> {placed:?}"
            );
            let completed = walls.complete(degenerate);
            assert!(
                completed == degenerate
                    || (completed.centre.is_finite() && completed.size.is_finite()),
                "{degenerate:?} -> {completed:?}"
            );
        }
    }
}

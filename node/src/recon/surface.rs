//! Surfaces out of a depth camera's noise. A consumer depth camera's range error grows with the
//! square of the range (σ = σ₁ · z², [`super::depth_noise`]): a cabinet's front seen from 3 m
//! under 6 mm at 1 m is a slab of points ±11 cm deep, and the box fitted to it is that deep. The
//! rules that complete a face to its object (back to the wall behind it, or to its name's
//! typical depth) then see a thick object and leave it, so a real camera loses the boxes a clean
//! one gets right.
//!
//! The thinning is a moving-least-squares projection (Alexa et al., "Computing and rendering
//! point set surfaces", 2003, in its simplest form): each point moves onto the plane fitted to
//! its neighbours within a radius of a few σ, where those neighbours form a plane (their
//! smallest spread well below the other two). A face's repeated noisy measurements collapse to
//! their mean surface; edges and thin parts (a pole, a leg: no plane) stay as they are. Only the
//! points a box is fitted to are thinned: the map keeps what the camera measured.
//!
//! Where it is used ([`crate::graph::listing::object_list`]): only a face completion of box-like
//! furniture is taken from the thinned points. Fitting every box to them was measured and not
//! kept (`eval map --effects realistic`, benchmark 0-9, paired): mean IoU +0.026 (beyond the
//! spread; cabinets, chairs and bins fitted tighter) but recall@0.25 -1.3, @0.5 +0.0, precision
//! -1.4: a plane over a curved surface shrinks plants and toilets, and a pillow's thinned top
//! became a worktop completed down to the floor.

use glam::{DVec3, Vec3};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rustc_hash::FxHashMap;

/// Neighbourhood radius in noise sigmas: a disc of radius r spreads its points by r / 2 in the
/// plane, against σ across it, so at 4 σ the plane stands out of the noise.
pub const RADIUS_SIGMAS: f32 = 4.0;
/// The neighbourhood radius at least (two of the map's 5 cm voxels) and at most (a small
/// object's size: beyond it corners round off).
pub const MIN_RADIUS_M: f32 = 0.1;
pub const MAX_RADIUS_M: f32 = 0.3;
/// Projections in turn: each thins what the one before left, so the next finds its plane
/// clearer (a sphere of 3 σ around a point 2 σ off the surface holds more of its own side: one
/// pass takes it to 0.9 σ, three to the surface within a few millimetres).
pub const PASSES: usize = 3;
/// Neighbours a plane is fitted to, at least.
const MIN_NEIGHBOURS: usize = 8;
/// A neighbourhood is a plane when its middle spread is at least this many times its smallest
/// (variances): a noisy plane in a 4 σ disc gives about 4, a line or a blob about 1.
const PLANE_RATIO: f64 = 2.0;

/// The neighbourhood radius for range noise `sigma_m`, clamped to the limits above; `None`
/// (nothing to thin) when the noise is not finite and positive.
pub fn thinning_radius(sigma_m: f32) -> Option<f32> {
    (sigma_m.is_finite() && sigma_m > 0.0)
        .then(|| (RADIUS_SIGMAS * sigma_m).clamp(MIN_RADIUS_M, MAX_RADIUS_M))
}

/// `points` each moved onto the plane of its neighbours within `radius` where they form one
/// (see the module notes). Non-finite points are kept as they are and never used as neighbours;
/// a non-finite or non-positive radius returns the points unchanged.
pub fn thin_to_surfaces(points: &[Vec3], radius: f32) -> Vec<Vec3> {
    let mut thinned = points.to_vec();
    if !(radius.is_finite() && radius > 0.0) || points.len() < MIN_NEIGHBOURS {
        return thinned;
    }
    for _ in 0..PASSES {
        thinned = project_once(&thinned, radius);
    }
    thinned
}

/// One projection of every point onto its neighbours' plane.
fn project_once(points: &[Vec3], radius: f32) -> Vec<Vec3> {
    let cell = |p: Vec3| {
        let c = (p / radius).floor();
        (c.x as i32, c.y as i32, c.z as i32)
    };
    let mut grid: FxHashMap<(i32, i32, i32), Vec<u32>> = FxHashMap::default();
    for (i, p) in points.iter().enumerate() {
        if p.is_finite() {
            grid.entry(cell(*p)).or_default().push(i as u32);
        }
    }
    let r2 = radius * radius;
    let mut neighbours: Vec<DVec3> = Vec::new();
    points
        .iter()
        .map(|&p| {
            if !p.is_finite() {
                return p;
            }
            neighbours.clear();
            let (cx, cy, cz) = cell(p);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        let Some(members) = grid.get(&(cx + dx, cy + dy, cz + dz)) else {
                            continue;
                        };
                        neighbours.extend(
                            members
                                .iter()
                                .map(|&j| points[j as usize])
                                .filter(|q| q.distance_squared(p) <= r2)
                                .map(Vec3::as_dvec3),
                        );
                    }
                }
            }
            project_onto_plane(p.as_dvec3(), &neighbours).map_or(p, |q| q.as_vec3())
        })
        .collect()
}

/// `p` projected onto the least-squares plane of `neighbours`, if they form a plane.
fn project_onto_plane(p: DVec3, neighbours: &[DVec3]) -> Option<DVec3> {
    if neighbours.len() < MIN_NEIGHBOURS {
        return None;
    }
    let centre = neighbours.iter().sum::<DVec3>() / neighbours.len() as f64;
    let mut covariance = Matrix3::<f64>::zeros();
    for q in neighbours {
        let d = Vector3::new(q.x - centre.x, q.y - centre.y, q.z - centre.z);
        covariance += d * d.transpose();
    }
    let eigen = SymmetricEigen::new(covariance / neighbours.len() as f64);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let (smallest, middle) = (eigen.eigenvalues[order[0]], eigen.eigenvalues[order[1]]);
    if !(smallest.is_finite() && middle.is_finite()) || middle < PLANE_RATIO * smallest.max(0.0) {
        return None;
    }
    let n = eigen.eigenvectors.column(order[0]);
    let normal = DVec3::new(n[0], n[1], n[2]);
    if !normal.is_finite() || normal.length_squared() < 0.5 {
        return None;
    }
    let normal = normal.normalize();
    let projected = p - normal * (p - centre).dot(normal);
    projected.is_finite().then_some(projected)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A 0.8 × 1.6 m vertical face in the plane y = 2, sampled every 5 cm, each sample measured
    /// `repeats` times with range noise `sigma` along y (the camera looks along y).
    fn noisy_face(sigma: f32, repeats: usize, seed: u64) -> Vec<Vec3> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut points = Vec::new();
        for _ in 0..repeats {
            for i in 0..16 {
                for k in 0..32 {
                    let (x, z) = (i as f32 * 0.05, k as f32 * 0.05);
                    points.push(Vec3::new(x, 2.0 + noise.sample(&mut rng), z));
                }
            }
        }
        points
    }

    fn spread_along_y(points: &[Vec3]) -> f32 {
        let mean = points.iter().map(|p| p.y).sum::<f32>() / points.len() as f32;
        (points.iter().map(|p| (p.y - mean).powi(2)).sum::<f32>() / points.len() as f32).sqrt()
    }

    #[test]
    fn a_face_seen_through_range_noise_thins_to_its_plane_and_keeps_its_extent() {
        let sigma = 0.05;
        let face = noisy_face(sigma, 3, 7);
        let thinned = thin_to_surfaces(&face, thinning_radius(sigma).unwrap());
        let before = spread_along_y(&face);
        let after = spread_along_y(&thinned);
        assert!(before > 0.045, "{before}");
        assert!(after < 0.3 * before, "spread {before} -> {after}");
        let mean_y = thinned.iter().map(|p| p.y).sum::<f32>() / thinned.len() as f32;
        assert!((mean_y - 2.0).abs() < 0.01, "{mean_y}");
        // Its width and height stay (within the 5 cm sampling).
        let (lo, hi) = thinned.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        );
        assert!(hi.x - lo.x > 0.7 && hi.z - lo.z > 1.5, "{lo} {hi}");
    }

    #[test]
    fn a_pole_is_not_a_plane_and_keeps_its_points() {
        let pole: Vec<Vec3> = (0..40)
            .map(|k| Vec3::new(1.0, 1.0, k as f32 * 0.03))
            .collect();
        assert_eq!(thin_to_surfaces(&pole, 0.2), pole);
    }

    #[test]
    fn degenerate_inputs_come_back_unchanged_and_finite() {
        // Identical points (zero spread), too few points, a NaN among them, bad radii.
        let same = vec![Vec3::new(0.5, 0.5, 0.5); 20];
        assert_eq!(thin_to_surfaces(&same, 0.1), same);
        let few = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
        assert_eq!(thin_to_surfaces(&few, 0.1), few);
        let mut with_nan = noisy_face(0.02, 1, 3);
        with_nan[5] = Vec3::NAN;
        let thinned = thin_to_surfaces(&with_nan, 0.1);
        assert!(thinned[5].is_nan());
        assert!(thinned
            .iter()
            .enumerate()
            .all(|(i, p)| i == 5 || p.is_finite()));
        for radius in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(thin_to_surfaces(&few, radius), few);
        }
        assert_eq!(thinning_radius(0.0), None);
        assert_eq!(thinning_radius(f32::NAN), None);
        assert_eq!(thinning_radius(1.0), Some(MAX_RADIUS_M));
        assert_eq!(thinning_radius(0.001), Some(MIN_RADIUS_M));
    }
}

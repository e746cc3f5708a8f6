//! Round objects seen from one side: a camera sees about half of a trash bin, a lamp shade or a
//! plant pot, and a box fitted to those points is the visible half (about half the object's
//! depth, 3D IoU ≤ 0.5 against the whole object). When the footprint of the points is a circular
//! arc, the circle through it says where the unseen half is, and the box is completed to the
//! circle's square. Nothing here knows class names: the shape of the points decides, and a set
//! that is no clear arc (flat faces, an L of two faces, a filled top) keeps its fitted box.

use glam::{DVec2, DVec3, Vec3};
use rand::{Rng, SeedableRng};
use rustc_hash::FxHashMap;

use super::boxes::OrientedBox;

/// Circle hypotheses tried per point set (three points each, drawn deterministically).
const HYPOTHESES: usize = 256;
/// Radius band relative to the fitted footprint's long side: a half arc gives 0.5, a third of a
/// circle about 0.58, a quarter 0.71; a nearly straight face would need a far larger radius.
const RADIUS_BAND: (f64, f64) = (0.4, 0.8);
/// The smallest and largest radius completed (m): below, points are too few to tell an arc from
/// noise; above, nothing a room holds is that round.
const RADIUS_RANGE_M: (f64, f64) = (0.04, 1.0);
/// A point on the circle lies within this of it (m), or `TOLERANCE_SHARE` of the radius.
const TOLERANCE_M: f64 = 0.015;
const TOLERANCE_SHARE: f64 = 0.05;
/// At least this many points and this share of the vertical surfaces' points on the circle
/// (seen round objects of the benchmark: 55–100%; a desk's or a toilet's best circle: 32–43%).
const MIN_INLIERS: usize = 8;
const MIN_INLIER_SHARE: f64 = 0.5;
/// A round object's points lie on or inside its circle: at most this share outside it (seen
/// round objects: none; the desk's and toilets' circles: 8–10%).
const MAX_OUTSIDE_SHARE: f64 = 0.03;
/// The arc the points cover without a gap (degrees), and the widest gap allowed along it, as an
/// angle and as a length: an L of two flat faces or a table's legs lie on a circle only in short
/// runs, with wide gaps between.
const MIN_ARC_DEG: f64 = 80.0;
const MAX_GAP_DEG: f64 = 60.0;
const MAX_GAP_M: f64 = 0.15;
/// Columns of the ground plane (m) and the height the points in one must span to be a vertical
/// surface: more than a table top's thickness, less than a lamp shade's height.
const COLUMN_M: f64 = 0.05;
const MIN_COLUMN_HEIGHT_M: f64 = 0.06;

/// A circle in the ground plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    pub centre: DVec2,
    pub radius: f64,
}

/// The box a map publishes for an object's points: [`OrientedBox::fit`], completed to the circle
/// of a round footprint seen from one side (see the module notes).
pub fn fit_object_box(points: &[Vec3], trim: f64) -> OrientedBox {
    let fitted = OrientedBox::fit(points, trim);
    let points: Vec<DVec3> = points
        .iter()
        .map(|p| p.as_dvec3())
        .filter(|p| p.is_finite())
        .collect();
    match round_footprint(&points, &fitted) {
        Some(circle) => complete_to_circle(fitted, circle),
        None => fitted,
    }
}

/// The circle the footprint of `points` lies on, if it is a clear arc of a size that fits the
/// box fitted to them.
pub fn round_footprint(points: &[DVec3], fitted: &OrientedBox) -> Option<Circle> {
    let long_side = fitted.size.x.max(fitted.size.y);
    let possible = long_side.is_finite()
        && long_side > 0.0
        && RADIUS_BAND.0 * long_side <= RADIUS_RANGE_M.1
        && RADIUS_BAND.1 * long_side >= RADIUS_RANGE_M.0;
    if !possible {
        return None;
    }
    let everything: Vec<DVec2> = points.iter().map(|p| p.truncate()).collect();
    // The outline is drawn by vertical surfaces (a bin's side, a shade): a table's top, one
    // thin layer, can lie on a circle through its legs without being round.
    let footprint = on_vertical_surfaces(points);
    if footprint.len() < MIN_INLIERS {
        return None;
    }
    let radius_ok = |r: f64| {
        r.is_finite()
            && r >= RADIUS_BAND.0 * long_side
            && r <= RADIUS_BAND.1 * long_side
            && (RADIUS_RANGE_M.0..=RADIUS_RANGE_M.1).contains(&r)
    };
    // Seeded: the same points always give the same box.
    let mut draw = rand_chacha::ChaCha8Rng::seed_from_u64(0x5eed);
    let too_many_outside = |circle: Circle| {
        outside(&everything, circle) as f64 > MAX_OUTSIDE_SHARE * everything.len() as f64
    };
    let n = footprint.len();
    let mut best: Option<(usize, Circle)> = None;
    for _ in 0..HYPOTHESES {
        let (a, b, c) = (
            draw.random_range(0..n),
            draw.random_range(0..n),
            draw.random_range(0..n),
        );
        let Some(circle) = circumcircle(footprint[a], footprint[b], footprint[c]) else {
            continue;
        };
        if !radius_ok(circle.radius) {
            continue;
        }
        // A hypothesis with points outside it is no object's outline (the base of a lamp under
        // its wider shade); among the others, the one most points lie on.
        if too_many_outside(circle) {
            continue;
        }
        let count = inliers(&footprint, circle).count();
        if best.is_none_or(|(most, _)| count > most) {
            best = Some((count, circle));
        }
    }
    let (_, hypothesis) = best?;
    // Refined by least squares on the hypothesis's points, then judged on its own points.
    let on_hypothesis: Vec<DVec2> = inliers(&footprint, hypothesis).collect();
    let circle = least_squares_circle(&on_hypothesis).filter(|c| radius_ok(c.radius))?;
    let on_circle: Vec<DVec2> = inliers(&footprint, circle).collect();
    let max_gap = MAX_GAP_DEG.to_radians().min(MAX_GAP_M / circle.radius);
    let arc = longest_unbroken_arc(&on_circle, circle.centre, max_gap);
    let accepted = on_circle.len() >= MIN_INLIERS
        && on_circle.len() as f64 >= MIN_INLIER_SHARE * footprint.len() as f64
        && !too_many_outside(circle)
        && arc >= MIN_ARC_DEG.to_radians();
    accepted.then_some(circle)
}

/// The footprints of the points in columns (`COLUMN_M` square) whose points span at least
/// `MIN_COLUMN_HEIGHT_M` in height: the vertical surfaces.
fn on_vertical_surfaces(points: &[DVec3]) -> Vec<DVec2> {
    let column = |p: &DVec3| {
        (
            (p.x / COLUMN_M).floor() as i64,
            (p.y / COLUMN_M).floor() as i64,
        )
    };
    let mut heights: FxHashMap<(i64, i64), (f64, f64)> = FxHashMap::default();
    for p in points {
        let range = heights.entry(column(p)).or_insert((p.z, p.z));
        *range = (range.0.min(p.z), range.1.max(p.z));
    }
    points
        .iter()
        .filter(|p| {
            let (low, high) = heights[&column(p)];
            high - low >= MIN_COLUMN_HEIGHT_M
        })
        .map(|p| p.truncate())
        .collect()
}

/// `fitted` grown (never shrunk) along its own axes to hold the circle's square; z unchanged.
pub fn complete_to_circle(fitted: OrientedBox, circle: Circle) -> OrientedBox {
    let (c, s) = (fitted.yaw.cos(), fitted.yaw.sin());
    let to_local = |p: DVec2| DVec2::new(c * p.x + s * p.y, -s * p.x + c * p.y);
    let centre = to_local(fitted.centre.truncate());
    let half = fitted.size.truncate() / 2.0;
    let round = to_local(circle.centre);
    let lo = (centre - half).min(round - DVec2::splat(circle.radius));
    let hi = (centre + half).max(round + DVec2::splat(circle.radius));
    let middle = (lo + hi) / 2.0;
    let completed = OrientedBox {
        centre: DVec3::new(
            c * middle.x - s * middle.y,
            s * middle.x + c * middle.y,
            fitted.centre.z,
        ),
        size: DVec3::new(hi.x - lo.x, hi.y - lo.y, fitted.size.z),
        yaw: fitted.yaw,
    };
    if completed.centre.is_finite() && completed.size.is_finite() {
        completed
    } else {
        fitted
    }
}

fn tolerance(radius: f64) -> f64 {
    TOLERANCE_M.max(TOLERANCE_SHARE * radius)
}

fn inliers(footprint: &[DVec2], circle: Circle) -> impl Iterator<Item = DVec2> + '_ {
    let tolerance = tolerance(circle.radius);
    footprint
        .iter()
        .copied()
        .filter(move |p| (p.distance(circle.centre) - circle.radius).abs() <= tolerance)
}

/// How many points lie outside `circle` (beyond its tolerance).
fn outside(points: &[DVec2], circle: Circle) -> usize {
    let reach = circle.radius + tolerance(circle.radius);
    points
        .iter()
        .filter(|p| p.distance(circle.centre) > reach)
        .count()
}

/// The circle through three points; `None` when they are (nearly) on one line.
fn circumcircle(a: DVec2, b: DVec2, c: DVec2) -> Option<Circle> {
    let (ab, ac) = (b - a, c - a);
    let d = 2.0 * ab.perp_dot(ac);
    if d.abs() < 1e-12 {
        return None;
    }
    let (ab2, ac2) = (ab.length_squared(), ac.length_squared());
    let offset = DVec2::new(ac.y * ab2 - ab.y * ac2, ab.x * ac2 - ac.x * ab2) / d;
    let circle = Circle {
        centre: a + offset,
        radius: offset.length(),
    };
    (circle.centre.is_finite() && circle.radius.is_finite()).then_some(circle)
}

/// The algebraic (Kåsa) least-squares circle: x² + y² + D x + E y + F = 0 solved in the frame
/// of the points' mean, which keeps the normal equations well conditioned.
fn least_squares_circle(points: &[DVec2]) -> Option<Circle> {
    if points.len() < 3 {
        return None;
    }
    let mean = points.iter().copied().sum::<DVec2>() / points.len() as f64;
    let (mut suu, mut suv, mut svv, mut suuu, mut svvv, mut suvv, mut svuu) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for p in points {
        let d = *p - mean;
        let (u, v) = (d.x, d.y);
        suu += u * u;
        suv += u * v;
        svv += v * v;
        suuu += u * u * u;
        svvv += v * v * v;
        suvv += u * v * v;
        svuu += v * u * u;
    }
    // Centre (uc, vc) solves [suu suv; suv svv] (uc, vc) = ½ (suuu + suvv, svvv + svuu).
    let det = suu * svv - suv * suv;
    if det.abs() < 1e-18 {
        return None;
    }
    let (ru, rv) = (0.5 * (suuu + suvv), 0.5 * (svvv + svuu));
    let uc = (ru * svv - rv * suv) / det;
    let vc = (suu * rv - suv * ru) / det;
    let n = points.len() as f64;
    let radius = (uc * uc + vc * vc + (suu + svv) / n).sqrt();
    let circle = Circle {
        centre: mean + DVec2::new(uc, vc),
        radius,
    };
    (circle.centre.is_finite() && radius.is_finite() && radius > 0.0).then_some(circle)
}

/// The longest arc around `centre` along which the points leave no gap wider than `max_gap`
/// (radians; the whole circle when they go all round). An L of two faces or a table's legs lie on
/// a circle only in short runs; the seen side of a bin is one long run, whatever else (the rim of
/// its top) lies on the circle beyond.
fn longest_unbroken_arc(points: &[DVec2], centre: DVec2, max_gap: f64) -> f64 {
    use std::f64::consts::TAU;
    let mut angles: Vec<f64> = points
        .iter()
        .map(|p| (p.y - centre.y).atan2(p.x - centre.x))
        .filter(|a| a.is_finite())
        .collect();
    if angles.len() < 2 {
        return 0.0;
    }
    angles.sort_by(f64::total_cmp);
    let n = angles.len();
    // Gap after each angle, going round (the last one wraps to the first).
    let gaps: Vec<f64> = (0..n)
        .map(|i| {
            if i + 1 < n {
                angles[i + 1] - angles[i]
            } else {
                angles[0] + TAU - angles[n - 1]
            }
        })
        .collect();
    let Some(open) = (0..n).find(|&i| gaps[i] > max_gap) else {
        return TAU;
    };
    // Walk once round from just after a wide gap, adding up runs of narrow gaps.
    let (mut longest, mut run) = (0.0f64, 0.0f64);
    for k in 1..=n {
        let gap = gaps[(open + k) % n];
        if gap > max_gap {
            longest = longest.max(run);
            run = 0.0;
        } else {
            run += gap;
        }
    }
    longest.max(run)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on the part of a vertical cylinder's side that a camera at `eye` sees (the half
    /// facing it), stacked every `dz` over `height`, with `cap` points on its top disc.
    fn seen_cylinder(centre: DVec2, radius: f64, height: f64, eye: DVec2, cap: bool) -> Vec<Vec3> {
        let facing = (eye - centre).normalize();
        let mut points = Vec::new();
        for k in 0..=36 {
            let angle = (k as f64 / 36.0 - 0.5) * std::f64::consts::PI * 0.95;
            let (c, s) = (angle.cos(), angle.sin());
            let dir = DVec2::new(c * facing.x - s * facing.y, s * facing.x + c * facing.y);
            let p = centre + dir * radius;
            for level in 0..8 {
                let z = height * level as f64 / 7.0;
                points.push(Vec3::new(p.x as f32, p.y as f32, z as f32));
            }
        }
        if cap {
            // About as dense as the map's 5 cm voxels leave a top.
            for i in -3i32..=3 {
                for j in -3i32..=3 {
                    let d = DVec2::new(i as f64, j as f64) * radius / 3.5;
                    if d.length() < radius {
                        let p = centre + d;
                        points.push(Vec3::new(p.x as f32, p.y as f32, height as f32));
                    }
                }
            }
        }
        points
    }

    /// `b` is a box of the whole cylinder: its square footprint at any yaw (a cylinder has
    /// none), centred on the axis, over its height.
    fn assert_whole_cylinder(b: &OrientedBox, centre: DVec2, radius: f64, (z0, z1): (f64, f64)) {
        let close = |a: f64, b: f64| (a - b).abs() < 0.015;
        assert!(
            b.centre.truncate().distance(centre) < 0.01
                && close(b.size.x, 2.0 * radius)
                && close(b.size.y, 2.0 * radius)
                && close(b.centre.z - b.size.z / 2.0, z0)
                && close(b.centre.z + b.size.z / 2.0, z1),
            "{b:?}"
        );
    }

    #[test]
    fn the_seen_half_of_a_round_bin_is_completed_to_the_whole_bin() {
        for (eye, cap) in [(DVec2::new(3.0, 1.0), true), (DVec2::new(-1.0, 4.0), false)] {
            let centre = DVec2::new(1.0, 2.0);
            let points = seen_cylinder(centre, 0.18, 0.6, eye, cap);
            let plain = OrientedBox::fit(&points, 0.02);
            let completed = fit_object_box(&points, 0.02);
            assert_whole_cylinder(&completed, centre, 0.18, (0.0, 0.6));
            assert!(plain.volume() < 0.8 * completed.volume(), "{plain:?}");
        }
    }

    #[test]
    fn a_lamp_s_shade_sets_its_circle_over_the_pole_and_the_base() {
        let centre = DVec2::new(-0.5, 0.3);
        let eye = DVec2::new(1.5, -1.0);
        let mut points = seen_cylinder(centre, 0.12, 0.16, eye, true);
        for p in &mut points {
            p.z += 0.34;
        }
        // The base is one layer of voxels: one point in every eight heights.
        points.extend(
            seen_cylinder(centre, 0.08, 0.04, eye, true)
                .into_iter()
                .step_by(8),
        );
        for k in 0..8 {
            points.push(Vec3::new(
                centre.x as f32,
                centre.y as f32,
                0.04 + 0.04 * k as f32,
            ));
        }
        assert_whole_cylinder(&fit_object_box(&points, 0.02), centre, 0.12, (0.0, 0.5));
    }

    /// Points on the vertical faces of an axis-aligned box `size` at `centre`, `faces` of them
    /// (front, then right, back, left).
    fn box_faces(centre: DVec2, size: DVec2, height: f64, faces: usize) -> Vec<Vec3> {
        let half = size / 2.0;
        let corners = [
            DVec2::new(-half.x, -half.y),
            DVec2::new(half.x, -half.y),
            DVec2::new(half.x, half.y),
            DVec2::new(-half.x, half.y),
        ];
        let mut points = Vec::new();
        for face in 0..faces {
            let (a, b) = (corners[face], corners[(face + 1) % 4]);
            for k in 0..=20 {
                let p = centre + a + (b - a) * (k as f64 / 20.0);
                for level in 0..6 {
                    let z = height * level as f64 / 5.0;
                    points.push(Vec3::new(p.x as f32, p.y as f32, z as f32));
                }
            }
        }
        points
    }

    #[test]
    fn flat_faces_an_l_of_two_faces_and_a_filled_top_keep_their_fitted_box() {
        let centre = DVec2::new(2.0, -1.0);
        let mut cases = vec![
            ("one face", box_faces(centre, DVec2::new(0.8, 0.5), 0.9, 1)),
            ("an L", box_faces(centre, DVec2::new(0.4, 0.3), 0.8, 2)),
            (
                "three faces",
                box_faces(centre, DVec2::new(0.5, 0.5), 0.5, 3),
            ),
        ];
        // A table top seen from above: a filled square.
        let mut top = Vec::new();
        for i in 0..=20 {
            for j in 0..=20 {
                let p = centre + DVec2::new(i as f64, j as f64) * 0.04;
                top.push(Vec3::new(p.x as f32, p.y as f32, 0.75));
            }
        }
        cases.push(("a filled top", top.clone()));
        // The same top on four legs, the rectangle's corners on one circle.
        let mut table = top;
        for (i, j) in [(1, 1), (19, 1), (19, 19), (1, 19)] {
            let p = centre + DVec2::new(i as f64, j as f64) * 0.04;
            for level in 0..15 {
                table.push(Vec3::new(p.x as f32, p.y as f32, 0.05 * level as f32));
            }
        }
        cases.push(("a table", table));
        for (name, points) in cases {
            let plain = OrientedBox::fit(&points, 0.02);
            let completed = fit_object_box(&points, 0.02);
            assert_eq!(completed, plain, "{name}");
        }
    }

    #[test]
    fn a_round_front_before_larger_flat_faces_inside_its_circle_keeps_its_fitted_box() {
        // A toilet's bowl seen from the front before its tank, a desk's rounded end before its
        // panels: flat vertical faces inside the arc's circle (none outside it, so only the
        // share of points on the circle tells them from a bin seen on one side).
        let centre = DVec2::new(0.5, 0.5);
        let radius = 0.25;
        let eye = DVec2::new(0.5, 3.0);
        let front = seen_cylinder(centre, radius, 0.4, eye, false);
        let arc: Vec<Vec3> = front
            .iter()
            .copied()
            .filter(|p| f64::from(p.y) > centre.y)
            .collect();
        let alone = fit_object_box(&arc, 0.02);
        assert!(
            alone.volume() > 1.2 * OrientedBox::fit(&arc, 0.02).volume(),
            "the arc alone is completed: {alone:?}"
        );
        // Two flat faces across the circle, behind the arc, with more points than it has.
        let mut with_faces = arc.clone();
        for y in [0.35, 0.45] {
            for k in 0..=30 {
                let x = centre.x - 0.18 + 0.36 * k as f64 / 30.0;
                for level in 0..8 {
                    let z = 0.4 * level as f64 / 7.0;
                    with_faces.push(Vec3::new(x as f32, y as f32, z as f32));
                }
            }
        }
        let on_arc = arc.len() as f64 / with_faces.len() as f64;
        assert!(on_arc < 0.5, "{on_arc}");
        assert_eq!(
            fit_object_box(&with_faces, 0.02),
            OrientedBox::fit(&with_faces, 0.02)
        );
    }

    #[test]
    fn degenerate_sets_give_the_fitted_box_and_stay_finite() {
        let p = Vec3::new(1.0, 2.0, 0.5);
        let line: Vec<Vec3> = (0..30)
            .map(|k| Vec3::new(k as f32 * 0.01, 0.0, 0.0))
            .collect();
        let column: Vec<Vec3> = (0..30)
            .map(|k| Vec3::new(0.3, 0.3, k as f32 * 0.01))
            .collect();
        for (name, points) in [
            ("empty", vec![]),
            ("one point", vec![p]),
            ("one point many times", vec![p; 40]),
            ("a line", line),
            ("a vertical column", column),
            ("NaN among points", vec![p, Vec3::NAN, p + Vec3::X]),
        ] {
            let b = fit_object_box(&points, 0.02);
            assert!(b.centre.is_finite() && b.size.is_finite(), "{name}: {b:?}");
            assert_eq!(b, OrientedBox::fit(&points, 0.02), "{name}");
        }
        assert!(circumcircle(DVec2::ZERO, DVec2::X, DVec2::X * 2.0).is_none());
        assert!(least_squares_circle(&[DVec2::ZERO, DVec2::ZERO, DVec2::ZERO]).is_none());
    }

    #[test]
    fn the_least_squares_circle_recovers_an_arc() {
        let centre = DVec2::new(0.7, -0.2);
        let arc: Vec<DVec2> = (0..20)
            .map(|k| {
                let a = k as f64 / 19.0 * 2.0;
                centre + DVec2::new(a.cos(), a.sin()) * 0.3
            })
            .collect();
        let circle = least_squares_circle(&arc).expect("an arc has a circle");
        assert!(circle.centre.distance(centre) < 1e-9 && (circle.radius - 0.3).abs() < 1e-9);
        let three = circumcircle(arc[0], arc[7], arc[19]).expect("three points on an arc");
        assert!(three.centre.distance(centre) < 1e-9);
    }

    #[test]
    fn the_unbroken_arc_is_the_longest_run_without_a_wide_gap() {
        let at = |degrees: &[f64]| -> Vec<DVec2> {
            degrees
                .iter()
                .map(|d| DVec2::new(d.to_radians().cos(), d.to_radians().sin()))
                .collect()
        };
        let arc = |degrees: &[f64]| longest_unbroken_arc(&at(degrees), DVec2::ZERO, 0.5);
        let close = |a: f64, b: f64| (a - b.to_radians()).abs() < 1e-9;
        // One run of 120 degrees and a lone point beyond.
        assert!(close(
            arc(&[0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0, 250.0]),
            120.0
        ));
        // Runs that wrap round through 180 / -180 degrees.
        assert!(close(arc(&[170.0, -170.0, -150.0, 0.0]), 40.0));
        // Clusters at the four corners of a square: no run longer than a cluster.
        assert!(close(
            arc(&[40.0, 50.0, 130.0, 140.0, 220.0, 230.0, 310.0, 320.0]),
            10.0
        ));
        // All round, and too few points.
        let round: Vec<f64> = (0..36).map(|k| f64::from(k) * 10.0).collect();
        assert!(close(arc(&round), 360.0));
        assert_eq!(arc(&[10.0]), 0.0);
        assert_eq!(arc(&[]), 0.0);
    }
}

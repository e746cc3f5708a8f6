//! Free space: a persistent instance that a window's views see through (the depth observed
//! behind where its points were) loses confidence; one merely out of view, occluded or
//! ungrouped, does not. And free space seen just past an instance's ends says where its object
//! ends: the points are kept with it ([`probes_beyond`], [`seen_free`]), so a box of an object seen
//! in part grows only where no view saw past it.

use glam::Vec3;

use crate::frame::WindowView;
use crate::recon::gaussians::Gaussians;

/// The mean camera centre of a window's views (`None` without finite ones).
pub(super) fn mean_camera_centre(views: &[WindowView]) -> Option<Vec3> {
    let centres: Vec<Vec3> = views
        .iter()
        .map(|v| v.keyframe.world_from_camera.translation.as_vec3())
        .filter(|c| c.is_finite())
        .collect();
    (!centres.is_empty()).then(|| centres.iter().sum::<Vec3>() / centres.len() as f32)
}

/// Sigmas of a depth camera's range noise at the observed depth ([`WindowView`]'s measured
/// noise) that a point and the depth observed through it may differ by before the view counts as
/// seeing free space there: 3 σ of the difference of two noisy depths (√2 σ). Without it, an
/// object 4 m away under 6 mm noise at 1 m (σ 9.6 cm) is "seen through" by a third of its points
/// in every view that does not group it, and dies.
const FREE_SPACE_NOISE_SIGMAS: f32 = 4.2;

/// Fraction of `g`'s Gaussians that `view` sees through: inside the image, in front of the
/// camera, with the observed depth behind them by more than `tolerance`, or the view's depth
/// noise ([`FREE_SPACE_NOISE_SIGMAS`]) if larger (free space where the point was), and the
/// number that project into the image. A point the view does not see
/// (occluded) or sees as a surface proves nothing against the instance; only free space does:
/// a window whose grouping missed an object the camera still sees in place is no evidence that
/// the object is gone.
pub(super) fn seen_through_fraction(
    g: &Gaussians,
    view: &WindowView,
    tolerance: f32,
) -> (f32, usize) {
    let noise_at_1m = view.depth_noise_at_1m.unwrap_or(0.0);
    let camera_from_world = view.keyframe.world_from_camera.inverse();
    let camera = &view.keyframe.camera;
    let width = camera.width as usize;
    let (mut through, mut inside) = (0usize, 0usize);
    for m in &g.means {
        let p = camera_from_world.transform_point(m.as_dvec3());
        let Some(pixel) = camera.project(p) else {
            continue;
        };
        let (u, v) = (pixel.x.round(), pixel.y.round());
        if u < 0.0 || v < 0.0 || u >= f64::from(camera.width) || v >= f64::from(camera.height) {
            continue;
        }
        inside += 1;
        let observed = view.depth[v as usize * width + u as usize];
        // Both depths carry the camera's noise where it was measured: free space only beyond
        // what the noise of the two explains.
        let tolerance = tolerance.max(FREE_SPACE_NOISE_SIGMAS * noise_at_1m * observed * observed);
        if observed.is_finite() && observed > 0.0 && (p.z as f32) + tolerance < observed {
            through += 1;
        }
    }
    (through as f32 / g.len().max(1) as f32, inside)
}

/// Distances (m) beyond an instance's ends at which a view may see free space: where it does,
/// the object ends before that point ([`super::super::amodal::grown_to_length`] reads them).
const PROBE_DISTANCES_M: [f32; 6] = [0.1, 0.2, 0.35, 0.5, 0.7, 1.0];
/// Points sampled from an instance to find its axes and ends: plenty for a box, and bounded
/// whatever the instance holds.
const FRAME_SAMPLES: usize = 512;
/// Share of an instance's sampled points trimmed at either end of an axis (stray points).
const END_TRIM: f64 = 0.02;

/// Where an instance's points end: its horizontal principal axis and the one across it, the
/// trimmed extents along both, and the heights to look past its ends at.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Extent {
    centre: Vec3,
    axes: [Vec3; 2],
    /// (low, high) along each axis, from `centre`.
    ends: [(f32, f32); 2],
    /// The median height of its points and just under its top (the 90th percentile less 2 cm):
    /// a table's top, a cabinet's body. A point under a table's top would be seen through.
    heights: [f32; 2],
}

/// [`Extent`] of `points` (`None` for fewer than 8 finite points or no horizontal extent).
fn extent_of(points: &[Vec3]) -> Option<Extent> {
    let step = points.len().div_ceil(FRAME_SAMPLES).max(1);
    let sample: Vec<Vec3> = points
        .iter()
        .step_by(step)
        .copied()
        .filter(|p| p.is_finite())
        .collect();
    if sample.len() < 8 {
        return None;
    }
    let centre = sample.iter().sum::<Vec3>() / sample.len() as f32;
    let (mut xx, mut xy, mut yy) = (0.0f32, 0.0f32, 0.0f32);
    for p in &sample {
        let d = *p - centre;
        xx += d.x * d.x;
        xy += d.x * d.y;
        yy += d.y * d.y;
    }
    // The principal direction of the 2 x 2 covariance: half the angle of (xx - yy, 2 xy).
    let angle = 0.5 * (2.0 * xy).atan2(xx - yy);
    if !angle.is_finite() || xx + yy <= 0.0 {
        return None;
    }
    let along = Vec3::new(angle.cos(), angle.sin(), 0.0);
    let across = Vec3::new(-along.y, along.x, 0.0);
    let trimmed = |mut values: Vec<f32>| {
        values.sort_by(f32::total_cmp);
        let cut = (END_TRIM * values.len() as f64) as usize;
        (values[cut], values[values.len() - 1 - cut])
    };
    let along_ends = trimmed(sample.iter().map(|p| (*p - centre).dot(along)).collect());
    let across_ends = trimmed(sample.iter().map(|p| (*p - centre).dot(across)).collect());
    let mut heights: Vec<f32> = sample.iter().map(|p| p.z).collect();
    heights.sort_by(f32::total_cmp);
    let at = |q: f64| heights[((q * (heights.len() - 1) as f64) as usize).min(heights.len() - 1)];
    let median = at(0.5);
    Some(Extent {
        centre,
        axes: [along, across],
        ends: [along_ends, across_ends],
        heights: [median, (at(0.9) - 0.02).max(median)],
    })
}

/// Instances farther than this (m, along the view) are not looked past: across a room, not
/// across a hall, where the depth's noise grows with the square of the range. A choice for speed
/// (`bench graph`, 500 instances: fusion 45.9 -> 29.6 ms with it); the eval ranges of the seen-in-part
/// rule gave the same figures with and without it (benchmark 7000, 8000, layouts 0, 40).
const MAX_PROBE_RANGE_M: f64 = 6.0;

/// Whether `point` lies in front of `view`'s camera within [`MAX_PROBE_RANGE_M`] and projects
/// within the image widened by half its size on every side: an instance whose centre does not is
/// too far out of view for any point past its ends (at most [`PROBE_DISTANCES_M`]'s last away)
/// to be seen.
pub(super) fn in_view(point: Vec3, view: &WindowView) -> bool {
    let camera = &view.keyframe.camera;
    let p = view
        .keyframe
        .world_from_camera
        .inverse()
        .transform_point(point.as_dvec3());
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    p.z <= MAX_PROBE_RANGE_M
        && camera.project(p).is_some_and(|pixel| {
            (-w / 2.0..=1.5 * w).contains(&pixel.x) && (-h / 2.0..=1.5 * h).contains(&pixel.y)
        })
}

/// Points beyond the ends of `points` along both horizontal axes, at [`PROBE_DISTANCES_M`] and
/// both [`Extent::heights`], on the line through the middle of each end.
pub(super) fn probes_beyond(points: &[Vec3]) -> Vec<Vec3> {
    let Some(e) = extent_of(points) else {
        return Vec::new();
    };
    let mut probes = Vec::with_capacity(4 * PROBE_DISTANCES_M.len() * 2);
    for (k, axis) in e.axes.iter().enumerate() {
        let other = e.axes[1 - k];
        let (lo, hi) = e.ends[1 - k];
        let middle = e.centre + other * ((lo + hi) / 2.0);
        for (end, sign) in [(e.ends[k].1, 1.0f32), (e.ends[k].0, -1.0)] {
            for d in PROBE_DISTANCES_M {
                for h in e.heights {
                    let p = middle + *axis * (end + sign * d);
                    probes.push(Vec3::new(p.x, p.y, h));
                }
            }
        }
    }
    probes
}

/// The `probes` `view` sees free space at: inside the image and in front of the camera, with the
/// depth it observed there behind them by more than `tolerance` (or the view's depth noise,
/// [`FREE_SPACE_NOISE_SIGMAS`], if larger). A probe hidden behind something, or on a surface the
/// view sees, proves nothing.
pub(super) fn seen_free(probes: &[Vec3], view: &WindowView, tolerance: f32) -> Vec<Vec3> {
    let noise_at_1m = view.depth_noise_at_1m.unwrap_or(0.0);
    let camera_from_world = view.keyframe.world_from_camera.inverse();
    let camera = &view.keyframe.camera;
    let (width, height) = (camera.width as usize, camera.height as usize);
    probes
        .iter()
        .copied()
        .filter(|q| {
            let p = camera_from_world.transform_point(q.as_dvec3());
            let Some(pixel) = camera.project(p) else {
                return false;
            };
            let (u, v) = (pixel.x.round(), pixel.y.round());
            if !(u >= 0.0 && v >= 0.0 && (u as usize) < width && (v as usize) < height) {
                return false;
            }
            let observed = view.depth.get(v as usize * width + u as usize).copied();
            let Some(observed) = observed.filter(|d| d.is_finite() && *d > 0.0) else {
                return false;
            };
            let tolerance =
                tolerance.max(FREE_SPACE_NOISE_SIGMAS * noise_at_1m * observed * observed);
            (p.z as f32) + tolerance < observed
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Keyframe;
    use crate::recon::camera::Camera;
    use crate::recon::Rigid;
    use glam::{DQuat, DVec2, DVec3};

    /// The piece of a table top a window grouped: 0.5 x 0.6 m at 0.75 m, x from -0.25 to 0.25.
    fn table_piece() -> Vec<Vec3> {
        (0..=10)
            .flat_map(|i| (0..=12).map(move |j| (i, j)))
            .map(|(i, j)| Vec3::new(-0.25 + 0.05 * i as f32, -0.3 + 0.05 * j as f32, 0.75))
            .collect()
    }

    /// A camera 3 m over the origin looking straight down, and the depth it measures of a table
    /// top at 0.75 m reaching from x = -0.25 to `table_end` (y within 0.3), floor elsewhere.
    fn view_from_above(table_end: f64) -> WindowView {
        let camera = Camera::from_fov(64, 48, 100f64.to_radians()).unwrap();
        // Camera x along world x, camera y along world -y, optical axis down.
        let pose = Rigid::new(
            DQuat::from_rotation_x(std::f64::consts::PI),
            DVec3::new(0.0, 0.0, 3.0),
        );
        let depth = (0..48)
            .flat_map(|v| (0..64).map(move |u| (u, v)))
            .map(|(u, v)| {
                let ray = camera.ray(DVec2::new(f64::from(u), f64::from(v)));
                let hit = pose.transform_point(ray * 2.25);
                let on_table = (-0.25..=table_end).contains(&hit.x) && hit.y.abs() <= 0.3;
                if on_table {
                    2.25
                } else {
                    3.0
                }
            })
            .collect();
        WindowView {
            keyframe: Keyframe {
                stamp_nanos: 0,
                camera,
                world_from_camera: pose,
            },
            depth,
            depth_noise_at_1m: None,
        }
    }

    #[test]
    fn a_view_sees_free_space_past_the_end_where_an_object_ends_and_none_where_it_goes_on() {
        let probes = probes_beyond(&table_piece());
        assert_eq!(probes.len(), 4 * PROBE_DISTANCES_M.len() * 2);
        let past = |x: f32| move |p: &&Vec3| p.x > x;
        // The table ends where the piece does: the floor is seen past every end.
        let ended = seen_free(&probes, &view_from_above(0.25), 0.1);
        assert!(ended.iter().filter(past(0.3)).count() >= 4, "{ended:?}");
        assert!(ended.iter().any(|p| p.x < -0.3));
        assert!(ended.iter().any(|p| p.y > 0.35));
        // The table goes on to x = 1.2: nothing is seen free past the piece's +x end before it.
        let goes_on = seen_free(&probes, &view_from_above(1.2), 0.1);
        assert!(
            goes_on.iter().filter(|p| p.x > 0.3 && p.x < 1.2).count() == 0,
            "{goes_on:?}"
        );
        assert!(
            goes_on.iter().any(|p| p.x < -0.3),
            "the -x end is still seen"
        );
        // Fewer than eight points, or none with a horizontal extent, have no ends.
        assert!(probes_beyond(&table_piece()[..5]).is_empty());
        assert!(probes_beyond(&[Vec3::new(1.0, 1.0, 0.5); 20]).is_empty());
    }

    #[test]
    fn non_finite_points_and_depths_give_no_free_space() {
        let mut points = table_piece();
        points.extend([Vec3::NAN, Vec3::new(f32::INFINITY, 0.0, 1.0)]);
        let probes = probes_beyond(&points);
        assert!(probes.iter().all(|p| p.is_finite()));
        let mut view = view_from_above(0.25);
        view.depth.iter_mut().for_each(|d| *d = f32::NAN);
        assert!(seen_free(&probes, &view, 0.1).is_empty());
        view.depth.truncate(10);
        assert!(seen_free(&probes, &view, 0.1).is_empty());
    }
}

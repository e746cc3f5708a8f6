//! Free space: a persistent instance that a window's views see through (the depth observed
//! behind where its points were) loses confidence; one merely out of view, occluded or
//! ungrouped, does not.

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

//! Brute force in f64: every Gaussian at every pixel, sorted by depth, with the same compositing
//! rules. Written independently of the tile path (its own projection), to check it and to measure
//! its speed-up; far too slow for use.

use super::project::check_inputs;
use super::project::world_covariance;
use super::*;

#[allow(clippy::needless_range_loop)] // explicit matrix indices read as the formula
pub fn render(
    g: &Gaussians,
    features: &[f32],
    channels: usize,
    camera: &Camera,
    camera_from_world: &Rigid,
    settings: &RasterSettings,
) -> Result<Render> {
    check_inputs(g, features, channels, camera, camera_from_world, settings)?;
    let (width, height) = (camera.width as usize, camera.height as usize);
    let r = camera_from_world.rotation_matrix();
    // (depth, index, mean, inverse covariance) of every Gaussian in front of the near plane.
    let mut visible: Vec<(f64, usize, [f64; 2], [f64; 3])> = Vec::new();
    for i in 0..g.len() {
        let p = r * g.means[i].as_dvec3() + camera_from_world.translation;
        if p.z <= settings.near {
            continue;
        }
        let lim_x =
            JACOBIAN_FOV_LIMIT * camera.cx.max(f64::from(camera.width) - camera.cx) / camera.fx;
        let lim_y =
            JACOBIAN_FOV_LIMIT * camera.cy.max(f64::from(camera.height) - camera.cy) / camera.fy;
        let (tx, ty) = (
            (p.x / p.z).clamp(-lim_x, lim_x),
            (p.y / p.z).clamp(-lim_y, lim_y),
        );
        // J (2×3) and Σ' = J R Σ Rᵀ Jᵀ, written out with matrices.
        let j = [
            [camera.fx / p.z, 0.0, -camera.fx * tx / p.z],
            [0.0, camera.fy / p.z, -camera.fy * ty / p.z],
        ];
        let sigma_camera = r * world_covariance(g, i) * r.transpose();
        let mut cov = [[0.0f64; 2]; 2];
        for (row, jr) in j.iter().enumerate() {
            for (col, jc) in j.iter().enumerate() {
                let mut sum = 0.0;
                for k in 0..3 {
                    for l in 0..3 {
                        sum += jr[k] * sigma_camera.col(l)[k] * jc[l];
                    }
                }
                cov[row][col] = sum;
            }
        }
        cov[0][0] += settings.low_pass;
        cov[1][1] += settings.low_pass;
        let det = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
        if det <= 0.0 {
            continue;
        }
        let inverse = [cov[1][1] / det, -cov[0][1] / det, cov[0][0] / det];
        let mean = [
            camera.fx * p.x / p.z + camera.cx,
            camera.fy * p.y / p.z + camera.cy,
        ];
        visible.push((p.z, i, mean, inverse));
    }
    visible.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut out = Render::empty(width, height, channels);
    let mut acc = vec![0.0f64; channels];
    for y in 0..height {
        for x in 0..width {
            let mut t = 1.0f64;
            let mut depth = 0.0f64;
            acc.iter_mut().for_each(|a| *a = 0.0);
            for (z, i, mean, inv) in &visible {
                let (dx, dy) = (x as f64 - mean[0], y as f64 - mean[1]);
                let power = -0.5 * (inv[0] * dx * dx + inv[2] * dy * dy) - inv[1] * dx * dy;
                if power > 0.0 {
                    continue;
                }
                let alpha = (f64::from(g.opacities[*i]) * power.exp()).min(f64::from(ALPHA_MAX));
                if alpha < f64::from(ALPHA_MIN) {
                    continue;
                }
                let next = t * (1.0 - alpha);
                if next < f64::from(TRANSMITTANCE_MIN) {
                    break;
                }
                for (c, a) in acc.iter_mut().enumerate() {
                    *a += f64::from(features[i * channels + c]) * alpha * t;
                }
                depth += z * alpha * t;
                t = next;
            }
            let pixel = y * width + x;
            let alpha = 1.0 - t;
            out.alpha[pixel] = alpha as f32;
            out.depth[pixel] = if alpha > 0.0 {
                (depth / alpha) as f32
            } else {
                0.0
            };
            for (c, a) in acc.iter().enumerate() {
                out.features[pixel * channels + c] = *a as f32;
            }
        }
    }
    Ok(out)
}

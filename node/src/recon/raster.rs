//! Tile-based EWA splatting (3DGS / gsplat): project each Gaussian's covariance
//! `Σ' = J W Σ Wᵀ Jᵀ` plus a 0.3-pixel low-pass, cull at the near plane, sort by depth per tile, and
//! composite front to back, stopping when transmittance would fall below 1e-4. Any channel set renders
//! in one pass (colour, embeddings, assignment probabilities), with accumulated alpha and depth.
//!
//! The footprint of a Gaussian is the ellipse where its alpha stays ≥ 1/255 (opacity-aware, not a
//! fixed 3σ), so culling by footprint drops nothing the compositing rule would keep: the result
//! equals evaluating every Gaussian at every pixel ([`reference`]) up to rounding.
//! Pixels are centred at integer coordinates (OpenCV). Distortion is not rendered: render into
//! [`Camera::undistorted`].

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use super::camera::Camera;
use super::gaussians::{safe_rotation, GaussianError, Gaussians};
use super::Rigid;

pub const DEFAULT_TILE_SIZE: usize = 16;
pub const DEFAULT_NEAR: f64 = 0.01;
pub const DEFAULT_LOW_PASS: f64 = 0.3;
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
pub const ALPHA_MAX: f32 = 0.99;
pub const TRANSMITTANCE_MIN: f32 = 1e-4;
/// Pixels of slack around the exact footprint, far above f32 rounding of pixel coordinates.
const FOOTPRINT_MARGIN: f64 = 1e-2;
/// 3DGS clamps the projection Jacobian for centres this far outside the field of view, so that
/// off-screen Gaussians do not blow up their screen-space covariance.
const JACOBIAN_FOV_LIMIT: f64 = 1.3;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RasterError {
    #[error(transparent)]
    Gaussians(#[from] GaussianError),
    #[error("features have {got} values, expected {expected} ({gaussians} Gaussians × {channels} channels)")]
    FeatureLength {
        got: usize,
        expected: usize,
        gaussians: usize,
        channels: usize,
    },
    #[error("feature {0} is not finite")]
    NonFiniteFeature(usize),
    #[error("camera: {0}")]
    Camera(#[from] super::camera::CameraError),
    #[error("camera pose is not finite")]
    BadPose,
    #[error("settings: {0}")]
    Settings(&'static str),
}

pub type Result<T> = std::result::Result<T, RasterError>;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RasterSettings {
    pub tile_size: usize,
    /// Gaussians with camera depth at or below this are culled.
    pub near: f64,
    /// Added to the projected covariance's diagonal (pixels²): keeps near-singular footprints
    /// invertible and anti-aliases sub-pixel Gaussians.
    pub low_pass: f64,
}

impl Default for RasterSettings {
    fn default() -> Self {
        Self {
            tile_size: DEFAULT_TILE_SIZE,
            near: DEFAULT_NEAR,
            low_pass: DEFAULT_LOW_PASS,
        }
    }
}

/// A rendered view: `channels` values per pixel (row-major), accumulated alpha, and depth
/// (alpha-normalised expected camera depth; 0 where nothing was rendered).
#[derive(Debug, Clone, PartialEq)]
pub struct Render {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub features: Vec<f32>,
    pub alpha: Vec<f32>,
    pub depth: Vec<f32>,
}

impl Render {
    /// Nothing rendered: zero features, alpha and depth.
    pub fn empty(width: usize, height: usize, channels: usize) -> Self {
        Self {
            width,
            height,
            channels,
            features: vec![0.0; width * height * channels],
            alpha: vec![0.0; width * height],
            depth: vec![0.0; width * height],
        }
    }
}

/// A Gaussian in screen space.
#[derive(Debug, Clone, Copy)]
struct Splat {
    /// Index of the Gaussian (and of its features).
    index: usize,
    mean: [f32; 2],
    /// Inverse 2D covariance (a, b, c): power = -½(a dx² + c dy²) - b dx dy.
    conic: [f32; 3],
    opacity: f32,
    /// Squared Mahalanobis radius of the footprint (alpha ≥ ALPHA_MIN inside).
    radius2: f32,
    depth: f64,
    /// Inclusive pixel bounds of the footprint, clipped to the image.
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
}

fn check_inputs(
    g: &Gaussians,
    features: &[f32],
    channels: usize,
    camera: &Camera,
    camera_from_world: &Rigid,
    settings: &RasterSettings,
) -> Result<()> {
    g.validate()?;
    let expected = g.len() * channels;
    if features.len() != expected {
        return Err(RasterError::FeatureLength {
            got: features.len(),
            expected,
            gaussians: g.len(),
            channels,
        });
    }
    if let Some(i) = features.iter().position(|v| !v.is_finite()) {
        return Err(RasterError::NonFiniteFeature(i));
    }
    camera.validate()?;
    if !camera_from_world.is_finite() {
        return Err(RasterError::BadPose);
    }
    if settings.tile_size == 0 {
        return Err(RasterError::Settings("tile_size must be at least 1"));
    }
    if !(settings.near > 0.0
        && settings.near.is_finite()
        && settings.low_pass > 0.0
        && settings.low_pass.is_finite())
    {
        return Err(RasterError::Settings(
            "near and low_pass must be positive and finite",
        ));
    }
    Ok(())
}

/// World covariance R S Sᵀ Rᵀ of Gaussian `i` (scales' signs ignored, rotation normalised).
pub(crate) fn world_covariance(g: &Gaussians, i: usize) -> DMat3 {
    let r = DMat3::from_quat(safe_rotation(g.rotations[i]).as_dquat());
    let s = g.scales[i].abs().as_dvec3();
    let m = r * DMat3::from_diagonal(s);
    m * m.transpose()
}

fn project(
    g: &Gaussians,
    i: usize,
    camera: &Camera,
    camera_from_world: &Rigid,
    world_from_camera_rotation: &DMat3,
    settings: &RasterSettings,
) -> Option<Splat> {
    let opacity = g.opacities[i];
    if opacity.is_nan() || opacity < ALPHA_MIN {
        return None; // can never reach the alpha threshold
    }
    let p = camera_from_world.transform_point(g.means[i].as_dvec3());
    if p.z.is_nan() || p.z <= settings.near {
        return None;
    }
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let lim_x = JACOBIAN_FOV_LIMIT * camera.cx.max(w - camera.cx) / camera.fx;
    let lim_y = JACOBIAN_FOV_LIMIT * camera.cy.max(h - camera.cy) / camera.fy;
    let tx = (p.x / p.z).clamp(-lim_x, lim_x);
    let ty = (p.y / p.z).clamp(-lim_y, lim_y);
    // Rows of J W (the projection Jacobian applied to the camera rotation), taken into the
    // Gaussian's local frame and scaled: with M = J W R S, Σ' = M Mᵀ.
    let j0 = DVec3::new(camera.fx / p.z, 0.0, -camera.fx * tx / p.z);
    let j1 = DVec3::new(0.0, camera.fy / p.z, -camera.fy * ty / p.z);
    let local_from_world = safe_rotation(g.rotations[i]).as_dquat().inverse();
    let scale = g.scales[i].abs().as_dvec3();
    let m0 = (local_from_world * (*world_from_camera_rotation * j0)) * scale;
    let m1 = (local_from_world * (*world_from_camera_rotation * j1)) * scale;
    let a = m0.dot(m0) + settings.low_pass;
    let b = m0.dot(m1);
    let c = m1.dot(m1) + settings.low_pass;
    let det = a * c - b * b;
    if !(det > 0.0 && det.is_finite()) {
        return None;
    }
    let mean_x = camera.fx * p.x / p.z + camera.cx;
    let mean_y = camera.fy * p.y / p.z + camera.cy;
    // Mahalanobis radius where opacity · exp(-r²/2) = ALPHA_MIN; the ellipse's bounding box has
    // half-widths r·√Σ'xx and r·√Σ'yy; a small margin absorbs rounding.
    let r2 = 2.0 * (f64::from(opacity) / f64::from(ALPHA_MIN)).ln().max(0.0);
    let half_x = (r2 * a).sqrt() + FOOTPRINT_MARGIN;
    let half_y = (r2 * c).sqrt() + FOOTPRINT_MARGIN;
    if mean_x + half_x < 0.0
        || mean_y + half_y < 0.0
        || mean_x - half_x > w - 1.0
        || mean_y - half_y > h - 1.0
    {
        return None;
    }
    if !(mean_x.is_finite() && mean_y.is_finite()) {
        return None;
    }
    let clip = |v: f64, max: f64| v.clamp(0.0, max) as usize;
    Some(Splat {
        index: i,
        mean: [mean_x as f32, mean_y as f32],
        conic: [(c / det) as f32, (-b / det) as f32, (a / det) as f32],
        opacity,
        radius2: r2 as f32,
        depth: p.z,
        x0: clip((mean_x - half_x).ceil(), w - 1.0),
        x1: clip((mean_x + half_x).floor(), w - 1.0),
        y0: clip((mean_y - half_y).ceil(), h - 1.0),
        y1: clip((mean_y + half_y).floor(), h - 1.0),
    })
}

/// Splats of the visible Gaussians and, per tile, its (tile, depth, splat) keys front to back.
struct Binned {
    splats: Vec<Splat>,
    keys: Vec<u128>,
    ranges: Vec<(usize, usize)>,
    tiles_x: usize,
}

impl Binned {
    /// Tile (`tx`, `ty`)'s pixel bounds and its splats, front to back.
    fn tile(
        &self,
        tx: usize,
        ty: usize,
        tile: usize,
        width: usize,
        height: usize,
    ) -> (TileBounds, impl Iterator<Item = usize> + '_) {
        let bounds = TileBounds {
            x0: tx * tile,
            y0: ty * tile,
            x1: ((tx + 1) * tile).min(width),
            y1: ((ty + 1) * tile).min(height),
        };
        let (a, b) = self.ranges[ty * self.tiles_x + tx];
        let order = self.keys[a..b].iter().map(|k| (*k & 0xffff_ffff) as usize);
        (bounds, order)
    }
}

fn bin(
    g: &Gaussians,
    camera: &Camera,
    camera_from_world: &Rigid,
    settings: &RasterSettings,
) -> Binned {
    let (width, height) = (camera.width as usize, camera.height as usize);
    let tile = settings.tile_size;
    let (tiles_x, tiles_y) = (width.div_ceil(tile), height.div_ceil(tile));

    let world_from_camera_rotation = camera_from_world.rotation_matrix().transpose();
    // Visible Gaussians only, in index order, so the composite loop walks dense memory.
    let splats: Vec<Splat> = (0..g.len())
        .into_par_iter()
        .filter_map(|i| {
            project(
                g,
                i,
                camera,
                camera_from_world,
                &world_from_camera_rotation,
                settings,
            )
        })
        .collect();
    // One key per (tile, Gaussian) overlap: tile, depth and splat position packed into a u128 so
    // that sorting integers gives each tile its Gaussians front to back, ties broken by index
    // (positive f64 depths order like their bit patterns; positions follow index order). The order
    // never depends on threads.
    let mut keys: Vec<u128> = splats
        .par_iter()
        .enumerate()
        .flat_map_iter(|(i, s)| {
            let tile_rows = s.y0 / tile..s.y1 / tile + 1;
            let tile_cols = s.x0 / tile..s.x1 / tile + 1;
            let depth_bits = s.depth.to_bits();
            tile_rows.flat_map(move |ty| {
                tile_cols.clone().map(move |tx| {
                    (((ty * tiles_x + tx) as u128) << 96)
                        | (u128::from(depth_bits) << 32)
                        | i as u128
                })
            })
        })
        .collect();
    keys.par_sort_unstable();
    let tile_of = |key: u128| (key >> 96) as usize;
    let mut ranges = vec![(0usize, 0usize); tiles_x * tiles_y];
    let mut start = 0;
    while start < keys.len() {
        let t = tile_of(keys[start]);
        let mut end = start;
        while end < keys.len() && tile_of(keys[end]) == t {
            end += 1;
        }
        ranges[t] = (start, end);
        start = end;
    }

    Binned {
        splats,
        keys,
        ranges,
        tiles_x,
    }
}

/// Render `channels` feature values per Gaussian (`features`, Gaussian-major) into `camera`
/// seen from `camera_from_world`. Deterministic: the same inputs give bit-identical outputs
/// whatever the thread count.
pub fn render(
    g: &Gaussians,
    features: &[f32],
    channels: usize,
    camera: &Camera,
    camera_from_world: &Rigid,
    settings: &RasterSettings,
) -> Result<Render> {
    check_inputs(g, features, channels, camera, camera_from_world, settings)?;
    if channels == 0 {
        // Output bands are split by channel count; render one zero channel for alpha and depth.
        let zeros = vec![0.0; g.len()];
        let rendered = render(g, &zeros, 1, camera, camera_from_world, settings)?;
        return Ok(Render {
            channels: 0,
            features: Vec::new(),
            ..rendered
        });
    }
    let (width, height) = (camera.width as usize, camera.height as usize);
    let tile = settings.tile_size;
    let binned = bin(g, camera, camera_from_world, settings);
    let mut out = Render::empty(width, height, channels);
    // Tile rows own disjoint bands of the output, so each is composited and written in parallel.
    let band = tile * width;
    out.features
        .par_chunks_mut(band * channels)
        .zip(out.alpha.par_chunks_mut(band))
        .zip(out.depth.par_chunks_mut(band))
        .enumerate()
        .for_each(|(ty, ((features_band, alpha_band), depth_band))| {
            for tx in 0..binned.tiles_x {
                let (bounds, order) = binned.tile(tx, ty, tile, width, height);
                let tile_out = composite_tile(&bounds, order, &binned.splats, features, channels);
                let tw = bounds.x1 - bounds.x0;
                for y in bounds.y0..bounds.y1 {
                    for x in bounds.x0..bounds.x1 {
                        let local = (y - bounds.y0) * tw + (x - bounds.x0);
                        let pixel = (y - ty * tile) * width + x;
                        let alpha = 1.0 - tile_out.transmittance[local];
                        alpha_band[pixel] = alpha;
                        depth_band[pixel] = if alpha > 0.0 {
                            tile_out.depth[local] / alpha
                        } else {
                            0.0
                        };
                        features_band[pixel * channels..(pixel + 1) * channels].copy_from_slice(
                            &tile_out.features[local * channels..(local + 1) * channels],
                        );
                    }
                }
            }
        });
    Ok(out)
}

/// A label image: per pixel the label carrying the largest share of the pixel's blend weight
/// (`None` where nothing rendered), with alpha and depth as [`render`] gives them.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelRender {
    pub width: usize,
    pub height: usize,
    pub labels: Vec<Option<u32>>,
    pub alpha: Vec<f32>,
    pub depth: Vec<f32>,
}

/// Render one label per Gaussian (`labels[i]` for Gaussian `i`): per pixel the label whose
/// Gaussians carry most of its blend weight. The same answer as rendering one one-hot channel per
/// label and taking the largest, at the cost of one channel whatever the number of labels.
pub fn render_labels(
    g: &Gaussians,
    labels: &[u32],
    camera: &Camera,
    camera_from_world: &Rigid,
    settings: &RasterSettings,
) -> Result<LabelRender> {
    check_inputs(g, &[], 0, camera, camera_from_world, settings)?;
    if labels.len() != g.len() {
        return Err(RasterError::FeatureLength {
            got: labels.len(),
            expected: g.len(),
            gaussians: g.len(),
            channels: 1,
        });
    }
    let (width, height) = (camera.width as usize, camera.height as usize);
    let tile = settings.tile_size;
    let binned = bin(g, camera, camera_from_world, settings);
    let mut out = LabelRender {
        width,
        height,
        labels: vec![None; width * height],
        alpha: vec![0.0; width * height],
        depth: vec![0.0; width * height],
    };
    let band = tile * width;
    out.labels
        .par_chunks_mut(band)
        .zip(out.alpha.par_chunks_mut(band))
        .zip(out.depth.par_chunks_mut(band))
        .enumerate()
        .for_each(|(ty, ((labels_band, alpha_band), depth_band))| {
            for tx in 0..binned.tiles_x {
                let (bounds, order) = binned.tile(tx, ty, tile, width, height);
                let n = (bounds.x1 - bounds.x0) * (bounds.y1 - bounds.y0);
                // Per pixel its labels' weights: a few entries (one per surface it sees).
                let mut slots: Vec<Vec<(u32, f32)>> = vec![Vec::new(); n];
                let (transmittance, depth) =
                    composite(&bounds, order, &binned.splats, |local, index, weight| {
                        let label = labels[index];
                        let pixel = &mut slots[local];
                        match pixel.iter_mut().find(|s| s.0 == label) {
                            Some(slot) => slot.1 += weight,
                            None => pixel.push((label, weight)),
                        }
                    });
                let tw = bounds.x1 - bounds.x0;
                for y in bounds.y0..bounds.y1 {
                    for x in bounds.x0..bounds.x1 {
                        let local = (y - bounds.y0) * tw + (x - bounds.x0);
                        let pixel = (y - ty * tile) * width + x;
                        let alpha = 1.0 - transmittance[local];
                        alpha_band[pixel] = alpha;
                        depth_band[pixel] = if alpha > 0.0 {
                            depth[local] / alpha
                        } else {
                            0.0
                        };
                        // Ties go to the label that arrived first (the nearer surface).
                        labels_band[pixel] = slots[local]
                            .iter()
                            .fold(None, |best: Option<(u32, f32)>, s| match best {
                                Some(b) if b.1 >= s.1 => Some(b),
                                _ => Some(*s),
                            })
                            .map(|(label, _)| label);
                    }
                }
            }
        });
    Ok(out)
}

#[derive(Debug)]
struct TileBounds {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

#[derive(Debug)]
struct TileOutput {
    transmittance: Vec<f32>,
    depth: Vec<f32>,
    features: Vec<f32>,
}

/// Composite a tile Gaussian by Gaussian (front to back), touching only the pixels of each
/// footprint; per pixel this is exactly the front-to-back loop of 3DGS.
fn composite_tile(
    b: &TileBounds,
    order: impl Iterator<Item = usize>,
    splats: &[Splat],
    features: &[f32],
    channels: usize,
) -> TileOutput {
    let n = (b.x1 - b.x0) * (b.y1 - b.y0);
    let mut acc = vec![0.0f32; n * channels];
    let (transmittance, depth) = composite(b, order, splats, |local, index, weight| {
        let feature = &features[index * channels..(index + 1) * channels];
        for (acc_c, f) in acc[local * channels..(local + 1) * channels]
            .iter_mut()
            .zip(feature)
        {
            *acc_c += f * weight;
        }
    });
    TileOutput {
        transmittance,
        depth,
        features: acc,
    }
}

/// The front-to-back loop of 3DGS over one tile: `blend(pixel in tile, Gaussian index, weight)`
/// receives every contribution; returns per pixel the transmittance and the weighted depth sum.
fn composite(
    b: &TileBounds,
    order: impl Iterator<Item = usize>,
    splats: &[Splat],
    mut blend: impl FnMut(usize, usize, f32),
) -> (Vec<f32>, Vec<f32>) {
    let tw = b.x1 - b.x0;
    let n = tw * (b.y1 - b.y0);
    let mut transmittance = vec![1.0f32; n];
    let mut done = vec![false; n];
    let mut depth = vec![0.0f32; n];
    let mut remaining = n;
    for i in order {
        if remaining == 0 {
            break;
        }
        let s = &splats[i];
        let (x0, x1) = (s.x0.max(b.x0), s.x1.min(b.x1 - 1));
        let (y0, y1) = (s.y0.max(b.y0), s.y1.min(b.y1 - 1));
        if x0 > x1 || y0 > y1 {
            continue;
        }
        let [a, bb, c] = s.conic;
        // Outside the footprint ellipse alpha < ALPHA_MIN: test the quadratic before the exp.
        let power_min = -0.5 * s.radius2;
        for y in y0..=y1 {
            let dy = y as f32 - s.mean[1];
            let c_dy2 = c * dy * dy;
            let b_dy = bb * dy;
            let row = (y - b.y0) * tw;
            for x in x0..=x1 {
                let local = row + (x - b.x0);
                let dx = x as f32 - s.mean[0];
                let power = -0.5 * (a * dx * dx + c_dy2) - b_dy * dx;
                if power > 0.0 || power < power_min || done[local] {
                    continue;
                }
                let alpha = (s.opacity * power.exp()).min(ALPHA_MAX);
                if alpha < ALPHA_MIN {
                    continue;
                }
                let t = transmittance[local];
                let next = t * (1.0 - alpha);
                if next < TRANSMITTANCE_MIN {
                    done[local] = true;
                    remaining -= 1;
                    continue;
                }
                let weight = alpha * t;
                blend(local, s.index, weight);
                depth[local] += s.depth as f32 * weight;
                transmittance[local] = next;
            }
        }
    }
    (transmittance, depth)
}

/// Brute force in f64: every Gaussian at every pixel, sorted by depth, with the same compositing
/// rules. Written independently of the tile path (its own projection), to check it and to measure
/// its speed-up; far too slow for use.
pub mod reference {
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
            let lim_y = JACOBIAN_FOV_LIMIT * camera.cy.max(f64::from(camera.height) - camera.cy)
                / camera.fy;
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
                    let alpha =
                        (f64::from(g.opacities[*i]) * power.exp()).min(f64::from(ALPHA_MAX));
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, Quat, Vec3};
    use proptest::prelude::*;

    /// A small deterministic pseudo-random generator, so scenes need no extra dependency.
    struct Lcg(u64);

    impl Lcg {
        fn next(&mut self) -> f32 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 40) as f32) / (1u64 << 24) as f32
        }

        fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.next()
        }
    }

    fn camera() -> Camera {
        Camera::pinhole(48, 36, 40.0, 42.0, 23.5, 17.0).unwrap()
    }

    /// `n` Gaussians in front of a camera at the origin looking down +z, with `c` channels.
    fn scene(seed: u64, n: usize, c: usize) -> (Gaussians, Vec<f32>) {
        let mut rng = Lcg(seed);
        let mut g = Gaussians::with_dims(0, 0);
        let mut features = Vec::new();
        for _ in 0..n {
            let z = rng.range(1.0, 6.0);
            let mean = Vec3::new(rng.range(-0.7, 0.7) * z, rng.range(-0.5, 0.5) * z, z);
            let scale = Vec3::new(
                rng.range(0.01, 0.3),
                rng.range(0.01, 0.3),
                rng.range(0.001, 0.2),
            );
            let rotation = Quat::from_xyzw(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            );
            g.push(
                mean,
                rng.range(0.05, 1.0),
                scale,
                rotation,
                Vec3::ONE,
                &[],
                &[],
            );
            features.extend((0..c).map(|_| rng.next()));
        }
        (g, features)
    }

    fn pose() -> Rigid {
        Rigid::IDENTITY
    }

    fn relative_error(fast: &[f32], reference: &[f32]) -> f64 {
        let max_ref = reference
            .iter()
            .fold(0.0f64, |m, v| m.max(f64::from(v.abs())));
        let max_diff = fast
            .iter()
            .zip(reference)
            .fold(0.0f64, |m, (a, b)| m.max(f64::from((a - b).abs())));
        max_diff / max_ref.max(1e-12)
    }

    fn assert_valid(r: &Render) {
        assert!(r.features.iter().all(|v| v.is_finite()));
        assert!(r.alpha.iter().all(|a| (0.0..=1.0).contains(a)));
        assert!(r
            .depth
            .iter()
            .zip(&r.alpha)
            .all(|(d, a)| d.is_finite() && *d >= 0.0 && (*a == 0.0 || *d > 0.0)));
    }

    #[test]
    fn tile_renderer_matches_brute_force_reference_on_random_scenes() {
        for (seed, n, c) in [(1, 40, 3), (2, 150, 8), (3, 300, 4), (4, 5, 1)] {
            let (g, features) = scene(seed, n, c);
            let settings = RasterSettings::default();
            let fast = render(&g, &features, c, &camera(), &pose(), &settings).unwrap();
            let slow = reference::render(&g, &features, c, &camera(), &pose(), &settings).unwrap();
            let errors = [
                relative_error(&fast.features, &slow.features),
                relative_error(&fast.alpha, &slow.alpha),
                relative_error(&fast.depth, &slow.depth),
            ];
            assert!(
                errors.iter().all(|e| *e <= 1e-4),
                "seed {seed}: relative errors {errors:?}"
            );
            assert!(
                fast.alpha.iter().any(|a| *a > 0.5),
                "seed {seed}: scene should cover pixels"
            );
            assert_valid(&fast);
        }
    }

    #[test]
    fn label_render_picks_the_label_a_one_hot_channel_render_picks() {
        for (seed, n, labels) in [(11, 60, 3), (12, 200, 9), (13, 400, 30)] {
            let (g, _) = scene(seed, n, 0);
            let label_of: Vec<u32> = (0..n).map(|i| (i * 7 % labels) as u32).collect();
            let one_hot: Vec<f32> = label_of
                .iter()
                .flat_map(|&l| (0..labels).map(move |k| if k == l as usize { 1.0 } else { 0.0 }))
                .collect();
            let settings = RasterSettings::default();
            let channels = render(&g, &one_hot, labels, &camera(), &pose(), &settings).unwrap();
            let fast = render_labels(&g, &label_of, &camera(), &pose(), &settings).unwrap();
            assert_eq!(fast.alpha, channels.alpha, "seed {seed}");
            assert_eq!(fast.depth, channels.depth, "seed {seed}");
            let mut compared = 0;
            for p in 0..fast.labels.len() {
                let weights = &channels.features[p * labels..(p + 1) * labels];
                let best = weights.iter().cloned().fold(0.0f32, f32::max);
                if best <= 0.0 {
                    assert_eq!(fast.labels[p], None, "seed {seed} pixel {p}");
                    continue;
                }
                // Where two labels tie to rounding, either is right.
                let chosen = fast.labels[p].expect("a rendered pixel has a label") as usize;
                assert!(
                    weights[chosen] >= best * (1.0 - 1e-5),
                    "seed {seed} pixel {p}: {weights:?} chose {chosen}"
                );
                compared += 1;
            }
            assert!(compared > 100, "seed {seed}: {compared} pixels");
        }
        let (g, _) = scene(1, 10, 0);
        assert!(
            render_labels(&g, &[0; 9], &camera(), &pose(), &RasterSettings::default()).is_err()
        );
    }

    #[test]
    fn the_comparison_is_sensitive_to_a_small_change() {
        // A 3% different low-pass filter is far outside the tolerance: the check above has teeth.
        let (g, features) = scene(1, 40, 3);
        let fast = render(
            &g,
            &features,
            3,
            &camera(),
            &pose(),
            &RasterSettings::default(),
        )
        .unwrap();
        let other = RasterSettings {
            low_pass: 0.31,
            ..RasterSettings::default()
        };
        let slow = reference::render(&g, &features, 3, &camera(), &pose(), &other).unwrap();
        assert!(relative_error(&fast.features, &slow.features) > 1e-3);
    }

    #[test]
    fn odd_tile_sizes_and_rotated_cameras_match_the_reference() {
        let (g, features) = scene(7, 120, 3);
        let settings = RasterSettings {
            tile_size: 7,
            ..RasterSettings::default()
        };
        let camera_from_world = Rigid::new(
            DQuat::from_rotation_y(0.2) * DQuat::from_rotation_z(0.4),
            glam::DVec3::new(0.1, -0.2, 0.5),
        );
        let fast = render(&g, &features, 3, &camera(), &camera_from_world, &settings).unwrap();
        let slow =
            reference::render(&g, &features, 3, &camera(), &camera_from_world, &settings).unwrap();
        assert!(relative_error(&fast.features, &slow.features) <= 1e-4);
    }

    #[test]
    fn rendering_is_deterministic_across_thread_counts() {
        let (g, features) = scene(11, 400, 5);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    render(
                        &g,
                        &features,
                        5,
                        &camera(),
                        &pose(),
                        &RasterSettings::default(),
                    )
                    .unwrap()
                })
        };
        assert_eq!(run(1), run(2));
        assert_eq!(run(2), run(3));
    }

    fn single(mean: Vec3, opacity: f32, scale: Vec3, rotation: Quat) -> Render {
        let mut g = Gaussians::with_dims(0, 0);
        g.push(mean, opacity, scale, rotation, Vec3::ONE, &[], &[]);
        let r = render(
            &g,
            &[1.0],
            1,
            &camera(),
            &pose(),
            &RasterSettings::default(),
        )
        .unwrap();
        assert_valid(&r);
        let slow = reference::render(
            &g,
            &[1.0],
            1,
            &camera(),
            &pose(),
            &RasterSettings::default(),
        )
        .unwrap();
        assert!(
            relative_error(&r.alpha, &slow.alpha) <= 1e-4 || slow.alpha.iter().all(|a| *a == 0.0)
        );
        r
    }

    fn covered(r: &Render) -> usize {
        r.alpha.iter().filter(|a| **a > 0.0).count()
    }

    #[test]
    fn degenerate_scales_stay_finite() {
        let centre = Vec3::new(0.0, 0.0, 2.0);
        for scale in [
            Vec3::ZERO,
            Vec3::splat(-0.1),
            Vec3::splat(1e-9),
            Vec3::splat(1e6),
            Vec3::new(0.5, 0.5, 0.0),
        ] {
            let r = single(centre, 0.9, scale, Quat::IDENTITY);
            assert!(covered(&r) > 0, "scale {scale} renders something");
        }
        // Zero scale is the low-pass footprint: a few pixels, not nothing and not everything.
        assert!(covered(&single(centre, 0.9, Vec3::ZERO, Quat::IDENTITY)) < 30);
        // Negative scales are their absolute values.
        assert_eq!(
            single(centre, 0.9, Vec3::splat(-0.1), Quat::IDENTITY),
            single(centre, 0.9, Vec3::splat(0.1), Quat::IDENTITY)
        );
    }

    #[test]
    fn near_singular_projected_covariances_stay_invertible() {
        // A needle across the view projects to a line, one along the view to a point: without the
        // low-pass both 2D covariances are singular.
        let centre = Vec3::new(0.0, 0.0, 2.0);
        let across = single(centre, 0.9, Vec3::new(0.5, 1e-9, 1e-9), Quat::IDENTITY);
        let along = single(centre, 0.9, Vec3::new(1e-9, 1e-9, 0.5), Quat::IDENTITY);
        assert!(covered(&across) > covered(&along));
        let row = 17 * 48;
        // 14 px from the centre is ~1.4σ of the needle's 10 px: alpha 0.9·e^(-1) ≈ 0.33.
        assert!(
            across.alpha[row + 10] > 0.25 && across.alpha[row + 38] > 0.25,
            "the line spans the view"
        );
        assert!(across.alpha[row - 48 * 5 + 24] < 0.05, "and is thin");
        assert!(covered(&along) < 30, "a point-like footprint");
    }

    #[test]
    fn zero_and_non_unit_quaternions_are_handled() {
        let centre = Vec3::new(0.1, 0.0, 2.0);
        let scale = Vec3::new(0.3, 0.05, 0.05);
        let zero = single(centre, 0.8, scale, Quat::from_xyzw(0.0, 0.0, 0.0, 0.0));
        let identity = single(centre, 0.8, scale, Quat::IDENTITY);
        assert_eq!(zero, identity);
        let scaled = single(centre, 0.8, scale, Quat::from_xyzw(0.0, 0.0, 3.0, 3.0));
        let unit = single(
            centre,
            0.8,
            scale,
            Quat::from_xyzw(0.0, 0.0, 1.0, 1.0).normalize(),
        );
        assert_eq!(scaled, unit);
    }

    #[test]
    fn gaussians_behind_on_and_far_from_the_near_plane() {
        let scale = Vec3::splat(0.1);
        assert_eq!(
            covered(&single(
                Vec3::new(0.0, 0.0, -1.0),
                1.0,
                scale,
                Quat::IDENTITY
            )),
            0
        );
        assert_eq!(
            covered(&single(
                Vec3::new(0.0, 0.0, DEFAULT_NEAR as f32),
                1.0,
                scale,
                Quat::IDENTITY
            )),
            0
        );
        assert_eq!(
            covered(&single(
                Vec3::new(0.0, 0.0, 1e-6),
                1.0,
                scale,
                Quat::IDENTITY
            )),
            0
        );
        let far = single(Vec3::new(0.0, 0.0, 1e6), 1.0, scale, Quat::IDENTITY);
        assert!(covered(&far) > 0 && covered(&far) < 30);
        let at = 17 * 48 + 24;
        assert!((far.depth[at] - 1e6).abs() / 1e6 < 1e-5);
    }

    #[test]
    fn opacity_zero_and_one() {
        let centre = Vec3::new(0.0, 0.0, 2.0);
        assert_eq!(
            covered(&single(centre, 0.0, Vec3::splat(0.2), Quat::IDENTITY)),
            0
        );
        let opaque = single(centre, 1.0, Vec3::splat(0.2), Quat::IDENTITY);
        // Alpha is capped at 0.99 per Gaussian.
        assert!(opaque.alpha.iter().all(|a| *a <= 0.99 + 1e-6));
        assert!(opaque.alpha.iter().any(|a| *a > 0.98));
    }

    #[test]
    fn centres_on_tile_borders_and_whole_image_gaussians() {
        // Pixel (16, 16) is a tile corner: its pixel and its neighbours across the border all see it.
        let camera = camera();
        let z = 2.0;
        let on_border = Vec3::new(
            ((16.0 - camera.cx) / camera.fx * z) as f32,
            ((16.0 - camera.cy) / camera.fy * z) as f32,
            z as f32,
        );
        let r = single(on_border, 0.9, Vec3::splat(0.02), Quat::IDENTITY);
        let at = |x: usize, y: usize| r.alpha[y * 48 + x];
        assert!(at(16, 16) > 0.5 && (at(15, 15) - at(17, 17)).abs() < 1e-3 && at(15, 16) > 0.0);
        let whole = single(
            Vec3::new(0.0, 0.0, 1.0),
            0.9,
            Vec3::splat(50.0),
            Quat::IDENTITY,
        );
        assert_eq!(covered(&whole), 48 * 36);
    }

    #[test]
    fn empty_scenes_render_nothing_and_bad_inputs_are_errors() {
        let empty = render(
            &Gaussians::default(),
            &[],
            4,
            &camera(),
            &pose(),
            &RasterSettings::default(),
        )
        .unwrap();
        assert!(empty.alpha.iter().all(|a| *a == 0.0) && empty.features.iter().all(|f| *f == 0.0));
        let (mut g, features) = scene(5, 3, 2);
        assert!(matches!(
            render(
                &g,
                &features[..5],
                2,
                &camera(),
                &pose(),
                &RasterSettings::default()
            ),
            Err(RasterError::FeatureLength { .. })
        ));
        let mut nan_features = features.clone();
        nan_features[1] = f32::NAN;
        assert!(matches!(
            render(
                &g,
                &nan_features,
                2,
                &camera(),
                &pose(),
                &RasterSettings::default()
            ),
            Err(RasterError::NonFiniteFeature(1))
        ));
        let bad_pose = Rigid::new(DQuat::IDENTITY, glam::DVec3::new(f64::INFINITY, 0.0, 0.0));
        assert!(matches!(
            render(
                &g,
                &features,
                2,
                &camera(),
                &bad_pose,
                &RasterSettings::default()
            ),
            Err(RasterError::BadPose)
        ));
        g.means[0].x = f32::NAN;
        assert!(matches!(
            render(
                &g,
                &features,
                2,
                &camera(),
                &pose(),
                &RasterSettings::default()
            ),
            Err(RasterError::Gaussians(_))
        ));
    }

    #[test]
    fn rendered_probabilities_sum_to_at_most_one() {
        let (g, _) = scene(9, 200, 0);
        let k = 4;
        let mut rng = Lcg(3);
        let mut probabilities = Vec::new();
        for _ in 0..g.len() {
            let raw: Vec<f32> = (0..k).map(|_| rng.next()).collect();
            let sum: f32 = raw.iter().sum();
            probabilities.extend(raw.iter().map(|v| v / sum));
        }
        let r = render(
            &g,
            &probabilities,
            k,
            &camera(),
            &pose(),
            &RasterSettings::default(),
        )
        .unwrap();
        for (pixel, alpha) in r.alpha.iter().enumerate() {
            let sum: f32 = r.features[pixel * k..(pixel + 1) * k].iter().sum();
            assert!(sum <= 1.0 + 1e-5 && (sum - alpha).abs() < 1e-4);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        #[test]
        fn any_finite_gaussians_render_finite_and_in_range(
            means in prop::collection::vec((-5f32..5.0, -5f32..5.0, -2f32..1e3), 0..20),
            scales in prop::collection::vec((-1e3f32..1e3, 0f32..1e-3, 0f32..1e6), 20),
            opacities in prop::collection::vec(-0.5f32..1.5, 20),
            quats in prop::collection::vec((-1f32..1.0, -1f32..1.0, -1f32..1.0, -1f32..1.0), 20),
        ) {
            let mut g = Gaussians::with_dims(0, 0);
            for (i, m) in means.iter().enumerate() {
                let s = scales[i];
                let q = quats[i];
                g.push(Vec3::new(m.0, m.1, m.2), opacities[i], Vec3::new(s.0, s.1, s.2), Quat::from_xyzw(q.0, q.1, q.2, q.3), Vec3::ONE, &[], &[]);
            }
            let features = vec![0.5; g.len() * 2];
            let r = render(&g, &features, 2, &camera(), &pose(), &RasterSettings::default()).unwrap();
            assert_valid(&r);
        }

        #[test]
        fn result_does_not_depend_on_gaussian_order(seed in 0u64..1000, rotate in 1usize..30) {
            let (g, features) = scene(seed, 30, 2);
            let order: Vec<usize> = (0..30).map(|i| (i + rotate) % 30).collect();
            let mut shuffled = Gaussians::with_dims(0, 0);
            let mut shuffled_features = Vec::new();
            for &i in &order {
                shuffled.push(g.means[i], g.opacities[i], g.scales[i], g.rotations[i], g.colors[i], &[], &[]);
                shuffled_features.extend_from_slice(&features[i * 2..i * 2 + 2]);
            }
            let a = render(&g, &features, 2, &camera(), &pose(), &RasterSettings::default()).unwrap();
            let b = render(&shuffled, &shuffled_features, 2, &camera(), &pose(), &RasterSettings::default()).unwrap();
            prop_assert_eq!(a, b);
        }
    }
}

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

use rayon::prelude::*;

mod composite;
mod project;
pub mod reference;

use super::camera::Camera;
use super::gaussians::{GaussianError, Gaussians};
use super::Rigid;
use composite::{composite, composite_tile};
use project::{bin, check_inputs};

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

#[cfg(test)]
mod tests;

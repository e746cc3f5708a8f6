//! Screen space: each Gaussian's covariance projected (EWA, with the low-pass), its opacity-aware
//! footprint, culling at the near plane, and the footprints binned into tiles by depth.

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use super::{RasterError, RasterSettings, Result, ALPHA_MIN, FOOTPRINT_MARGIN, JACOBIAN_FOV_LIMIT};
use crate::recon::camera::Camera;
use crate::recon::gaussians::{safe_rotation, Gaussians};
use crate::recon::Rigid;

/// The pixels of one tile: columns `x0..x1`, rows `y0..y1`.
#[derive(Debug)]
pub(super) struct TileBounds {
    pub(super) x0: usize,
    pub(super) y0: usize,
    pub(super) x1: usize,
    pub(super) y1: usize,
}

/// A Gaussian in screen space.
#[derive(Debug, Clone, Copy)]
pub(super) struct Splat {
    /// Index of the Gaussian (and of its features).
    pub(super) index: usize,
    pub(super) mean: [f32; 2],
    /// Inverse 2D covariance (a, b, c): power = -½(a dx² + c dy²) - b dx dy.
    pub(super) conic: [f32; 3],
    pub(super) opacity: f32,
    /// Squared Mahalanobis radius of the footprint (alpha ≥ ALPHA_MIN inside).
    pub(super) radius2: f32,
    pub(super) depth: f64,
    /// Inclusive pixel bounds of the footprint, clipped to the image.
    pub(super) x0: usize,
    pub(super) x1: usize,
    pub(super) y0: usize,
    pub(super) y1: usize,
}

pub(super) fn check_inputs(
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

pub(super) fn project(
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
pub(super) struct Binned {
    pub(super) splats: Vec<Splat>,
    pub(super) keys: Vec<u128>,
    pub(super) ranges: Vec<(usize, usize)>,
    pub(super) tiles_x: usize,
}

impl Binned {
    /// Tile (`tx`, `ty`)'s pixel bounds and its splats, front to back.
    pub(super) fn tile(
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

pub(super) fn bin(
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

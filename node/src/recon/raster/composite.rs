//! Compositing: front to back over one tile, per pixel exactly the loop of 3DGS, stopping when
//! transmittance would fall below [`TRANSMITTANCE_MIN`].

use super::project::{Splat, TileBounds};
use super::{ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN};

#[derive(Debug)]
pub(super) struct TileOutput {
    pub(super) transmittance: Vec<f32>,
    pub(super) depth: Vec<f32>,
    pub(super) features: Vec<f32>,
}

/// Composite a tile Gaussian by Gaussian (front to back), touching only the pixels of each
/// footprint; per pixel this is exactly the front-to-back loop of 3DGS.
pub(super) fn composite_tile(
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
pub(super) fn composite(
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

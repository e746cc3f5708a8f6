//! A view rendered at a sensor's resolution, resampled to a model's resolution exactly as the node
//! resamples its camera images (`node/src/model/reconstruction.rs`: colour bilinear with pixel
//! centres on pixel centres, depth nearest, the camera scaled about pixel centres). A training set
//! rendered this way shows the model the sensor effects at the scale the node meets them: applied
//! at 128 × 96 instead, a depth edge drops pixels 2.5 times as wide and read noise is not averaged
//! by the resampling. The node's test `dataset_resampling_matches_the_node` pins the parity.

use crate::render::{Pinhole, RenderedView};
use crate::simulation::SimView;

/// Bilinear resize of interleaved RGB (the node's `resize_rgb_planar`, rounded back to bytes).
pub fn bilinear_rgb(rgb: &[u8], from: (usize, usize), to: (usize, usize)) -> Vec<u8> {
    let ((w, h), (width, height)) = (from, to);
    let mut out = vec![0u8; 3 * width * height];
    if w == 0 || h == 0 {
        return out;
    }
    let sx = w as f32 / width as f32;
    let sy = h as f32 / height as f32;
    for y in 0..height {
        let fy = ((y as f32 + 0.5) * sy - 0.5).clamp(0.0, (h - 1) as f32);
        let (y0, wy) = (fy.floor() as usize, fy - fy.floor());
        let y1 = (y0 + 1).min(h - 1);
        for x in 0..width {
            let fx = ((x as f32 + 0.5) * sx - 0.5).clamp(0.0, (w - 1) as f32);
            let (x0, wx) = (fx.floor() as usize, fx - fx.floor());
            let x1 = (x0 + 1).min(w - 1);
            for c in 0..3 {
                let at = |xx: usize, yy: usize| f32::from(rgb[(yy * w + xx) * 3 + c]);
                let top = at(x0, y0) * (1.0 - wx) + at(x1, y0) * wx;
                let bottom = at(x0, y1) * (1.0 - wx) + at(x1, y1) * wx;
                let value = top * (1.0 - wy) + bottom * wy;
                out[(y * width + x) * 3 + c] = value.round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

/// Nearest-neighbour resize (the node's `resize_depth`; also for the ground-truth labels, which
/// must not be blended).
pub fn nearest<T: Copy>(values: &[T], from: (usize, usize), to: (usize, usize)) -> Vec<T> {
    let ((w, h), (width, height)) = (from, to);
    let mut out = Vec::with_capacity(width * height);
    if w == 0 || h == 0 {
        return out;
    }
    for y in 0..height {
        let sy = (((y as f32 + 0.5) * h as f32 / height as f32) as usize).min(h - 1);
        for x in 0..width {
            let sx = (((x as f32 + 0.5) * w as f32 / width as f32) as usize).min(w - 1);
            out.push(values[sy * w + sx]);
        }
    }
    out
}

/// The camera after resizing its image (the node's `resized_camera`).
pub fn resized_pinhole(pinhole: &Pinhole, width: u32, height: u32) -> Pinhole {
    let sx = f64::from(width) / f64::from(pinhole.width);
    let sy = f64::from(height) / f64::from(pinhole.height);
    Pinhole {
        width,
        height,
        fx: pinhole.fx * sx,
        fy: pinhole.fy * sy,
        cx: (pinhole.cx + 0.5) * sx - 0.5,
        cy: (pinhole.cy + 0.5) * sy - 0.5,
    }
}

/// `view` at `width × height`: what the sensor recorded resampled as the node resamples it, the
/// ground truth by nearest neighbour (the labels of the pixels the node's depth comes from).
pub fn view_at(view: &SimView, width: u32, height: u32) -> SimView {
    let from = (view.truth.width as usize, view.truth.height as usize);
    let to = (width as usize, height as usize);
    let truth = RenderedView {
        width,
        height,
        rgb: bilinear_rgb(&view.truth.rgb, from, to),
        depth: nearest(&view.truth.depth, from, to),
        instance: nearest(&view.truth.instance, from, to),
        class: nearest(&view.truth.class, from, to),
    };
    SimView {
        camera: view.camera,
        pinhole: resized_pinhole(&view.pinhole, width, height),
        distortion: view.distortion,
        rotation: view.rotation,
        position: view.position,
        truth,
        rgb: Some(bilinear_rgb(view.sensor_rgb(), from, to)),
        depth: Some(nearest(view.sensor_depth(), from, to)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_a_flat_image_keeps_its_values() {
        let rgb = vec![7u8; 3 * 10 * 6];
        assert!(bilinear_rgb(&rgb, (10, 6), (4, 3)).iter().all(|v| *v == 7));
        let depth = vec![1.5f32; 60];
        assert_eq!(nearest(&depth, (10, 6), (4, 3)), vec![1.5f32; 12]);
    }

    #[test]
    fn resampling_an_empty_image_stays_empty_and_finite() {
        assert!(bilinear_rgb(&[], (0, 0), (4, 3)).iter().all(|v| *v == 0));
        assert!(nearest::<f32>(&[], (0, 0), (4, 3)).is_empty());
    }

    #[test]
    fn a_resized_pinhole_projects_the_same_ray_onto_the_same_place() {
        let p = Pinhole::from_fov(320, 240, 90f64.to_radians());
        let q = resized_pinhole(&p, 128, 96);
        // A ray through sensor pixel centre u lands on model coordinate (u + 0.5) * 0.4 - 0.5.
        let u = 100.0;
        let u_model = (u + 0.5) * 0.4 - 0.5;
        let ray = (u - p.cx) / p.fx;
        assert!((q.cx + ray * q.fx - u_model).abs() < 1e-9);
    }
}

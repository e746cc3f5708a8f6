//! Metrics every benchmark reports (ARCHITECTURE.md §6), defined exactly as scikit-image / scikit-learn
//! compute them (checked against reference numbers those libraries produced):
//! PSNR; SSIM (11×11 Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03, population covariance,
//! mean over pixels whose window lies inside the image, then over channels); depth abs-rel and
//! δ < 1.25 on valid pixels; semantic mIoU and pixel accuracy; adjusted Rand index.

use std::collections::HashMap;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricError {
    #[error("inputs differ in size: {0} vs {1}")]
    SizeMismatch(usize, usize),
    #[error("image of {width}×{height}×{channels} does not hold {len} values")]
    Shape {
        width: usize,
        height: usize,
        channels: usize,
        len: usize,
    },
    #[error("SSIM needs at least 11×11 pixels, got {0}×{1}")]
    TooSmall(usize, usize),
    #[error("no valid pixels")]
    Empty,
    #[error("data range must be positive and finite")]
    BadRange,
}

pub type Result<T> = std::result::Result<T, MetricError>;

fn same_len(a: usize, b: usize) -> Result<()> {
    if a == b {
        Ok(())
    } else {
        Err(MetricError::SizeMismatch(a, b))
    }
}

/// Peak signal-to-noise ratio in dB; infinite for identical inputs (as scikit-image).
pub fn psnr(prediction: &[f32], target: &[f32], data_range: f64) -> Result<f64> {
    same_len(prediction.len(), target.len())?;
    if prediction.is_empty() {
        return Err(MetricError::Empty);
    }
    if !(data_range > 0.0 && data_range.is_finite()) {
        return Err(MetricError::BadRange);
    }
    let mse = prediction
        .iter()
        .zip(target)
        .map(|(p, t)| (f64::from(*p) - f64::from(*t)).powi(2))
        .sum::<f64>()
        / prediction.len() as f64;
    Ok(10.0 * (data_range * data_range / mse).log10())
}

const SSIM_SIGMA: f64 = 1.5;
const SSIM_RADIUS: usize = 5; // int(3.5 σ + 0.5), scipy's default truncation
const SSIM_K1: f64 = 0.01;
const SSIM_K2: f64 = 0.03;

fn gaussian_kernel() -> [f64; 2 * SSIM_RADIUS + 1] {
    let mut k = [0.0; 2 * SSIM_RADIUS + 1];
    for (i, v) in k.iter_mut().enumerate() {
        let x = i as f64 - SSIM_RADIUS as f64;
        *v = (-x * x / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let sum: f64 = k.iter().sum();
    k.map(|v| v / sum)
}

/// Mean SSIM of two images, row-major `height × width × channels`.
pub fn ssim(
    prediction: &[f32],
    target: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    data_range: f64,
) -> Result<f64> {
    same_len(prediction.len(), target.len())?;
    if prediction.len() != width * height * channels || channels == 0 {
        return Err(MetricError::Shape {
            width,
            height,
            channels,
            len: prediction.len(),
        });
    }
    if width < 2 * SSIM_RADIUS + 1 || height < 2 * SSIM_RADIUS + 1 {
        return Err(MetricError::TooSmall(width, height));
    }
    if !(data_range > 0.0 && data_range.is_finite()) {
        return Err(MetricError::BadRange);
    }
    let kernel = gaussian_kernel();
    let c1 = (SSIM_K1 * data_range).powi(2);
    let c2 = (SSIM_K2 * data_range).powi(2);
    let r = SSIM_RADIUS;
    let mut total = 0.0;
    for c in 0..channels {
        let at = |img: &[f32], x: usize, y: usize| f64::from(img[(y * width + x) * channels + c]);
        // Horizontal pass of the five filtered maps (x, y, x², y², xy) for every row.
        let mut horizontal = vec![[0.0f64; 5]; width * height];
        for y in 0..height {
            for x in r..width - r {
                let mut sums = [0.0; 5];
                for (k, w) in kernel.iter().enumerate() {
                    let (a, b) = (at(prediction, x + k - r, y), at(target, x + k - r, y));
                    sums[0] += w * a;
                    sums[1] += w * b;
                    sums[2] += w * a * a;
                    sums[3] += w * b * b;
                    sums[4] += w * a * b;
                }
                horizontal[y * width + x] = sums;
            }
        }
        let mut channel_sum = 0.0;
        for y in r..height - r {
            for x in r..width - r {
                let mut m = [0.0; 5];
                for (k, w) in kernel.iter().enumerate() {
                    let h = horizontal[(y + k - r) * width + x];
                    for (mi, hi) in m.iter_mut().zip(h) {
                        *mi += w * hi;
                    }
                }
                let (mx, my) = (m[0], m[1]);
                let (vx, vy, vxy) = (m[2] - mx * mx, m[3] - my * my, m[4] - mx * my);
                channel_sum += ((2.0 * mx * my + c1) * (2.0 * vxy + c2))
                    / ((mx * mx + my * my + c1) * (vx + vy + c2));
            }
        }
        total += channel_sum / ((width - 2 * r) * (height - 2 * r)) as f64;
    }
    Ok(total / channels as f64)
}

/// Depth errors on pixels where both depths are finite and positive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthScores {
    pub abs_rel: f64,
    /// Fraction with max(pred/gt, gt/pred) < 1.25.
    pub delta1: f64,
    pub valid: usize,
}

pub fn depth_scores(prediction: &[f32], target: &[f32]) -> Result<DepthScores> {
    same_len(prediction.len(), target.len())?;
    let (mut abs_rel, mut within, mut valid) = (0.0, 0usize, 0usize);
    for (p, t) in prediction.iter().zip(target) {
        let (p, t) = (f64::from(*p), f64::from(*t));
        if !(p.is_finite() && t.is_finite() && p > 0.0 && t > 0.0) {
            continue;
        }
        valid += 1;
        abs_rel += (p - t).abs() / t;
        if (p / t).max(t / p) < 1.25 {
            within += 1;
        }
    }
    if valid == 0 {
        return Err(MetricError::Empty);
    }
    Ok(DepthScores {
        abs_rel: abs_rel / valid as f64,
        delta1: within as f64 / valid as f64,
        valid,
    })
}

/// Semantic segmentation scores.
#[derive(Debug, Clone, PartialEq)]
pub struct SemanticScores {
    /// Mean IoU over classes present in the target or the prediction.
    pub miou: f64,
    pub pixel_accuracy: f64,
    /// IoU per class (NaN for classes absent from both).
    pub iou: Vec<f64>,
}

/// mIoU and pixel accuracy over `num_classes` labels; labels at or above `num_classes` count as
/// the explicit `other` class (index `other`). Pixels whose target equals `ignore` are skipped.
pub fn semantic_scores(
    prediction: &[u32],
    target: &[u32],
    num_classes: usize,
    other: u32,
    ignore: Option<u32>,
) -> Result<SemanticScores> {
    same_len(prediction.len(), target.len())?;
    let k = num_classes.max(other as usize + 1);
    let fold = |label: u32| {
        if (label as usize) < num_classes {
            label as usize
        } else {
            other as usize
        }
    };
    let mut confusion = vec![0u64; k * k];
    let mut counted = 0u64;
    for (p, t) in prediction.iter().zip(target) {
        if Some(*t) == ignore {
            continue;
        }
        confusion[fold(*t) * k + fold(*p)] += 1;
        counted += 1;
    }
    if counted == 0 {
        return Err(MetricError::Empty);
    }
    let correct: u64 = (0..k).map(|c| confusion[c * k + c]).sum();
    let mut iou = vec![f64::NAN; k];
    for (c, value) in iou.iter_mut().enumerate() {
        let tp = confusion[c * k + c];
        let in_target: u64 = (0..k).map(|j| confusion[c * k + j]).sum();
        let in_prediction: u64 = (0..k).map(|i| confusion[i * k + c]).sum();
        let union = in_target + in_prediction - tp;
        if union > 0 {
            *value = tp as f64 / union as f64;
        }
    }
    let present: Vec<f64> = iou.iter().copied().filter(|v| !v.is_nan()).collect();
    Ok(SemanticScores {
        miou: present.iter().sum::<f64>() / present.len() as f64,
        pixel_accuracy: correct as f64 / counted as f64,
        iou,
    })
}

fn pairs(n: u64) -> f64 {
    (n as f64) * (n.saturating_sub(1) as f64) / 2.0
}

/// Adjusted Rand index of two labelings of the same items (label values are arbitrary).
/// As scikit-learn: 1.0 when both are a single cluster or both all singletons.
pub fn adjusted_rand_index(a: &[u32], b: &[u32]) -> Result<f64> {
    same_len(a.len(), b.len())?;
    let n = a.len() as u64;
    if n == 0 {
        return Err(MetricError::Empty);
    }
    let mut joint: HashMap<(u32, u32), u64> = HashMap::new();
    let mut rows: HashMap<u32, u64> = HashMap::new();
    let mut cols: HashMap<u32, u64> = HashMap::new();
    for (x, y) in a.iter().zip(b) {
        *joint.entry((*x, *y)).or_default() += 1;
        *rows.entry(*x).or_default() += 1;
        *cols.entry(*y).or_default() += 1;
    }
    let (r, c) = (rows.len() as u64, cols.len() as u64);
    if (r == 1 && c == 1) || (r == n && c == n) {
        return Ok(1.0);
    }
    let index: f64 = joint.values().map(|v| pairs(*v)).sum();
    let sum_rows: f64 = rows.values().map(|v| pairs(*v)).sum();
    let sum_cols: f64 = cols.values().map(|v| pairs(*v)).sum();
    let expected = sum_rows * sum_cols / pairs(n);
    let max = (sum_rows + sum_cols) / 2.0;
    if max == expected {
        return Ok(1.0);
    }
    Ok((index - expected) / (max - expected))
}

/// Full-resolution `values` (row-major, `full` = width × height) sampled at the centres of a
/// `size` grid (nearest: labels and depth must not blend).
pub fn sample_nearest<T: Copy>(values: &[T], full: (usize, usize), size: (usize, usize)) -> Vec<T> {
    let ((fw, fh), (w, h)) = (full, size);
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        let sy = (((y as f64 + 0.5) * fh as f64 / h as f64) as usize).min(fh - 1);
        for x in 0..w {
            let sx = (((x as f64 + 0.5) * fw as f64 / w as f64) as usize).min(fw - 1);
            out.push(values[sy * fw + sx]);
        }
    }
    out
}

/// Where one object's pixels went in a predicted instance segmentation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectCoverage {
    pub object: u32,
    pub pixels: u64,
    /// IoU of the object's pixels with its best-overlapping object instance (0 when none).
    pub best_iou: f64,
    /// Shares of the object's pixels: in that best instance, in other object instances (split),
    /// in instances that are mostly structure (given to the room), and in none (noise, not lifted).
    pub in_best: f64,
    pub split: f64,
    pub to_structure: f64,
    pub unassigned: f64,
    /// Share of the best instance's pixels that are not this object (merged with something else).
    pub impurity: f64,
}

/// Per object (truth labels other than `structure`, with at least `min_pixels` pixels): how well
/// the predicted instances cover it. `predicted` uses `unassigned` for pixels in no instance; a
/// predicted instance whose pixels are mostly `structure` counts as structure, not as an object
/// instance. This locates a segmentation's loss: objects split, merged, given to the room, or
/// dropped.
pub fn object_coverage(
    predicted: &[u32],
    truth: &[u32],
    unassigned: u32,
    structure: u32,
    min_pixels: u64,
) -> Result<Vec<ObjectCoverage>> {
    same_len(predicted.len(), truth.len())?;
    let mut joint: HashMap<(u32, u32), u64> = HashMap::new();
    let mut instance_sizes: HashMap<u32, u64> = HashMap::new();
    let mut object_sizes: HashMap<u32, u64> = HashMap::new();
    for (&p, &t) in predicted.iter().zip(truth) {
        *joint.entry((p, t)).or_default() += 1;
        *object_sizes.entry(t).or_default() += 1;
        if p != unassigned {
            *instance_sizes.entry(p).or_default() += 1;
        }
    }
    let structure_instance = |p: u32| {
        let size = instance_sizes.get(&p).copied().unwrap_or(0);
        2 * joint.get(&(p, structure)).copied().unwrap_or(0) > size
    };
    let mut objects: Vec<(u32, u64)> = object_sizes
        .into_iter()
        .filter(|&(t, n)| t != structure && n >= min_pixels.max(1))
        .collect();
    objects.sort_unstable();
    Ok(objects
        .into_iter()
        .map(|(object, pixels)| {
            let (mut best, mut best_overlap) = (None, 0u64);
            let (mut structure_pixels, mut none) = (0u64, 0u64);
            let mut overlaps: Vec<(u32, u64)> = joint
                .iter()
                .filter(|((_, t), _)| *t == object)
                .map(|((p, _), &n)| (*p, n))
                .collect();
            overlaps.sort_unstable();
            for &(p, n) in &overlaps {
                if p == unassigned {
                    none += n;
                } else if structure_instance(p) {
                    structure_pixels += n;
                } else if n > best_overlap {
                    (best, best_overlap) = (Some(p), n);
                }
            }
            let share = |n: u64| n as f64 / pixels as f64;
            let (best_iou, impurity) = best.map_or((0.0, 0.0), |p| {
                let size = instance_sizes[&p];
                let union = pixels + size - best_overlap;
                (
                    best_overlap as f64 / union as f64,
                    1.0 - best_overlap as f64 / size as f64,
                )
            });
            let split = pixels - best_overlap - structure_pixels - none;
            ObjectCoverage {
                object,
                pixels,
                best_iou,
                in_best: share(best_overlap),
                split: share(split),
                to_structure: share(structure_pixels),
                unassigned: share(none),
                impurity,
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_taken_at_cell_centres() {
        let full: Vec<u16> = (0..16).collect(); // 4 × 4
        assert_eq!(sample_nearest(&full, (4, 4), (2, 2)), vec![5, 7, 13, 15]);
        assert_eq!(sample_nearest(&full, (4, 4), (4, 4)), full);
    }

    const REFERENCE: &str = include_str!("../../tests/reference/metrics.json");

    fn floats(v: &serde_json::Value) -> Vec<f32> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().map_or(f32::NAN, |f| f as f32))
            .collect()
    }

    fn labels(v: &serde_json::Value) -> Vec<u32> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap() as u32)
            .collect()
    }

    fn close(a: f64, b: f64, tol: f64, what: &str) {
        assert!(
            (a - b).abs() <= tol * b.abs().max(1.0),
            "{what}: {a} vs reference {b}"
        );
    }

    #[test]
    fn match_scikit_image_and_scikit_learn() {
        let reference: serde_json::Value = serde_json::from_str(REFERENCE).unwrap();
        let images = reference["images"].as_array().unwrap();
        assert!(images.len() >= 3);
        for case in images {
            let (w, h, c) = (
                case["width"].as_u64().unwrap() as usize,
                case["height"].as_u64().unwrap() as usize,
                case["channels"].as_u64().unwrap() as usize,
            );
            let (a, b) = (floats(&case["prediction"]), floats(&case["target"]));
            close(
                psnr(&a, &b, 1.0).unwrap(),
                case["psnr"].as_f64().unwrap(),
                1e-6,
                "psnr",
            );
            close(
                ssim(&a, &b, w, h, c, 1.0).unwrap(),
                case["ssim"].as_f64().unwrap(),
                1e-6,
                "ssim",
            );
        }
        for case in reference["depth"].as_array().unwrap() {
            let s = depth_scores(&floats(&case["prediction"]), &floats(&case["target"])).unwrap();
            close(
                s.abs_rel,
                case["abs_rel"].as_f64().unwrap(),
                1e-6,
                "abs_rel",
            );
            close(s.delta1, case["delta1"].as_f64().unwrap(), 1e-12, "delta1");
        }
        for case in reference["semantic"].as_array().unwrap() {
            let s = semantic_scores(
                &labels(&case["prediction"]),
                &labels(&case["target"]),
                case["num_classes"].as_u64().unwrap() as usize,
                case["other"].as_u64().unwrap() as u32,
                None,
            )
            .unwrap();
            close(s.miou, case["miou"].as_f64().unwrap(), 1e-12, "miou");
            close(
                s.pixel_accuracy,
                case["pixel_accuracy"].as_f64().unwrap(),
                1e-12,
                "accuracy",
            );
        }
        for case in reference["ari"].as_array().unwrap() {
            let ari = adjusted_rand_index(&labels(&case["a"]), &labels(&case["b"])).unwrap();
            close(ari, case["ari"].as_f64().unwrap(), 1e-12, "ari");
        }
    }

    #[test]
    fn object_coverage_splits_an_object_into_where_its_pixels_went() {
        const NONE: u32 = u32::MAX;
        let (a, b, c, room) = (10, 11, 12, 13);
        let mut predicted = Vec::new();
        let mut truth = Vec::new();
        let mut put = |p: u32, t: u32, n: usize| {
            predicted.extend(std::iter::repeat_n(p, n));
            truth.extend(std::iter::repeat_n(t, n));
        };
        // Object 1: 6 pixels in A, 2 in B, 1 given to the room, 1 in no instance.
        put(a, 1, 6);
        put(b, 1, 2);
        put(room, 1, 1);
        put(NONE, 1, 1);
        // Object 2: 2 pixels merged into A, 4 in C; the room instance is mostly structure (0).
        put(a, 2, 2);
        put(c, 2, 4);
        put(room, 0, 8);
        let all = object_coverage(&predicted, &truth, NONE, 0, 1).unwrap();
        assert_eq!(all.len(), 2, "structure is not an object");
        let one = all[0];
        assert_eq!((one.object, one.pixels), (1, 10));
        assert!((one.best_iou - 6.0 / 12.0).abs() < 1e-12);
        assert!((one.in_best - 0.6).abs() < 1e-12);
        assert!((one.split - 0.2).abs() < 1e-12);
        assert!((one.to_structure - 0.1).abs() < 1e-12);
        assert!((one.unassigned - 0.1).abs() < 1e-12);
        assert!((one.impurity - 0.25).abs() < 1e-12, "A holds 2 of object 2");
        let two = all[1];
        assert!((two.best_iou - 4.0 / 6.0).abs() < 1e-12);
        assert!((two.split - 2.0 / 6.0).abs() < 1e-12);
        assert_eq!(two.impurity, 0.0);
        // Small objects are left out; an object in no instance has a zero, finite IoU.
        assert_eq!(
            object_coverage(&predicted, &truth, NONE, 0, 7)
                .unwrap()
                .len(),
            1
        );
        let dropped = object_coverage(&[NONE; 3], &[5; 3], NONE, 0, 1).unwrap();
        assert_eq!(dropped[0].best_iou, 0.0);
        assert_eq!(dropped[0].unassigned, 1.0);
        assert!(object_coverage(&[], &[], NONE, 0, 1).unwrap().is_empty());
    }

    #[test]
    fn hard_cases_stay_meaningful() {
        let img = vec![0.5f32; 12 * 12];
        assert_eq!(psnr(&img, &img, 1.0).unwrap(), f64::INFINITY);
        assert!((ssim(&img, &img, 12, 12, 1, 1.0).unwrap() - 1.0).abs() < 1e-12);
        assert!(matches!(
            ssim(&img[..100], &img[..100], 10, 10, 1, 1.0),
            Err(MetricError::TooSmall(10, 10))
        ));
        assert!(psnr(&img, &img[..3], 1.0).is_err());
        assert!(depth_scores(&[f32::NAN, 0.0], &[1.0, 1.0]).is_err());
        assert_eq!(adjusted_rand_index(&[1, 1, 1], &[7, 7, 7]).unwrap(), 1.0);
        assert_eq!(adjusted_rand_index(&[1, 2, 3], &[4, 5, 6]).unwrap(), 1.0);
        assert_eq!(
            adjusted_rand_index(&[0, 0, 1, 1], &[5, 5, 9, 9]).unwrap(),
            1.0
        );
        let s = semantic_scores(&[0, 9, 9], &[0, 1, 2], 3, 2, None).unwrap();
        // Label 9 folds into `other` (2): one of the two pixels predicted `other` is right.
        assert_eq!(s.pixel_accuracy, 2.0 / 3.0);
        assert!(s.iou[1] == 0.0 && (s.iou[2] - 0.5).abs() < 1e-12);
        assert!(semantic_scores(&[1], &[1], 2, 1, Some(1)).is_err());
    }
}

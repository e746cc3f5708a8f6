//! Metrics every benchmark reports (DESIGN §7), defined exactly as scikit-image / scikit-learn
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

#[cfg(test)]
mod tests {
    use super::*;

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

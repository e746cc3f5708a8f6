//! How noisy a depth camera is, measured from its own images. Consumer depth cameras (structured
//! light, stereo, time of flight) measure range with an error that grows with the square of the
//! range (σ(z) = σ₁ · z², σ₁ the error at 1 m: a few millimetres), which the data sheet may not
//! give and which changes with the surface and the light. Fusion's free-space test allows for it
//! (a far object is not "seen through" by noise), and `eval map` reports it.
//!
//! The estimator: the second difference of depth along image rows, z[u-1] − 2 z[u] + z[u+1], is
//! zero on a plane seen head-on and small on any smooth surface, while independent noise of σ per
//! pixel gives it a spread of σ·√6. Divided by z², its median absolute value over an image gives
//! σ₁ (the median ignores the few triples across an object's edge). Measured on the sensor's own
//! grid: a resampled image spaces its samples unevenly, which a slanted surface turns into second
//! differences that are not noise. Spatially correlated noise (stereo matching smooths over a
//! window) is underestimated.
//!
//! Tried and not kept (benchmark 0-29, `--effects realistic`, measured on 16 cores of a lent
//! machine): shrinking each instance's box by the noise along its view (each extent E to
//! √(E² − (4.1 σ)²), σ = σ₁ r² from its windows' ranges) made faces thin again, so cabinets,
//! fridges and bookshelves fitted (29 objects' IoU up by 0.03 to 0.62), but objects the camera
//! saw only partly (bins, plants, lamps) shrank further (21 down): recall@0.25 / @0.5 / precision
//! 67.8 / 44.1 / 78.3% -> 68.2 / 43.7 / 78.8%, with a cap at half the extent 68.2 / 43.3 / 78.8%.

use super::median;

/// Below this (m at 1 m range) the depth counts as noise-free: the second differences of a
/// rendered or filtered image's smooth and curved surfaces, not noise (the clean simulator's
/// views measure up to 1.2e-4; the `realistic` preset's camera 6.0e-3 against its 6e-3; consumer
/// depth cameras 1e-3 to 1e-2).
pub const MIN_NOISE_AT_1M: f32 = 5e-4;

/// Triples needed before an estimate is trusted.
const MIN_SAMPLES: usize = 500;

/// Normal consistency of the median absolute deviation (σ = 1.4826 · MAD for a normal
/// distribution), and √6, the spread of a second difference of three independent samples.
const MAD_TO_SIGMA: f32 = 1.4826;
const SECOND_DIFFERENCE_SPREAD: f32 = 2.449_489_7;

/// The depth noise at 1 m (σ₁, metres) of row-major depth images (`(metres, width)` each), pooled:
/// `None` when fewer than [`MIN_SAMPLES`] triples of valid pixels exist or the noise is below
/// [`MIN_NOISE_AT_1M`].
pub fn noise_at_1m<'a>(images: impl IntoIterator<Item = (&'a [f32], usize)>) -> Option<f32> {
    let valid = |d: f32| d.is_finite() && d > 0.0;
    let mut scaled = Vec::new();
    for (depth, width) in images {
        if width < 3 {
            continue;
        }
        // Every other row: ~38,000 triples of a 320 × 240 image are plenty for a median, at
        // half the cost (0.7 ms a view on 2 cores).
        for row in depth.chunks_exact(width).step_by(2) {
            for t in row.windows(3) {
                let (a, z, b) = (t[0], t[1], t[2]);
                if valid(a) && valid(z) && valid(b) {
                    scaled.push(((a - 2.0 * z + b) / (z * z)).abs());
                }
            }
        }
    }
    if scaled.len() < MIN_SAMPLES {
        return None;
    }
    let sigma = MAD_TO_SIGMA * median(&mut scaled)? / SECOND_DIFFERENCE_SPREAD;
    (sigma.is_finite() && sigma >= MIN_NOISE_AT_1M).then_some(sigma)
}

/// The median of the measured values among `measurements` (views of a window, windows of a
/// run); `None` when none was measured.
pub fn median_measured(measurements: impl IntoIterator<Item = Option<f32>>) -> Option<f32> {
    let mut measured: Vec<f32> = measurements.into_iter().flatten().collect();
    median(&mut measured)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A wall 2 m ahead and a floor receding in the lower half, 160 × 120.
    fn room(noise_at_1m: f32, seed: u64) -> Vec<f32> {
        let (w, h) = (160usize, 120usize);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let unit = Normal::new(0.0f32, 1.0).unwrap();
        let mut depth = Vec::with_capacity(w * h);
        for v in 0..h {
            for _ in 0..w {
                // The floor: 1.2 m below a camera with f = 100, z = 1.2 f / (v - cy).
                let z = if v > 70 {
                    (120.0 / (v as f32 - 60.0)).min(2.0)
                } else {
                    2.0
                };
                depth.push(z + noise_at_1m * z * z * unit.sample(&mut rng));
            }
        }
        depth
    }

    #[test]
    fn the_noise_of_a_depth_camera_is_measured_within_ten_percent() {
        for (seed, truth) in [(1, 0.002f32), (2, 0.006), (3, 0.02)] {
            let depth = room(truth, seed);
            let measured = noise_at_1m([(depth.as_slice(), 160)]).unwrap();
            assert!(
                (measured / truth - 1.0).abs() < 0.1,
                "σ₁ {truth}: measured {measured}"
            );
        }
    }

    #[test]
    fn the_median_skips_what_was_not_measured() {
        assert_eq!(
            median_measured([None, Some(0.004), Some(0.006), Some(0.02)]),
            Some(0.006)
        );
        assert_eq!(median_measured([None, None]), None);
    }

    #[test]
    fn clean_depth_and_too_few_pixels_measure_no_noise() {
        let clean = room(0.0, 0);
        assert_eq!(noise_at_1m([(clean.as_slice(), 160)]), None);
        // Edges (a step of 1 m every 10 pixels) do not count as noise.
        let steps: Vec<f32> = (0..160 * 120)
            .map(|i| 2.0 + ((i % 160) / 10 % 2) as f32)
            .collect();
        assert_eq!(noise_at_1m([(steps.as_slice(), 160)]), None);
        let few = room(0.01, 4);
        assert_eq!(noise_at_1m([(&few[..320], 160)]), None);
        // Invalid pixels and degenerate widths are skipped, not counted.
        let nan = vec![f32::NAN; 160 * 120];
        assert_eq!(noise_at_1m([(nan.as_slice(), 160), (&few[..], 2)]), None);
    }
}

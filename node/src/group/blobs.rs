//! Seeded Gaussian blobs (sklearn's `make_blobs` recipe: centres uniform in [-10, 10]^d, unit
//! standard deviation): test and benchmark data for grouping.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// `n` points in `dims` dimensions around `centers` centres (equal shares, interleaved), with
/// their true labels.
pub fn blobs(n: usize, dims: usize, centers: usize, std: f32, seed: u64) -> (Vec<f32>, Vec<u32>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let centres: Vec<Vec<f32>> = (0..centers.max(1))
        .map(|_| (0..dims).map(|_| rng.random_range(-10.0..10.0)).collect())
        .collect();
    let mut points = Vec::with_capacity(n * dims);
    let mut labels = Vec::with_capacity(n);
    for i in 0..n {
        let k = i % centres.len();
        for c in &centres[k] {
            let z: f32 = StandardNormal.sample(&mut rng);
            points.push(c + std * z);
        }
        labels.push(k as u32);
    }
    (points, labels)
}

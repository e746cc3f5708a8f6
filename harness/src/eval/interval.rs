//! How far an `eval map` figure can be trusted: a 95% interval over scenes (percentile
//! bootstrap, scenes drawn with replacement and their counts pooled as the full run pools them),
//! and the same for the difference between two runs over the same scenes (paired: each draw
//! takes the same scenes from both). A change to the map is worth believing when the paired
//! interval of its difference excludes zero; one scene's objects move together, so scenes, not
//! objects, are what is resampled.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::score::{Counts, Summary};

/// Bootstrap draws per interval: the 2.5% and 97.5% percentiles are stable to about a tenth of a
/// point at this many.
pub const DRAWS: usize = 2000;
/// Fixed, so that a run and its rerun print the same intervals.
pub const SEED: u64 = 0x6766_6d61_7030;

/// A figure of a [`Summary`], by its `summary.json` name.
pub type Figure = (&'static str, fn(&Summary) -> f64);

/// The figures an interval is given for.
pub const HEADLINE: [Figure; 4] = [
    ("recall_at_25", |s| s.recall_at_25),
    ("recall_at_50", |s| s.recall_at_50),
    ("mean_iou", |s| s.mean_iou),
    ("precision", |s| s.precision),
];

/// A figure over all scenes and its 95% bootstrap interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Interval {
    pub name: &'static str,
    pub value: f64,
    pub low: f64,
    pub high: f64,
}

impl Interval {
    /// True when the interval lies wholly on one side of zero (for a difference).
    pub fn excludes_zero(&self) -> bool {
        self.low > 0.0 || self.high < 0.0
    }
}

/// Each headline figure of the pooled `per_scene` counts with its 95% interval over scenes.
/// With fewer than two scenes the interval is the value itself (nothing to resample).
pub fn intervals(per_scene: &[Counts]) -> Vec<Interval> {
    let pooled = pool(per_scene, 0..per_scene.len());
    let mut draws = Draws::new(per_scene.len());
    let samples: Vec<Summary> = (0..DRAWS)
        .map(|_| pool(per_scene, draws.next()).summary())
        .collect();
    HEADLINE
        .iter()
        .map(|&(name, figure)| {
            let mut values: Vec<f64> = samples.iter().map(figure).collect();
            let (low, high) = percentiles(&mut values, per_scene.len());
            Interval {
                name,
                value: figure(&pooled.summary()),
                low: low.unwrap_or(figure(&pooled.summary())),
                high: high.unwrap_or(figure(&pooled.summary())),
            }
        })
        .collect()
}

/// The difference `now − before` of each headline figure with its paired 95% interval; `now`
/// and `before` hold the same scenes in the same order.
pub fn paired_differences(now: &[Counts], before: &[Counts]) -> Vec<Interval> {
    debug_assert_eq!(now.len(), before.len());
    let n = now.len().min(before.len());
    let (now, before) = (&now[..n], &before[..n]);
    let mut draws = Draws::new(n);
    let samples: Vec<(Summary, Summary)> = (0..DRAWS)
        .map(|_| {
            let picked = draws.next();
            (
                pool(now, picked.clone()).summary(),
                pool(before, picked).summary(),
            )
        })
        .collect();
    let (pooled_now, pooled_before) = (pool(now, 0..n).summary(), pool(before, 0..n).summary());
    HEADLINE
        .iter()
        .map(|&(name, figure)| {
            let value = figure(&pooled_now) - figure(&pooled_before);
            let mut values: Vec<f64> = samples.iter().map(|(a, b)| figure(a) - figure(b)).collect();
            let (low, high) = percentiles(&mut values, n);
            Interval {
                name,
                value,
                low: low.unwrap_or(value),
                high: high.unwrap_or(value),
            }
        })
        .collect()
}

fn pool(per_scene: &[Counts], picked: impl IntoIterator<Item = usize>) -> Counts {
    let mut total = Counts::default();
    for i in picked {
        total.add(&per_scene[i]);
    }
    total
}

/// The 2.5% and 97.5% percentiles, or `None` when there is nothing to resample.
fn percentiles(values: &mut [f64], scenes: usize) -> (Option<f64>, Option<f64>) {
    if scenes < 2 || values.is_empty() {
        return (None, None);
    }
    values.sort_by(f64::total_cmp);
    let at =
        |q: f64| values[((q * (values.len() - 1) as f64).round() as usize).min(values.len() - 1)];
    (Some(at(0.025)), Some(at(0.975)))
}

/// Scene indices drawn with replacement, `scenes` per draw, from a fixed seed.
struct Draws {
    rng: ChaCha8Rng,
    scenes: usize,
}

impl Draws {
    fn new(scenes: usize) -> Self {
        Self {
            rng: ChaCha8Rng::seed_from_u64(SEED),
            scenes,
        }
    }

    fn next(&mut self) -> Vec<usize> {
        if self.scenes == 0 {
            return Vec::new();
        }
        (0..self.scenes)
            .map(|_| self.rng.random_range(0..self.scenes))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(objects: u64, found: u64) -> Counts {
        Counts {
            objects_scored: objects,
            found_25: found,
            found_50: found / 2,
            iou_sum: found as f64 * 0.5,
            instances_listed: objects,
            instances_true: found,
            ..Counts::default()
        }
    }

    fn figure<'a>(intervals: &'a [Interval], name: &str) -> &'a Interval {
        intervals
            .iter()
            .find(|i| i.name == name)
            .expect("every headline figure has an interval")
    }

    #[test]
    fn interval_brackets_the_pooled_value_and_widens_with_spread_between_scenes() {
        let alike: Vec<Counts> = (0..20).map(|_| scene(10, 7)).collect();
        let spread: Vec<Counts> = (0..20)
            .map(|i| scene(10, if i % 2 == 0 { 4 } else { 10 }))
            .collect();
        let tight = *figure(&intervals(&alike), "recall_at_25");
        let wide = *figure(&intervals(&spread), "recall_at_25");
        assert!((tight.value - 0.7).abs() < 1e-12 && tight.low == 0.7 && tight.high == 0.7);
        assert!((wide.value - 0.7).abs() < 1e-12);
        assert!(wide.low < 0.7 && wide.high > 0.7, "{wide:?}");
        // Half the scenes at 0.4 and half at 1.0: the standard error of the mean of 20 is
        // 0.3 / sqrt(20) = 0.067, so the 95% interval is about ±0.13.
        assert!(
            wide.high - wide.low > 0.15 && wide.high - wide.low < 0.4,
            "{wide:?}"
        );
    }

    #[test]
    fn paired_difference_sees_a_small_gain_on_every_scene_that_unpaired_intervals_hide() {
        let before: Vec<Counts> = (0..20)
            .map(|i| scene(10, if i % 2 == 0 { 4 } else { 9 }))
            .collect();
        let now: Vec<Counts> = before
            .iter()
            .map(|c| scene(c.objects_scored, c.found_25 + 1))
            .collect();
        let gain = *figure(&paired_differences(&now, &before), "recall_at_25");
        assert!((gain.value - 0.1).abs() < 1e-12);
        assert!(gain.excludes_zero() && gain.low > 0.09, "{gain:?}");
        let (a, b) = (
            *figure(&intervals(&now), "recall_at_25"),
            *figure(&intervals(&before), "recall_at_25"),
        );
        assert!(
            a.low < b.high,
            "the unpaired intervals overlap: {a:?} {b:?}"
        );
        // A change that helps half the scenes and hurts the other half is not believed.
        let mixed: Vec<Counts> = before
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let found = if i % 4 < 2 {
                    c.found_25 + 1
                } else {
                    c.found_25 - 1
                };
                scene(c.objects_scored, found)
            })
            .collect();
        let noise = *figure(&paired_differences(&mixed, &before), "recall_at_25");
        assert!(!noise.excludes_zero(), "{noise:?}");
    }

    #[test]
    fn no_scenes_or_one_scene_gives_a_finite_interval_of_no_width() {
        for per_scene in [vec![], vec![scene(5, 3)]] {
            for interval in intervals(&per_scene)
                .into_iter()
                .chain(paired_differences(&per_scene, &per_scene))
            {
                assert!(interval.value.is_finite(), "{interval:?}");
                assert_eq!(
                    (interval.low, interval.high),
                    (interval.value, interval.value)
                );
            }
        }
    }

    #[test]
    fn intervals_are_the_same_on_a_rerun() {
        let per_scene: Vec<Counts> = (0..7).map(|i| scene(8, i % 8)).collect();
        assert_eq!(intervals(&per_scene), intervals(&per_scene));
    }
}

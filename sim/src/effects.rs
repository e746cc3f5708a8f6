//! The effects registry: every imperfection the simulator can add, each a separate pass that runs
//! only when the scene lists it. A scene without effects is the clean render, bit for bit, and
//! pays nothing for the passes it does not use.
//!
//! Passes run in the physical order of a camera whatever their order in the scene file: the lens
//! (distortion) and the shutter (motion blur) at render time, then exposure, then sensor noise on
//! RGB; depth noise before depth dropout. Stream effects (frame drops, timestamp jitter, odometry
//! drift) and moving objects act on the sequence, in [`crate::simulation`].

use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::render::PlumbBob;

/// One effect with its parameters, as a scene file lists it (`[[effects]] kind = "..."`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, tag = "kind", rename_all = "snake_case")]
pub enum Effect {
    /// Gaussian read noise on RGB; `sigma` in 8-bit levels.
    SensorNoise { sigma: f64 },
    /// The shutter stays open `exposure_secs` while the robot (and any moving object) moves: RGB is
    /// the mean of `samples` renders over that interval. Depth and ground truth stay sharp.
    MotionBlur { exposure_secs: f64, samples: usize },
    /// Global RGB gain oscillating between `min_gain` and `max_gain` every `period_secs`
    /// (auto-exposure hunting, lights dimming).
    Exposure {
        min_gain: f64,
        max_gain: f64,
        period_secs: f64,
    },
    /// Depth noise growing with the square of the range as in structured-light and stereo
    /// sensors: σ(z) = `sigma_at_1m` · z².
    DepthNoise { sigma_at_1m: f64 },
    /// Invalid depth (NaN in 32FC1, 0 in 16UC1): random pixels with `probability`, and pixels next
    /// to a depth discontinuity larger than `edge_m`.
    DepthDropout { probability: f64, edge_m: f64 },
    /// Plumb-bob lens distortion; the recorded CameraInfo carries the coefficients.
    LensDistortion {
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        k3: f64,
    },
    /// `count` objects standing on the floor (and what stands on them) slide back and forth by
    /// `amplitude_m` every `period_secs`, along a direction on which they hit nothing.
    MovingObjects {
        count: usize,
        amplitude_m: f64,
        period_secs: f64,
    },
    /// Each frame's camera messages are lost with `probability` (TF keeps coming).
    FrameDrops { probability: f64 },
    /// Camera header stamps are off the capture time by Gaussian noise of `sigma_secs`.
    TimestampJitter { sigma_secs: f64 },
    /// The odometry on `/tf` drifts away from the true pose as a random walk: `sigma_m` metres and
    /// `sigma_yaw_deg` degrees per √second. `/gt/tf` keeps the truth.
    OdometryDrift { sigma_m: f64, sigma_yaw_deg: f64 },
}

/// Identifies an effect's random stream, so adding one effect never changes another's noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stream {
    SensorNoise = 1,
    DepthNoise = 2,
    DepthDropout = 3,
    MovingObjects = 4,
    FrameDrops = 5,
    TimestampJitter = 6,
    OdometryDrift = 7,
    DatasetDraw = 8,
}

/// A generator for one (scene seed, effect, frame, camera): frames can be rendered in any order
/// and in parallel and still come out the same.
pub(crate) fn rng(seed: u64, stream: Stream, frame: u64, camera: u64) -> ChaCha8Rng {
    // SplitMix64 finaliser over the combined key.
    let mut z = seed
        ^ (stream as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ frame.wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ camera.wrapping_mul(0x1656_67B1_9E37_79F9);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ChaCha8Rng::seed_from_u64(z ^ (z >> 31))
}

fn check(ok: bool, what: &str) -> Result<(), String> {
    if ok {
        Ok(())
    } else {
        Err(format!("effect parameters: {what}"))
    }
}

impl Effect {
    /// The effect's name as scene files spell it.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::SensorNoise { .. } => "sensor_noise",
            Self::MotionBlur { .. } => "motion_blur",
            Self::Exposure { .. } => "exposure",
            Self::DepthNoise { .. } => "depth_noise",
            Self::DepthDropout { .. } => "depth_dropout",
            Self::LensDistortion { .. } => "lens_distortion",
            Self::MovingObjects { .. } => "moving_objects",
            Self::FrameDrops { .. } => "frame_drops",
            Self::TimestampJitter { .. } => "timestamp_jitter",
            Self::OdometryDrift { .. } => "odometry_drift",
        }
    }

    /// Parameters in range (finite, non-negative, probabilities in [0, 1]).
    pub fn validate(&self) -> Result<(), String> {
        let finite_nonneg = |v: f64| v.is_finite() && v >= 0.0;
        let probability = |p: f64| (0.0..=1.0).contains(&p);
        match *self {
            Self::SensorNoise { sigma } => check(finite_nonneg(sigma), "sensor_noise.sigma"),
            Self::MotionBlur {
                exposure_secs,
                samples,
            } => check(
                finite_nonneg(exposure_secs) && (2..=64).contains(&samples),
                "motion_blur needs exposure_secs >= 0 and 2..=64 samples",
            ),
            Self::Exposure {
                min_gain,
                max_gain,
                period_secs,
            } => check(
                finite_nonneg(min_gain)
                    && max_gain.is_finite()
                    && max_gain >= min_gain
                    && period_secs.is_finite()
                    && period_secs > 0.0,
                "exposure needs 0 <= min_gain <= max_gain and period_secs > 0",
            ),
            Self::DepthNoise { sigma_at_1m } => {
                check(finite_nonneg(sigma_at_1m), "depth_noise.sigma_at_1m")
            }
            Self::DepthDropout {
                probability: p,
                edge_m,
            } => check(
                probability(p) && edge_m.is_finite() && edge_m > 0.0,
                "depth_dropout needs probability in [0, 1] and edge_m > 0",
            ),
            Self::LensDistortion { k1, k2, p1, p2, k3 } => check(
                [k1, k2, p1, p2, k3]
                    .iter()
                    .all(|c| c.is_finite() && c.abs() < 2.0),
                "lens_distortion coefficients must be finite and moderate (|c| < 2)",
            ),
            Self::MovingObjects {
                amplitude_m,
                period_secs,
                ..
            } => check(
                finite_nonneg(amplitude_m) && period_secs.is_finite() && period_secs > 0.0,
                "moving_objects needs amplitude_m >= 0 and period_secs > 0",
            ),
            Self::FrameDrops { probability: p } => check(
                probability(p) && p < 1.0,
                "frame_drops.probability in [0, 1)",
            ),
            Self::TimestampJitter { sigma_secs } => {
                check(finite_nonneg(sigma_secs), "timestamp_jitter.sigma_secs")
            }
            Self::OdometryDrift {
                sigma_m,
                sigma_yaw_deg,
            } => check(
                finite_nonneg(sigma_m) && finite_nonneg(sigma_yaw_deg),
                "odometry_drift sigmas",
            ),
        }
    }

    pub fn lens(&self) -> Option<PlumbBob> {
        match *self {
            Self::LensDistortion { k1, k2, p1, p2, k3 } => Some(PlumbBob { k1, k2, p1, p2, k3 }),
            _ => None,
        }
    }
}

/// A named set of effects: what `--effects <preset>` and a scene file's `effects_preset` expand to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Preset {
    /// No effect: the exact render.
    Clean,
    /// A consumer depth camera on a moving robot: range-squared depth noise (6 mm at 1 m), 3%
    /// random depth dropout plus the pixels at 8 cm discontinuities, sensor noise, motion blur,
    /// exposure hunting, 5% frame drops and mild odometry drift.
    Realistic,
    /// Only random depth dropout with this probability (the dropout axis of the benchmarks).
    Dropout(f64),
    /// Only the named effects of `realistic` (bit `i` set: its `i`-th effect), to learn which
    /// of a real camera's effects costs the map what.
    RealisticOnly(u16),
}

impl Preset {
    /// `clean`, `realistic`, `realistic:<effect>,<effect>` (only those of realistic's effects,
    /// e.g. `realistic:depth_noise,depth_dropout`), or `dropout:<probability>` (e.g.
    /// `dropout:0.1`).
    pub fn parse(name: &str) -> Result<Self, String> {
        match name {
            "clean" => Ok(Self::Clean),
            "realistic" => Ok(Self::Realistic),
            _ if name.starts_with("realistic:") => {
                let kinds: Vec<&str> = realistic_effects().iter().map(Effect::kind).collect();
                let mut mask = 0u16;
                for wanted in name["realistic:".len()..].split(',') {
                    let bit = kinds.iter().position(|k| *k == wanted).ok_or_else(|| {
                        format!(
                            "`{wanted}` in preset `{name}` is none of realistic's effects ({})",
                            kinds.join(", ")
                        )
                    })?;
                    mask |= 1 << bit;
                }
                Ok(Self::RealisticOnly(mask))
            }
            _ => {
                let probability = name
                    .strip_prefix("dropout:")
                    .and_then(|p| p.parse::<f64>().ok())
                    .filter(|p| (0.0..=1.0).contains(p))
                    .ok_or_else(|| {
                        format!(
                            "unknown effects preset `{name}` (clean, realistic, \
                             realistic:<effect>,..., dropout:<0..1>)"
                        )
                    })?;
                Ok(Self::Dropout(probability))
            }
        }
    }

    pub fn name(&self) -> String {
        match self {
            Self::Clean => "clean".into(),
            Self::Realistic => "realistic".into(),
            Self::Dropout(p) => format!("dropout:{p}"),
            Self::RealisticOnly(_) => {
                let kinds: Vec<&str> = self.effects().iter().map(Effect::kind).collect();
                format!("realistic:{}", kinds.join(","))
            }
        }
    }

    pub fn effects(&self) -> Vec<Effect> {
        match *self {
            Self::Clean => Vec::new(),
            Self::Realistic => realistic_effects(),
            Self::RealisticOnly(mask) => realistic_effects()
                .into_iter()
                .enumerate()
                .filter(|(i, _)| mask & (1 << i) != 0)
                .map(|(_, e)| e)
                .collect(),
            // Edges only beyond any room's depth range: random pixels alone.
            Self::Dropout(probability) if probability > 0.0 => vec![Effect::DepthDropout {
                probability,
                edge_m: 1e3,
            }],
            Self::Dropout(_) => Vec::new(),
        }
    }

    /// The effects of one training sample of a dataset rendered with this preset (`sim dataset
    /// --effects`): `realistic` is drawn per scene, so the model sees the whole range a robot
    /// meets: a quarter of the scenes clean, the others with the preset's camera effects and a
    /// random-dropout probability of 1, 3, 10 or 30% (the benchmark's dropout axis). Frame drops
    /// are left out: a dataset sample is a window of frames, not a stream.
    pub fn sample_effects(&self, seed: u64) -> Vec<Effect> {
        let mut rng = rng(seed, Stream::DatasetDraw, 0, 0);
        let mut effects = match self {
            Self::Realistic => {
                if rng.random::<f64>() < 0.25 {
                    return Vec::new();
                }
                let dropout = [0.01, 0.03, 0.1, 0.3][rng.random_range(0..4)];
                let mut effects = self.effects();
                for effect in &mut effects {
                    if let Effect::DepthDropout { probability, .. } = effect {
                        *probability = dropout;
                    }
                }
                effects
            }
            _ => self.effects(),
        };
        effects.retain(|e| !matches!(e, Effect::FrameDrops { .. }));
        effects
    }
}

/// `realistic`'s effects, in the order `realistic:<effect>,...` bits refer to.
fn realistic_effects() -> Vec<Effect> {
    vec![
        Effect::MotionBlur {
            exposure_secs: 0.015,
            samples: 3,
        },
        Effect::Exposure {
            min_gain: 0.85,
            max_gain: 1.15,
            period_secs: 4.0,
        },
        Effect::SensorNoise { sigma: 3.0 },
        Effect::DepthNoise { sigma_at_1m: 0.006 },
        Effect::DepthDropout {
            probability: 0.03,
            edge_m: 0.08,
        },
        Effect::FrameDrops { probability: 0.05 },
        Effect::OdometryDrift {
            sigma_m: 0.004,
            sigma_yaw_deg: 0.1,
        },
    ]
}

/// Exposure gain at `time_secs`: a sinusoid between the two gains.
pub(crate) fn exposure_gain(min_gain: f64, max_gain: f64, period_secs: f64, time_secs: f64) -> f64 {
    let phase = (time_secs / period_secs * std::f64::consts::TAU).sin();
    min_gain + (max_gain - min_gain) * 0.5 * (1.0 + phase)
}

pub(crate) fn apply_gain(rgb: &mut [u8], gain: f64) {
    for value in rgb {
        *value = (f64::from(*value) * gain).round().clamp(0.0, 255.0) as u8;
    }
}

pub(crate) fn add_sensor_noise(rgb: &mut [u8], sigma: f64, rng: &mut ChaCha8Rng) {
    let Ok(normal) = Normal::new(0.0, sigma) else {
        return;
    };
    for value in rgb {
        let noisy = f64::from(*value) + normal.sample(rng);
        *value = noisy.round().clamp(0.0, 255.0) as u8;
    }
}

pub(crate) fn add_depth_noise(depth: &mut [f32], sigma_at_1m: f64, rng: &mut ChaCha8Rng) {
    let Ok(unit) = Normal::new(0.0, 1.0) else {
        return;
    };
    for z in depth.iter_mut().filter(|z| z.is_finite()) {
        let sigma = sigma_at_1m * f64::from(*z) * f64::from(*z);
        let noisy = f64::from(*z) + sigma * unit.sample(rng);
        // A sensor never reports a surface behind itself.
        *z = noisy.max(1e-3) as f32;
    }
}

/// Drop random pixels and pixels at depth discontinuities (judged on `clean`, the exact depth,
/// as a real sensor loses the mixed pixels at object boundaries).
pub(crate) fn drop_depth(
    depth: &mut [f32],
    clean: &[f32],
    width: usize,
    probability: f64,
    edge_m: f64,
    rng: &mut ChaCha8Rng,
) {
    let height = clean.len() / width.max(1);
    let edge = edge_m as f32;
    for v in 0..height {
        for u in 0..width {
            let i = v * width + u;
            let z = clean[i];
            let at_edge = (u + 1 < width && (clean[i + 1] - z).abs() > edge)
                || (v + 1 < height && (clean[i + width] - z).abs() > edge)
                || (u > 0 && (clean[i - 1] - z).abs() > edge)
                || (v > 0 && (clean[i - width] - z).abs() > edge);
            // Draw for every pixel so the random pattern does not depend on the edges.
            let random = rng.random::<f64>() < probability;
            if at_edge || random {
                depth[i] = f32::NAN;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_independent_and_reproducible() {
        let draw = |stream, frame, camera| rng(7, stream, frame, camera).random::<u64>();
        assert_eq!(
            draw(Stream::SensorNoise, 3, 0),
            draw(Stream::SensorNoise, 3, 0)
        );
        assert_ne!(
            draw(Stream::SensorNoise, 3, 0),
            draw(Stream::DepthNoise, 3, 0)
        );
        assert_ne!(
            draw(Stream::SensorNoise, 3, 0),
            draw(Stream::SensorNoise, 4, 0)
        );
        assert_ne!(
            draw(Stream::SensorNoise, 3, 0),
            draw(Stream::SensorNoise, 3, 1)
        );
        assert_ne!(
            draw(Stream::SensorNoise, 3, 0),
            rng(8, Stream::SensorNoise, 3, 0).random::<u64>()
        );
    }

    #[test]
    fn invalid_parameters_are_rejected() {
        assert!(Effect::SensorNoise { sigma: f64::NAN }.validate().is_err());
        assert!(Effect::FrameDrops { probability: 1.0 }.validate().is_err());
        assert!(Effect::MotionBlur {
            exposure_secs: 0.01,
            samples: 1
        }
        .validate()
        .is_err());
        assert!(Effect::Exposure {
            min_gain: 1.2,
            max_gain: 0.8,
            period_secs: 1.0
        }
        .validate()
        .is_err());
        assert!(Effect::DepthNoise { sigma_at_1m: 0.002 }.validate().is_ok());
    }

    #[test]
    fn depth_noise_with_zero_sigma_and_nan_pixels_stays_finite_where_it_was() {
        let mut depth = vec![1.0, f32::NAN, 3.0];
        add_depth_noise(&mut depth, 0.0, &mut rng(1, Stream::DepthNoise, 0, 0));
        assert_eq!(depth[0], 1.0);
        assert!(depth[1].is_nan());
        assert_eq!(depth[2], 3.0);
    }

    #[test]
    fn exposure_gain_spans_its_range() {
        let gains: Vec<f64> = (0..100)
            .map(|i| exposure_gain(0.5, 1.5, 1.0, f64::from(i) / 100.0))
            .collect();
        let lo = gains.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = gains.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert!((lo - 0.5).abs() < 1e-3 && (hi - 1.5).abs() < 1e-3);
    }
}

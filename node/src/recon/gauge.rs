//! Gauge alignment (ARCHITECTURE.md §2). A model pass predicts cameras in its own gauge (first camera at
//! the origin, arbitrary scale). The paper's scale between two predictions sharing views C is
//! `γ = Σ_C ‖t_ref‖ / Σ_C ‖t_new‖`; in the node the reference is the world, and a Sim(3) fit
//! (Umeyama) on the shared camera centres gives rotation, translation and scale together.
//!
//! Degenerate geometry (pure rotation, coincident cameras, a single shared view, zero
//! translations) cannot fix the scale: the aligner falls back to the last good scale, takes the
//! rotation from the cameras' orientations, and says which fallback it used. Nothing returns NaN.

use glam::{DQuat, DVec3};
use nalgebra::{Matrix3, Vector3};

use super::Rigid;

/// Camera centres closer than this (RMS about their centroid, in the new gauge's units) cannot fix
/// a scale or rotation.
pub const MIN_CENTRE_SPREAD: f64 = 1e-6;
/// Bounds on an accepted scale; outside them the fit is treated as degenerate.
pub const SCALE_RANGE: (f64, f64) = (1e-6, 1e6);

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GaugeError {
    #[error("no shared views to align")]
    NoSharedViews,
    #[error("{reference} reference poses but {new} new poses")]
    Mismatch { reference: usize, new: usize },
    #[error("pose {0} is not finite")]
    NonFinite(usize),
}

/// Why the fit fell back to the last good scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fallback {
    /// Only one shared view.
    SingleView,
    /// The new cameras' centres (nearly) coincide: pure rotation or a stationary camera.
    CoincidentCentres,
    /// The fitted scale was out of range or not finite.
    BadScale,
}

/// A similarity transform `reference ← new`: `x_ref = scale · R x_new + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    pub scale: f64,
    pub rotation: DQuat,
    pub translation: DVec3,
}

impl Sim3 {
    pub fn transform_point(&self, p: DVec3) -> DVec3 {
        self.scale * (self.rotation * p) + self.translation
    }

    /// Map a `world_from_camera` pose of the new gauge into the reference gauge.
    pub fn transform_pose(&self, pose: &Rigid) -> Rigid {
        Rigid::new(
            (self.rotation * pose.rotation).normalize(),
            self.transform_point(pose.translation),
        )
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    pub sim3: Sim3,
    /// Set when the scale came from the last good alignment instead of this fit.
    pub fallback: Option<Fallback>,
    /// RMS distance between aligned new centres and reference centres.
    pub rms_error: f64,
}

/// The paper's scale `γ = Σ‖t_ref‖ / Σ‖t_new‖`; `None` when it is undefined (zero or non-finite sums).
pub fn paper_scale(reference: &[DVec3], new: &[DVec3]) -> Option<f64> {
    let sum_ref: f64 = reference.iter().map(|t| t.length()).sum();
    let sum_new: f64 = new.iter().map(|t| t.length()).sum();
    let gamma = sum_ref / sum_new;
    (sum_new > 0.0 && gamma.is_finite() && gamma > 0.0).then_some(gamma)
}

/// Umeyama's closed-form similarity fit `dst ≈ s R src + t`; `None` if degenerate.
pub fn umeyama(src: &[DVec3], dst: &[DVec3]) -> Option<Sim3> {
    let n = src.len();
    if n < 2 || n != dst.len() {
        return None;
    }
    let mean = |v: &[DVec3]| v.iter().copied().sum::<DVec3>() / n as f64;
    let (mu_src, mu_dst) = (mean(src), mean(dst));
    let var_src = src
        .iter()
        .map(|p| (*p - mu_src).length_squared())
        .sum::<f64>()
        / n as f64;
    if var_src.is_nan() || var_src <= MIN_CENTRE_SPREAD * MIN_CENTRE_SPREAD {
        return None;
    }
    let mut cov = Matrix3::<f64>::zeros();
    for (s, d) in src.iter().zip(dst) {
        let (a, b) = (*d - mu_dst, *s - mu_src);
        cov += Vector3::new(a.x, a.y, a.z) * Vector3::new(b.x, b.y, b.z).transpose();
    }
    cov /= n as f64;
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut signs = Matrix3::<f64>::identity();
    if (u.determinant() * v_t.determinant()) < 0.0 {
        signs[(2, 2)] = -1.0;
    }
    let r = u * signs * v_t;
    let trace: f64 = (0..3).map(|i| svd.singular_values[i] * signs[(i, i)]).sum();
    let scale = trace / var_src;
    let rotation = DQuat::from_mat3(&glam::DMat3::from_cols_array(&[
        r[(0, 0)],
        r[(1, 0)],
        r[(2, 0)],
        r[(0, 1)],
        r[(1, 1)],
        r[(2, 1)],
        r[(0, 2)],
        r[(1, 2)],
        r[(2, 2)],
    ]))
    .normalize();
    let translation = mu_dst - scale * (rotation * mu_src);
    let sim3 = Sim3 {
        scale,
        rotation,
        translation,
    };
    (scale.is_finite() && rotation.is_finite() && translation.is_finite()).then_some(sim3)
}

/// Aligns successive model passes, remembering the last good scale.
#[derive(Debug, Clone)]
pub struct GaugeAligner {
    last_good_scale: f64,
}

impl Default for GaugeAligner {
    fn default() -> Self {
        Self {
            last_good_scale: 1.0,
        }
    }
}

impl GaugeAligner {
    pub fn new(initial_scale: f64) -> Self {
        Self {
            last_good_scale: if initial_scale.is_finite() && initial_scale > 0.0 {
                initial_scale
            } else {
                1.0
            },
        }
    }

    pub fn last_good_scale(&self) -> f64 {
        self.last_good_scale
    }

    /// Align `new` camera poses (`world_from_camera` in the model's gauge) to `reference` poses of
    /// the same views.
    pub fn align(&mut self, reference: &[Rigid], new: &[Rigid]) -> Result<Alignment, GaugeError> {
        if reference.len() != new.len() {
            return Err(GaugeError::Mismatch {
                reference: reference.len(),
                new: new.len(),
            });
        }
        if new.is_empty() {
            return Err(GaugeError::NoSharedViews);
        }
        if let Some(i) = reference.iter().chain(new).position(|p| !p.is_finite()) {
            return Err(GaugeError::NonFinite(i % new.len()));
        }
        let ref_centres: Vec<DVec3> = reference.iter().map(|p| p.translation).collect();
        let new_centres: Vec<DVec3> = new.iter().map(|p| p.translation).collect();
        let fit = umeyama(&new_centres, &ref_centres)
            .filter(|s| s.scale > SCALE_RANGE.0 && s.scale < SCALE_RANGE.1);
        let (sim3, fallback) = match fit {
            Some(sim3) => {
                self.last_good_scale = sim3.scale;
                (sim3, None)
            }
            None => {
                let reason = if new.len() == 1 {
                    Fallback::SingleView
                } else if umeyama_spread(&new_centres) <= MIN_CENTRE_SPREAD {
                    Fallback::CoincidentCentres
                } else {
                    Fallback::BadScale
                };
                (self.orientation_fit(reference, new), Some(reason))
            }
        };
        let rms_error = (ref_centres
            .iter()
            .zip(&new_centres)
            .map(|(r, n)| (sim3.transform_point(*n) - *r).length_squared())
            .sum::<f64>()
            / new.len() as f64)
            .sqrt();
        Ok(Alignment {
            sim3,
            fallback,
            rms_error,
        })
    }

    /// Rotation from the cameras' orientations (mean of `R_ref R_newᵀ`), the last good scale, and
    /// the translation that matches the centroids.
    fn orientation_fit(&self, reference: &[Rigid], new: &[Rigid]) -> Sim3 {
        let first = (reference[0].rotation * new[0].rotation.inverse()).normalize();
        let mut sum = glam::DVec4::ZERO;
        for (r, n) in reference.iter().zip(new) {
            let mut q = (r.rotation * n.rotation.inverse()).normalize();
            if q.dot(first) < 0.0 {
                q = -q; // same hemisphere, so the average does not cancel
            }
            sum += glam::DVec4::from(q);
        }
        let rotation = if sum.length() > 1e-12 {
            DQuat::from_vec4(sum).normalize()
        } else {
            first
        };
        let n = new.len() as f64;
        let mu_ref = reference.iter().map(|p| p.translation).sum::<DVec3>() / n;
        let mu_new = new.iter().map(|p| p.translation).sum::<DVec3>() / n;
        let scale = self.last_good_scale;
        Sim3 {
            scale,
            rotation,
            translation: mu_ref - scale * (rotation * mu_new),
        }
    }
}

fn umeyama_spread(centres: &[DVec3]) -> f64 {
    let mu = centres.iter().copied().sum::<DVec3>() / centres.len() as f64;
    (centres
        .iter()
        .map(|p| (*p - mu).length_squared())
        .sum::<f64>()
        / centres.len() as f64)
        .sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> Sim3 {
        Sim3 {
            scale: 2.5,
            rotation: DQuat::from_euler(glam::EulerRot::ZYX, 0.4, -0.2, 0.9),
            translation: DVec3::new(1.0, -3.0, 0.5),
        }
    }

    fn poses(centres: &[DVec3]) -> Vec<Rigid> {
        centres
            .iter()
            .enumerate()
            .map(|(i, c)| Rigid::new(DQuat::from_rotation_y(0.1 * i as f64), *c))
            .collect()
    }

    fn assert_finite(a: &Alignment) {
        assert!(
            a.sim3.scale.is_finite()
                && a.sim3.rotation.is_finite()
                && a.sim3.translation.is_finite()
        );
        assert!(a.rms_error.is_finite());
    }

    #[test]
    fn recovers_a_known_similarity() {
        let new = poses(&[
            DVec3::ZERO,
            DVec3::new(0.3, 0.0, 0.1),
            DVec3::new(0.1, 0.4, -0.2),
            DVec3::new(-0.2, 0.1, 0.5),
        ]);
        let t = truth();
        let reference: Vec<Rigid> = new.iter().map(|p| t.transform_pose(p)).collect();
        let mut aligner = GaugeAligner::default();
        let a = aligner.align(&reference, &new).unwrap();
        assert_eq!(a.fallback, None);
        assert!((a.sim3.scale - 2.5).abs() < 1e-9);
        assert!(a.sim3.rotation.dot(t.rotation).abs() > 1.0 - 1e-12);
        assert!((a.sim3.translation - t.translation).length() < 1e-9);
        assert!(a.rms_error < 1e-9);
        assert!((aligner.last_good_scale() - 2.5).abs() < 1e-9);
    }

    #[test]
    fn paper_scale_matches_the_formula_and_refuses_zero() {
        let new = [DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, 2.0, 0.0)];
        let reference = [DVec3::new(3.0, 0.0, 0.0), DVec3::new(0.0, 6.0, 0.0)];
        assert_eq!(paper_scale(&reference, &new), Some(3.0));
        assert_eq!(paper_scale(&reference, &[DVec3::ZERO, DVec3::ZERO]), None);
        assert_eq!(paper_scale(&[], &[]), None);
    }

    #[test]
    fn pure_rotation_falls_back_to_the_last_good_scale() {
        let mut aligner = GaugeAligner::new(1.7);
        let t = truth();
        let new: Vec<Rigid> = (0..4)
            .map(|i| {
                Rigid::new(
                    DQuat::from_rotation_z(0.3 * i as f64),
                    DVec3::new(0.2, 0.1, 0.0),
                )
            })
            .collect();
        let reference: Vec<Rigid> = new.iter().map(|p| t.transform_pose(p)).collect();
        let a = aligner.align(&reference, &new).unwrap();
        assert_eq!(a.fallback, Some(Fallback::CoincidentCentres));
        assert_eq!(a.sim3.scale, 1.7);
        assert!(
            a.sim3.rotation.dot(t.rotation).abs() > 1.0 - 1e-9,
            "rotation from orientations"
        );
        assert_finite(&a);
    }

    #[test]
    fn coincident_cameras_and_zero_translations_stay_finite() {
        let mut aligner = GaugeAligner::default();
        let zero = vec![Rigid::IDENTITY; 3];
        let a = aligner.align(&zero, &zero).unwrap();
        assert_eq!(a.fallback, Some(Fallback::CoincidentCentres));
        assert_eq!(a.sim3.scale, 1.0);
        assert_finite(&a);
        assert!(umeyama(&[DVec3::ZERO; 3], &[DVec3::ONE; 3]).is_none());
    }

    #[test]
    fn one_shared_view_uses_its_orientation_and_the_last_scale() {
        let mut aligner = GaugeAligner::new(2.0);
        let new = [Rigid::new(
            DQuat::from_rotation_x(0.5),
            DVec3::new(1.0, 0.0, 0.0),
        )];
        let reference = [Rigid::new(
            DQuat::from_rotation_x(0.5) * DQuat::IDENTITY,
            DVec3::new(5.0, 0.0, 0.0),
        )];
        let a = aligner.align(&reference, &new).unwrap();
        assert_eq!(a.fallback, Some(Fallback::SingleView));
        assert_eq!(a.sim3.scale, 2.0);
        assert!(
            (a.sim3.transform_point(DVec3::new(1.0, 0.0, 0.0)) - DVec3::new(5.0, 0.0, 0.0))
                .length()
                < 1e-9
        );
        assert_finite(&a);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let mut aligner = GaugeAligner::default();
        assert_eq!(aligner.align(&[], &[]), Err(GaugeError::NoSharedViews));
        assert!(aligner.align(&[Rigid::IDENTITY], &[]).is_err());
        let nan = Rigid::new(DQuat::IDENTITY, DVec3::new(f64::NAN, 0.0, 0.0));
        assert!(matches!(
            aligner.align(&[nan], &[Rigid::IDENTITY]),
            Err(GaugeError::NonFinite(_))
        ));
        assert!(GaugeAligner::new(f64::NAN).last_good_scale() == 1.0);
    }

    #[test]
    fn collinear_centres_still_fit_scale() {
        // Centres on a line fix scale and translation; the rotation about the line is free.
        let new = poses(&[DVec3::ZERO, DVec3::X, DVec3::X * 2.0]);
        let reference = poses(&[DVec3::ZERO, DVec3::X * 3.0, DVec3::X * 6.0]);
        let a = GaugeAligner::default().align(&reference, &new).unwrap();
        assert!((a.sim3.scale - 3.0).abs() < 1e-9);
        assert!(a.rms_error < 1e-9);
    }
}

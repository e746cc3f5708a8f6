//! A small tf2-like buffer: static transforms plus a time-ordered history of dynamic ones,
//! looked up by stamp with interpolation.

use std::collections::{HashMap, VecDeque};

use crate::recon::Rigid;

/// Why a TF lookup has no answer (yet).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LookupError {
    /// The chain exists but the newest transform is older than the stamp: wait for more TF.
    NotYet,
    /// The stamp is older than the history kept.
    TooOld,
    /// No chain from the frame to the world frame (yet).
    Disconnected(String),
}

/// A small tf2-like buffer: static transforms plus a time-ordered history of dynamic ones.
#[derive(Debug, Default)]
pub struct TfBuffer {
    statics: HashMap<String, (String, Rigid)>,
    dynamic: HashMap<String, VecDeque<(i64, String, Rigid)>>,
    history_nanos: i64,
    newest_nanos: Option<i64>,
}

/// Chains longer than this are treated as cycles.
const MAX_TF_DEPTH: usize = 64;

impl TfBuffer {
    pub fn new(history_secs: f64) -> Self {
        Self {
            history_nanos: (history_secs * 1e9) as i64,
            ..Self::default()
        }
    }

    pub fn newest_nanos(&self) -> Option<i64> {
        self.newest_nanos
    }

    pub fn insert(
        &mut self,
        parent: String,
        child: String,
        stamp: i64,
        rigid: Rigid,
        is_static: bool,
    ) {
        if is_static {
            self.statics.insert(child, (parent, rigid));
            return;
        }
        self.newest_nanos = Some(self.newest_nanos.map_or(stamp, |n| n.max(stamp)));
        let samples = self.dynamic.entry(child).or_default();
        // Keep samples sorted; they nearly always arrive in order, so search from the back.
        let at = samples
            .iter()
            .rposition(|(t, _, _)| *t <= stamp)
            .map_or(0, |i| i + 1);
        if at > 0 && samples[at - 1].0 == stamp {
            samples[at - 1] = (stamp, parent, rigid);
        } else {
            samples.insert(at, (stamp, parent, rigid));
        }
        let horizon = samples.back().map_or(stamp, |(t, _, _)| *t) - self.history_nanos;
        while samples.len() > 2 && samples.front().is_some_and(|(t, _, _)| *t < horizon) {
            samples.pop_front();
        }
    }

    /// `parent_from_child` at `stamp` for one edge, interpolated between bracketing samples.
    fn edge(
        &self,
        child: &str,
        stamp: i64,
        tolerance: i64,
    ) -> Option<Result<(String, Rigid), LookupError>> {
        if let Some((parent, rigid)) = self.statics.get(child) {
            return Some(Ok((parent.clone(), *rigid)));
        }
        let samples = self.dynamic.get(child)?;
        let (first, last) = (samples.front()?, samples.back()?);
        if stamp > last.0 {
            // A little extrapolation covers sensors stamped just after the latest odometry.
            return Some(if stamp - last.0 <= tolerance {
                Ok((last.1.clone(), last.2))
            } else {
                Err(LookupError::NotYet)
            });
        }
        if stamp < first.0 {
            return Some(if first.0 - stamp <= tolerance {
                Ok((first.1.clone(), first.2))
            } else {
                Err(LookupError::TooOld)
            });
        }
        let after = samples.iter().position(|(t, _, _)| *t >= stamp)?;
        let (t1, parent, r1) = &samples[after];
        if after == 0 || *t1 == stamp {
            return Some(Ok((parent.clone(), *r1)));
        }
        let (t0, _, r0) = &samples[after - 1];
        let s = (stamp - t0) as f64 / (t1 - t0) as f64;
        Some(Ok((parent.clone(), r0.lerp(r1, s))))
    }

    /// `target_from_source` at `stamp`, walking from `source` up to `target`.
    pub fn lookup(
        &self,
        target: &str,
        source: &str,
        stamp: i64,
        tolerance_nanos: i64,
    ) -> Result<Rigid, LookupError> {
        let mut target_from_frame = Rigid::IDENTITY;
        let mut frame = source.trim_start_matches('/').to_owned();
        for _ in 0..MAX_TF_DEPTH {
            if frame == target {
                return Ok(target_from_frame);
            }
            match self.edge(&frame, stamp, tolerance_nanos) {
                None => {
                    return Err(LookupError::Disconnected(format!(
                        "no transform to `{target}` from `{frame}`"
                    )))
                }
                Some(Err(e)) => return Err(e),
                Some(Ok((parent, parent_from_frame))) => {
                    target_from_frame = parent_from_frame.compose(&target_from_frame);
                    frame = parent;
                }
            }
        }
        Err(LookupError::Disconnected(format!(
            "TF chain from `{source}` is longer than {MAX_TF_DEPTH} (a cycle?)"
        )))
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::super::test_messages::{tf, ID};
    use super::super::validate::validate_transform;
    use super::*;

    #[test]
    fn tf_chain_interpolates_and_composes() {
        let mut buffer = TfBuffer::new(10.0);
        let (p, c, t, r) =
            validate_transform(&tf("map", "base", 0, 0.0, ID).transforms[0]).unwrap();
        buffer.insert(p, c, t, r, false);
        let (p, c, t, r) =
            validate_transform(&tf("map", "base", 1_000, 2.0, ID).transforms[0]).unwrap();
        buffer.insert(p, c, t, r, false);
        // base -> cam: rotate 90° about z, static.
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let (p, c, t, r) =
            validate_transform(&tf("base", "cam", 0, 1.0, [0.0, 0.0, half, half]).transforms[0])
                .unwrap();
        buffer.insert(p, c, t, r, true);
        let map_from_cam = buffer.lookup("map", "cam", 500, 0).unwrap();
        assert!((map_from_cam.translation - DVec3::new(2.0, 0.0, 0.0)).length() < 1e-9);
        let x_axis = map_from_cam.rotation * DVec3::X;
        assert!((x_axis - DVec3::Y).length() < 1e-9);
        assert_eq!(
            buffer.lookup("map", "cam", 5_000, 0),
            Err(LookupError::NotYet)
        );
        assert!(matches!(
            buffer.lookup("map", "other", 500, 0),
            Err(LookupError::Disconnected(_))
        ));
    }

    #[test]
    fn tf_cycle_is_an_error_not_a_hang() {
        let mut buffer = TfBuffer::new(10.0);
        buffer.insert("a".into(), "b".into(), 0, Rigid::IDENTITY, true);
        buffer.insert("b".into(), "a".into(), 0, Rigid::IDENTITY, true);
        assert!(matches!(
            buffer.lookup("map", "a", 0, 0),
            Err(LookupError::Disconnected(_))
        ));
    }

    fn at_x(x: f64) -> Rigid {
        Rigid::new(glam::DQuat::IDENTITY, DVec3::new(x, 0.0, 0.0))
    }

    #[test]
    fn out_of_order_samples_are_sorted_and_interpolated() {
        let mut buffer = TfBuffer::new(10.0);
        for (stamp, x) in [(2_000, 2.0), (1_000, 1.0), (3_000, 3.0), (2_000, 2.5)] {
            buffer.insert("map".into(), "base".into(), stamp, at_x(x), false);
        }
        // The second sample at 2,000 replaced the first.
        let x_at = |stamp| {
            buffer
                .lookup("map", "base", stamp, 0)
                .unwrap()
                .translation
                .x
        };
        assert!((x_at(1_500) - 1.75).abs() < 1e-12);
        assert!((x_at(2_500) - 2.75).abs() < 1e-12);
        assert!((x_at(2_000) - 2.5).abs() < 1e-12);
    }

    #[test]
    fn rotation_is_interpolated_on_the_sphere() {
        let mut buffer = TfBuffer::new(10.0);
        let yaw = |degrees: f64| {
            Rigid::new(
                glam::DQuat::from_rotation_z(degrees.to_radians()),
                DVec3::ZERO,
            )
        };
        buffer.insert("map".into(), "base".into(), 0, yaw(0.0), false);
        buffer.insert("map".into(), "base".into(), 1_000, yaw(90.0), false);
        let halfway = buffer.lookup("map", "base", 500, 0).unwrap();
        let x_axis = halfway.rotation * DVec3::X;
        let angle = x_axis.y.atan2(x_axis.x).to_degrees();
        assert!((angle - 45.0).abs() < 1e-9, "{angle}");
        assert!((halfway.rotation.length() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn extrapolation_is_allowed_within_the_tolerance_only() {
        let mut buffer = TfBuffer::new(10.0);
        buffer.insert("map".into(), "base".into(), 1_000, at_x(1.0), false);
        buffer.insert("map".into(), "base".into(), 2_000, at_x(2.0), false);
        // Just after the newest sample: its value, within the tolerance; beyond it: not yet.
        let after = buffer.lookup("map", "base", 2_050, 100).unwrap();
        assert_eq!(after.translation.x, 2.0);
        assert_eq!(
            buffer.lookup("map", "base", 2_150, 100),
            Err(LookupError::NotYet)
        );
        // Just before the oldest: its value within the tolerance; beyond it: too old.
        assert_eq!(
            buffer
                .lookup("map", "base", 950, 100)
                .unwrap()
                .translation
                .x,
            1.0
        );
        assert_eq!(
            buffer.lookup("map", "base", 850, 100),
            Err(LookupError::TooOld)
        );
    }

    #[test]
    fn history_is_bounded_and_older_stamps_are_too_old() {
        let mut buffer = TfBuffer::new(1.0);
        for second in 0..10i64 {
            buffer.insert(
                "map".into(),
                "base".into(),
                second * 1_000_000_000,
                at_x(second as f64),
                false,
            );
        }
        assert_eq!(buffer.newest_nanos(), Some(9_000_000_000));
        // Samples older than one second before the newest are gone.
        assert_eq!(
            buffer.lookup("map", "base", 2_000_000_000, 0),
            Err(LookupError::TooOld)
        );
        let recent = buffer.lookup("map", "base", 8_500_000_000, 0).unwrap();
        assert!((recent.translation.x - 8.5).abs() < 1e-9);
    }
}

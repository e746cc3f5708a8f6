//! Validate camera intrinsics and TF transforms into the geometric core's types.

use glam::{DQuat, DVec3};
use groupforward_msgs::geometry_msgs::TransformStamped;
use groupforward_msgs::sensor_msgs::CameraInfo;

use super::decode::check_dimensions;
use super::reject::{reject, Reject, Rejection};
use crate::recon::camera::{Camera, PlumbBob};
use crate::recon::Rigid;

/// Validate a `CameraInfo` into a camera model.
pub fn validate_camera_info(msg: &CameraInfo, max_side: u32) -> Result<Camera, Rejection> {
    check_dimensions(msg.width, msg.height, max_side)?;
    let finite = msg
        .k
        .iter()
        .chain(&msg.d)
        .chain(&msg.p)
        .all(|v| v.is_finite());
    let (fx, fy, cx, cy) = (msg.k[0], msg.k[4], msg.k[2], msg.k[5]);
    if !finite || fx <= 0.0 || fy <= 0.0 {
        return reject(
            Reject::BadIntrinsics,
            format!("K = {:?}, D = {:?}", msg.k, msg.d),
        );
    }
    let distortion = PlumbBob::from_ros(&msg.distortion_model, &msg.d).map_err(|e| Rejection {
        reason: Reject::UnsupportedDistortion,
        detail: e.to_string(),
    })?;
    Ok(Camera {
        width: msg.width,
        height: msg.height,
        fx,
        fy,
        cx,
        cy,
        distortion,
    })
}

/// Largest deviation of a quaternion's norm from 1 that is renormalised rather than rejected
/// (tf2 rejects clearly denormalised rotations too).
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// Validate one transform into (parent, child, stamp, parent_from_child).
pub fn validate_transform(t: &TransformStamped) -> Result<(String, String, i64, Rigid), Rejection> {
    let (tr, q) = (&t.transform.translation, &t.transform.rotation);
    let values = [tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w];
    if !values.iter().all(|v| v.is_finite()) {
        return reject(
            Reject::NonFiniteTransform,
            format!("{} -> {}: {values:?}", t.header.frame_id, t.child_frame_id),
        );
    }
    let norm = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return reject(
            Reject::NonUnitQuaternion,
            format!(
                "{} -> {}: |q| = {norm}",
                t.header.frame_id, t.child_frame_id
            ),
        );
    }
    if t.header.frame_id.is_empty() || t.child_frame_id.is_empty() {
        return reject(Reject::EmptyFrameId, "transform with an empty frame id");
    }
    let rigid = Rigid {
        rotation: DQuat::from_xyzw(q.x, q.y, q.z, q.w).normalize(),
        translation: DVec3::new(tr.x, tr.y, tr.z),
    };
    Ok((
        strip_slash(&t.header.frame_id),
        strip_slash(&t.child_frame_id),
        t.header.stamp.as_nanos(),
        rigid,
    ))
}

/// tf2 ignores a leading slash in frame ids.
pub(super) fn strip_slash(frame: &str) -> String {
    frame.trim_start_matches('/').to_owned()
}

#[cfg(test)]
mod tests {
    use super::super::test_messages::{info, tf, ID};
    use super::*;

    #[test]
    fn nan_intrinsics_and_bad_transforms_are_rejected() {
        let mut bad = info(4, 4);
        bad.k[0] = f64::NAN;
        assert_eq!(
            validate_camera_info(&bad, 64).unwrap_err().reason,
            Reject::BadIntrinsics
        );
        let mut fisheye = info(4, 4);
        fisheye.distortion_model = "equidistant".into();
        fisheye.d = vec![0.1, 0.01, 0.0, 0.0];
        assert_eq!(
            validate_camera_info(&fisheye, 64).unwrap_err().reason,
            Reject::UnsupportedDistortion
        );
        let mut plumb_bob = info(4, 4);
        plumb_bob.distortion_model = "plumb_bob".into();
        plumb_bob.d = vec![-0.2, 0.05, 0.0, 0.0, 0.0];
        assert_eq!(
            validate_camera_info(&plumb_bob, 64).unwrap().distortion.k1,
            -0.2
        );
        let mut zero_f = info(4, 4);
        zero_f.k[4] = 0.0;
        assert_eq!(
            validate_camera_info(&zero_f, 64).unwrap_err().reason,
            Reject::BadIntrinsics
        );
        let nan = tf("map", "cam", 0, f64::NAN, ID);
        assert_eq!(
            validate_transform(&nan.transforms[0]).unwrap_err().reason,
            Reject::NonFiniteTransform
        );
        let non_unit = tf("map", "cam", 0, 0.0, [0.0, 0.0, 0.0, 2.0]);
        assert_eq!(
            validate_transform(&non_unit.transforms[0])
                .unwrap_err()
                .reason,
            Reject::NonUnitQuaternion
        );
        let zero_q = tf("map", "cam", 0, 0.0, [0.0; 4]);
        assert!(validate_transform(&zero_q.transforms[0]).is_err());
        let nan_q = tf("map", "cam", 0, 0.0, [f64::NAN, 0.0, 0.0, 1.0]);
        assert_eq!(
            validate_transform(&nan_q.transforms[0]).unwrap_err().reason,
            Reject::NonFiniteTransform
        );
    }

    #[test]
    fn transforms_with_an_empty_frame_id_are_rejected() {
        for (parent, child) in [("", "cam"), ("map", "")] {
            let message = tf(parent, child, 0, 0.0, ID);
            assert_eq!(
                validate_transform(&message.transforms[0])
                    .unwrap_err()
                    .reason,
                Reject::EmptyFrameId
            );
        }
        // tf2 drops a leading slash: `/map` is `map`.
        let (parent, child, _, _) =
            validate_transform(&tf("/map", "/cam", 0, 0.0, ID).transforms[0]).unwrap();
        assert_eq!((parent.as_str(), child.as_str()), ("map", "cam"));
    }
}

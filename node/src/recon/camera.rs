//! Pinhole cameras with plumb-bob distortion, the 9-d camera encoding of VGGT-style models, and
//! frame-convention conversions (REP-103 optical = OpenCV; OpenGL; REP-103 body).

use glam::{DMat3, DQuat, DVec2, DVec3};

use super::Rigid;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    #[error("intrinsics must be finite with positive focal lengths and size, got {0}")]
    BadIntrinsics(String),
    #[error(
        "distortion `{0}` is not supported (plumb_bob, or rational_polynomial with k4..k6 = 0)"
    )]
    UnsupportedDistortion(String),
    #[error("pose encoding must be 9 finite values with fields of view in (0, pi), got {0:?}")]
    BadEncoding([f64; 9]),
}

pub type Result<T> = std::result::Result<T, CameraError>;

/// Brown–Conrady ("plumb_bob") coefficients, as in `CameraInfo.d`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PlumbBob {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl PlumbBob {
    /// From `CameraInfo.distortion_model` and `.d`: plumb_bob, or rational_polynomial whose extra
    /// coefficients are zero; all-zero coefficients under any model mean no distortion.
    pub fn from_ros(model: &str, d: &[f64]) -> Result<Self> {
        if d.iter().all(|v| *v == 0.0) {
            return Ok(Self::default());
        }
        match model {
            "plumb_bob" | "rational_polynomial"
                if d.len() >= 5 && d[5..].iter().all(|v| *v == 0.0) =>
            {
                Ok(Self {
                    k1: d[0],
                    k2: d[1],
                    p1: d[2],
                    p2: d[3],
                    k3: d[4],
                })
            }
            other => Err(CameraError::UnsupportedDistortion(format!(
                "{other} with {} coefficients",
                d.len()
            ))),
        }
    }

    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3] == [0.0; 5]
    }

    /// Distort normalised image coordinates.
    pub fn distort(&self, p: DVec2) -> DVec2 {
        let r2 = p.length_squared();
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        DVec2::new(
            p.x * radial + 2.0 * self.p1 * p.x * p.y + self.p2 * (r2 + 2.0 * p.x * p.x),
            p.y * radial + self.p1 * (r2 + 2.0 * p.y * p.y) + 2.0 * self.p2 * p.x * p.y,
        )
    }

    /// Undistort normalised coordinates by fixed-point iteration (as OpenCV's undistortPoints),
    /// stopping when the re-distorted point is within 1e-12 or after 50 iterations.
    pub fn undistort(&self, distorted: DVec2) -> DVec2 {
        let mut p = distorted;
        for _ in 0..50 {
            let r2 = p.length_squared();
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            let delta = DVec2::new(
                2.0 * self.p1 * p.x * p.y + self.p2 * (r2 + 2.0 * p.x * p.x),
                self.p1 * (r2 + 2.0 * p.y * p.y) + 2.0 * self.p2 * p.x * p.y,
            );
            let next = (distorted - delta) / radial;
            if !next.is_finite() {
                break;
            }
            p = next;
            if (self.distort(p) - distorted).length_squared() < 1e-24 {
                break;
            }
        }
        p
    }
}

/// A pinhole camera: `u = fx x/z + cx`, `v = fy y/z + cy` in its optical frame, then distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub distortion: PlumbBob,
}

impl Camera {
    pub fn pinhole(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Result<Self> {
        let camera = Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion: PlumbBob::default(),
        };
        camera.validate()?;
        Ok(camera)
    }

    /// A camera with square pixels, horizontal field of view `fov_x` and the principal point at the
    /// image centre: `(w - 1) / 2`, since pixel centres are at integers.
    pub fn from_fov(width: u32, height: u32, fov_x: f64) -> Result<Self> {
        let f = f64::from(width) / 2.0 / (fov_x / 2.0).tan();
        let (cx, cy) = (
            (f64::from(width) - 1.0) / 2.0,
            (f64::from(height) - 1.0) / 2.0,
        );
        Self::pinhole(width, height, f, f, cx, cy)
    }

    pub fn validate(&self) -> Result<()> {
        let ok = [self.fx, self.fy, self.cx, self.cy]
            .iter()
            .all(|v| v.is_finite())
            && self.fx > 0.0
            && self.fy > 0.0
            && self.width > 0
            && self.height > 0
            && [
                self.distortion.k1,
                self.distortion.k2,
                self.distortion.p1,
                self.distortion.p2,
                self.distortion.k3,
            ]
            .iter()
            .all(|v| v.is_finite());
        if ok {
            Ok(())
        } else {
            Err(CameraError::BadIntrinsics(format!("{self:?}")))
        }
    }

    /// Project a point of the optical frame; `None` behind (or on) the image plane.
    pub fn project(&self, p: DVec3) -> Option<DVec2> {
        if p.z.is_nan() || p.z <= 0.0 {
            return None;
        }
        let n = self.distortion.distort(DVec2::new(p.x / p.z, p.y / p.z));
        Some(DVec2::new(self.fx * n.x + self.cx, self.fy * n.y + self.cy))
    }

    /// The unit-depth ray (z = 1) through a (distorted) pixel.
    pub fn ray(&self, pixel: DVec2) -> DVec3 {
        let distorted = DVec2::new((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy);
        let n = if self.distortion.is_zero() {
            distorted
        } else {
            self.distortion.undistort(distorted)
        };
        DVec3::new(n.x, n.y, 1.0)
    }

    /// The optical-frame point at `depth` (z, metres) behind a pixel.
    pub fn unproject(&self, pixel: DVec2, depth: f64) -> DVec3 {
        self.ray(pixel) * depth
    }

    /// The same camera without distortion.
    pub fn undistorted(&self) -> Self {
        Self {
            distortion: PlumbBob::default(),
            ..*self
        }
    }

    pub fn fov_x(&self) -> f64 {
        2.0 * (f64::from(self.width) / 2.0 / self.fx).atan()
    }

    pub fn fov_y(&self) -> f64 {
        2.0 * (f64::from(self.height) / 2.0 / self.fy).atan()
    }
}

/// The 9-d camera encoding of VGGT: `[t (3), q (4, xyzw), fov_h, fov_w]` of the extrinsic
/// `camera_from_world` (OpenCV), with the principal point at the image centre.
pub fn encode_pose(world_from_camera: &Rigid, camera: &Camera) -> [f64; 9] {
    let camera_from_world = world_from_camera.inverse();
    let q = camera_from_world.rotation;
    let t = camera_from_world.translation;
    [
        t.x,
        t.y,
        t.z,
        q.x,
        q.y,
        q.z,
        q.w,
        camera.fov_y(),
        camera.fov_x(),
    ]
}

/// Decode a 9-d encoding into `world_from_camera` and a pinhole camera of the given size.
pub fn decode_pose(encoding: &[f64; 9], width: u32, height: u32) -> Result<(Rigid, Camera)> {
    let [tx, ty, tz, qx, qy, qz, qw, fov_h, fov_w] = *encoding;
    let fov_ok = |f: f64| f > 0.0 && f < std::f64::consts::PI;
    let q = DQuat::from_xyzw(qx, qy, qz, qw);
    if !encoding.iter().all(|v| v.is_finite())
        || !fov_ok(fov_h)
        || !fov_ok(fov_w)
        || q.length() < 1e-12
    {
        return Err(CameraError::BadEncoding(*encoding));
    }
    let camera_from_world = Rigid::new(q.normalize(), DVec3::new(tx, ty, tz));
    let fy = f64::from(height) / 2.0 / (fov_h / 2.0).tan();
    let fx = f64::from(width) / 2.0 / (fov_w / 2.0).tan();
    let camera = Camera::pinhole(
        width,
        height,
        fx,
        fy,
        f64::from(width) / 2.0,
        f64::from(height) / 2.0,
    )?;
    Ok((camera_from_world.inverse(), camera))
}

/// Rotation from an OpenGL camera frame (x right, y up, z backward) to the optical frame.
pub fn optical_from_opengl() -> DQuat {
    DQuat::from_mat3(&DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0)))
}

/// Rotation from the optical frame to a REP-103 body frame (x forward, y left, z up) at the same
/// place: `body_from_optical` maps optical z (forward) to body x.
pub fn body_from_optical() -> DQuat {
    DQuat::from_mat3(&DMat3::from_cols(
        DVec3::new(0.0, -1.0, 0.0),
        DVec3::new(0.0, 0.0, -1.0),
        DVec3::new(1.0, 0.0, 0.0),
    ))
}

/// Convert `world_from_camera` of an OpenGL-convention camera (NeRF / Blender) to the optical frame.
pub fn opengl_to_optical(world_from_gl_camera: &Rigid) -> Rigid {
    world_from_gl_camera.compose(&Rigid::new(optical_from_opengl().inverse(), DVec3::ZERO))
}

/// A 640×480 camera with strong barrel distortion (the values the OpenCV checks use).
#[cfg(test)]
pub(crate) fn distorted_test_camera() -> Camera {
    Camera {
        distortion: PlumbBob {
            k1: -0.28,
            k2: 0.07,
            p1: 0.001,
            p2: -0.0005,
            k3: 0.0,
        },
        ..Camera::pinhole(640, 480, 500.0, 505.0, 321.5, 239.0).expect("valid intrinsics")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn distorted() -> Camera {
        distorted_test_camera()
    }

    #[test]
    fn project_unproject_round_trip_with_distortion() {
        let camera = distorted();
        for (u, v) in [(0.0, 0.0), (320.0, 240.0), (639.0, 479.0), (100.5, 400.25)] {
            let p = camera.unproject(DVec2::new(u, v), 2.5);
            assert!((p.z - 2.5).abs() < 1e-12);
            let back = camera.project(p).unwrap();
            assert!(
                (back - DVec2::new(u, v)).length() < 1e-6,
                "{u},{v} -> {back}"
            );
        }
        assert!(camera.project(DVec3::new(0.0, 0.0, -1.0)).is_none());
        assert!(camera.project(DVec3::new(1.0, 0.0, 0.0)).is_none());
    }

    #[test]
    fn plumb_bob_matches_opencv_values() {
        // cv2.projectPoints of (0.3, -0.2, 1) with K = I and D = (-0.28, 0.07, 0.001, -0.0005, 0).
        let d = distorted().distortion;
        let p = d.distort(DVec2::new(0.3, -0.2));
        let r2: f64 = 0.13;
        let radial = 1.0 - 0.28 * r2 + 0.07 * r2 * r2;
        let expected_x = 0.3 * radial + 2.0 * 0.001 * 0.3 * -0.2 + -0.0005 * (r2 + 2.0 * 0.09);
        assert!((p.x - expected_x).abs() < 1e-15);
    }

    #[test]
    fn pose_encoding_round_trips() {
        let camera = Camera::pinhole(518, 392, 400.0, 410.0, 259.0, 196.0).unwrap();
        let world_from_camera = Rigid::new(
            DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1),
            DVec3::new(1.0, -2.0, 0.5),
        );
        let encoding = encode_pose(&world_from_camera, &camera);
        let (pose, decoded) = decode_pose(&encoding, 518, 392).unwrap();
        assert!((pose.translation - world_from_camera.translation).length() < 1e-9);
        assert!(pose.rotation.dot(world_from_camera.rotation).abs() > 1.0 - 1e-12);
        assert!((decoded.fx - 400.0).abs() < 1e-9 && (decoded.fy - 410.0).abs() < 1e-9);
        assert!(decode_pose(&[0.0; 9], 10, 10).is_err());
        let mut nan = encoding;
        nan[0] = f64::NAN;
        assert!(decode_pose(&nan, 10, 10).is_err());
    }

    #[test]
    fn frame_conventions() {
        // Optical z (forward) is body x; optical x (right) is body -y; optical y (down) is body -z.
        let q = body_from_optical();
        assert!((q * DVec3::Z - DVec3::X).length() < 1e-12);
        assert!((q * DVec3::X + DVec3::Y).length() < 1e-12);
        assert!((q * DVec3::Y + DVec3::Z).length() < 1e-12);
        // An OpenGL camera looks down its -z: the same direction as optical +z.
        let gl = Rigid::IDENTITY;
        let optical = opengl_to_optical(&gl);
        assert!((optical.rotation * DVec3::Z - DVec3::NEG_Z).length() < 1e-12);
        // The sim's base-from-optical mounting quaternion equals body_from_optical.
        let [x, y, z, w] = groupforward_sim::testcard::BASE_FROM_OPTICAL;
        assert!(DQuat::from_xyzw(x, y, z, w).dot(q).abs() > 1.0 - 1e-12);
    }

    #[test]
    fn ros_distortion_models() {
        assert!(
            PlumbBob::from_ros("plumb_bob", &[0.1, 0.0, 0.0, 0.0, 0.0])
                .unwrap()
                .k1
                == 0.1
        );
        assert!(PlumbBob::from_ros("equidistant", &[0.0; 4])
            .unwrap()
            .is_zero());
        assert!(PlumbBob::from_ros("equidistant", &[0.1, 0.0, 0.0, 0.0]).is_err());
        assert!(PlumbBob::from_ros(
            "rational_polynomial",
            &[0.1, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0]
        )
        .is_err());
        assert!(PlumbBob::from_ros("plumb_bob", &[0.1, 0.2]).is_err());
    }

    #[test]
    fn bad_intrinsics_are_errors() {
        assert!(Camera::pinhole(10, 10, f64::NAN, 1.0, 0.0, 0.0).is_err());
        assert!(Camera::pinhole(10, 10, 0.0, 1.0, 0.0, 0.0).is_err());
        assert!(Camera::pinhole(0, 10, 1.0, 1.0, 0.0, 0.0).is_err());
    }
}

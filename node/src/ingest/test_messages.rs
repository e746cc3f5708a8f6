//! Messages for tests: well-formed images, camera info and TF for the ingest tests, and the
//! hostile ones of the node's flood test and the harness's soak (`bench soak`).

use groupforward_msgs::builtin_interfaces::Time;
use groupforward_msgs::geometry_msgs::{Quaternion, Transform, TransformStamped, Vector3};
use groupforward_msgs::sensor_msgs::{CameraInfo, Image};
use groupforward_msgs::std_msgs::Header;
use groupforward_msgs::tf2_msgs::TFMessage;

pub fn header(nanos: i64, frame: &str) -> Header {
    Header {
        stamp: Time::from_nanos(nanos),
        frame_id: frame.into(),
    }
}

pub fn image(w: u32, h: u32, enc: &str, bpp: u32, nanos: i64) -> Image {
    Image {
        header: header(nanos, "cam_optical"),
        height: h,
        width: w,
        encoding: enc.into(),
        is_bigendian: 0,
        step: w * bpp,
        data: (0..w * h * bpp).map(|i| (i % 251) as u8).collect(),
    }
}

pub fn info(w: u32, h: u32) -> CameraInfo {
    CameraInfo {
        header: header(0, "cam_optical"),
        width: w,
        height: h,
        k: [
            100.0,
            0.0,
            w as f64 / 2.0,
            0.0,
            100.0,
            h as f64 / 2.0,
            0.0,
            0.0,
            1.0,
        ],
        ..Default::default()
    }
}

pub fn tf(parent: &str, child: &str, nanos: i64, x: f64, q: [f64; 4]) -> TFMessage {
    TFMessage {
        transforms: vec![TransformStamped {
            header: header(nanos, parent),
            child_frame_id: child.into(),
            transform: Transform {
                translation: Vector3 { x, y: 0.0, z: 0.0 },
                rotation: Quaternion {
                    x: q[0],
                    y: q[1],
                    z: q[2],
                    w: q[3],
                },
            },
        }],
    }
}

pub const ID: [f64; 4] = [0.0, 0.0, 0.0, 1.0];

/// Where a [`hostile_message`] goes: one of a camera's three topics, or a transform topic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HostileTarget {
    Image,
    CameraInfo,
    Depth,
    Tf,
    TfStatic,
}

impl HostileTarget {
    pub fn is_tf(self) -> bool {
        matches!(self, Self::Tf | Self::TfStatic)
    }
}

/// One seeded bad message, and where it goes: garbage behind a broken encapsulation header, a
/// good image cut short, 10⁵ × 10⁵ claimed with a few bytes sent, 0 × 0 or an unknown encoding, a
/// transform with a NaN translation or a zero quaternion stamped in 1970, or a truncated
/// transform. Every one must be rejected and counted, none may panic (the node's flood test and
/// `bench soak`).
pub fn hostile_message(rng: &mut impl rand::Rng) -> (HostileTarget, Vec<u8>) {
    use groupforward_msgs::cdr;
    let camera = [
        HostileTarget::Image,
        HostileTarget::CameraInfo,
        HostileTarget::Depth,
    ];
    let image_or_depth = [HostileTarget::Image, HostileTarget::Depth];
    let kind = rng.random_range(0..6);
    let payload = match kind {
        0 => {
            let mut bytes: Vec<u8> = (0..rng.random_range(0..300))
                .map(|_| rng.random())
                .collect();
            bytes.splice(0..0, [0xff, 0xff, 0, 0]);
            bytes
        }
        1 => {
            let good = cdr::encode(&image(8, 6, "rgb8", 3, 1)).unwrap_or_default();
            good[..rng.random_range(0..good.len().max(1))].to_vec()
        }
        2 => {
            let mut m = image(8, 6, "rgb8", 3, 1);
            m.width = 100_000;
            m.height = 100_000;
            m.step = 300_000;
            cdr::encode(&m).unwrap_or_default()
        }
        3 => {
            let m = if rng.random() {
                image(0, 0, "rgb8", 3, 1)
            } else {
                image(8, 6, "yuv_magic", 3, 1)
            };
            cdr::encode(&m).unwrap_or_default()
        }
        4 => {
            let q = if rng.random() {
                [0.0, 0.0, 0.0, 0.0]
            } else {
                [0.0, 0.0, 0.0, 1.0]
            };
            cdr::encode(&tf("map", "base", 1, f64::NAN, q)).unwrap_or_default()
        }
        _ => {
            let bytes =
                cdr::encode(&tf("map", "base", 1, 0.0, [0.0, 0.0, 0.0, 1.0])).unwrap_or_default();
            bytes[..rng.random_range(0..bytes.len().saturating_sub(1).max(1))].to_vec()
        }
    };
    let target = match kind {
        4 | 5 => {
            if rng.random() {
                HostileTarget::Tf
            } else {
                HostileTarget::TfStatic
            }
        }
        0 | 1 => camera[rng.random_range(0..camera.len())],
        _ => image_or_depth[rng.random_range(0..2)],
    };
    (target, payload)
}

//! Messages for the ingest tests.

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

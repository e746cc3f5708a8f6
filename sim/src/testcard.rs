//! A test-card camera rig: a robot driving a circle, its camera seeing a fronto-parallel card at a
//! fixed distance. Everything a robot records comes out of it (rgb8 image, 32FC1 depth, CameraInfo,
//! `/tf` odometry and `/tf_static` mounting), stamped and deterministic, with no objects: it checks
//! plumbing (decode, sync, transport), not perception.

use groupforward_msgs::builtin_interfaces::Time;
use groupforward_msgs::geometry_msgs::{Quaternion, Transform, TransformStamped, Vector3};
use groupforward_msgs::sensor_msgs::{CameraInfo, Image};
use groupforward_msgs::std_msgs::Header;
use groupforward_msgs::tf2_msgs::TFMessage;

/// Topics the rig records on: the common ROS 2 RGB-D driver layout (and the node's defaults).
pub const IMAGE_TOPIC: &str = "/camera/color/image_raw";
pub const CAMERA_INFO_TOPIC: &str = "/camera/color/camera_info";
pub const DEPTH_TOPIC: &str = "/camera/depth/image_raw";
pub const TF_TOPIC: &str = "/tf";
pub const TF_STATIC_TOPIC: &str = "/tf_static";

/// REP-103: `base_link` is x forward, z up; the optical frame is z forward, x right, y down.
pub const BASE_FROM_OPTICAL: [f64; 4] = [-0.5, 0.5, -0.5, 0.5];

#[derive(Debug, Clone, PartialEq)]
pub struct TestCard {
    pub width: u32,
    pub height: u32,
    pub rate_hz: f64,
    /// Radius of the circle the robot drives, metres.
    pub radius: f64,
    /// Distance from the camera to the card, metres.
    pub card_distance: f32,
    pub start_nanos: i64,
    pub world_frame: String,
    pub camera_frame: String,
}

impl Default for TestCard {
    fn default() -> Self {
        Self {
            width: 160,
            height: 120,
            rate_hz: 10.0,
            radius: 1.0,
            card_distance: 2.0,
            start_nanos: 1_700_000_000_000_000_000,
            world_frame: "map".into(),
            camera_frame: "camera_color_optical_frame".into(),
        }
    }
}

/// Everything recorded at one instant.
#[derive(Debug, Clone, PartialEq)]
pub struct TestCardFrame {
    pub stamp: Time,
    pub image: Image,
    pub depth: Image,
    pub camera_info: CameraInfo,
    pub tf: TFMessage,
}

impl TestCard {
    pub fn stamp(&self, index: u64) -> Time {
        Time::from_nanos(self.start_nanos + (index as f64 * 1e9 / self.rate_hz) as i64)
    }

    fn header(&self, index: u64, frame: &str) -> Header {
        Header {
            stamp: self.stamp(index),
            frame_id: frame.into(),
        }
    }

    /// Pinhole intrinsics with a 60° horizontal field of view.
    pub fn camera_info(&self, index: u64) -> CameraInfo {
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let f = w / 2.0 / (30f64.to_radians()).tan();
        CameraInfo {
            header: self.header(index, &self.camera_frame),
            width: self.width,
            height: self.height,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: [f, 0.0, w / 2.0, 0.0, f, h / 2.0, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                f,
                0.0,
                w / 2.0,
                0.0,
                0.0,
                f,
                h / 2.0,
                0.0,
                0.0,
                0.0,
                1.0,
                0.0,
            ],
            ..Default::default()
        }
    }

    /// `base_link` → camera optical frame, for `/tf_static`.
    pub fn tf_static(&self) -> TFMessage {
        let [x, y, z, w] = BASE_FROM_OPTICAL;
        TFMessage {
            transforms: vec![TransformStamped {
                header: self.header(0, "base_link"),
                child_frame_id: self.camera_frame.clone(),
                transform: Transform {
                    translation: Vector3 {
                        x: 0.1,
                        y: 0.0,
                        z: 1.2,
                    },
                    rotation: Quaternion { x, y, z, w },
                },
            }],
        }
    }

    /// Heading (yaw) of the robot at frame `index`: a full circle every 100 frames.
    fn yaw(index: u64) -> f64 {
        (index % 100) as f64 / 100.0 * std::f64::consts::TAU
    }

    /// `world` → `base_link` odometry for `/tf`.
    pub fn tf(&self, index: u64) -> TFMessage {
        let yaw = Self::yaw(index);
        TFMessage {
            transforms: vec![TransformStamped {
                header: self.header(index, &self.world_frame),
                child_frame_id: "base_link".into(),
                transform: Transform {
                    translation: Vector3 {
                        x: self.radius * yaw.cos(),
                        y: self.radius * yaw.sin(),
                        z: 0.0,
                    },
                    rotation: Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: (yaw / 2.0).sin(),
                        w: (yaw / 2.0).cos(),
                    },
                },
            }],
        }
    }

    /// A colour gradient with a checkerboard that scrolls with the heading.
    pub fn image(&self, index: u64) -> Image {
        let shift = (Self::yaw(index) / std::f64::consts::TAU * f64::from(self.width)) as u32;
        let mut data = Vec::with_capacity((self.width * self.height * 3) as usize);
        for y in 0..self.height {
            for x in 0..self.width {
                let checker = (((x + shift) / 16 + y / 16) % 2) as u8;
                data.extend_from_slice(&[
                    (x * 255 / self.width.max(1)) as u8,
                    (y * 255 / self.height.max(1)) as u8,
                    checker * 200 + 30,
                ]);
            }
        }
        Image {
            header: self.header(index, &self.camera_frame),
            height: self.height,
            width: self.width,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: self.width * 3,
            data,
        }
    }

    /// Metric depth of the card (32FC1).
    pub fn depth(&self, index: u64) -> Image {
        let pixels = (self.width * self.height) as usize;
        let data = std::iter::repeat_n(self.card_distance.to_le_bytes(), pixels)
            .flatten()
            .collect();
        Image {
            header: self.header(index, &self.camera_frame),
            height: self.height,
            width: self.width,
            encoding: "32FC1".into(),
            is_bigendian: 0,
            step: self.width * 4,
            data,
        }
    }

    pub fn frame(&self, index: u64) -> TestCardFrame {
        TestCardFrame {
            stamp: self.stamp(index),
            image: self.image(index),
            depth: self.depth(index),
            camera_info: self.camera_info(index),
            tf: self.tf(index),
        }
    }
}

impl TestCard {
    /// A rosbag2 MCAP bag of `frames` frames (depth only if `with_depth`), in memory.
    pub fn bag(&self, frames: u64, with_depth: bool) -> groupforward_msgs::bag::Result<Vec<u8>> {
        let mut bag = groupforward_msgs::bag::BagWriter::new(std::io::Cursor::new(Vec::new()))?;
        bag.write(TF_STATIC_TOPIC, self.stamp(0).as_nanos(), &self.tf_static())?;
        for index in 0..frames {
            let frame = self.frame(index);
            let t = frame.stamp.as_nanos();
            bag.write(TF_TOPIC, t, &frame.tf)?;
            bag.write(CAMERA_INFO_TOPIC, t, &frame.camera_info)?;
            if with_depth {
                bag.write(DEPTH_TOPIC, t, &frame.depth)?;
            }
            bag.write(IMAGE_TOPIC, t, &frame.image)?;
        }
        Ok(bag.finish()?.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_deterministic_and_consistent() {
        let card = TestCard::default();
        assert_eq!(card.frame(3), card.frame(3));
        let f = card.frame(7);
        assert_eq!(f.image.data.len() as u32, f.image.step * f.image.height);
        assert_eq!(f.depth.data.len() as u32, f.depth.step * f.depth.height);
        assert_eq!(f.image.header.stamp, f.depth.header.stamp);
        assert_eq!(f.tf.transforms[0].header.stamp, f.image.header.stamp);
        assert!(card.stamp(1).as_nanos() - card.stamp(0).as_nanos() == 100_000_000);
        let q = &f.tf.transforms[0].transform.rotation;
        assert!(((q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt() - 1.0).abs() < 1e-12);
        assert_ne!(card.image(0).data, card.image(10).data);
    }

    #[test]
    fn bag_holds_every_message_in_time_order() {
        let card = TestCard::default();
        let bytes = card.bag(3, true).unwrap();
        let messages: Vec<_> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap())
            .collect();
        assert_eq!(messages.len(), 1 + 3 * 4);
        assert!(messages.windows(2).all(|w| w[0].log_time <= w[1].log_time));
        assert_eq!(messages.last().unwrap().channel.topic, IMAGE_TOPIC);
    }
}

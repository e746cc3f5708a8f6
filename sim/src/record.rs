//! Record a simulation as a rosbag2 bag: what a robot records (colour as Image or
//! CompressedImage, CameraInfo, depth, `/tf`, `/tf_static`) plus ground truth on `/gt/...` topics
//! that the node never subscribes to: exact depth, instance and class images, the object list and
//! the true robot pose.

use std::io::{Seek, Write};

use glam::{DQuat, DVec3};
use groupforward_msgs::builtin_interfaces::Time;
use groupforward_msgs::geometry_msgs::{
    Point, Pose, PoseWithCovariance, Quaternion, Transform, TransformStamped, Vector3,
};
use groupforward_msgs::sensor_msgs::{CameraInfo, CompressedImage, Image};
use groupforward_msgs::std_msgs::Header;
use groupforward_msgs::tf2_msgs::TFMessage;
use groupforward_msgs::vision_msgs::{
    BoundingBox3D, Detection3D, Detection3DArray, ObjectHypothesis, ObjectHypothesisWithPose,
};
use rayon::prelude::*;

use crate::library;
use crate::render::Scene;
use crate::scene::{mount_pose, RobotPose};
use crate::simulation::{SimFrame, SimView, Simulation};
use groupforward_msgs::bag::{BagError, BagWriter, OfferedQos};

#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error("encoding a {0} image: {1}")]
    Image(&'static str, String),
}

pub type Result<T> = std::result::Result<T, RecordError>;

/// How the colour image is recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ColorFormat {
    /// `sensor_msgs/Image`, rgb8, on `/<camera>/color/image_raw`.
    #[default]
    Raw,
    /// `sensor_msgs/CompressedImage` on `/<camera>/color/image_raw/compressed`.
    Png,
    Jpeg {
        quality: u8,
    },
}

/// How depth is recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DepthFormat {
    /// 32FC1 metres, NaN where invalid.
    #[default]
    Metres32,
    /// 16UC1 millimetres, 0 where invalid (as RealSense and Kinect drivers publish).
    Millimetres16,
}

#[derive(Debug, Clone, PartialEq)]
pub struct RecordOptions {
    /// Stamp of frame 0, nanoseconds since the epoch.
    pub start_nanos: i64,
    pub color: ColorFormat,
    pub depth: DepthFormat,
    pub ground_truth: bool,
    pub world_frame: String,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            start_nanos: 1_700_000_000_000_000_000,
            color: ColorFormat::Raw,
            depth: DepthFormat::Metres32,
            ground_truth: true,
            world_frame: "map".into(),
        }
    }
}

/// Topic names for one camera of the rig (the common ROS 2 RGB-D driver layout).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraTopics {
    pub image: String,
    pub compressed: String,
    pub camera_info: String,
    pub depth: String,
    pub frame_id: String,
    pub gt_depth: String,
    pub gt_instance: String,
    pub gt_class: String,
}

impl CameraTopics {
    pub fn new(camera: &str) -> Self {
        Self {
            image: format!("/{camera}/color/image_raw"),
            compressed: format!("/{camera}/color/image_raw/compressed"),
            camera_info: format!("/{camera}/color/camera_info"),
            depth: format!("/{camera}/depth/image_raw"),
            frame_id: format!("{camera}_color_optical_frame"),
            gt_depth: format!("/gt/{camera}/depth"),
            gt_instance: format!("/gt/{camera}/instance"),
            gt_class: format!("/gt/{camera}/class"),
        }
    }
}

pub const TF_TOPIC: &str = "/tf";
pub const TF_STATIC_TOPIC: &str = "/tf_static";
pub const GT_TF_TOPIC: &str = "/gt/tf";
pub const GT_OBJECTS_TOPIC: &str = "/gt/objects";
pub const BASE_FRAME: &str = "base_link";

/// What a recording holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecordSummary {
    pub frames: usize,
    pub dropped: usize,
    pub messages: u64,
}

fn time(nanos: i64) -> Time {
    Time::from_nanos(nanos)
}

fn stamp_nanos(options: &RecordOptions, secs: f64) -> i64 {
    options.start_nanos + (secs * 1e9).round() as i64
}

fn quaternion(q: DQuat) -> Quaternion {
    Quaternion {
        x: q.x,
        y: q.y,
        z: q.z,
        w: q.w,
    }
}

fn transform(
    parent: &str,
    child: &str,
    stamp: Time,
    rotation: DQuat,
    t: DVec3,
) -> TransformStamped {
    TransformStamped {
        header: Header {
            stamp,
            frame_id: parent.into(),
        },
        child_frame_id: child.into(),
        transform: Transform {
            translation: Vector3 {
                x: t.x,
                y: t.y,
                z: t.z,
            },
            rotation: quaternion(rotation),
        },
    }
}

fn robot_tf(options: &RecordOptions, pose: &RobotPose, stamp: Time) -> TFMessage {
    TFMessage {
        transforms: vec![transform(
            &options.world_frame,
            BASE_FRAME,
            stamp,
            DQuat::from_rotation_z(pose.yaw),
            pose.position,
        )],
    }
}

fn header(stamp: Time, frame_id: &str) -> Header {
    Header {
        stamp,
        frame_id: frame_id.into(),
    }
}

fn image(
    header: Header,
    width: u32,
    height: u32,
    encoding: &str,
    bytes_per_pixel: u32,
    data: Vec<u8>,
) -> Image {
    Image {
        header,
        height,
        width,
        encoding: encoding.into(),
        is_bigendian: 0,
        step: width * bytes_per_pixel,
        data,
    }
}

/// The CameraInfo of a view: K from the pinhole, D from the lens (plumb_bob), P = [K | 0].
pub fn camera_info(view: &SimView, header: Header) -> CameraInfo {
    let c = &view.pinhole;
    CameraInfo {
        header,
        width: c.width,
        height: c.height,
        distortion_model: "plumb_bob".into(),
        d: view
            .distortion
            .map_or(vec![0.0; 5], |d| d.coefficients().to_vec()),
        k: [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            c.fx, 0.0, c.cx, 0.0, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..Default::default()
    }
}

/// Ground-truth objects: one detection per instance, `id` = instance id, class name as the
/// hypothesis, the object's pose, and its world-aligned bounding box.
pub fn objects_message(scene: &Scene, header: Header) -> Detection3DArray {
    let classes = library::classes();
    let detections = scene
        .objects
        .iter()
        .map(|object| {
            let (lo, hi) = object.bounds();
            let center = (lo + hi) / 2.0;
            let size = hi - lo;
            let class_name = classes
                .iter()
                .find(|c| c.id == object.class_id)
                .map_or("unknown", |c| c.name);
            let pose = Pose {
                position: Point {
                    x: object.position.x,
                    y: object.position.y,
                    z: object.position.z,
                },
                orientation: quaternion(DQuat::from_rotation_z(object.yaw)),
            };
            Detection3D {
                header: header.clone(),
                results: vec![ObjectHypothesisWithPose {
                    hypothesis: ObjectHypothesis {
                        class_id: class_name.into(),
                        score: 1.0,
                    },
                    pose: PoseWithCovariance {
                        pose,
                        ..Default::default()
                    },
                }],
                bbox: BoundingBox3D {
                    center: Pose {
                        position: Point {
                            x: center.x,
                            y: center.y,
                            z: center.z,
                        },
                        orientation: Quaternion {
                            x: 0.0,
                            y: 0.0,
                            z: 0.0,
                            w: 1.0,
                        },
                    },
                    size: Vector3 {
                        x: size.x,
                        y: size.y,
                        z: size.z,
                    },
                },
                id: object.instance_id.to_string(),
            }
        })
        .collect();
    Detection3DArray { header, detections }
}

fn u16_bytes(values: impl Iterator<Item = u16>) -> Vec<u8> {
    values.flat_map(u16::to_le_bytes).collect()
}

fn encode_png(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>> {
    let mut out = std::io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        rgb,
        width,
        height,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| RecordError::Image("png", e.to_string()))?;
    Ok(out.into_inner())
}

fn encode_jpeg(width: u32, height: u32, rgb: &[u8], quality: u8) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality)
        .encode(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| RecordError::Image("jpeg", e.to_string()))?;
    Ok(out)
}

/// Record every frame of `sim` into `bag`. Frames are rendered in parallel in small batches and
/// written in order; `progress` is called with the number of frames done.
pub fn record<W: Write + Seek>(
    sim: &Simulation,
    options: &RecordOptions,
    bag: &mut BagWriter<W>,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<RecordSummary> {
    let cameras: Vec<CameraTopics> = sim
        .file
        .cameras
        .iter()
        .map(|c| CameraTopics::new(&c.name))
        .collect();
    for topics in &cameras {
        for topic in [
            &topics.image,
            &topics.compressed,
            &topics.camera_info,
            &topics.depth,
        ] {
            bag.set_qos(topic, OfferedQos::sensor_data());
        }
    }
    bag.set_qos(TF_STATIC_TOPIC, OfferedQos::latched());
    let start = time(options.start_nanos);
    let statics = TFMessage {
        transforms: sim
            .file
            .cameras
            .iter()
            .zip(&cameras)
            .map(|(camera, topics)| {
                let (rotation, position) = mount_pose(camera);
                transform(BASE_FRAME, &topics.frame_id, start, rotation, position)
            })
            .collect(),
    };
    bag.write(TF_STATIC_TOPIC, options.start_nanos, &statics)?;
    let mut summary = RecordSummary::default();
    let batch = rayon::current_num_threads().max(1) * 2;
    let count = sim.frame_count();
    for first in (0..count).step_by(batch) {
        let frames: Vec<SimFrame> = (first..(first + batch).min(count))
            .into_par_iter()
            .map(|i| sim.frame(i))
            .collect();
        for frame in &frames {
            write_frame(frame, &cameras, options, bag)?;
            summary.frames += 1;
            summary.dropped += usize::from(frame.dropped);
        }
        progress(summary.frames);
    }
    summary.messages = bag.message_count();
    Ok(summary)
}

fn write_frame<W: Write + Seek>(
    frame: &SimFrame,
    cameras: &[CameraTopics],
    options: &RecordOptions,
    bag: &mut BagWriter<W>,
) -> Result<()> {
    let log_nanos = stamp_nanos(options, frame.time_secs);
    let true_stamp = time(log_nanos);
    bag.write(
        TF_TOPIC,
        log_nanos,
        &robot_tf(options, &frame.odometry, true_stamp),
    )?;
    if options.ground_truth {
        bag.write(
            GT_TF_TOPIC,
            log_nanos,
            &robot_tf(options, &frame.robot, true_stamp),
        )?;
        let objects = objects_message(&frame.scene, header(true_stamp, &options.world_frame));
        bag.write(GT_OBJECTS_TOPIC, log_nanos, &objects)?;
    }
    let stamp = time(stamp_nanos(options, frame.stamp_secs));
    for view in &frame.views {
        let topics = &cameras[view.camera];
        let (w, h) = (view.truth.width, view.truth.height);
        let head = header(stamp, &topics.frame_id);
        bag.write(
            &topics.camera_info,
            log_nanos,
            &camera_info(view, head.clone()),
        )?;
        let depth = match options.depth {
            DepthFormat::Metres32 => image(
                head.clone(),
                w,
                h,
                "32FC1",
                4,
                view.sensor_depth()
                    .iter()
                    .flat_map(|z| z.to_le_bytes())
                    .collect(),
            ),
            DepthFormat::Millimetres16 => image(
                head.clone(),
                w,
                h,
                "16UC1",
                2,
                u16_bytes(view.sensor_depth().iter().map(|z| {
                    if z.is_finite() {
                        (z * 1000.0).round().clamp(0.0, 65535.0) as u16
                    } else {
                        0
                    }
                })),
            ),
        };
        bag.write(&topics.depth, log_nanos, &depth)?;
        match options.color {
            ColorFormat::Raw => {
                let rgb = image(head.clone(), w, h, "rgb8", 3, view.sensor_rgb().to_vec());
                bag.write(&topics.image, log_nanos, &rgb)?;
            }
            ColorFormat::Png | ColorFormat::Jpeg { .. } => {
                let (format, data) = match options.color {
                    ColorFormat::Jpeg { quality } => (
                        "rgb8; jpeg compressed rgb8",
                        encode_jpeg(w, h, view.sensor_rgb(), quality)?,
                    ),
                    _ => (
                        "rgb8; png compressed rgb8",
                        encode_png(w, h, view.sensor_rgb())?,
                    ),
                };
                let message = CompressedImage {
                    header: head.clone(),
                    format: format.into(),
                    data,
                };
                bag.write(&topics.compressed, log_nanos, &message)?;
            }
        }
        if options.ground_truth {
            let exact = image(
                head.clone(),
                w,
                h,
                "32FC1",
                4,
                view.truth
                    .depth
                    .iter()
                    .flat_map(|z| z.to_le_bytes())
                    .collect(),
            );
            bag.write(&topics.gt_depth, log_nanos, &exact)?;
            let ids = |values: &[u16]| u16_bytes(values.iter().copied());
            let instance = image(head.clone(), w, h, "mono16", 2, ids(&view.truth.instance));
            bag.write(&topics.gt_instance, log_nanos, &instance)?;
            let class = image(head, w, h, "mono16", 2, ids(&view.truth.class));
            bag.write(&topics.gt_class, log_nanos, &class)?;
        }
    }
    Ok(())
}

/// Record `sim` into an in-memory MCAP file.
pub fn record_to_memory(
    sim: &Simulation,
    options: &RecordOptions,
) -> Result<(Vec<u8>, RecordSummary)> {
    let mut bag = BagWriter::new(std::io::Cursor::new(Vec::new()))?;
    let summary = record(sim, options, &mut bag, &|_| {})?;
    Ok((bag.finish()?.into_inner(), summary))
}

/// Record `sim` into a rosbag2 bag directory (`<dir>/<name>_0.mcap` and `metadata.yaml`).
pub fn record_to_dir(
    sim: &Simulation,
    options: &RecordOptions,
    dir: &std::path::Path,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<RecordSummary> {
    let (mut bag, file_name) = BagWriter::create_dir(dir).map_err(BagError::Io)?;
    let summary = record(sim, options, &mut bag, progress)?;
    bag.finish_dir(dir, &file_name)?;
    Ok(summary)
}

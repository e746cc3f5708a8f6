//! Ingest: decode and validate camera, depth, camera-info and TF messages, and sync them by stamp
//! into [`SyncedFrame`]s (colour + optional depth + camera model + `world_from_camera` from TF).
//!
//! Every malformed input is rejected with a reason code, counted, and logged once per reason; no
//! input can make this stage panic. Time is stamp time, never wall time, so a replayed bag syncs
//! exactly as it did live.

use std::collections::{BTreeMap, HashMap, VecDeque};

use glam::{DQuat, DVec3};
use groupforward_msgs::sensor_msgs::{CameraInfo, CompressedImage, Image};
use groupforward_msgs::tf2_msgs::TFMessage;
use groupforward_msgs::{cdr, geometry_msgs::TransformStamped};

use crate::config::{CameraConfig, Config, ImageTransport};
use crate::recon::camera::{Camera, PlumbBob};
pub use crate::recon::Rigid;

/// Why an input was rejected. The string codes appear in status messages and logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Reject {
    MalformedCdr,
    UnknownEncoding,
    BadDimensions,
    SizeMismatch,
    CompressedDecodeFailed,
    BadIntrinsics,
    UnsupportedDistortion,
    CameraInfoMismatch,
    NonFiniteTransform,
    NonUnitQuaternion,
    EmptyFrameId,
    NoCameraInfo,
    NoMatchingDepth,
    NoPose,
    PendingOverflow,
    QueueOverflow,
}

impl Reject {
    pub fn code(self) -> &'static str {
        match self {
            Self::MalformedCdr => "malformed_cdr",
            Self::UnknownEncoding => "unknown_encoding",
            Self::BadDimensions => "bad_dimensions",
            Self::SizeMismatch => "size_mismatch",
            Self::CompressedDecodeFailed => "compressed_decode_failed",
            Self::BadIntrinsics => "bad_intrinsics",
            Self::UnsupportedDistortion => "unsupported_distortion",
            Self::CameraInfoMismatch => "camera_info_mismatch",
            Self::NonFiniteTransform => "non_finite_transform",
            Self::NonUnitQuaternion => "non_unit_quaternion",
            Self::EmptyFrameId => "empty_frame_id",
            Self::NoCameraInfo => "no_camera_info",
            Self::NoMatchingDepth => "no_matching_depth",
            Self::NoPose => "no_pose",
            Self::PendingOverflow => "pending_overflow",
            Self::QueueOverflow => "queue_overflow",
        }
    }
}

/// A rejection with its human-readable detail.
#[derive(Debug, Clone, PartialEq)]
pub struct Rejection {
    pub reason: Reject,
    pub detail: String,
}

fn reject<T>(reason: Reject, detail: impl Into<String>) -> Result<T, Rejection> {
    Err(Rejection {
        reason,
        detail: detail.into(),
    })
}

/// An 8-bit RGB image, row-major, tightly packed.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

/// Metric depth, row-major; invalid pixels are NaN.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    pub metres: Vec<f32>,
}

/// One camera frame with everything later stages need.
#[derive(Debug, Clone, PartialEq)]
pub struct SyncedFrame {
    /// Name of the configured camera.
    pub camera_name: String,
    pub stamp_nanos: i64,
    /// The image's optical frame (REP-103: z forward, x right, y down).
    pub frame_id: String,
    pub rgb: RgbImage,
    pub depth: Option<DepthImage>,
    /// Validated intrinsics and distortion from the latest CameraInfo.
    pub camera: Camera,
    pub world_from_camera: Rigid,
}

fn check_dimensions(width: u32, height: u32, max_side: u32) -> Result<(), Rejection> {
    if width == 0 || height == 0 || width > max_side || height > max_side {
        return reject(
            Reject::BadDimensions,
            format!("{width}x{height} (allowed 1..={max_side} per side)"),
        );
    }
    Ok(())
}

/// Bytes per pixel and channel order of the colour encodings we accept.
fn colour_layout(encoding: &str) -> Option<(usize, [usize; 3])> {
    match encoding {
        "rgb8" => Some((3, [0, 1, 2])),
        "bgr8" => Some((3, [2, 1, 0])),
        "rgba8" => Some((4, [0, 1, 2])),
        "bgra8" => Some((4, [2, 1, 0])),
        "mono8" | "8UC1" => Some((1, [0, 0, 0])),
        _ => None,
    }
}

/// Rows of `step` bytes each holding at least `row_bytes` of pixel data.
fn check_layout(msg: &Image, bytes_per_pixel: usize) -> Result<(), Rejection> {
    let row_bytes = msg.width as usize * bytes_per_pixel;
    if (msg.step as usize) < row_bytes {
        return reject(
            Reject::SizeMismatch,
            format!(
                "step {} < width {} x {bytes_per_pixel}",
                msg.step, msg.width
            ),
        );
    }
    let expected = msg.step as usize * msg.height as usize;
    if msg.data.len() != expected {
        return reject(
            Reject::SizeMismatch,
            format!(
                "{} data bytes, step x height = {expected} ({}x{} {})",
                msg.data.len(),
                msg.width,
                msg.height,
                msg.encoding
            ),
        );
    }
    Ok(())
}

/// Decode a raw colour image (rgb8, bgr8, rgba8, bgra8, mono8) to RGB.
pub fn decode_image(msg: &Image, max_side: u32) -> Result<RgbImage, Rejection> {
    check_dimensions(msg.width, msg.height, max_side)?;
    let Some((bpp, order)) = colour_layout(&msg.encoding) else {
        return reject(
            Reject::UnknownEncoding,
            format!("colour encoding `{}`", msg.encoding),
        );
    };
    check_layout(msg, bpp)?;
    let (w, h) = (msg.width as usize, msg.height as usize);
    let mut data = Vec::with_capacity(w * h * 3);
    for row in msg.data.chunks_exact(msg.step as usize).take(h) {
        for px in row[..w * bpp].chunks_exact(bpp) {
            data.extend_from_slice(&[px[order[0]], px[order[1]], px[order[2]]]);
        }
    }
    Ok(RgbImage {
        width: msg.width,
        height: msg.height,
        data,
    })
}

/// Decode a jpeg / png `CompressedImage` to RGB.
pub fn decode_compressed(msg: &CompressedImage, max_side: u32) -> Result<RgbImage, Rejection> {
    let format = msg.format.to_ascii_lowercase();
    if format.contains("compresseddepth") {
        return reject(
            Reject::UnknownEncoding,
            format!("compressed depth `{}` on a colour topic", msg.format),
        );
    }
    let reader = image::ImageReader::new(std::io::Cursor::new(&msg.data))
        .with_guessed_format()
        .map_err(|e| Rejection {
            reason: Reject::CompressedDecodeFailed,
            detail: e.to_string(),
        })?;
    let Some(kind) = reader.format() else {
        return reject(
            Reject::CompressedDecodeFailed,
            format!("format `{}`: not jpeg or png data", msg.format),
        );
    };
    if !matches!(kind, image::ImageFormat::Jpeg | image::ImageFormat::Png) {
        return reject(
            Reject::UnknownEncoding,
            format!("compressed format {kind:?}"),
        );
    }
    // Check the header's size before decoding pixels, so a hostile header cannot allocate much.
    let (width, height) = reader.into_dimensions().map_err(|e| Rejection {
        reason: Reject::CompressedDecodeFailed,
        detail: e.to_string(),
    })?;
    check_dimensions(width, height, max_side)?;
    let decoded = image::load_from_memory_with_format(&msg.data, kind).map_err(|e| Rejection {
        reason: Reject::CompressedDecodeFailed,
        detail: e.to_string(),
    })?;
    let rgb = decoded.to_rgb8();
    Ok(RgbImage {
        width: rgb.width(),
        height: rgb.height(),
        data: rgb.into_raw(),
    })
}

/// Decode a depth image: 16UC1 / mono16 in millimetres (0 = invalid) or 32FC1 in metres.
pub fn decode_depth(msg: &Image, max_side: u32) -> Result<DepthImage, Rejection> {
    check_dimensions(msg.width, msg.height, max_side)?;
    let bpp = match msg.encoding.as_str() {
        "16UC1" | "mono16" => 2,
        "32FC1" => 4,
        other => {
            return reject(
                Reject::UnknownEncoding,
                format!("depth encoding `{other}` (expected 16UC1 or 32FC1)"),
            )
        }
    };
    check_layout(msg, bpp)?;
    let (w, h) = (msg.width as usize, msg.height as usize);
    let big = msg.is_bigendian != 0;
    let mut metres = Vec::with_capacity(w * h);
    for row in msg.data.chunks_exact(msg.step as usize).take(h) {
        for px in row[..w * bpp].chunks_exact(bpp) {
            let value = if bpp == 2 {
                let raw = [px[0], px[1]];
                let mm = if big {
                    u16::from_be_bytes(raw)
                } else {
                    u16::from_le_bytes(raw)
                };
                if mm == 0 {
                    f32::NAN
                } else {
                    f32::from(mm) * 1e-3
                }
            } else {
                let raw = [px[0], px[1], px[2], px[3]];
                let m = if big {
                    f32::from_be_bytes(raw)
                } else {
                    f32::from_le_bytes(raw)
                };
                if m.is_finite() && m > 0.0 {
                    m
                } else {
                    f32::NAN
                }
            };
            metres.push(value);
        }
    }
    Ok(DepthImage {
        width: msg.width,
        height: msg.height,
        metres,
    })
}

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
fn strip_slash(frame: &str) -> String {
    frame.trim_start_matches('/').to_owned()
}

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

/// Per-reason counters that log the first occurrence of each reason.
#[derive(Debug, Default)]
pub struct Rejections {
    counts: BTreeMap<Reject, u64>,
}

impl Rejections {
    pub fn record(&mut self, source: &str, rejection: &Rejection) {
        let count = self.counts.entry(rejection.reason).or_insert(0);
        *count += 1;
        if *count == 1 {
            tracing::warn!(
                source,
                reason = rejection.reason.code(),
                "rejected input: {} (further rejections for this reason are counted, not logged)",
                rejection.detail
            );
        } else {
            tracing::debug!(
                source,
                reason = rejection.reason.code(),
                "{}",
                rejection.detail
            );
        }
    }

    pub fn count(&self, reason: Reject) -> u64 {
        self.counts.get(&reason).copied().unwrap_or(0)
    }

    pub fn iter(&self) -> impl Iterator<Item = (Reject, u64)> + '_ {
        self.counts.iter().map(|(r, c)| (*r, *c))
    }

    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }
}

/// What a subscribed topic carries for ingest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Route {
    Image(usize),
    CompressedImage(usize),
    CameraInfo(usize),
    Depth(usize),
    Tf,
    TfStatic,
}

impl Route {
    /// The ROS type the topic carries.
    pub fn type_name(self) -> &'static str {
        use groupforward_msgs::RosMessage;
        match self {
            Self::Image(_) | Self::Depth(_) => Image::TYPE_NAME,
            Self::CompressedImage(_) => CompressedImage::TYPE_NAME,
            Self::CameraInfo(_) => CameraInfo::TYPE_NAME,
            Self::Tf | Self::TfStatic => TFMessage::TYPE_NAME,
        }
    }
}

/// Per-camera ingest counters.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CameraCounters {
    pub received: u64,
    pub synced: u64,
    pub rejected: u64,
    pub last_stamp_nanos: i64,
}

#[derive(Debug)]
struct PendingFrame {
    stamp: i64,
    frame_id: String,
    rgb: RgbImage,
}

#[derive(Debug)]
struct CameraState {
    config: CameraConfig,
    info: Option<Camera>,
    pending: VecDeque<PendingFrame>,
    depths: VecDeque<(i64, DepthImage)>,
    counters: CameraCounters,
}

/// The ingest stage: feed it messages with [`Ingest::handle`]; it returns the frames that became
/// complete.
#[derive(Debug)]
pub struct Ingest {
    cameras: Vec<CameraState>,
    tf: TfBuffer,
    world_frame: String,
    tolerance_nanos: i64,
    max_wait_nanos: i64,
    pending_cap: usize,
    max_side: u32,
    pub rejections: Rejections,
    pub tf_received: u64,
    pub tf_rejected: u64,
}

impl Ingest {
    pub fn new(config: &Config) -> Self {
        Self {
            cameras: config
                .cameras
                .iter()
                .map(|c| CameraState {
                    config: c.clone(),
                    info: None,
                    pending: VecDeque::new(),
                    depths: VecDeque::new(),
                    counters: CameraCounters::default(),
                })
                .collect(),
            tf: TfBuffer::new(config.tf.history_secs),
            world_frame: config.tf.world_frame.trim_start_matches('/').to_owned(),
            tolerance_nanos: (config.ingest.sync_tolerance_secs * 1e9) as i64,
            max_wait_nanos: (config.ingest.max_pose_wait_secs * 1e9) as i64,
            pending_cap: config.ingest.pending_frames,
            max_side: config.ingest.max_image_side,
            rejections: Rejections::default(),
            tf_received: 0,
            tf_rejected: 0,
        }
    }

    /// The topics ingest subscribes to (as configured, unresolved) and what each carries.
    pub fn routes(config: &Config) -> Vec<(String, Route)> {
        let mut routes = Vec::new();
        for (i, camera) in config.cameras.iter().enumerate() {
            let image_route = match camera.transport {
                ImageTransport::Raw => Route::Image(i),
                ImageTransport::Compressed => Route::CompressedImage(i),
            };
            routes.push((camera.image_topic.clone(), image_route));
            routes.push((camera.camera_info_topic.clone(), Route::CameraInfo(i)));
            if let Some(depth) = &camera.depth_topic {
                routes.push((depth.clone(), Route::Depth(i)));
            }
        }
        routes.push((config.tf.topic.clone(), Route::Tf));
        routes.push((config.tf.static_topic.clone(), Route::TfStatic));
        routes
    }

    pub fn camera_names(&self) -> impl Iterator<Item = &str> {
        self.cameras.iter().map(|c| c.config.name.as_str())
    }

    pub fn camera_counters(&self, index: usize) -> Option<&CameraCounters> {
        self.cameras.get(index).map(|c| &c.counters)
    }

    pub fn camera_count(&self) -> usize {
        self.cameras.len()
    }

    fn reject_camera(&mut self, camera: usize, source: &str, rejection: &Rejection) {
        self.rejections.record(source, rejection);
        if let Some(c) = self.cameras.get_mut(camera) {
            c.counters.rejected += 1;
        }
    }

    /// Count an input that never reached decoding (e.g. dropped by a full queue).
    pub fn record_dropped(&mut self, route: Route, rejection: &Rejection) {
        match route {
            Route::Image(i)
            | Route::CompressedImage(i)
            | Route::CameraInfo(i)
            | Route::Depth(i) => self.reject_camera(i, "queue", rejection),
            Route::Tf | Route::TfStatic => {
                self.tf_rejected += 1;
                self.rejections.record("queue", rejection);
            }
        }
    }

    /// Handle one serialized message from `route`; returns the frames that completed.
    pub fn handle(&mut self, route: Route, payload: &[u8]) -> Vec<SyncedFrame> {
        match route {
            Route::Tf | Route::TfStatic => {
                self.handle_tf(payload, route == Route::TfStatic);
                (0..self.cameras.len())
                    .flat_map(|i| self.resolve(i))
                    .collect()
            }
            Route::Image(i) | Route::CompressedImage(i) => {
                let decoded = match route {
                    Route::Image(_) => cdr::decode::<Image>(payload)
                        .map_err(malformed)
                        .and_then(|m| Ok((decode_image(&m, self.max_side)?, m.header))),
                    _ => cdr::decode::<CompressedImage>(payload)
                        .map_err(malformed)
                        .and_then(|m| Ok((decode_compressed(&m, self.max_side)?, m.header))),
                };
                match decoded {
                    Err(rejection) => self.reject_camera(i, "image", &rejection),
                    Ok((rgb, header)) => {
                        let stamp = header.stamp.as_nanos();
                        let camera = &mut self.cameras[i];
                        camera.counters.received += 1;
                        camera.counters.last_stamp_nanos = stamp;
                        camera.pending.push_back(PendingFrame {
                            stamp,
                            frame_id: strip_slash(&header.frame_id),
                            rgb,
                        });
                        if camera.pending.len() > self.pending_cap {
                            camera.pending.pop_front();
                            let rejection = Rejection {
                                reason: Reject::PendingOverflow,
                                detail: format!(
                                    "camera `{}`: more than {} frames waiting for camera info, depth or pose",
                                    camera.config.name, self.pending_cap
                                ),
                            };
                            self.reject_camera(i, "image", &rejection);
                        }
                    }
                }
                self.resolve(i)
            }
            Route::CameraInfo(i) => {
                match cdr::decode::<CameraInfo>(payload)
                    .map_err(malformed)
                    .and_then(|m| validate_camera_info(&m, self.max_side))
                {
                    Ok(info) => self.cameras[i].info = Some(info),
                    Err(rejection) => self.reject_camera(i, "camera_info", &rejection),
                }
                self.resolve(i)
            }
            Route::Depth(i) => {
                match cdr::decode::<Image>(payload)
                    .map_err(malformed)
                    .and_then(|m| Ok((decode_depth(&m, self.max_side)?, m.header.stamp.as_nanos())))
                {
                    Ok((depth, stamp)) => {
                        let depths = &mut self.cameras[i].depths;
                        depths.push_back((stamp, depth));
                        while depths.len() > self.pending_cap * 2 {
                            depths.pop_front();
                        }
                    }
                    Err(rejection) => self.reject_camera(i, "depth", &rejection),
                }
                self.resolve(i)
            }
        }
    }

    fn handle_tf(&mut self, payload: &[u8], is_static: bool) {
        let message = match cdr::decode::<TFMessage>(payload) {
            Ok(m) => m,
            Err(e) => {
                self.tf_rejected += 1;
                self.rejections.record("tf", &malformed(e));
                return;
            }
        };
        for transform in &message.transforms {
            match validate_transform(transform) {
                Ok((parent, child, stamp, rigid)) => {
                    self.tf_received += 1;
                    self.tf.insert(parent, child, stamp, rigid, is_static);
                }
                Err(rejection) => {
                    self.tf_rejected += 1;
                    self.rejections.record("tf", &rejection);
                }
            }
        }
    }

    /// Complete every pending frame of camera `index` that can be completed, oldest first, and
    /// drop those that waited too long.
    fn resolve(&mut self, index: usize) -> Vec<SyncedFrame> {
        let mut done = Vec::new();
        let mut dropped = Vec::new();
        let camera = &mut self.cameras[index];
        let newest = camera
            .counters
            .last_stamp_nanos
            .max(self.tf.newest_nanos().unwrap_or(i64::MIN));
        let mut keep = VecDeque::new();
        while let Some(frame) = camera.pending.pop_front() {
            let expired = newest.saturating_sub(frame.stamp) > self.max_wait_nanos;
            let Some(info) = &camera.info else {
                if expired {
                    dropped.push(Rejection {
                        reason: Reject::NoCameraInfo,
                        detail: format!("camera `{}`: no CameraInfo received", camera.config.name),
                    });
                } else {
                    keep.push_back(frame);
                }
                continue;
            };
            if (info.width, info.height) != (frame.rgb.width, frame.rgb.height) {
                dropped.push(Rejection {
                    reason: Reject::CameraInfoMismatch,
                    detail: format!(
                        "camera `{}`: image {}x{} but CameraInfo {}x{}",
                        camera.config.name,
                        frame.rgb.width,
                        frame.rgb.height,
                        info.width,
                        info.height
                    ),
                });
                continue;
            }
            let depth = if camera.config.depth_topic.is_some() {
                let matched = camera
                    .depths
                    .iter()
                    .filter(|(t, d)| {
                        (t - frame.stamp).abs() <= self.tolerance_nanos
                            && (d.width, d.height) == (frame.rgb.width, frame.rgb.height)
                    })
                    .min_by_key(|(t, _)| (t - frame.stamp).abs());
                match matched {
                    Some((_, d)) => Some(d.clone()),
                    None if expired => {
                        dropped.push(Rejection {
                            reason: Reject::NoMatchingDepth,
                            detail: format!(
                                "camera `{}`: no depth image of the same size within {} ms of the colour stamp",
                                camera.config.name,
                                self.tolerance_nanos / 1_000_000
                            ),
                        });
                        continue;
                    }
                    None => {
                        keep.push_back(frame);
                        continue;
                    }
                }
            } else {
                None
            };
            match self.tf.lookup(
                &self.world_frame,
                &frame.frame_id,
                frame.stamp,
                self.tolerance_nanos,
            ) {
                Ok(world_from_camera) => {
                    camera.counters.synced += 1;
                    done.push(SyncedFrame {
                        camera_name: camera.config.name.clone(),
                        stamp_nanos: frame.stamp,
                        frame_id: frame.frame_id,
                        rgb: frame.rgb,
                        depth,
                        camera: *info,
                        world_from_camera,
                    });
                }
                Err(LookupError::TooOld) => dropped.push(Rejection {
                    reason: Reject::NoPose,
                    detail: format!(
                        "camera `{}`: stamp older than the TF history",
                        camera.config.name
                    ),
                }),
                Err(e) if expired => dropped.push(Rejection {
                    reason: Reject::NoPose,
                    detail: format!("camera `{}`: {e:?}", camera.config.name),
                }),
                Err(_) => keep.push_back(frame),
            }
        }
        camera.pending = keep;
        for rejection in dropped {
            self.reject_camera(index, "sync", &rejection);
        }
        done
    }
}

fn malformed(e: cdr::CdrError) -> Rejection {
    Rejection {
        reason: Reject::MalformedCdr,
        detail: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use groupforward_msgs::builtin_interfaces::Time;
    use groupforward_msgs::geometry_msgs::{Quaternion, Transform, Vector3};
    use groupforward_msgs::std_msgs::Header;

    fn header(nanos: i64, frame: &str) -> Header {
        Header {
            stamp: Time::from_nanos(nanos),
            frame_id: frame.into(),
        }
    }

    fn image(w: u32, h: u32, enc: &str, bpp: u32, nanos: i64) -> Image {
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

    fn info(w: u32, h: u32) -> CameraInfo {
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

    fn tf(parent: &str, child: &str, nanos: i64, x: f64, q: [f64; 4]) -> TFMessage {
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

    const ID: [f64; 4] = [0.0, 0.0, 0.0, 1.0];

    fn no_depth_config() -> Config {
        let mut c = Config::default();
        c.cameras[0].depth_topic = None;
        c
    }

    #[test]
    fn colour_encodings_convert_to_rgb() {
        let mut bgr = image(2, 1, "bgr8", 3, 0);
        bgr.data = vec![1, 2, 3, 4, 5, 6];
        assert_eq!(decode_image(&bgr, 64).unwrap().data, vec![3, 2, 1, 6, 5, 4]);
        let mut rgba = image(1, 1, "rgba8", 4, 0);
        rgba.data = vec![9, 8, 7, 255];
        assert_eq!(decode_image(&rgba, 64).unwrap().data, vec![9, 8, 7]);
        let mut mono = image(1, 1, "mono8", 1, 0);
        mono.data = vec![42];
        assert_eq!(decode_image(&mono, 64).unwrap().data, vec![42, 42, 42]);
        // Row padding (step > width * bpp) is skipped.
        let mut padded = image(1, 2, "mono8", 1, 0);
        padded.step = 4;
        padded.data = vec![1, 0, 0, 0, 2, 0, 0, 0];
        assert_eq!(
            decode_image(&padded, 64).unwrap().data,
            vec![1, 1, 1, 2, 2, 2]
        );
    }

    #[test]
    fn bad_images_are_rejected_with_reasons() {
        let reason = |m: &Image| decode_image(m, 64).unwrap_err().reason;
        let mut short = image(4, 4, "rgb8", 3, 0);
        short.data.pop();
        assert_eq!(reason(&short), Reject::SizeMismatch);
        assert_eq!(
            reason(&image(4, 4, "yuv422", 2, 0)),
            Reject::UnknownEncoding
        );
        assert_eq!(reason(&image(0, 0, "rgb8", 3, 0)), Reject::BadDimensions);
        let mut absurd = image(1, 1, "rgb8", 3, 0);
        absurd.width = 100_000;
        assert_eq!(reason(&absurd), Reject::BadDimensions);
        let mut step = image(4, 1, "rgb8", 3, 0);
        step.step = 2;
        assert_eq!(reason(&step), Reject::SizeMismatch);
    }

    #[test]
    fn depth_decodes_units_and_invalid_pixels() {
        let mut d16 = image(2, 1, "16UC1", 2, 0);
        d16.data = [1500u16, 0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let d = decode_depth(&d16, 64).unwrap();
        assert!((d.metres[0] - 1.5).abs() < 1e-6 && d.metres[1].is_nan());
        let mut d32 = image(3, 1, "32FC1", 4, 0);
        d32.data = [2.25f32, f32::INFINITY, -1.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let d = decode_depth(&d32, 64).unwrap();
        assert_eq!(d.metres[0], 2.25);
        assert!(d.metres[1].is_nan() && d.metres[2].is_nan());
        assert_eq!(
            decode_depth(&image(2, 1, "rgb8", 3, 0), 64)
                .unwrap_err()
                .reason,
            Reject::UnknownEncoding
        );
    }

    #[test]
    fn compressed_png_and_jpeg_decode_and_garbage_is_rejected() {
        let rgb =
            image::RgbImage::from_fn(8, 4, |x, y| image::Rgb([x as u8 * 30, y as u8 * 60, 7]));
        for format in [image::ImageFormat::Png, image::ImageFormat::Jpeg] {
            let mut bytes = Vec::new();
            rgb.write_to(&mut std::io::Cursor::new(&mut bytes), format)
                .unwrap();
            let msg = CompressedImage {
                header: header(0, "c"),
                format: "rgb8; jpeg compressed bgr8".into(),
                data: bytes,
            };
            let out = decode_compressed(&msg, 64).unwrap();
            assert_eq!((out.width, out.height), (8, 4));
            if format == image::ImageFormat::Png {
                assert_eq!(out.data, rgb.as_raw().clone());
            }
            let mut truncated = msg.clone();
            truncated.data.truncate(20);
            assert_eq!(
                decode_compressed(&truncated, 64).unwrap_err().reason,
                Reject::CompressedDecodeFailed
            );
            // Larger than allowed: refused from the header alone.
            assert_eq!(
                decode_compressed(&msg, 4).unwrap_err().reason,
                Reject::BadDimensions
            );
        }
        let garbage = CompressedImage {
            data: vec![1, 2, 3, 4, 5],
            ..Default::default()
        };
        assert_eq!(
            decode_compressed(&garbage, 64).unwrap_err().reason,
            Reject::CompressedDecodeFailed
        );
    }

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

    #[test]
    fn frames_sync_with_info_depth_and_pose() {
        let config = Config::default();
        let mut ingest = Ingest::new(&config);
        let t = 1_000_000_000;
        assert!(ingest
            .handle(
                Route::Image(0),
                &cdr::encode(&image(4, 2, "rgb8", 3, t)).unwrap()
            )
            .is_empty());
        assert!(ingest
            .handle(Route::CameraInfo(0), &cdr::encode(&info(4, 2)).unwrap())
            .is_empty());
        let mut depth = image(4, 2, "32FC1", 4, t + 1_000);
        depth.data = [1.0f32; 8].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert!(ingest
            .handle(Route::Depth(0), &cdr::encode(&depth).unwrap())
            .is_empty());
        let frames = ingest.handle(
            Route::Tf,
            &cdr::encode(&tf("map", "cam_optical", t, 3.0, ID)).unwrap(),
        );
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].rgb.width, 4);
        assert_eq!(frames[0].depth.as_ref().unwrap().metres, vec![1.0; 8]);
        assert!((frames[0].world_from_camera.translation.x - 3.0).abs() < 1e-12);
        let counters = ingest.camera_counters(0).unwrap();
        assert_eq!(
            (counters.received, counters.synced, counters.rejected),
            (1, 1, 0)
        );
    }

    #[test]
    fn frames_without_pose_expire_with_a_reason() {
        let config = no_depth_config();
        let mut ingest = Ingest::new(&config);
        ingest.handle(Route::CameraInfo(0), &cdr::encode(&info(4, 2)).unwrap());
        ingest.handle(
            Route::Image(0),
            &cdr::encode(&image(4, 2, "rgb8", 3, 0)).unwrap(),
        );
        // A frame 1 s later (> max_pose_wait 0.5 s) expires the first one.
        ingest.handle(
            Route::Image(0),
            &cdr::encode(&image(4, 2, "rgb8", 3, 1_000_000_000)).unwrap(),
        );
        assert_eq!(ingest.rejections.count(Reject::NoPose), 1);
    }

    #[test]
    fn mismatched_camera_info_and_garbage_are_counted() {
        let config = no_depth_config();
        let mut ingest = Ingest::new(&config);
        ingest.handle(Route::CameraInfo(0), &cdr::encode(&info(8, 8)).unwrap());
        ingest.handle(
            Route::Image(0),
            &cdr::encode(&image(4, 2, "rgb8", 3, 0)).unwrap(),
        );
        assert_eq!(ingest.rejections.count(Reject::CameraInfoMismatch), 1);
        ingest.handle(Route::Image(0), &[0, 1, 0, 0, 9, 9]);
        ingest.handle(Route::Tf, &[1, 2, 3]);
        assert_eq!(ingest.rejections.count(Reject::MalformedCdr), 2);
        assert_eq!(ingest.tf_rejected, 1);
        assert_eq!(ingest.camera_counters(0).unwrap().rejected, 2);
    }

    #[test]
    fn pending_queue_is_bounded() {
        let config = no_depth_config();
        let mut ingest = Ingest::new(&config);
        // Same stamp every time: nothing expires, so only the bound drops frames.
        for _ in 0..20 {
            ingest.handle(
                Route::Image(0),
                &cdr::encode(&image(4, 2, "rgb8", 3, 0)).unwrap(),
            );
        }
        assert_eq!(
            ingest.rejections.count(Reject::PendingOverflow),
            20 - config.ingest.pending_frames as u64
        );
    }

    proptest::proptest! {
        #[test]
        fn any_bytes_on_any_route_never_panic(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..256),
                                              route in 0usize..5) {
            let config = Config::default();
            let mut ingest = Ingest::new(&config);
            let route = [Route::Image(0), Route::CameraInfo(0), Route::Depth(0), Route::Tf, Route::TfStatic][route];
            let _ = ingest.handle(route, &bytes);
            let mut framed = groupforward_msgs::cdr::ENCAPSULATION_CDR_LE.to_vec();
            framed.extend_from_slice(&bytes);
            let _ = ingest.handle(route, &framed);
            let _ = ingest.handle(Route::CompressedImage(0), &framed);
        }

        #[test]
        fn any_image_header_never_panics(w in 0u32..64, h in 0u32..64, step in 0u32..256, len in 0usize..512,
                                         enc in 0usize..8, big in 0u8..2) {
            let encodings = ["rgb8", "bgr8", "rgba8", "bgra8", "mono8", "16UC1", "32FC1", "x"];
            let msg = Image { height: h, width: w, step, encoding: encodings[enc].into(), is_bigendian: big,
                              data: vec![7; len], ..Default::default() };
            let _ = decode_image(&msg, 32);
            let _ = decode_depth(&msg, 32);
        }
    }
}

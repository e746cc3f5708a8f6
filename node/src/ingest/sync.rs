//! The ingest stage: route each message to its decoder, keep colour frames pending until their
//! camera info, depth (within the sync tolerance) and TF pose are there, and emit
//! [`SyncedFrame`]s. Frames that wait too long are dropped with a reason.

use std::collections::VecDeque;

use groupforward_msgs::cdr;
use groupforward_msgs::sensor_msgs::{CameraInfo, CompressedImage, Image};
use groupforward_msgs::tf2_msgs::TFMessage;

use super::config::{CameraConfig, ImageTransport, IngestSection, TfSection};
use super::decode::{decode_compressed, decode_depth, decode_image};
use super::depth_validity::{mark_invalid_depth, DepthValidity};
use super::reject::{malformed, Reject, Rejection, Rejections};
use super::tf::{LookupError, TfBuffer};
use super::validate::{strip_slash, validate_camera_info, validate_transform};
use crate::frame::{DepthImage, RgbImage, SyncedFrame};
use crate::recon::camera::Camera;

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
    /// Pixels of the accepted depth images, and why some were invalid.
    pub depth: DepthValidity,
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
    settings: IngestSection,
    pub rejections: Rejections,
    pub tf_received: u64,
    pub tf_rejected: u64,
}

impl Ingest {
    pub fn new(cameras: &[CameraConfig], tf: &TfSection, settings: &IngestSection) -> Self {
        Self {
            cameras: cameras
                .iter()
                .map(|c| CameraState {
                    config: c.clone(),
                    info: None,
                    pending: VecDeque::new(),
                    depths: VecDeque::new(),
                    counters: CameraCounters::default(),
                })
                .collect(),
            tf: TfBuffer::new(tf.history_secs),
            world_frame: tf.world_frame.trim_start_matches('/').to_owned(),
            tolerance_nanos: (settings.sync_tolerance_secs * 1e9) as i64,
            max_wait_nanos: (settings.max_pose_wait_secs * 1e9) as i64,
            pending_cap: settings.pending_frames,
            max_side: settings.max_image_side,
            settings: settings.clone(),
            rejections: Rejections::default(),
            tf_received: 0,
            tf_rejected: 0,
        }
    }

    /// The topics ingest subscribes to (as configured, unresolved) and what each carries.
    pub fn routes(cameras: &[CameraConfig], tf: &TfSection) -> Vec<(String, Route)> {
        let mut routes = Vec::new();
        for (i, camera) in cameras.iter().enumerate() {
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
        routes.push((tf.topic.clone(), Route::Tf));
        routes.push((tf.static_topic.clone(), Route::TfStatic));
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
                    .and_then(|(mut depth, stamp)| {
                        let validity = mark_invalid_depth(&mut depth, &self.settings)?;
                        Ok((depth, stamp, validity))
                    }) {
                    Ok((depth, stamp, validity)) => {
                        self.cameras[i].counters.depth.add(&validity);
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

#[cfg(test)]
mod tests {
    use super::super::test_messages::{image, info, tf, ID};
    use super::*;

    /// The three sections of a full node config that ingest reads.
    struct Config {
        cameras: Vec<CameraConfig>,
        tf: TfSection,
        ingest: IngestSection,
    }

    impl Config {
        fn default() -> Self {
            Self {
                cameras: vec![CameraConfig::default()],
                tf: TfSection::default(),
                ingest: IngestSection::default(),
            }
        }
    }

    fn ingest_for(config: &Config) -> Ingest {
        Ingest::new(&config.cameras, &config.tf, &config.ingest)
    }

    fn no_depth_config() -> Config {
        let mut c = Config::default();
        c.cameras[0].depth_topic = None;
        c
    }

    #[test]
    fn frames_sync_with_info_depth_and_pose() {
        let config = Config::default();
        let mut ingest = ingest_for(&config);
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
        let mut ingest = ingest_for(&config);
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
        let mut ingest = ingest_for(&config);
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
        let mut ingest = ingest_for(&config);
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

    #[test]
    fn frames_without_camera_info_expire_with_a_reason() {
        let config = no_depth_config();
        let mut ingest = ingest_for(&config);
        for stamp in [0, 1_000_000_000] {
            ingest.handle(
                Route::Image(0),
                &cdr::encode(&image(4, 2, "rgb8", 3, stamp)).unwrap(),
            );
        }
        assert_eq!(ingest.rejections.count(Reject::NoCameraInfo), 1);
        assert_eq!(ingest.rejections.total(), 1);
        assert_eq!(ingest.camera_counters(0).unwrap().rejected, 1);
    }

    #[test]
    fn frames_without_depth_expire_with_a_reason_and_never_sync_without_it() {
        let config = Config::default();
        let mut ingest = ingest_for(&config);
        ingest.handle(Route::CameraInfo(0), &cdr::encode(&info(4, 2)).unwrap());
        let pose = |t| cdr::encode(&tf("map", "cam_optical", t, 0.0, ID)).unwrap();
        ingest.handle(Route::Tf, &pose(0));
        ingest.handle(
            Route::Image(0),
            &cdr::encode(&image(4, 2, "rgb8", 3, 0)).unwrap(),
        );
        // Pose and info are there; only depth is missing, so nothing may sync.
        assert!(ingest.handle(Route::Tf, &pose(100_000_000)).is_empty());
        // A depth image of another size does not match either.
        let mut small = image(2, 2, "32FC1", 4, 0);
        small.data = [1.0f32; 4].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert!(ingest
            .handle(Route::Depth(0), &cdr::encode(&small).unwrap())
            .is_empty());
        ingest.handle(Route::Tf, &pose(1_000_000_000));
        assert_eq!(ingest.rejections.count(Reject::NoMatchingDepth), 1);
        assert_eq!(ingest.rejections.total(), 1);
        assert_eq!(ingest.camera_counters(0).unwrap().synced, 0);
    }

    #[test]
    fn invalid_depth_is_marked_and_counted_and_a_depth_image_without_any_is_rejected() {
        let config = Config::default();
        let mut ingest = ingest_for(&config);
        ingest.handle(Route::CameraInfo(0), &cdr::encode(&info(4, 2)).unwrap());
        let t = 1_000_000_000;
        ingest.handle(
            Route::Image(0),
            &cdr::encode(&image(4, 2, "rgb8", 3, t)).unwrap(),
        );
        // 16UC1 millimetres: two dropped (0), one beyond 10 m, five at 1.5 m of which the corner
        // one has no valid neighbour left (isolated).
        let mut depth = image(4, 2, "16UC1", 2, t);
        depth.data = [1500u16, 0, 1500, 1500, 0, 1500, 1500, 20000]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        ingest.handle(Route::Depth(0), &cdr::encode(&depth).unwrap());
        let frames = ingest.handle(
            Route::Tf,
            &cdr::encode(&tf("map", "cam_optical", t, 0.0, ID)).unwrap(),
        );
        let metres = &frames[0].depth.as_ref().unwrap().metres;
        assert_eq!(metres.iter().filter(|z| z.is_nan()).count(), 4);
        let counted = ingest.camera_counters(0).unwrap().depth;
        assert_eq!(
            (
                counted.pixels,
                counted.missing,
                counted.out_of_range,
                counted.isolated
            ),
            (8, 2, 1, 1)
        );
        // All zero: rejected with its reason, counted once, nothing synced from it.
        let mut blind = image(4, 2, "16UC1", 2, 2 * t);
        blind.data = vec![0; 16];
        assert!(ingest
            .handle(Route::Depth(0), &cdr::encode(&blind).unwrap())
            .is_empty());
        assert_eq!(ingest.rejections.count(Reject::NoValidDepth), 1);
        assert_eq!(ingest.camera_counters(0).unwrap().depth.pixels, 8);
    }

    proptest::proptest! {
        #[test]
        fn any_bytes_on_any_route_are_accounted_for_once(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..256),
                                                         route in 0usize..6, framed in proptest::prelude::any::<bool>()) {
            let config = Config::default();
            let mut ingest = ingest_for(&config);
            let route = [Route::Image(0), Route::CompressedImage(0), Route::CameraInfo(0), Route::Depth(0), Route::Tf,
                         Route::TfStatic][route];
            let payload = if framed {
                let mut with_header = groupforward_msgs::cdr::ENCAPSULATION_CDR_LE.to_vec();
                with_header.extend_from_slice(&bytes);
                with_header
            } else {
                bytes
            };
            let frames = ingest.handle(route, &payload);
            proptest::prop_assert!(frames.is_empty(), "nothing can sync from one message");
            let counters = ingest.camera_counters(0).unwrap().clone();
            match route {
                // A colour image is either waiting (received) or rejected, exactly once.
                Route::Image(_) | Route::CompressedImage(_) => {
                    proptest::prop_assert_eq!(counters.received + counters.rejected, 1);
                    proptest::prop_assert_eq!(ingest.rejections.total(), counters.rejected);
                }
                // Camera info and depth are kept or rejected once; neither counts as a frame.
                Route::CameraInfo(_) | Route::Depth(_) => {
                    proptest::prop_assert_eq!(counters.received, 0);
                    proptest::prop_assert!(ingest.rejections.total() <= 1);
                    proptest::prop_assert_eq!(ingest.rejections.total(), counters.rejected);
                }
                // Each transform of a decodable message is accepted or rejected once; an
                // undecodable message is one rejection.
                Route::Tf | Route::TfStatic => {
                    let seen = ingest.tf_received + ingest.tf_rejected;
                    match cdr::decode::<TFMessage>(&payload) {
                        Ok(message) => proptest::prop_assert_eq!(seen, message.transforms.len() as u64),
                        Err(_) => {
                            proptest::prop_assert_eq!((ingest.tf_received, ingest.tf_rejected), (0, 1));
                            proptest::prop_assert_eq!(ingest.rejections.count(Reject::MalformedCdr), 1);
                        }
                    }
                    proptest::prop_assert_eq!(ingest.rejections.total(), ingest.tf_rejected);
                }
            }
        }
    }
}

//! Ingest: decode and validate camera, depth, camera-info and TF messages, and sync them by stamp
//! into [`SyncedFrame`](crate::frame::SyncedFrame)s (colour + optional depth + camera model +
//! `world_from_camera` from TF).
//!
//! Every malformed input is rejected with a reason code, counted, and logged once per reason; no
//! input can make this stage panic. Time is stamp time, never wall time, so a replayed bag syncs
//! exactly as it did live.
//!
//! - [`config`]: the stage's config sections (cameras, TF, sync bounds);
//! - [`decode`]: raw, compressed and depth images;
//! - [`depth_validity`]: depth without a measurement, out of range or isolated, marked NaN and
//!   counted;
//! - [`validate`]: camera intrinsics and transforms;
//! - [`tf`]: the TF buffer, looked up by stamp;
//! - [`reject`]: reasons and their counters;
//! - [`sync`]: the stage itself, which pairs colour with camera info, depth and pose.

pub mod config;
pub mod decode;
pub mod depth_validity;
pub mod reject;
pub mod sync;
pub mod tf;
pub mod validate;

pub mod test_messages;

pub use config::{CameraConfig, ImageTransport, IngestSection, TfSection};
pub use decode::{decode_compressed, decode_depth, decode_image};
pub use depth_validity::{mark_invalid_depth, DepthValidity};
pub use reject::{Reject, Rejection, Rejections};
pub use sync::{CameraCounters, Ingest, Route};
pub use tf::{LookupError, TfBuffer};
pub use validate::{validate_camera_info, validate_transform};

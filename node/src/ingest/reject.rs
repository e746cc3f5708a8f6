//! Why an input was rejected, and per-reason counters that log each reason once.

use std::collections::BTreeMap;

use groupforward_msgs::cdr;

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
    NoValidDepth,
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
            Self::NoValidDepth => "no_valid_depth",
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

pub(super) fn reject<T>(reason: Reject, detail: impl Into<String>) -> Result<T, Rejection> {
    Err(Rejection {
        reason,
        detail: detail.into(),
    })
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

pub(super) fn malformed(e: cdr::CdrError) -> Rejection {
    Rejection {
        reason: Reject::MalformedCdr,
        detail: e.to_string(),
    }
}

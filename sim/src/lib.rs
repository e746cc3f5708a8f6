//! groupforward-sim: scenes with exact ground truth for groupforward.
//!
//! So far it holds [`testcard`], a deterministic camera rig (colour, depth, camera info and TF
//! along a circular trajectory) that exercises the node's ingest end to end, and [`bag`], a
//! rosbag2 MCAP writer. The scene renderer with objects, instance ground truth and effects builds
//! on the same rig types.

pub mod bag;
pub mod testcard;

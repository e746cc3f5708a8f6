//! groupforward-sim: scenes with exact ground truth for groupforward.
//!
//! So far it holds [`testcard`], a deterministic camera rig (colour, depth, camera info and TF
//! along a circular trajectory) that exercises the node's ingest end to end. The scene renderer
//! with objects, instance ground truth, effects and bag output builds on the same rig types.

pub mod testcard;

//! Evaluation against the simulator's ground truth (DESIGN §7), the first part of
//! `groupforward eval`:
//!
//! - [`run`]: a sim scene through the node's stages (bag → ingest → keyframes → window pass →
//!   fusion), every window processed, ground truth kept beside the pipeline;
//! - [`score`]: the final map and each window's instances scored against the objects.

pub mod run;
pub mod score;

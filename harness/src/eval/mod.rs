//! Evaluation against the simulator's ground truth (ARCHITECTURE.md §6), the first part of
//! `groupforward eval`:
//!
//! - [`baseline`]: the ablation without instances (semantic features lifted per voxel);
//! - [`interval`]: 95% bootstrap intervals over scenes, of a run's figures and of the
//!   difference between two runs;
//! - [`picture`]: a scene's map from above (objects by outcome, instances by what they are);
//! - [`run`]: a sim scene through the node's stages (bag → ingest → keyframes → window pass →
//!   fusion), every window processed, ground truth kept beside the pipeline;
//! - [`score`]: the final map and each window's instances scored against the objects;
//! - [`refer`]: the scene's referring expressions asked through the `Refer` service's handler,
//!   answers matched to the objects they name;
//! - [`window`]: single windows scored as a feed-forward pass is (depth, ARI, semantics, novel
//!   views).

pub mod baseline;
pub mod interval;
pub mod picture;
pub mod refer;
pub mod run;
pub mod score;
pub mod window;

//! groupforward-sim: scenes with exact ground truth for groupforward.
//!
//! [`library`]: indoor object classes built from analytic primitives, with descriptions,
//! affordances and support surfaces. [`scene`]: TOML scene files (room, objects, camera rig,
//! trajectory, effects). [`procedural`]: seeded, physically plausible layouts in named splits.
//! [`render`]: a CPU ray caster producing RGB, metric depth, instance and class ids.
//! [`effects`] and [`simulation`]: a scene played over time with only the effects it lists.
//! [`record`]: rosbag2 MCAP bags (written by `groupforward_msgs::bag`) of what a robot records
//! plus `/gt/...` topics.
//! [`dataset`]: training datasets on disk. [`referring`]: referring expressions generated from
//! ground truth. [`testcard`]: a plumbing rig for the node's ingest.

pub mod dataset;
pub mod effects;
pub mod library;
pub mod procedural;
pub mod record;
pub mod referring;
pub mod render;
pub mod resample;
pub mod scene;
pub mod simulation;
pub mod testcard;

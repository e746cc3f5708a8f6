//! groupforward-sim: scenes with exact ground truth for groupforward.
//!
//! So far: [`library`], indoor object classes built from analytic primitives with descriptions and
//! affordances; [`render`], a CPU ray caster producing RGB, metric depth, instance and class ids;
//! [`testcard`], a deterministic camera rig that exercises the node's ingest end to end; and
//! [`bag`], a rosbag2 MCAP writer; [`scene`], TOML scene files (room, objects, camera rig,
//! trajectory). Procedural layouts, effects and the sim CLI build on these.

pub mod bag;
pub mod library;
pub mod render;
pub mod scene;
pub mod testcard;

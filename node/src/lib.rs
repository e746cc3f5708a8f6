//! groupforward: a robotics node that turns camera streams into a referable 3D scene.
//!
//! Pipeline stages are plain structs over plain data, each testable without a network:
//! - [`ingest`]: decode, validate and sync camera, depth, camera-info and TF messages by stamp;
//! - [`node`]: the loop that feeds the stages from a bounded queue and reports status;
//! - [`recon`]: cameras, Gaussians, the tile rasterizer, gauge alignment and metrics;
//! - [`graph`]: the persistent instance map (fusion across windows, scene graph, snapshots);
//! - [`group`]: HDBSCAN over instance embeddings and softmax assignment to instances;
//! - [`model`]: ONNX models through `ort` (runtime discovery, manifests, runners);
//! - [`transport`]: rmw_zenoh-compatible zenoh transport (and an in-memory one for tests);
//! - [`replay`]: publish a rosbag2 MCAP bag as a live robot would;
//! - [`window`]: keyframes, one model pass per window, grouping into window instances;
//! - [`demo`]: everything in one process over an embedded zenoh peer.
//!
//! Semantics per instance and referring land as further stages.

pub mod config;
pub mod demo;
pub mod graph;
pub mod group;
pub mod ingest;
pub mod model;
pub mod node;
pub mod recon;
pub mod replay;
pub mod transport;
pub mod window;

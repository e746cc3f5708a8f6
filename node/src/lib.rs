//! groupforward: a robotics node that turns camera streams into a referable 3D scene.
//!
//! Data flow (ARCHITECTURE.md §2): camera, depth, camera-info and TF messages → [`ingest`] (decode,
//! validate, sync by stamp) → [`window`] (keyframes; one [`model`] pass per window; [`group`]:
//! HDBSCAN on the embeddings, semantic prototypes) → [`graph`] (fusion into the persistent map,
//! scene graph, snapshots) → [`refer`] (referring queries on a snapshot of the map) → services and
//! status. [`node`] runs that loop over a [`transport`].
//!
//! Modules, bottom up; each imports only modules above it in this list, never one below:
//!
//! | module | holds |
//! |---|---|
//! | [`timing`] | the pipeline's stages, their durations per pass, p50 / p99 over recent passes |
//! | [`recon`] | the geometric core: rigid transforms, cameras, Gaussians, the tile rasterizer, gauge alignment, metrics |
//! | [`frame`] | the data that flows between stages: images, synced frames, keyframes, window instances |
//! | [`transport`] | rmw_zenoh-compatible zenoh transport, an in-memory one for tests; its config section |
//! | [`ingest`] | decode, validate, TF buffer and stamp sync; its config sections |
//! | [`model`] | ONNX models through `ort` (runtime discovery, manifests, runners); its config section |
//! | [`group`] | HDBSCAN over instance embeddings, softmax assignment, semantic prototypes and naming |
//! | [`graph`] | the persistent instance map: fusion across windows, scene graph, snapshots |
//! | [`exposure`] | exposure compensation of keyframes (auto-exposure hunting), measured on shared surface |
//! | [`window`] | keyframe selection and one window pass (model → lifting → grouping → prototypes) |
//! | [`refer`] | referring (RSRF): parse, retrieve, reason (built-in or a VLM), evidence, answers |
//! | [`config`] | assembles the stages' sections into the node's YAML config |
//! | [`node`] | the loop: input queue, window worker, services, status |
//! | [`outputs`] | the published messages: detections, instance arrays, masks, markers, cloud, scene graph |
//! | [`record`] | the node's own rosbag2 recording of what it publishes |
//! | [`client`] | a client of a running node: its services and JSON API over zenoh |
//! | [`replay`] | publish a rosbag2 MCAP bag as a live robot would |
//!
//! This library is what a robot runs; it does not link the simulator. The evaluation, demo and
//! soak harness is `groupforward-harness`, the command line `groupforward-cli`
//! (ARCHITECTURE.md at the repository's root).

pub mod client;
pub mod config;
pub mod exposure;
pub mod frame;
pub mod graph;
pub mod group;
pub mod ingest;
pub mod model;
pub mod node;
pub mod observations;
pub mod outputs;
pub mod recon;
pub mod record;
pub mod refer;
pub mod replay;
pub mod timing;
pub mod transport;
pub mod window;

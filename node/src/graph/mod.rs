//! The persistent instance map and its scene graph (ARCHITECTURE.md §4).
//!
//! Each window pass yields instances (Gaussians plus a semantic prototype). [`SceneMap::fuse`]
//! associates them with the persistent instances by 3D overlap (nearest-neighbour ratio) plus
//! prototype similarity with an optimal assignment (Kuhn–Munkres, `pathfinding`), after which a
//! window instance left over that lies mostly on one persistent instance joins it as a part of
//! that object; matched ones merge (voxel-downsampled Gaussians, count-weighted prototype), unmatched ones are born, and
//! persistent instances where the window sees free space lose confidence and die.
//! Memory stays bounded: Gaussians per instance and keyframes are capped, and instances beyond a
//! clearing radius from the robot are dropped. [`SceneMap::graph`] derives nodes and edges.

pub mod amodal;
pub mod error;
pub mod fusion;
pub mod instance;
pub mod listing;
pub mod persist;
pub mod scene_graph;
pub mod walls;

pub use error::GraphError;
pub use fusion::{FusionReport, Kinds, SceneMap};
pub use instance::{cosine, Fitted, FusionParams, Instance};
pub use scene_graph::{EdgeView, GraphEdge, GraphNode, NodeView, SceneGraph};

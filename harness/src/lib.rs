//! groupforward-harness: the node's stages driven by the simulator, for what a robot never runs.
//!
//! | module | holds |
//! |---|---|
//! | [`eval`] | sim scenes through the node's stages, the map, windows and referring scored against ground truth |
//! | [`demo`] | sim scene → bag → replay → node → queries, in one process over an embedded zenoh peer |
//! | [`soak`] | the node under hostile traffic and a two-camera flood, for `bench soak` |
//! | [`vocabulary`] | the default vocabulary file, generated from the simulator's class library |
//!
//! It depends on the runtime library (`groupforward`) and the simulator; the runtime library
//! depends on neither (ARCHITECTURE.md).

pub mod demo;
pub mod eval;
pub mod soak;
pub mod vocabulary;

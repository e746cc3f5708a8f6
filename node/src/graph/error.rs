//! What can go wrong in fusion and the scene graph.

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraphError {
    #[error("window instance {0}: {1}")]
    BadInstance(usize, String),
    #[error("rendering a keyframe: {0}")]
    Render(String),
}

//! What can stop the node: the transport or a name that does not resolve.

use crate::transport::TransportError;

#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("naming: {0}")]
    Naming(#[from] groupforward_msgs::rmw_zenoh::NamingError),
}

pub type Result<T> = std::result::Result<T, NodeError>;

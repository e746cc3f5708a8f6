//! Message layer of groupforward: plain data and codecs, no transport, no inference.
//!
//! - [`types`]: Rust types of the ROS 2 messages the node reads and writes (standard ones and
//!   `groupforward_msgs`), field for field as the `.msg` files under `msgs/ros/`.
//! - [`cdr`]: XCDR1 encoding with the 4-byte encapsulation header, as ROS 2 puts it on the wire and in
//!   rosbag2 files.
//! - [`idl`]: `.msg` / `.srv` parsing and RIHS01 type hashes (REP-2011).
//! - [`rmw_zenoh`]: key expressions, liveliness tokens and sample attachments of ROS 2's rmw_zenoh,
//!   so ROS 2 tools see the node's topics and services with no bridge.
//! - [`bag`]: rosbag2 MCAP bags as `ros2 bag record` writes them (the simulator's recordings and
//!   the node's own `record` output).

pub mod bag;
pub mod cdr;
pub mod idl;
pub mod rmw_zenoh;
pub mod types;

pub use types::*;

/// A ROS 2 message type with its fully qualified name (`sensor_msgs/msg/Image`).
pub trait RosMessage: serde::Serialize + serde::de::DeserializeOwned {
    const TYPE_NAME: &'static str;

    /// The RIHS01 type hash, computed from the embedded IDL.
    fn type_hash() -> idl::Result<String> {
        idl::type_hash(Self::TYPE_NAME)
    }
}

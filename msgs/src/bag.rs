//! Write rosbag2-style MCAP bags: one `ros2msg` schema per type (the `.msg` text), `cdr` channels
//! whose metadata carries the publisher's RIHS01 type hash, as `ros2 bag record` writes them
//! (Jazzy). `groupforward replay` and `ros2 bag play` read them back.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use crate::{cdr, RosMessage};

#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("mcap: {0}")]
    Mcap(#[from] mcap::McapError),
    #[error("cannot encode a {0} message: {1}")]
    Encode(&'static str, cdr::CdrError),
    #[error("no embedded definition of {0}")]
    UnknownType(String),
    #[error("bag file: {0}")]
    Io(std::io::Error),
    #[error("type hash of {0}: {1}")]
    Hash(String, crate::idl::IdlError),
}

pub type Result<T> = std::result::Result<T, BagError>;

/// What a recording publisher offered: the QoS `ros2 bag play` replays a topic with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OfferedQos {
    pub best_effort: bool,
    pub transient_local: bool,
    pub depth: u32,
}

impl Default for OfferedQos {
    /// ROS 2's default profile: reliable, volatile, keep last 10.
    fn default() -> Self {
        Self {
            best_effort: false,
            transient_local: false,
            depth: 10,
        }
    }
}

impl OfferedQos {
    /// ROS 2's sensor-data profile (best effort, keep last 5), as camera drivers publish.
    pub fn sensor_data() -> Self {
        Self {
            best_effort: true,
            depth: 5,
            ..Self::default()
        }
    }

    /// `/tf_static`: reliable, transient local, keep last 1.
    pub fn latched() -> Self {
        Self {
            transient_local: true,
            depth: 1,
            ..Self::default()
        }
    }

    /// The rosbag2 (metadata version 9) YAML list with this one profile, indented by `indent`.
    fn yaml(&self, indent: &str) -> String {
        // rmw's "infinite" duration.
        let infinite = format!("\n{indent}    sec: 9223372036\n{indent}    nsec: 854775807");
        format!(
            "{indent}- history: keep_last\n{indent}  depth: {}\n{indent}  reliability: {}\n\
             {indent}  durability: {}\n{indent}  deadline:{infinite}\n{indent}  lifespan:{infinite}\n\
             {indent}  liveliness: automatic\n{indent}  liveliness_lease_duration:{infinite}\n\
             {indent}  avoid_ros_namespace_conventions: false",
            self.depth,
            if self.best_effort { "best_effort" } else { "reliable" },
            if self.transient_local { "transient_local" } else { "volatile" },
        )
    }
}

#[derive(Debug, Clone)]
struct TopicRecord {
    channel: u16,
    type_name: String,
    hash: String,
    count: u64,
    qos: OfferedQos,
}

/// An MCAP writer that adds channels as topics first appear.
pub struct BagWriter<W: Write + Seek> {
    writer: mcap::Writer<W>,
    topics: BTreeMap<String, TopicRecord>,
    qos: BTreeMap<String, OfferedQos>,
    sequence: u32,
    first_nanos: Option<i64>,
    last_nanos: i64,
}

impl<W: Write + Seek> std::fmt::Debug for BagWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "BagWriter({} topics)", self.topics.len())
    }
}

impl<W: Write + Seek> BagWriter<W> {
    pub fn new(sink: W) -> Result<Self> {
        Ok(Self {
            // rosbag2 readers (ros2 bag, rosbags) insist on the "ros2" profile.
            writer: mcap::WriteOptions::new()
                .profile("ros2")
                .library(concat!("groupforward-sim ", env!("CARGO_PKG_VERSION")))
                .create(sink)?,
            topics: BTreeMap::new(),
            qos: BTreeMap::new(),
            sequence: 0,
            first_nanos: None,
            last_nanos: 0,
        })
    }

    /// Record `topic` as offered with `qos` (default: reliable, volatile, depth 10). Call before
    /// the topic's first message.
    pub fn set_qos(&mut self, topic: &str, qos: OfferedQos) {
        self.qos.insert(topic.to_owned(), qos);
    }

    fn channel(&mut self, topic: &str, type_name: &str) -> Result<u16> {
        if let Some(record) = self.topics.get_mut(topic) {
            record.count += 1;
            return Ok(record.channel);
        }
        let definition = crate::idl::message_definition(type_name)
            .map_err(|_| BagError::UnknownType(type_name.to_owned()))?;
        let schema = self
            .writer
            .add_schema(type_name, "ros2msg", definition.as_bytes())?;
        let hash = crate::idl::type_hash(type_name)
            .map_err(|e| BagError::Hash(type_name.to_owned(), e))?;
        let qos = self.qos.get(topic).copied().unwrap_or_default();
        let metadata = BTreeMap::from([
            ("topic_type_hash".to_owned(), hash.clone()),
            ("offered_qos_profiles".to_owned(), qos.yaml("")),
        ]);
        let id = self.writer.add_channel(schema, topic, "cdr", &metadata)?;
        self.topics.insert(
            topic.to_owned(),
            TopicRecord {
                channel: id,
                type_name: type_name.to_owned(),
                hash,
                count: 1,
                qos,
            },
        );
        Ok(id)
    }

    /// Record `message` on `topic` at `log_time_nanos`.
    pub fn write<T: RosMessage>(
        &mut self,
        topic: &str,
        log_time_nanos: i64,
        message: &T,
    ) -> Result<()> {
        let data = cdr::encode(message).map_err(|e| BagError::Encode(T::TYPE_NAME, e))?;
        self.write_encoded(topic, T::TYPE_NAME, log_time_nanos, &data)
    }

    /// Record an already CDR-encoded message of type `type_name` (`pkg/msg/Type`, one the
    /// embedded IDL defines) on `topic` at `log_time_nanos`.
    pub fn write_encoded(
        &mut self,
        topic: &str,
        type_name: &str,
        log_time_nanos: i64,
        data: &[u8],
    ) -> Result<()> {
        let channel_id = self.channel(topic, type_name)?;
        self.sequence += 1;
        self.first_nanos = Some(
            self.first_nanos
                .map_or(log_time_nanos, |t| t.min(log_time_nanos)),
        );
        self.last_nanos = self.last_nanos.max(log_time_nanos);
        let time = u64::try_from(log_time_nanos).unwrap_or(0);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: time,
            publish_time: time,
        };
        self.writer.write_to_known_channel(&header, data)?;
        Ok(())
    }

    /// Write the summary and return the sink.
    pub fn finish(mut self) -> Result<W> {
        self.writer.finish()?;
        Ok(self.writer.into_inner())
    }

    /// Messages written so far.
    pub fn message_count(&self) -> u64 {
        self.topics.values().map(|t| t.count).sum()
    }

    /// rosbag2's `metadata.yaml` (version 9, as Jazzy writes) for this bag stored as `file_name`
    /// in the bag directory.
    pub fn metadata_yaml(&self, file_name: &str) -> String {
        let start = self.first_nanos.unwrap_or(0);
        let duration = (self.last_nanos - start).max(0);
        let count = self.message_count();
        let mut topics = String::new();
        for (name, t) in &self.topics {
            topics.push_str(&format!(
                "    - topic_metadata:\n        name: {name}\n        type: {}\n        \
                 serialization_format: cdr\n        offered_qos_profiles:\n{}\n        \
                 type_description_hash: {}\n      message_count: {}\n",
                t.type_name,
                t.qos.yaml("          "),
                t.hash,
                t.count
            ));
        }
        format!(
            "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  \
             duration:\n    nanoseconds: {duration}\n  starting_time:\n    \
             nanoseconds_since_epoch: {start}\n  message_count: {count}\n  \
             topics_with_message_count:\n{topics}  compression_format: \"\"\n  \
             compression_mode: \"\"\n  relative_file_paths:\n    - {file_name}\n  files:\n    \
             - path: {file_name}\n      starting_time:\n        nanoseconds_since_epoch: {start}\n      \
             duration:\n        nanoseconds: {duration}\n      message_count: {count}\n  \
             custom_data: ~\n  ros_distro: jazzy\n"
        )
    }
}

impl BagWriter<std::io::BufWriter<std::fs::File>> {
    /// A bag directory as `ros2 bag record` leaves it: `<dir>/<dir name>_0.mcap`; call
    /// [`BagWriter::finish_dir`] to write `metadata.yaml` next to it.
    pub fn create_dir(dir: &std::path::Path) -> std::io::Result<(Self, String)> {
        std::fs::create_dir_all(dir)?;
        let stem = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "bag".into());
        let file_name = format!("{stem}_0.mcap");
        let file = std::fs::File::create(dir.join(&file_name))?;
        let writer = Self::new(std::io::BufWriter::new(file)).map_err(std::io::Error::other)?;
        Ok((writer, file_name))
    }

    /// Finish the MCAP file and write `metadata.yaml` (atomically: temp file, then rename).
    pub fn finish_dir(self, dir: &std::path::Path, file_name: &str) -> Result<()> {
        let metadata = self.metadata_yaml(file_name);
        let sink = self.finish()?;
        sink.into_inner()
            .map_err(|e| BagError::Io(e.into_error()))?
            .sync_all()
            .map_err(BagError::Io)?;
        let temp = dir.join("metadata.yaml.tmp");
        std::fs::write(&temp, metadata).map_err(BagError::Io)?;
        std::fs::rename(&temp, dir.join("metadata.yaml")).map_err(BagError::Io)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::std_msgs::Header;

    #[test]
    fn written_bag_reads_back_with_schema_hash_and_payload() {
        let mut bag = BagWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
        let header = Header {
            frame_id: "map".into(),
            ..Default::default()
        };
        bag.write("/h", 5, &header).unwrap();
        bag.write("/h", 6, &header).unwrap();
        let bytes = bag.finish().unwrap().into_inner();
        let messages: Vec<_> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap())
            .collect();
        assert_eq!(messages.len(), 2);
        let channel = &messages[0].channel;
        assert_eq!(channel.topic, "/h");
        assert_eq!(channel.schema.as_ref().unwrap().name, "std_msgs/msg/Header");
        assert_eq!(
            channel.metadata["topic_type_hash"],
            Header::type_hash().unwrap()
        );
        assert_eq!(messages[1].log_time, 6);
        assert_eq!(cdr::decode::<Header>(&messages[0].data).unwrap(), header);
    }
}

//! Write rosbag2-style MCAP bags: one `ros2msg` schema per type (the `.msg` text), `cdr` channels
//! whose metadata carries the publisher's RIHS01 type hash, as `ros2 bag record` writes them
//! (Jazzy). `groupforward replay` and `ros2 bag play` read them back.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use groupforward_msgs::idl::EMBEDDED;
use groupforward_msgs::{cdr, RosMessage};

#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("mcap: {0}")]
    Mcap(#[from] mcap::McapError),
    #[error("cannot encode a {0} message: {1}")]
    Encode(&'static str, cdr::CdrError),
    #[error("no embedded definition of {0}")]
    UnknownType(&'static str),
    #[error("type hash of {0}: {1}")]
    Hash(&'static str, groupforward_msgs::idl::IdlError),
}

pub type Result<T> = std::result::Result<T, BagError>;

/// An MCAP writer that adds channels as topics first appear.
pub struct BagWriter<W: Write + Seek> {
    writer: mcap::Writer<W>,
    channels: BTreeMap<String, u16>,
    sequence: u32,
}

impl<W: Write + Seek> std::fmt::Debug for BagWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "BagWriter({} channels)", self.channels.len())
    }
}

impl<W: Write + Seek> BagWriter<W> {
    pub fn new(sink: W) -> Result<Self> {
        Ok(Self {
            writer: mcap::Writer::new(sink)?,
            channels: BTreeMap::new(),
            sequence: 0,
        })
    }

    fn channel<T: RosMessage>(&mut self, topic: &str) -> Result<u16> {
        if let Some(id) = self.channels.get(topic) {
            return Ok(*id);
        }
        let (_, _, _, text) = EMBEDDED
            .iter()
            .find(|(kind, pkg, name, _)| {
                *kind == "msg" && format!("{pkg}/msg/{name}") == T::TYPE_NAME
            })
            .ok_or(BagError::UnknownType(T::TYPE_NAME))?;
        let schema = self
            .writer
            .add_schema(T::TYPE_NAME, "ros2msg", text.as_bytes())?;
        let hash = T::type_hash().map_err(|e| BagError::Hash(T::TYPE_NAME, e))?;
        let metadata = BTreeMap::from([("topic_type_hash".to_owned(), hash)]);
        let id = self.writer.add_channel(schema, topic, "cdr", &metadata)?;
        self.channels.insert(topic.to_owned(), id);
        Ok(id)
    }

    /// Record `message` on `topic` at `log_time_nanos`.
    pub fn write<T: RosMessage>(
        &mut self,
        topic: &str,
        log_time_nanos: i64,
        message: &T,
    ) -> Result<()> {
        let channel_id = self.channel::<T>(topic)?;
        self.sequence += 1;
        let time = u64::try_from(log_time_nanos).unwrap_or(0);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: time,
            publish_time: time,
        };
        let data = cdr::encode(message).map_err(|e| BagError::Encode(T::TYPE_NAME, e))?;
        self.writer.write_to_known_channel(&header, &data)?;
        Ok(())
    }

    /// Write the summary and return the sink.
    pub fn finish(mut self) -> Result<W> {
        self.writer.finish()?;
        Ok(self.writer.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use groupforward_msgs::std_msgs::Header;

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

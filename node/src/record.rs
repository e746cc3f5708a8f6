//! `--record-outputs`: everything the node publishes, also written to a rosbag2 bag directory
//! (`<dir>/<dir name>_0.mcap` and `metadata.yaml`, as `ros2 bag record` leaves it), so that a run
//! can be inspected in Foxglove or checked by any bag reader. A [`RecordingTransport`] wraps the
//! node's transport: subscriptions and services pass through; each publisher also records.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use groupforward_msgs::bag::{BagError, BagWriter, OfferedQos};

use crate::transport::{Endpoint, JsonHandler, Publisher, Result, ServiceHandler, Sink, Transport};

#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("cannot create the bag directory {0}: {1}")]
    Create(PathBuf, std::io::Error),
    #[error("bag {0}: {1}")]
    Bag(PathBuf, BagError),
}

/// The bag being written; shared by every recording publisher.
pub struct Recorder {
    dir: PathBuf,
    file_name: String,
    bag: Mutex<Option<BagWriter<BufWriter<File>>>>,
    failures: std::sync::atomic::AtomicU64,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Recorder({})", self.dir.display())
    }
}

impl Recorder {
    /// Start a bag directory at `dir` (created; an existing bag file there is replaced).
    pub fn create(dir: &Path) -> std::result::Result<Arc<Self>, RecordError> {
        let (bag, file_name) =
            BagWriter::create_dir(dir).map_err(|e| RecordError::Create(dir.to_path_buf(), e))?;
        Ok(Arc::new(Self {
            dir: dir.to_path_buf(),
            file_name,
            bag: Mutex::new(Some(bag)),
            failures: std::sync::atomic::AtomicU64::new(0),
        }))
    }

    fn record(&self, endpoint: &Endpoint, payload: &[u8]) {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as i64);
        let Ok(mut bag) = self.bag.lock() else { return };
        let Some(bag) = bag.as_mut() else { return };
        if let Err(e) = bag.write_encoded(&endpoint.name, &endpoint.type_name, now, payload) {
            // The first failure is logged; the rest are counted and reported when the bag closes.
            if self
                .failures
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed)
                == 0
            {
                tracing::warn!("cannot record {}: {e}", endpoint.name);
            }
        }
    }

    fn offer(&self, endpoint: &Endpoint) {
        if let Ok(mut bag) = self.bag.lock() {
            if let Some(bag) = bag.as_mut() {
                bag.set_qos(
                    &endpoint.name,
                    OfferedQos {
                        best_effort: endpoint.qos.best_effort,
                        transient_local: endpoint.qos.transient_local,
                        depth: endpoint.qos.depth,
                    },
                );
            }
        }
    }

    /// Close the bag: write the MCAP summary and `metadata.yaml`. Returns the messages recorded;
    /// later publishes are not recorded.
    pub fn finish(&self) -> std::result::Result<u64, RecordError> {
        let bag = self.bag.lock().ok().and_then(|mut b| b.take());
        let Some(bag) = bag else { return Ok(0) };
        let count = bag.message_count();
        let failures = self.failures.load(std::sync::atomic::Ordering::Relaxed);
        if failures > 0 {
            tracing::warn!("{failures} messages could not be recorded");
        }
        bag.finish_dir(&self.dir, &self.file_name)
            .map_err(|e| RecordError::Bag(self.dir.clone(), e))?;
        Ok(count)
    }
}

/// A transport whose publishers also write every message to `recorder`'s bag.
pub struct RecordingTransport<'a> {
    pub inner: &'a dyn Transport,
    pub recorder: Arc<Recorder>,
}

impl std::fmt::Debug for RecordingTransport<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "RecordingTransport({:?})", self.recorder)
    }
}

struct RecordingPublisher {
    inner: Box<dyn Publisher>,
    endpoint: Endpoint,
    recorder: Arc<Recorder>,
}

impl Publisher for RecordingPublisher {
    fn publish(&self, payload: &[u8]) -> Result<()> {
        self.recorder.record(&self.endpoint, payload);
        self.inner.publish(payload)
    }
}

impl Transport for RecordingTransport<'_> {
    fn subscribe(&self, topic: &Endpoint, sink: Sink) -> Result<()> {
        self.inner.subscribe(topic, sink)
    }

    fn advertise(&self, topic: &Endpoint) -> Result<Box<dyn Publisher>> {
        self.recorder.offer(topic);
        Ok(Box::new(RecordingPublisher {
            inner: self.inner.advertise(topic)?,
            endpoint: topic.clone(),
            recorder: self.recorder.clone(),
        }))
    }

    fn serve(&self, service: &Endpoint, handler: ServiceHandler) -> Result<()> {
        self.inner.serve(service, handler)
    }

    fn serve_json(&self, prefix: &str, handler: JsonHandler) -> Result<()> {
        self.inner.serve_json(prefix, handler)
    }
}

//! Replay a rosbag2 MCAP bag over the transport at its recorded rate (or faster / slower), with the
//! rmw_zenoh key, type hash and attachment a live ROS 2 publisher would use.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use groupforward_msgs::rmw_zenoh::{resolve_name, Qos};

use crate::transport::{Endpoint, Publisher, Transport, TransportError};

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("cannot read bag {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path} holds no .mcap file (only MCAP storage is supported)")]
    NoMcap { path: String },
    #[error("{path} is not a valid MCAP file: {source}")]
    Mcap {
        path: String,
        source: mcap::McapError,
    },
    #[error(transparent)]
    Transport(#[from] TransportError),
}

pub type Result<T> = std::result::Result<T, ReplayError>;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayOptions {
    /// Playback speed: 1 is real time, 2 twice as fast; 0 publishes as fast as possible.
    pub rate: f64,
    /// Start again from the beginning after the last message, `loops` times in all (0: forever).
    pub loops: u32,
    pub progress: bool,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self {
            rate: 1.0,
            loops: 1,
            progress: true,
        }
    }
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplaySummary {
    pub published: u64,
    /// Messages on topics that could not be published, by topic, with the reason.
    pub skipped: HashMap<String, (u64, String)>,
    pub elapsed: Duration,
}

/// The `.mcap` files of a bag: the file itself, or those in a rosbag2 directory, in name order.
pub fn bag_files(path: &Path) -> Result<Vec<PathBuf>> {
    if path.is_file() {
        return Ok(vec![path.to_owned()]);
    }
    let io = |source| ReplayError::Io {
        path: path.display().to_string(),
        source,
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(io)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(ReplayError::NoMcap {
            path: path.display().to_string(),
        });
    }
    Ok(files)
}

/// The endpoint to publish a bag channel on, or why it cannot be published.
fn channel_endpoint(channel: &mcap::Channel<'_>) -> std::result::Result<Endpoint, String> {
    let type_name = channel
        .schema
        .as_ref()
        .map(|s| s.name.clone())
        .ok_or("channel has no schema")?;
    if channel.message_encoding != "cdr" {
        return Err(format!(
            "encoding `{}` is not cdr",
            channel.message_encoding
        ));
    }
    // rosbag2 (Jazzy) records the publisher's hash; older bags fall back to the embedded IDL.
    let type_hash = match channel.metadata.get("topic_type_hash") {
        Some(hash) if hash.starts_with("RIHS01_") => hash.clone(),
        _ => groupforward_msgs::idl::type_hash(&type_name).map_err(|_| {
            format!("type `{type_name}` has no recorded hash and is not known here")
        })?,
    };
    let name = resolve_name("/", "replay", &channel.topic).map_err(|e| e.to_string())?;
    Ok(Endpoint {
        name,
        type_name,
        type_hash,
        qos: Qos::default(),
        lossless: false,
    })
}

/// Publish every message of the bag at `path` through `transport`.
pub fn replay(
    path: &Path,
    transport: &dyn Transport,
    options: ReplayOptions,
) -> Result<ReplaySummary> {
    let files = bag_files(path)?;
    let buffers = files
        .iter()
        .map(|f| {
            std::fs::read(f).map_err(|source| ReplayError::Io {
                path: f.display().to_string(),
                source,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
    replay_buffers(&names, &buffers, transport, options)
}

/// Publish every message of in-memory MCAP files (`names` label them in errors), in order.
pub fn replay_buffers(
    names: &[String],
    buffers: &[Vec<u8>],
    transport: &dyn Transport,
    options: ReplayOptions,
) -> Result<ReplaySummary> {
    let total: u64 = buffers
        .iter()
        .filter_map(|b| mcap::Summary::read(b).ok().flatten())
        .filter_map(|s| s.stats.map(|s| s.message_count))
        .sum();
    let bar = if options.progress {
        let bar = indicatif::ProgressBar::new(total * u64::from(options.loops.max(1)));
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{spinner} replay [{elapsed_precise}] {bar:40} {pos}/{len} msgs ({per_sec})",
        ) {
            bar.set_style(style);
        }
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };
    let mut publishers: HashMap<String, Box<dyn Publisher>> = HashMap::new();
    let mut summary = ReplaySummary::default();
    let started = Instant::now();
    let mut pass = 0;
    while options.loops == 0 || pass < options.loops {
        pass += 1;
        let pass_start = Instant::now();
        let mut first_log_time: Option<u64> = None;
        for (name, buffer) in names.iter().zip(buffers) {
            let stream = mcap::MessageStream::new(buffer).map_err(|source| ReplayError::Mcap {
                path: name.clone(),
                source,
            })?;
            for message in stream {
                let message = message.map_err(|source| ReplayError::Mcap {
                    path: name.clone(),
                    source,
                })?;
                let first = *first_log_time.get_or_insert(message.log_time);
                if options.rate > 0.0 {
                    let offset = message.log_time.saturating_sub(first) as f64 / 1e9 / options.rate;
                    let due = pass_start + Duration::from_secs_f64(offset);
                    if let Some(wait) = due.checked_duration_since(Instant::now()) {
                        std::thread::sleep(wait);
                    }
                }
                let topic = &message.channel.topic;
                if !publishers.contains_key(topic) {
                    match channel_endpoint(&message.channel) {
                        Ok(endpoint) => {
                            publishers.insert(topic.clone(), transport.advertise(&endpoint)?);
                        }
                        Err(reason) => {
                            let entry = summary
                                .skipped
                                .entry(topic.clone())
                                .or_insert((0, reason.clone()));
                            if entry.0 == 0 {
                                tracing::warn!(topic, "not replayed: {reason}");
                            }
                            entry.0 += 1;
                            bar.inc(1);
                            continue;
                        }
                    }
                }
                if let Some(publisher) = publishers.get(topic) {
                    publisher.publish(&message.data)?;
                    summary.published += 1;
                }
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    summary.elapsed = started.elapsed();
    Ok(summary)
}

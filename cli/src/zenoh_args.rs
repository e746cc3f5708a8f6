//! The zenoh and config flags that `run` and `replay` share.

use std::path::PathBuf;

use anyhow::Result;
use groupforward::config::Config;

#[derive(Debug, Clone, clap::Args)]
pub struct ZenohArgs {
    /// Node config (YAML); defaults are used where it is silent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Zenoh endpoints to connect to, replacing the config's (repeatable).
    #[arg(long)]
    connect: Vec<String>,
    /// Zenoh endpoints to listen on, replacing the config's (repeatable).
    #[arg(long)]
    listen: Vec<String>,
    /// A zenoh JSON5 config (authentication, access control, TLS), replacing the config's
    /// `zenoh.config_file`.
    #[arg(long)]
    zenoh_config: Option<String>,
    /// The middleware, replacing the config's `transport`: zenoh, or ros2 (native ROS 2, in a
    /// build with the `ros2` feature).
    #[arg(long)]
    transport: Option<groupforward::transport::TransportKind>,
}

impl ZenohArgs {
    /// The config file (or the defaults) with the command line's endpoints applied.
    pub fn load(&self) -> Result<Config> {
        let mut config = match &self.config {
            Some(path) => Config::load(path)?,
            None => Config::default(),
        };
        if !self.connect.is_empty() {
            config.zenoh.connect = self.connect.clone();
        }
        if !self.listen.is_empty() {
            config.zenoh.listen = self.listen.clone();
        }
        if let Some(transport) = self.transport {
            config.transport = transport;
        }
        if let Some(file) = &self.zenoh_config {
            config.zenoh.config_file = Some(file.clone());
        }
        Ok(config)
    }
}

//! A node's settings.

use pab_core::isotp::RxConfig;

/// A node's settings. `Config::new(node_id)` gives the defaults of `docs/can-protocol.md`.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// The node id, 1..=127; table images carry it and must match.
    pub node_id: u8,
    /// Time between heartbeats (default 1 s).
    pub heartbeat_period_us: u64,
    /// Shortest time between two fault frames with the same code (default 100 ms).
    pub fault_interval_us: u64,
    /// How the node receives table transfers (block size, STmin, N_Cr).
    pub isotp: RxConfig,
}

/// Why a configuration was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigError {
    /// The node id is 0 (the tool's) or above 127.
    NodeId(u8),
    /// The heartbeat period is below 10 ms or above an hour.
    HeartbeatPeriod,
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ConfigError::NodeId(id) => write!(f, "node id {id} is outside 1..=127"),
            ConfigError::HeartbeatPeriod => {
                f.write_str("heartbeat period must be between 10 ms and 1 hour")
            }
        }
    }
}

impl core::error::Error for ConfigError {}

impl Config {
    /// The defaults for node `node_id`.
    pub fn new(node_id: u8) -> Result<Config, ConfigError> {
        let config = Config {
            node_id,
            heartbeat_period_us: 1_000_000,
            fault_interval_us: crate::faults::DEFAULT_INTERVAL_US,
            // Block size 8: a board acknowledges every 56 bytes, so a burst never outruns its
            // receive FIFO; STmin 0 leaves the pacing to the bus.
            isotp: RxConfig {
                block_size: 8,
                ..RxConfig::default()
            },
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks the settings.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.node_id == 0 || self.node_id > pab_core::protocol::MAX_NODE_ID {
            return Err(ConfigError::NodeId(self.node_id));
        }
        if !(10_000..=3_600_000_000).contains(&self.heartbeat_period_us) {
            return Err(ConfigError::HeartbeatPeriod);
        }
        Ok(())
    }
}

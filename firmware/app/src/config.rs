//! A node's settings.

use pab_core::isotp::RxConfig;

/// The default [`Config::store_interval_us`]: 1 s.
pub const DEFAULT_STORE_INTERVAL_US: u64 = 1_000_000;
/// The largest [`Config::store_interval_us`]: 2 s.
pub const MAX_STORE_INTERVAL_US: u64 = 2_000_000;

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
    /// Shortest time between the starts of two saves of a table to storage (default 1 s, at
    /// most 2 s so that `pabctl push`, which waits 3 s for the answer, still hears it): a table
    /// applied sooner after the last save runs at once and is stored, and answered, when the
    /// interval has passed. Bounds the flash wear that repeated pushes cause.
    pub store_interval_us: u64,
}

/// Why a configuration was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ConfigError {
    /// The node id is 0 (the tool's) or above 127.
    NodeId(u8),
    /// The heartbeat period is below 10 ms or above an hour.
    HeartbeatPeriod,
    /// The store interval is above 2 s.
    StoreInterval,
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ConfigError::NodeId(id) => write!(f, "node id {id} is outside 1..=127"),
            ConfigError::HeartbeatPeriod => {
                f.write_str("heartbeat period must be between 10 ms and 1 hour")
            }
            ConfigError::StoreInterval => {
                f.write_str("the store interval must be at most 2 s (pabctl push waits 3 s)")
            }
        }
    }
}

impl core::error::Error for ConfigError {}

impl Config {
    /// The defaults for node `node_id`.
    pub fn new(node_id: u8) -> Result<Config, ConfigError> {
        let config = Config::defaults(node_id);
        config.validate()?;
        Ok(config)
    }

    /// The defaults for a node without a node id: it sends from its provisional address and
    /// takes only identity requests and assignments until `pabctl assign` gives it one
    /// ([`crate::Node::set_identity`]). `node_id` reads 0 until then.
    pub fn unassigned() -> Config {
        Config::defaults(0)
    }

    /// The defaults for `node_id` (0: unassigned), or [`Config::unassigned`]'s for `None`.
    pub fn for_node(node_id: Option<u8>) -> Result<Config, ConfigError> {
        match node_id {
            Some(id) => Config::new(id),
            None => Ok(Config::unassigned()),
        }
    }

    fn defaults(node_id: u8) -> Config {
        Config {
            node_id,
            heartbeat_period_us: 1_000_000,
            fault_interval_us: crate::faults::DEFAULT_INTERVAL_US,
            store_interval_us: DEFAULT_STORE_INTERVAL_US,
            // Block size 8: a board acknowledges every 56 bytes, so a burst never outruns its
            // receive FIFO; STmin 0 leaves the pacing to the bus.
            isotp: RxConfig {
                block_size: 8,
                ..RxConfig::default()
            },
        }
    }

    /// Checks the settings.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.node_id == 0 || self.node_id > pab_core::protocol::MAX_NODE_ID {
            return Err(ConfigError::NodeId(self.node_id));
        }
        if !(10_000..=3_600_000_000).contains(&self.heartbeat_period_us) {
            return Err(ConfigError::HeartbeatPeriod);
        }
        if self.store_interval_us > MAX_STORE_INTERVAL_US {
            return Err(ConfigError::StoreInterval);
        }
        Ok(())
    }
}

/// A node id given as text at compile time, for the boards' `PAB_NODE_ID`:
/// `parse_node_id(option_env!("PAB_NODE_ID"))` in a `const` gives 1 without it, the number for
/// a decimal number in 1..=127, 0 for `unassigned` (no compiled id: [`Config::unassigned`]), and
/// a compile error naming `PAB_NODE_ID` for anything else.
/// (Called at run time with bad text, it panics: use it in `const` items only.)
pub const fn parse_node_id(text: Option<&str>) -> u8 {
    let Some(text) = text else {
        return 1;
    };
    let digits = text.as_bytes();
    if let b"unassigned" = digits {
        return 0;
    }
    assert!(
        !digits.is_empty() && digits.len() <= 3,
        "PAB_NODE_ID must be a decimal number in 1..=127"
    );
    let mut value: u32 = 0;
    let mut rest = digits;
    while let [digit, tail @ ..] = rest {
        assert!(
            digit.is_ascii_digit(),
            "PAB_NODE_ID must be a decimal number in 1..=127"
        );
        value = value * 10 + (*digit - b'0') as u32;
        rest = tail;
    }
    assert!(
        value >= 1 && value <= pab_core::protocol::MAX_NODE_ID as u32,
        "PAB_NODE_ID must be a decimal number in 1..=127"
    );
    value as u8
}

//! What a node keeps of its configuration across restarts: its node id and its bit rate, set
//! over the bus (`pabctl assign`, `pabctl config`), in a power-fail-safe configuration page
//! ([`pab_storage::TableStore::save_settings`]). What a board compiles in is only the default
//! of an erased page.
//!
//! One 16-bit record:
//!
//! ```text
//! bits 0-6    node id (0: none, the compiled default applies)
//! bits 7-9    bit rate code (0: the compiled default; 1 125, 2 250, 3 500, 4 1000 kbit/s)
//! bits 10-12  the previous bit rate's code (what a trial goes back to)
//! bit 13      trial: the bit rate was set over the bus and has not heard the bus yet
//! bit 14      fell back: the last trial heard nothing and the previous rate was restored
//! bit 15      0
//! ```

/// The bit rates a record can name, by code (code 0, the compiled default, is not among them).
const BITRATES_KBPS: [u16; 4] = [125, 250, 500, 1000];

/// How long a node on a bit rate set over the bus waits to hear a frame before it goes back to
/// the previous rate, µs (DESIGN: 5 s). Every node of ours sends a heartbeat each second, so a
/// bus with one other node on it is heard within a second.
pub const BITRATE_TRIAL_US: u64 = 5_000_000;

/// A node's stored configuration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Settings {
    /// The node id set over the bus (`None`: the compiled default, or unassigned without one).
    pub node_id: Option<u8>,
    /// The bit rate set over the bus, kbit/s (`None`: the compiled default).
    pub bitrate_kbps: Option<u16>,
    /// The bit rate before it, kbit/s (`None`: the compiled default).
    pub previous_kbps: Option<u16>,
    /// `bitrate_kbps` has not heard the bus yet: the node starts on it and goes back to
    /// `previous_kbps` if it hears nothing within [`BITRATE_TRIAL_US`].
    pub trial: bool,
    /// The last trial heard nothing: the node went back to the previous rate.
    pub fell_back: bool,
}

/// The code of a bit rate in a record; `None` for one a node cannot be set to.
pub fn bitrate_code(kbps: u16) -> Option<u16> {
    let index = BITRATES_KBPS.iter().position(|&rate| rate == kbps)?;
    u16::try_from(index).ok().map(|index| index + 1)
}

fn code_of(kbps: Option<u16>) -> u16 {
    kbps.and_then(bitrate_code).unwrap_or(0)
}

fn rate_of(code: u16) -> Result<Option<u16>, ()> {
    match code {
        0 => Ok(None),
        code => BITRATES_KBPS
            .get(usize::from(code) - 1)
            .copied()
            .map(Some)
            .ok_or(()),
    }
}

impl Settings {
    /// The record of these settings.
    pub fn record(&self) -> u16 {
        u16::from(self.node_id.unwrap_or(0) & 0x7F)
            | code_of(self.bitrate_kbps) << 7
            | code_of(self.previous_kbps) << 10
            | u16::from(self.trial) << 13
            | u16::from(self.fell_back) << 14
    }

    /// The settings of a record; `None` for a record no node wrote (bit 15, a rate code above
    /// 4).
    pub fn from_record(record: u16) -> Option<Settings> {
        if record & 0x8000 != 0 {
            return None;
        }
        let node_id = (record & 0x7F) as u8;
        Some(Settings {
            node_id: (node_id != 0).then_some(node_id),
            bitrate_kbps: rate_of(record >> 7 & 0b111).ok()?,
            previous_kbps: rate_of(record >> 10 & 0b111).ok()?,
            trial: record & 1 << 13 != 0,
            fell_back: record & 1 << 14 != 0,
        })
    }

    /// The settings a node starts with from what its store's configuration page gave
    /// ([`pab_storage::TableStore::load_settings`]): the defaults for an erased page, an
    /// unreadable one or a record of another format ([`crate::Node::set_settings`] says so).
    pub fn from_loaded(loaded: &Result<Option<u16>, pab_storage::StoreError>) -> Settings {
        match loaded {
            Ok(Some(record)) => Settings::from_record(*record).unwrap_or_default(),
            Ok(None) | Err(_) => Settings::default(),
        }
    }

    /// The bit rate to start on, kbit/s, given the board's compiled default.
    pub fn start_bitrate(&self, default_kbps: u16) -> u16 {
        self.bitrate_kbps.unwrap_or(default_kbps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_record_round_trips_or_is_refused() {
        let mut valid = 0;
        for record in 0..=u16::MAX {
            match Settings::from_record(record) {
                Some(settings) => {
                    assert_eq!(settings.record(), record, "{record:#06x}");
                    valid += 1;
                }
                None => {
                    assert!(record & 0x8000 != 0 || (record >> 7 & 7) > 4 || (record >> 10 & 7) > 4)
                }
            }
        }
        // 128 ids x 5 rates x 5 previous rates x 2 x 2.
        assert_eq!(valid, 128 * 5 * 5 * 4);
        assert_eq!(Settings::default().record(), 0);
        assert_eq!(bitrate_code(500), Some(3));
        assert_eq!(bitrate_code(800), None);
    }
}

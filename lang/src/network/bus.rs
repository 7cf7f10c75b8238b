//! `[bus]`: the CAN bus the network's nodes share, its bit rate, and for CAN FD its data phase's.
//!
//! ```toml
//! [bus]
//! bitrate = 500000        # bit/s, 1 to 1000000: the nominal (arbitration) rate
//! data_bitrate = 2000000  # optional: a CAN FD bus, its data phase at bitrate to 8000000 bit/s
//! ```
//!
//! One bit rate for the bus: HBBA's `bus` resource is a percentage of its time, and `pabctl
//! check` computes every frame stream's worst-case response time at it. `[hbba] bitrate`, the
//! older place of the same number, is still read in a file without `[bus]`; a file with both is
//! refused (two numbers for one bus).
//!
//! With `data_bitrate` the bus is a CAN FD bus: topics may be `fd = true`, the project's table
//! transfers go as ISO-TP on CAN FD with 64-byte frames, and a node whose controller is classic
//! only (`fd = false`) is refused, since a classic controller that is not FD-tolerant destroys
//! every CAN FD frame with an error frame. `data_bitrate = bitrate` is CAN FD without bit-rate
//! switching; above it, the FD frames switch (BRS) for their data phase.

use std::ops::Range;

use schemars::JsonSchema;
use serde::Deserialize;

use super::Builder;
use super::hbba::MAX_BITRATE;
use super::spanned::Spanned;
use crate::can_frame::MAX_DATA_BITRATE;

/// `[bus] bitrate = N` and, for CAN FD, `data_bitrate = N`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawBus {
    /// Required: bit/s, 1 to 1000000: the bus's nominal rate (its arbitration phase's, and every
    /// bit's of a classic frame).
    bitrate: Spanned<i64>,
    /// Optional: bit/s, `bitrate` to 8000000: makes the bus a CAN FD bus, whose FD frames (topics
    /// with `fd = true`, the table transfers) send their data phase at this rate (with bit-rate
    /// switching when above `bitrate`; equal to it, CAN FD without switching). Default: a
    /// classic CAN bus.
    data_bitrate: Option<Spanned<i64>>,
}

/// The bus's bit rates and where the file says them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Bus {
    /// Bit/s, 1 to [`MAX_BITRATE`]: the nominal rate.
    pub bitrate: u32,
    /// Where it is written (`[bus] bitrate`, or `[hbba] bitrate`).
    pub span: Range<usize>,
    /// A CAN FD bus's data rate (`[bus] data_bitrate`), bit/s, `bitrate` to
    /// [`MAX_DATA_BITRATE`]; `None` on a classic bus.
    pub data_bitrate: Option<u32>,
}

impl Bus {
    /// Whether it is a CAN FD bus (`data_bitrate` written).
    pub fn is_fd(&self) -> bool {
        self.data_bitrate.is_some()
    }
}

impl Builder<'_> {
    /// `[bus]`, if the file has it; `None` also after reporting its mistake (a mistaken
    /// `data_bitrate` leaves a classic bus, after its error).
    pub(super) fn bus(&mut self, raw: Option<&Spanned<RawBus>>) -> Option<Bus> {
        let raw = raw?.get_ref();
        let mut bus = self.bitrate(&raw.bitrate)?;
        if let Some(data) = &raw.data_bitrate {
            let value = *data.get_ref();
            match u32::try_from(value) {
                Ok(rate) if rate >= bus.bitrate && rate <= MAX_DATA_BITRATE => {
                    bus.data_bitrate = Some(rate);
                }
                _ => {
                    let why = if value > i64::from(MAX_DATA_BITRATE) {
                        " (the fastest data phase CAN FD controllers and transceivers commonly offer)"
                    } else {
                        " (the data phase is never slower than the arbitration; equal to it: CAN FD without bit-rate switching)"
                    };
                    self.error(
                        data.span(),
                        format!(
                            "data_bitrate = {value}: bit/s of the CAN FD data phase, from `bitrate` ({}) to {MAX_DATA_BITRATE}{why}",
                            bus.bitrate
                        ),
                    );
                }
            }
        }
        Some(bus)
    }

    /// A `bitrate` (of `[bus]` or `[hbba]`), checked: `None` after reporting it.
    pub(super) fn bitrate(&mut self, bitrate: &Spanned<i64>) -> Option<Bus> {
        let value = *bitrate.get_ref();
        match u32::try_from(value) {
            Ok(rate) if rate >= 1 && i64::from(rate) <= MAX_BITRATE => Some(Bus {
                bitrate: rate,
                span: bitrate.span(),
                data_bitrate: None,
            }),
            _ => {
                let hint = if value > MAX_BITRATE {
                    "; a CAN FD bus's faster data phase is `data_bitrate` in [bus]"
                } else {
                    ""
                };
                self.error(
                    bitrate.span(),
                    format!(
                        "bitrate = {value}: bit/s, 1 to {MAX_BITRATE} (the nominal rate, CAN's arbitration phase){hint}"
                    ),
                );
                None
            }
        }
    }
}

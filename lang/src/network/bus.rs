//! `[bus]`: the CAN bus the network's nodes share, its bit rate.
//!
//! ```toml
//! [bus]
//! bitrate = 500000      # bit/s, 1 to 1000000 (classic CAN)
//! ```
//!
//! One bit rate for the bus: HBBA's `bus` resource is a percentage of it, and `pabctl check`
//! computes every frame stream's worst-case response time at it. `[hbba] bitrate`, the older
//! place of the same number, is still read in a file without `[bus]`; a file with both is
//! refused (two numbers for one bus).

use std::ops::Range;

use schemars::JsonSchema;
use serde::Deserialize;

use super::Builder;
use super::hbba::MAX_BITRATE;
use super::spanned::Spanned;

/// `[bus] bitrate = N`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawBus {
    /// Required: bit/s, 1 to 1000000 (classic CAN; CAN FD's data rate comes with CAN FD
    /// support).
    bitrate: Spanned<i64>,
}

/// The bus's bit rate and where the file says it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Bus {
    /// Bit/s, 1 to [`MAX_BITRATE`].
    pub bitrate: u32,
    /// Where it is written (`[bus] bitrate`, or `[hbba] bitrate`).
    pub span: Range<usize>,
}

impl Builder<'_> {
    /// `[bus]`, if the file has it; `None` also after reporting its mistake.
    pub(super) fn bus(&mut self, raw: Option<&Spanned<RawBus>>) -> Option<Bus> {
        let bitrate = &raw?.get_ref().bitrate;
        self.bitrate(bitrate)
    }

    /// A `bitrate` (of `[bus]` or `[hbba]`), checked: `None` after reporting it.
    pub(super) fn bitrate(&mut self, bitrate: &Spanned<i64>) -> Option<Bus> {
        let value = *bitrate.get_ref();
        match u32::try_from(value) {
            Ok(rate) if rate >= 1 && i64::from(rate) <= MAX_BITRATE => Some(Bus {
                bitrate: rate,
                span: bitrate.span(),
            }),
            _ => {
                self.error(
                    bitrate.span(),
                    format!("bitrate = {value}: bit/s, 1 to {MAX_BITRATE} (classic CAN)"),
                );
                None
            }
        }
    }
}

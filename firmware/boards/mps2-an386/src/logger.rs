//! The `log` crate's messages (pab-app's, this firmware's) on QEMU's standard error, through
//! semihosting, with the board's uptime.
//!
//! Why `log` and not defmt: defmt needs a probe and its host decoder to be read; under QEMU,
//! semihosting prints plain text on the emulator's stderr, which a test or a person reads as it
//! is. Each message costs a trap into the emulator (the emulated CPU stops meanwhile), so the
//! level is `Info` (a few lines at boot and per table transfer); pab-app's per-frame messages are
//! at `Debug` and cost one level comparison each.

use core::fmt::Write as _;

use log::{Level, LevelFilter, Metadata, Record};
use pab_core::decimal::Decimal;

use crate::semihosting::{self, TEXT_CAPACITY, Text};

struct Semihosting;

static LOGGER: Semihosting = Semihosting;

impl log::Log for Semihosting {
    fn enabled(&self, metadata: &Metadata<'_>) -> bool {
        metadata.level() <= log::max_level()
    }

    fn log(&self, record: &Record<'_>) {
        if !self.enabled(record.metadata()) {
            return;
        }
        // One line, formatted first, written with one call: semihosting writes are slow.
        let mut line = Text::line();
        let micros = embassy_time::Instant::now().as_micros();
        // Seconds and microseconds as u32s, written through `Decimal` as the messages' integers
        // are: the text of `{seconds:>6}.{fraction:06}` without core::fmt's integer formatters
        // (u32's and its padding, some 630 bytes of the flash; u64's 256 more). 2^32 s is 136
        // years.
        let seconds = u32::try_from(micros / 1_000_000).unwrap_or(u32::MAX);
        let fraction = (micros % 1_000_000) as u32;
        let (seconds, fraction) = (
            Decimal::padded(seconds, 6, b' '),
            Decimal::padded(fraction, 6, b'0'),
        );
        // The level padded to five characters by hand, and the line written out as it is: the
        // same text as `{:<5}` and `{line}`, without the level's and the string's `Display`.
        let level = match record.level() {
            Level::Error => "ERROR ",
            Level::Warn => "WARN  ",
            Level::Info => "INFO  ",
            Level::Debug => "DEBUG ",
            Level::Trace => "TRACE ",
        };
        // The pieces of a line that does not fit are taken up to the first that does not, as a
        // `heapless::String` would; one that ends exactly full is cut for "...".
        let _ = write!(line, "{seconds}.{fraction} ")
            .and_then(|()| line.write_str(level))
            .and_then(|()| line.write_fmt(*record.args()));
        if line.is_full() {
            line.truncate_to_char(TEXT_CAPACITY - 4);
            let _ = line.write_str("...");
        }
        let _ = line.write_str("\n");
        semihosting::eprint_bytes(line.as_bytes());
    }

    fn flush(&self) {}
}

/// Installs the logger at `level`. A second call changes nothing.
pub fn init(level: LevelFilter) {
    if log::set_logger(&LOGGER).is_ok() {
        log::set_max_level(level);
    }
}

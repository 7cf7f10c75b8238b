//! The host's services through semihosting: console output and the exit status. Only under
//! QEMU (`-semihosting-config enable=on`) or a debugger; on a bare board a semihosting call
//! halts at a breakpoint.

use core::fmt::{self, Write as _};

use cortex_m_semihosting::{debug, hio};

/// Writes `text` to the host's standard error (QEMU's stderr): formatted into a [`Text`] that
/// writes itself out whenever it fills, so the same text goes out in a few calls. Slow: a trap
/// into the emulator per call. Errors are ignored: there is nobody to report them to.
pub fn eprint(text: fmt::Arguments<'_>) {
    let mut out = Text::streaming();
    let _ = out.write_fmt(text);
    out.flush();
}

/// Writes `bytes` to the host's standard error as they are, in one call: [`eprint`] without the
/// formatting.
pub fn eprint_bytes(bytes: &[u8]) {
    if let Ok(mut stderr) = hio::hstderr() {
        let _ = stderr.write_all(bytes);
    }
}

/// Ends the emulation with `status` as QEMU's exit status (0 success, 1 failure).
pub fn exit(success: bool) -> ! {
    debug::exit(if success {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    // Without semihosting the call above returns: wait for a debugger.
    loop {
        cortex_m::asm::bkpt();
    }
}

/// Bytes a [`Text`] holds: the logger's longest line, its newline included.
pub const TEXT_CAPACITY: usize = 192;

/// Text on its way to the host's standard error, gathered so that it goes out in one call, as
/// whole UTF-8 characters: what [`eprint`] formats and the logger's lines. The one
/// [`fmt::Write`] that both format into (the logger's line was a `heapless::String`, [`eprint`]
/// wrote to semihosting's `HostStream`): each writer's `write_char` and `write_fmt` took some
/// 150 bytes of the flash.
///
/// A piece that does not fit in what is left is written out after what is gathered (streaming,
/// [`eprint`]'s), or refused whole with an error, the text kept as it was (a line's, as
/// `heapless::String`'s `write_str` does).
pub struct Text {
    bytes: [u8; TEXT_CAPACITY],
    len: usize,
    streaming: bool,
}

impl Text {
    /// An empty line: a piece that does not fit is refused.
    pub const fn line() -> Text {
        Text {
            bytes: [0; TEXT_CAPACITY],
            len: 0,
            streaming: false,
        }
    }

    /// An empty text that writes itself out when a piece does not fit.
    pub const fn streaming() -> Text {
        Text {
            streaming: true,
            ..Text::line()
        }
    }

    /// The bytes gathered.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or_default()
    }

    /// Whether every byte is taken.
    pub fn is_full(&self) -> bool {
        self.len == TEXT_CAPACITY
    }

    /// Keeps the first `len` bytes, or fewer: those of the characters that begin before
    /// `len`, so that what is left is whole characters.
    pub fn truncate_to_char(&mut self, mut len: usize) {
        // A UTF-8 continuation byte is 0b10xx_xxxx: the character began before it.
        while self.bytes.get(len).is_some_and(|&byte| byte & 0xC0 == 0x80) {
            len -= 1;
        }
        self.len = self.len.min(len);
    }

    /// Writes out what is gathered ([`eprint_bytes`]) and empties the text.
    pub fn flush(&mut self) {
        eprint_bytes(self.as_bytes());
        self.len = 0;
    }
}

impl fmt::Write for Text {
    fn write_str(&mut self, piece: &str) -> fmt::Result {
        let piece = piece.as_bytes();
        if piece.len() > TEXT_CAPACITY - self.len {
            if !self.streaming {
                return Err(fmt::Error);
            }
            self.flush();
            if piece.len() > TEXT_CAPACITY {
                eprint_bytes(piece);
                return Ok(());
            }
        }
        let end = self.len + piece.len();
        if let Some(slot) = self.bytes.get_mut(self.len..end) {
            slot.copy_from_slice(piece);
            self.len = end;
        }
        Ok(())
    }
}

//! CRC-32/ISO-HDLC (the CRC of zlib, Ethernet and PNG): reflected polynomial 0xEDB88320, initial
//! value and final XOR 0xFFFFFFFF.
//!
//! Why this CRC: every tool a user will inspect an image with already has it (`zlib.crc32` in
//! Python, `crc32` on the command line), and it detects every single-bit, double-bit and odd-count
//! error and every burst up to 32 bits in images far larger than ours. Table-driven, one byte per
//! step: the 1 KiB table is built at compile time.

const POLYNOMIAL: u32 = 0xEDB8_8320;

// Evaluated at compile time: an index out of bounds would fail the build, not panic.
#[allow(clippy::indexing_slicing)]
const TABLE: [u32; 256] = {
    let mut table = [0u32; 256];
    let mut byte = 0;
    while byte < 256 {
        let mut crc = byte as u32;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ POLYNOMIAL
            } else {
                crc >> 1
            };
            bit += 1;
        }
        table[byte] = crc;
        byte += 1;
    }
    table
};

/// An incremental CRC-32 computation.
#[derive(Clone, Copy, Debug)]
pub struct Crc32(u32);

impl Crc32 {
    /// A computation over no bytes yet.
    pub const fn new() -> Self {
        Crc32(0xFFFF_FFFF)
    }

    /// Feeds `bytes`.
    pub fn update(mut self, bytes: &[u8]) -> Self {
        for &byte in bytes {
            let index = usize::from((self.0 as u8) ^ byte);
            // `index` is a u8, the table has 256 entries.
            let entry = TABLE.get(index).copied().unwrap_or(0);
            self.0 = (self.0 >> 8) ^ entry;
        }
        self
    }

    /// The CRC of the bytes fed so far.
    pub const fn finish(self) -> u32 {
        self.0 ^ 0xFFFF_FFFF
    }
}

impl Default for Crc32 {
    fn default() -> Self {
        Crc32::new()
    }
}

/// The CRC-32 of `bytes`.
pub fn crc32(bytes: &[u8]) -> u32 {
    Crc32::new().update(bytes).finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value_of_the_catalogue() {
        // The "check" value of CRC-32/ISO-HDLC in the CRC catalogue.
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
        assert_eq!(
            Crc32::new().update(b"1234").update(b"56789").finish(),
            0xCBF4_3926
        );
    }
}

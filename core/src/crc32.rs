//! CRC-32/ISO-HDLC (the CRC of zlib, Ethernet and PNG): reflected polynomial 0xEDB88320, initial
//! value and final XOR 0xFFFFFFFF.
//!
//! Why this CRC: every tool a user will inspect an image with already has it (`zlib.crc32` in
//! Python, `crc32` on the command line), and it detects every single-bit, double-bit and odd-count
//! error and every burst up to 32 bits in images far larger than ours. Table-driven, half a byte
//! per step: the 64-byte table is built at compile time. A byte-wide table would be twice as fast
//! and cost 960 bytes more flash; the CRC runs once per image loaded or saved and per key record,
//! never on the frame path, so the boards keep the flash.

const POLYNOMIAL: u32 = 0xEDB8_8320;

// Evaluated at compile time: an index out of bounds would fail the build, not panic.
#[allow(clippy::indexing_slicing)]
const TABLE: [u32; 16] = {
    let mut table = [0u32; 16];
    let mut nibble = 0;
    while nibble < 16 {
        let mut crc = nibble as u32;
        let mut bit = 0;
        while bit < 4 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ POLYNOMIAL
            } else {
                crc >> 1
            };
            bit += 1;
        }
        table[nibble] = crc;
        nibble += 1;
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

    /// Feeds `bytes`. Out of line: the loader, the store and the key page each inlined a copy
    /// (it never runs on the frame path).
    #[inline(never)]
    pub fn update(mut self, bytes: &[u8]) -> Self {
        for &byte in bytes {
            let mut crc = self.0 ^ u32::from(byte);
            // Low nibble first: the CRC is reflected. `crc & 15` indexes the 16 entries.
            for _ in 0..2 {
                let entry = TABLE.get((crc & 15) as usize).copied().unwrap_or(0);
                crc = (crc >> 4) ^ entry;
            }
            self.0 = crc;
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

/// The CRC-32 of `bytes`. Out of line: eight callers (the store's, the loader's) inlined it,
/// 32 bytes of the NUCLEO-G474RE's flash.
#[inline(never)]
pub fn crc32(bytes: &[u8]) -> u32 {
    Crc32::new().update(bytes).finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bitwise definition, one bit per step: what the table must reproduce.
    fn bitwise(bytes: &[u8]) -> u32 {
        let mut crc = 0xFFFF_FFFFu32;
        for &byte in bytes {
            crc ^= u32::from(byte);
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ POLYNOMIAL
                } else {
                    crc >> 1
                };
            }
        }
        crc ^ 0xFFFF_FFFF
    }

    #[test]
    fn every_byte_value_and_a_long_input_agree_with_the_bitwise_definition() {
        for byte in 0..=255u8 {
            assert_eq!(crc32(&[byte]), bitwise(&[byte]), "byte {byte:#04x}");
        }
        let long: [u8; 1000] = core::array::from_fn(|i| (i * 7 + i / 13) as u8);
        assert_eq!(crc32(&long), bitwise(&long));
    }

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

//! CRC-32/ISO-HDLC, bit by bit: written here from the catalogue's definition (reflected
//! polynomial 0xEDB88320, initial value and final XOR 0xFFFFFFFF), not taken from pab-core, so
//! that a fixed-up image also checks pab-core's table-driven CRC.

/// The CRC of `parts`, concatenated.
pub fn crc32(parts: &[&[u8]]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for byte in parts.iter().flat_map(|part| part.iter()) {
        crc ^= u32::from(*byte);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_check_value_of_the_catalogue() {
        assert_eq!(super::crc32(&[b"1234", b"56789"]), 0xCBF4_3926);
    }
}

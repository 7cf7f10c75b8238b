//! Integers written in decimal through `core::fmt` without its integer formatter.
//!
//! On a board that logs through `core::fmt` (the emulated Cortex-M4), `u32`'s `Display` and the
//! padding it goes through (`Formatter::pad_integral`) take some 630 bytes of flash; [`Decimal`]
//! writes the same text a character at a time, for the few places that log an integer.

use core::fmt::{self, Write as _};

/// A `u32` in decimal, right-aligned in at least `width` characters (at most 10 count) filled
/// with `fill`: `Decimal::new(n)` writes what `{n}` writes, `Decimal::padded(n, 6, b' ')` what
/// `{n:>6}` does and `Decimal::padded(n, 6, b'0')` what `{n:06}` does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Decimal {
    value: u32,
    width: u8,
    fill: u8,
}

impl Decimal {
    /// `value` as `{value}` writes it.
    pub const fn new(value: u32) -> Self {
        Decimal {
            value,
            width: 0,
            fill: b' ',
        }
    }

    /// `value` right-aligned in `width` characters (10 at most: wider is 10), `fill` (an ASCII
    /// character) before its digits.
    pub const fn padded(value: u32, width: u8, fill: u8) -> Self {
        Decimal { value, width, fill }
    }
}

impl fmt::Display for Decimal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // u32::MAX has 10 digits. The text is built from its end, then written out.
        let mut text = [0u8; 10];
        let mut value = self.value;
        let mut start = text.len();
        for (written, slot) in text.iter_mut().rev().enumerate() {
            // The units digit always; then the other digits, then the fill up to the width.
            let used = value != 0 || written == 0;
            if !used && written >= usize::from(self.width) {
                break;
            }
            *slot = if used {
                b'0' + (value % 10) as u8
            } else {
                self.fill
            };
            value /= 10;
            start -= 1;
        }
        for &byte in text.iter().skip(start) {
            f.write_char(char::from(byte))?;
        }
        Ok(())
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Decimal {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "{=u32}", self.value)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::format;

    use super::Decimal;

    const VALUES: [u32; 16] = [
        0,
        1,
        9,
        10,
        99,
        100,
        12_345,
        99_999,
        100_000,
        999_999,
        1_000_000,
        4_000_000,
        123_456_789,
        1_000_000_000,
        u32::MAX - 1,
        u32::MAX,
    ];

    #[test]
    fn writes_what_u32_display_writes() {
        for value in VALUES.into_iter().chain(0..2000) {
            assert_eq!(format!("{}", Decimal::new(value)), format!("{value}"));
            assert_eq!(
                format!("{}", Decimal::padded(value, 6, b' ')),
                format!("{value:>6}")
            );
            assert_eq!(
                format!("{}", Decimal::padded(value, 6, b'0')),
                format!("{value:06}")
            );
            for width in 0..=10u8 {
                let w = usize::from(width);
                assert_eq!(
                    format!("{}", Decimal::padded(value, width, b'0')),
                    format!("{value:0w$}")
                );
            }
        }
    }

    #[test]
    fn wider_than_ten_is_ten() {
        assert_eq!(
            format!("{}", Decimal::padded(7, 12, b' ')),
            format!("{:>10}", 7)
        );
    }
}

//! CAN frames as the bus carries them: their data lengths, classic and CAN FD, and their
//! transmission times with worst-case bit stuffing (what `pabctl check`'s response times and
//! HBBA's bus costs count), and one frame's bits as it is actually sent, with the stuff bits its
//! own bits need ([`transmitted`]: what the simulator's timed bus counts).
//!
//! # Data lengths
//!
//! A classic frame carries 0 to [`CLASSIC_DATA_LEN`] bytes; a CAN FD frame 0 to 8, 12, 16, 20,
//! 24, 32, 48 or 64 ([`FD_DATA_LEN`]): its DLC codes 9 to 15 stand for the seven lengths above 8
//! (ISO 11898-1:2015, 10.4.2.4). Both constants and the table of lengths are `pab_core::frame`'s
//! ([`fd_length`]); not `pab_core::frame::MAX_DATA_LEN`, which is the length of the core's frame
//! buffer (64 with its feature `fd`, 8 without): a topic's length is a property of the bus,
//! whatever the buffer of the build.
//!
//! # A CAN FD frame's bits (ISO 11898-1:2015, clause 10.4, the FD base and extended formats)
//!
//! In the order sent, with the phase each bit is sent in when the frame switches its bit rate
//! (BRS recessive):
//!
//! | field | bits | phase | stuffing |
//! | --- | ---: | --- | --- |
//! | SOF | 1 | nominal | dynamic |
//! | base identifier | 11 | nominal | dynamic |
//! | extended format only: SRR, IDE, identifier extension | 1 + 1 + 18 | nominal | dynamic |
//! | RRS (an FD frame has no remote form: always dominant) | 1 | nominal | dynamic |
//! | base format only: IDE | 1 | nominal | dynamic |
//! | FDF (recessive: an FD frame), res | 1 + 1 | nominal | dynamic |
//! | BRS | 1 | nominal (see below) | dynamic |
//! | ESI, DLC | 1 + 4 | data | dynamic |
//! | data field | 8·s | data | dynamic |
//! | stuff count (3-bit Gray-coded count of the dynamic stuff bits, mod 8, and a parity bit) | 4 | data | fixed |
//! | CRC sequence: CRC-17 for s ≤ 16, CRC-21 above | 17 or 21 | data | fixed |
//! | fixed stuff bits: one before the stuff count, then one after every 4 bits of stuff count and CRC | 6 or 7 | data | — |
//! | CRC delimiter | 1 | data (see below) | — |
//! | ACK slot, ACK delimiter, EOF | 1 + 1 + 7 | nominal | — |
//! | intermission (the interframe space before the next frame's SOF) | 3 | nominal | — |
//!
//! That is 17 bits up to BRS in the base format and 36 in the extended one, 5 + 8s dynamically
//! stuffed bits after them, 4 + 17 + 6 = 27 or 4 + 21 + 7 = 32 bits of CRC field with its fixed
//! stuff bits, and 1 + 12 bits after it.
//!
//! **Where the rate switches.** The bit rate switches to the data rate at the sample point of BRS
//! and back at the sample point of the CRC delimiter (ISO 11898-1:2015, 10.4.2.3 and 10.4.2.5):
//! BRS's part up to its sample point is nominal time, the rest of it data time (the data bit
//! timing's phase segment 2), and the CRC delimiter's part up to its sample point data time,
//! the rest nominal. Both sample points sit at the same place of their bit timing, so the two
//! bits together last exactly one nominal bit and one data bit, whatever the sample points: BRS
//! is counted as a nominal bit and the CRC delimiter as a data bit.
//!
//! **Dynamic stuffing.** From SOF to the end of the data field a transmitter inserts a bit of the
//! opposite value after 5 equal bits, and the stuff bit starts the next run: at worst one after
//! the first 5 bits and one after every 4 bits from then on, ⌊(n − 1)/4⌋ over n bits (Davis et
//! al. 2007's bound, the Linux kernel's `can_bitstuffing_len`). The CRC field has no dynamic
//! stuffing: its fixed stuff bits are there whatever the bits. A stuff bit due after the last
//! bit of the data field is counted besides the first fixed stuff bit (whether the fixed bit
//! replaces it is not counted on: at most one bit too many, never one too few).
//!
//! **The worst case per phase.** With n_a bits up to BRS (17 or 36), the stuff bits inserted
//! after original bits 5, 9, 13, ... below n_a are sent at the nominal rate, ⌊(n_a − 2)/4⌋ of
//! them (3 or 8); a stuff bit after BRS itself is sent after the switch, at the data rate. That
//! pattern puts the most stuff bits both in the nominal phase and in the frame as a whole (every
//! prefix of it is as dense as stuffing allows), so it is the worst for any pair of rates (a
//! nominal bit lasts at least as long as a data bit). So:
//!
//! - nominal bits: n_a + ⌊(n_a − 2)/4⌋ + 12 = **32** in the base format, **56** in the extended
//!   one, whatever the data length;
//! - data bits: 5 + 8s, their share of the stuff bits ⌊(n_a + 5 + 8s − 1)/4⌋ − ⌊(n_a − 2)/4⌋
//!   (= 2s + 2 in both formats), the CRC field and the delimiter: **10s + 35** for s ≤ 16 and
//!   **10s + 40** above.
//!
//! In all, 10s + 67 bits for a base-format frame of s ≤ 16 bytes and 10s + 72 above (67, 147,
//! 187 and 712 for 0, 8, 12 and 64 bytes), 24 more in the extended format (91, 171, 736): the
//! Linux kernel's
//! `can_frame_bits(true, is_eff, true, true, len)` (include/linux/can/length.h, since 6.3,
//! worst-case bit stuffing and the intermission), which the tests compare with. Without bit-rate
//! switching every bit is nominal. A classic frame is [`frame_bits`]' (Davis et al. 2007,
//! eq. 2).

pub use pab_core::frame::{CLASSIC_DATA_LEN, FD_DATA_LEN};

/// The highest data bit rate of a CAN FD bus (`[bus] data_bitrate`): 8 Mbit/s, the fastest
/// data phase CAN FD controllers and transceivers commonly offer.
pub const MAX_DATA_BITRATE: u32 = 8_000_000;

/// The smallest CAN FD data length that holds `len` bytes (`len` itself up to 8, then 12, 16,
/// 20, 24, 32, 48, 64), `None` above 64.
pub fn fd_length(len: usize) -> Option<usize> {
    pab_core::frame::fd_length(len).map(usize::from)
}

/// Whether `len` is a CAN FD data length: 0 to 8, 12, 16, 20, 24, 32, 48 or 64.
pub fn is_fd_length(len: usize) -> bool {
    fd_length(len) == Some(len)
}

/// The bits of a classic CAN data frame of `length` data bytes (0..=8), with the worst-case bit
/// stuffing, including the 3-bit interframe space: g + 8s + 13 + ⌊(g + 8s − 1)/4⌋, g = 34 for
/// an 11-bit identifier and 54 for a 29-bit one (Davis et al. 2007, eq. 2): 55 + 10s and
/// 80 + 10s bits, 135 and 160 for 8 bytes.
pub const fn frame_bits(length: u8, extended: bool) -> u64 {
    let g: u64 = if extended { 54 } else { 34 };
    let s = length as u64;
    g + 8 * s + 13 + (g + 8 * s - 1) / 4
}

/// A CAN FD frame's bits with the worst-case bit stuffing, by phase (the module's table).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FdBits {
    /// Sent at the nominal bit rate: SOF to BRS with their stuff bits, ACK, EOF, intermission.
    pub nominal: u64,
    /// Sent at the data bit rate when the frame switches (BRS), else at the nominal rate too:
    /// ESI, DLC, the data field and their stuff bits, the CRC field with its fixed stuff bits,
    /// the CRC delimiter.
    pub data: u64,
}

impl FdBits {
    /// All of them.
    pub const fn total(&self) -> u64 {
        self.nominal + self.data
    }
}

/// The bits of a CAN FD data frame of `length` data bytes (rounded up to a CAN FD length, at
/// most 64) with the worst-case bit stuffing, the intermission included, by phase.
pub fn fd_frame_bits(length: u8, extended: bool) -> FdBits {
    let s = fd_length(usize::from(length)).unwrap_or(FD_DATA_LEN) as u64;
    // SOF to BRS.
    let arbitration: u64 = if extended { 36 } else { 17 };
    // ESI, DLC, data: the rest of the dynamically stuffed bits.
    let dynamic = 5 + 8 * s;
    let stuff_all = (arbitration + dynamic - 1) / 4;
    // Stuff bits after original bits 5, 9, ... before BRS: before the switch.
    let stuff_nominal = (arbitration - 2) / 4;
    let crc: u64 = if s <= 16 { 17 } else { 21 };
    // One before the stuff count, then one after every 4 bits of stuff count and CRC.
    let fixed_stuff = (4 + crc).div_ceil(4);
    // ACK slot, ACK delimiter, EOF, intermission.
    let tail = 1 + 1 + 7 + 3;
    FdBits {
        nominal: arbitration + stuff_nominal + tail,
        data: dynamic + (stuff_all - stuff_nominal) + 4 + crc + fixed_stuff + 1,
    }
}

/// The intermission: the 3 recessive nominal bits after a frame's EOF, before the next frame's
/// SOF may start (ISO 11898-1:2015, 10.4.5). Every count of this module includes it; a receiver
/// has the frame before it ([`Transmitted::to_end_of_frame`]).
pub const INTERMISSION_BITS: u64 = 3;

/// The bits one frame takes on the bus as a transmitter sends it ([`transmitted`]): its own bits
/// and the stuff bits that these very bits need, by phase, the intermission included.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Transmitted {
    /// Sent at the nominal rate: a classic frame's every bit; a CAN FD frame's SOF to BRS with
    /// their stuff bits, ACK, EOF and the intermission (and every bit without bit-rate switching).
    pub nominal: u64,
    /// Sent at the data rate: a CAN FD frame with bit-rate switching, from ESI to the CRC
    /// delimiter ([`FdBits::data`]'s fields). 0 for any other frame.
    pub data: u64,
    /// Of these, the stuff bits (dynamic, and a CAN FD frame's fixed ones in its CRC field).
    pub stuff: u64,
}

impl Transmitted {
    /// How long the frame occupies the bus, in the units of `base`, the intermission included:
    /// when the next frame may start.
    pub fn time(&self, base: &TimeBase) -> u64 {
        self.nominal * base.nominal + self.data * base.data
    }

    /// How long until its EOF has ended, in the units of `base`: when the receivers have the
    /// frame (the intermission that follows belongs to the bus, not to the frame).
    pub fn to_end_of_frame(&self, base: &TimeBase) -> u64 {
        self.time(base) - INTERMISSION_BITS * base.nominal
    }
}

/// The CAN CRC-15 (ISO 11898-1, polynomial x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1,
/// 0x4599, initial value 0) of `bits`, most significant first: a classic frame's CRC over its
/// unstuffed SOF, arbitration, control and data fields.
pub fn crc15(bits: impl IntoIterator<Item = bool>) -> u16 {
    let mut crc: u16 = 0;
    for bit in bits {
        let feedback = bit ^ (crc >> 14 & 1 == 1);
        crc = (crc << 1) & 0x7FFF;
        if feedback {
            crc ^= 0x4599;
        }
    }
    crc
}

/// `frame` built bit by bit as a transmitter sends it (ISO 11898-1:2015: a classic frame's base
/// or extended format, data or remote; a CAN FD frame's FD base or extended format, with or
/// without bit-rate switching: the fields of the module's table), its dynamic stuff bits
/// inserted where its own bits need them (after every 5 equal bits, the stuff bit starting the
/// next run: from SOF to the end of the CRC sequence in a classic frame, whose CRC-15 is computed
/// here as its receivers check it; from SOF to the end of the data field in a CAN FD frame), and
/// a CAN FD frame's fixed stuff bits. A CAN FD frame's stuff count and CRC do not change how many
/// bits it takes (their stuffing is fixed), so they are not computed. A stuff bit due right after
/// a CAN FD frame's data field is counted besides the first fixed stuff bit, as
/// [`fd_frame_bits`] counts it: at most one bit too many.
///
/// What the simulator's timed bus counts for each frame (`pabctl sim --timed-bus`); the tests
/// compare it with [`frame_bits`] and [`fd_frame_bits`], the worst cases, which it never exceeds.
pub fn transmitted(frame: &pab_core::Frame) -> Transmitted {
    fn push(fields: &mut Vec<(bool, bool)>, value: u64, count: u32, data_phase: bool) {
        for i in (0..count).rev() {
            fields.push(((value >> i) & 1 == 1, data_phase));
        }
    }
    let (id, extended) = frame.raw_id();
    let fd = frame.is_fd();
    let brs = fd && frame.is_brs();
    // (value, sent in the data phase), SOF to the last dynamically stuffed bit.
    let mut fields: Vec<(bool, bool)> = Vec::with_capacity(160 + 8 * FD_DATA_LEN);
    push(&mut fields, 0, 1, false); // SOF, dominant
    let base = if extended { id >> 18 } else { id };
    push(&mut fields, u64::from(base), 11, false);
    if extended {
        push(&mut fields, 1, 1, false); // SRR, recessive
        push(&mut fields, 1, 1, false); // IDE, recessive: extended
        push(&mut fields, u64::from(id & 0x3FFFF), 18, false);
    }
    if fd {
        push(&mut fields, 0, 1, false); // RRS: an FD frame has no remote form
        if !extended {
            push(&mut fields, 0, 1, false); // IDE, dominant: base format
        }
        push(&mut fields, 1, 1, false); // FDF, recessive: an FD frame
        push(&mut fields, 0, 1, false); // res
        push(&mut fields, u64::from(brs), 1, false); // BRS
        push(&mut fields, 0, 1, brs); // ESI: error active
        let length = frame.payload().len();
        let code = pab_core::frame::FD_LENGTHS
            .iter()
            .position(|&l| usize::from(l) == length)
            .unwrap_or(15);
        push(&mut fields, code as u64, 4, brs);
    } else {
        push(&mut fields, u64::from(frame.is_remote()), 1, false); // RTR
        // Extended format: r1, r0; base format: IDE (dominant), r0. Dominant all.
        push(&mut fields, 0, 2, false);
        push(
            &mut fields,
            embedded_can::Frame::dlc(frame) as u64,
            4,
            false,
        );
    }
    for &byte in frame.payload() {
        push(&mut fields, u64::from(byte), 8, brs);
    }
    if !fd {
        let crc = crc15(fields.iter().map(|&(bit, _)| bit));
        push(&mut fields, u64::from(crc), 15, false);
    }
    // Dynamic stuffing: a stuff bit is sent in the phase the bus is in after the bit before it
    // (after BRS, the last nominal bit of a switching frame: the data phase).
    let (mut nominal, mut data, mut stuff) = (0u64, 0u64, 0u64);
    let mut run: (Option<bool>, u32) = (None, 0);
    for (index, &(bit, data_phase)) in fields.iter().enumerate() {
        if data_phase {
            data += 1;
        } else {
            nominal += 1;
        }
        run = if run.0 == Some(bit) {
            (run.0, run.1 + 1)
        } else {
            (Some(bit), 1)
        };
        if run.1 == 5 {
            let after_switch = data_phase || fields.get(index + 1).is_some_and(|f| f.1);
            if after_switch {
                data += 1;
            } else {
                nominal += 1;
            }
            stuff += 1;
            run = (Some(!bit), 1);
        }
    }
    if fd {
        let crc: u64 = if frame.payload().len() <= 16 { 17 } else { 21 };
        // One fixed stuff bit before the stuff count, then one after every 4 bits of it and CRC.
        let fixed = (4 + crc).div_ceil(4);
        // Stuff count, CRC, fixed stuff bits, CRC delimiter: the data phase (module docs).
        let field = 4 + crc + fixed + 1;
        if brs {
            data += field;
        } else {
            nominal += field;
        }
        stuff += fixed;
    } else {
        nominal += 1; // CRC delimiter
    }
    // ACK slot and delimiter, EOF, intermission.
    nominal += 2 + 7 + INTERMISSION_BITS;
    Transmitted {
        nominal,
        data,
        stuff,
    }
}

/// The most time units a second of an analysis: 10^9 (a unit of 1 ns).
pub const MAX_UNITS_PER_SECOND: u64 = 1_000_000_000;

/// The unit of time in which a bus's frames are counted exactly: 1/`per_second` s, in which a
/// bit of the nominal (arbitration) rate lasts `nominal` units and a bit of the data phase
/// `data` units.
///
/// On a classic bus the unit is the bit time (`per_second` the bit rate, both bits 1 unit). On
/// a CAN FD bus it is 1/lcm(bitrate, data_bitrate) s, so that both bits are whole numbers of
/// units and a frame's time is exact: at 500 kbit/s and 2 Mbit/s, 0.5 µs, a nominal bit 4 units
/// and a data bit 1. When that least common multiple exceeds 10^9 a second (rates with no
/// common divisor to speak of, e.g. 999 999 and 8 000 000), the unit is 1 ns and each bit is
/// rounded up to whole nanoseconds: never shorter than it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TimeBase {
    /// Units a second.
    pub per_second: u64,
    /// A nominal bit, in units.
    pub nominal: u64,
    /// A data-phase bit, in units.
    pub data: u64,
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

impl TimeBase {
    /// The time base of a bus at `bitrate` (bit/s, at least 1) and, for CAN FD, `data_bitrate`
    /// (its data phase's; at least 1).
    pub fn new(bitrate: u32, data_bitrate: Option<u32>) -> TimeBase {
        let nominal_rate = u64::from(bitrate.max(1));
        let data_rate = data_bitrate.map_or(nominal_rate, |rate| u64::from(rate.max(1)));
        let lcm = nominal_rate / gcd(nominal_rate, data_rate) * data_rate;
        if lcm <= MAX_UNITS_PER_SECOND {
            TimeBase {
                per_second: lcm,
                nominal: lcm / nominal_rate,
                data: lcm / data_rate,
            }
        } else {
            TimeBase {
                per_second: MAX_UNITS_PER_SECOND,
                nominal: MAX_UNITS_PER_SECOND.div_ceil(nominal_rate),
                data: MAX_UNITS_PER_SECOND.div_ceil(data_rate),
            }
        }
    }

    /// The transmission time, in units, of a data frame of `length` bytes with worst-case
    /// stuffing and the intermission: a CAN FD frame when `fd` (its data phase at the data
    /// rate: with bit-rate switching whenever the data rate is above the nominal one), else a
    /// classic one (`length` at most 8).
    pub fn frame(&self, fd: bool, length: u8, extended: bool) -> u64 {
        if fd {
            let bits = fd_frame_bits(length, extended);
            bits.nominal * self.nominal + bits.data * self.data
        } else {
            frame_bits(length.min(CLASSIC_DATA_LEN as u8), extended) * self.nominal
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classic_frames_are_davis_et_al_s() {
        assert_eq!(frame_bits(8, false), 135);
        assert_eq!(frame_bits(8, true), 160);
        assert_eq!(frame_bits(0, false), 55);
        assert_eq!(frame_bits(0, true), 80);
        for s in 0..=8u8 {
            assert_eq!(frame_bits(s, false), 55 + 10 * u64::from(s));
            assert_eq!(frame_bits(s, true), 80 + 10 * u64::from(s));
        }
    }

    /// The Linux kernel's worst-case length of a CAN FD frame (include/linux/can/length.h,
    /// `can_frame_bits(true, is_eff, true, true, len)`): the header before the data field
    /// (22 bits base, 41 extended) and the data, stuffed at worst (n + ⌊(n − 1)/4⌋), then the
    /// CRC field with its stuff count, fixed stuff bits and delimiter (28 bits with CRC-17, 33
    /// with CRC-21), ACK, EOF (9) and the intermission (3).
    fn linux_can_frame_bits(extended: bool, len: u64) -> u64 {
        let header = if extended { 41 } else { 22 };
        let stuffed = header + 8 * len;
        let crc_field = if len <= 16 { 28 } else { 33 };
        stuffed + (stuffed - 1) / 4 + crc_field + 9 + 3
    }

    #[test]
    fn fd_frames_by_phase() {
        // Base format: 32 nominal bits whatever the length; 10s + 35 data bits (CRC-17), 10s + 40
        // (CRC-21).
        for (length, data) in [
            (0, 35),
            (8, 115),
            (12, 155),
            (16, 195),
            (20, 240),
            (64, 680),
        ] {
            assert_eq!(
                fd_frame_bits(length, false),
                FdBits { nominal: 32, data },
                "{length} bytes"
            );
            assert_eq!(fd_frame_bits(length, true), FdBits { nominal: 56, data });
        }
        // A length between two CAN FD lengths is sent as the next one (padded).
        assert_eq!(fd_frame_bits(9, false), fd_frame_bits(12, false));
        assert_eq!(fd_frame_bits(200, true), fd_frame_bits(64, true));
    }

    #[test]
    fn fd_frame_totals_are_the_linux_kernels() {
        for len in (0..=8).chain([12, 16, 20, 24, 32, 48, 64]) {
            for extended in [false, true] {
                assert_eq!(
                    fd_frame_bits(len as u8, extended).total(),
                    linux_can_frame_bits(extended, len),
                    "{len} bytes, extended {extended}"
                );
            }
        }
        assert_eq!(fd_frame_bits(0, false).total(), 67);
        assert_eq!(fd_frame_bits(8, false).total(), 147);
        assert_eq!(fd_frame_bits(12, false).total(), 187);
        assert_eq!(fd_frame_bits(64, false).total(), 712);
        assert_eq!(fd_frame_bits(64, true).total(), 736);
    }

    #[test]
    fn frame_times_with_and_without_bit_rate_switching() {
        // 500 kbit/s and 2 Mbit/s: units of 0.5 µs, a nominal bit 4 units, a data bit 1.
        let brs = TimeBase::new(500_000, Some(2_000_000));
        assert_eq!(
            brs,
            TimeBase {
                per_second: 2_000_000,
                nominal: 4,
                data: 1
            }
        );
        // 64 bytes, base format: 32 × 4 + 680 = 808 units = 404 µs (a classic 8-byte frame at
        // 500 kbit/s: 270 µs for an eighth of the data).
        assert_eq!(brs.frame(true, 64, false), 808);
        assert_eq!(brs.frame(true, 64, true), 56 * 4 + 680);
        assert_eq!(brs.frame(true, 0, false), 32 * 4 + 35);
        assert_eq!(brs.frame(true, 8, false), 32 * 4 + 115);
        assert_eq!(brs.frame(true, 12, true), 56 * 4 + 155);
        // A classic frame on that bus: its bits at the nominal rate.
        assert_eq!(brs.frame(false, 8, false), 135 * 4);
        // CAN FD without switching (the data rate the nominal one): every bit nominal.
        let plain = TimeBase::new(500_000, Some(500_000));
        assert_eq!(
            plain,
            TimeBase {
                per_second: 500_000,
                nominal: 1,
                data: 1
            }
        );
        assert_eq!(plain.frame(true, 64, false), 712);
        assert_eq!(plain.frame(true, 8, true), 171);
        // A classic bus: the unit is the bit.
        let classic = TimeBase::new(500_000, None);
        assert_eq!(classic, plain);
        assert_eq!(classic.frame(false, 8, true), 160);
        // Rates with a common multiple past 10^9 a second: 1 ns units, bits rounded up.
        let odd = TimeBase::new(999_999, Some(8_000_000));
        assert_eq!(
            odd,
            TimeBase {
                per_second: 1_000_000_000,
                nominal: 1001,
                data: 125
            }
        );
        // 1 Mbit/s and 5 Mbit/s: 0.2 µs units.
        assert_eq!(
            TimeBase::new(1_000_000, Some(5_000_000)),
            TimeBase {
                per_second: 5_000_000,
                nominal: 5,
                data: 1
            }
        );
        // 800 kbit/s and 2 Mbit/s: 0.25 µs units, 5 and 2 of them.
        assert_eq!(
            TimeBase::new(800_000, Some(2_000_000)),
            TimeBase {
                per_second: 4_000_000,
                nominal: 5,
                data: 2
            }
        );
    }

    /// A CAN FD frame with bit-rate switching as [`transmitted`] builds it, bit by bit: (nominal
    /// bits, data bits).
    fn fd_transmitted(id: u32, extended: bool, data: &[u8]) -> (u64, u64) {
        let frame = pab_core::Frame::fd(pab_core::frame::raw_id(id, extended).unwrap(), data, true)
            .unwrap();
        let bits = transmitted(&frame);
        (bits.nominal, bits.data)
    }

    /// CRC-15/CAN's check value (the CRC of the ASCII bytes "123456789"): 0x059E.
    #[test]
    fn the_crc_is_can_s() {
        let bits = b"123456789"
            .iter()
            .flat_map(|&byte| (0..8).rev().map(move |i| byte >> i & 1 == 1));
        assert_eq!(crc15(bits), 0x059E);
    }

    /// Frames whose stuffing can be counted by hand.
    #[test]
    fn frames_built_bit_by_bit_by_hand() {
        let standard =
            |id: u16| embedded_can::Id::Standard(embedded_can::StandardId::new(id).unwrap());
        // Standard id 0, no data: SOF, identifier, RTR, IDE, r0 and DLC are 19 dominant bits,
        // and their CRC-15 is 0: 34 dominant bits, a stuff bit after every 5 of them (each
        // stuff bit ends the run): 6, then 13 fixed-form bits with the intermission.
        let zero = pab_core::Frame::data(standard(0), &[]).unwrap();
        assert_eq!(
            transmitted(&zero),
            Transmitted {
                nominal: 34 + 6 + 13,
                data: 0,
                stuff: 6
            }
        );
        // Without stuff bits a classic frame is 47 + 8s bits (67 + 8s extended), intermission
        // included; a remote frame has no data field, whatever its DLC.
        let mut state = 0x1234_5678_9ABC_DEF1u64;
        for _ in 0..500 {
            let s = (next(&mut state) % 9) as usize;
            let data: Vec<u8> = (0..s).map(|_| next(&mut state) as u8).collect();
            let id = next(&mut state) as u32;
            let std = pab_core::Frame::data(standard((id & 0x7FF) as u16), &data).unwrap();
            let bits = transmitted(&std);
            assert_eq!(bits.nominal - bits.stuff, 47 + 8 * s as u64, "{std:?}");
            assert_eq!(bits.data, 0);
            let ext = pab_core::Frame::with_raw_id(id & 0x1FFF_FFFF, true, &data).unwrap();
            let bits = transmitted(&ext);
            assert_eq!(bits.nominal - bits.stuff, 67 + 8 * s as u64, "{ext:?}");
            let remote = <pab_core::Frame as embedded_can::Frame>::new_remote(
                pab_core::frame::raw_id(id & 0x1FFF_FFFF, true).unwrap(),
                s,
            )
            .unwrap();
            let bits = transmitted(&remote);
            assert_eq!(bits.nominal - bits.stuff, 67, "{remote:?}");
        }
        // A CAN FD frame without bit-rate switching: the same bits as with it, all nominal.
        let data = [0x0F; 12];
        let id = standard(0x141);
        let switching = transmitted(&pab_core::Frame::fd(id, &data, true).unwrap());
        let plain = transmitted(&pab_core::Frame::fd(id, &data, false).unwrap());
        assert_eq!(plain.data, 0);
        assert_eq!(plain.nominal, switching.nominal + switching.data);
        assert_eq!(plain.stuff, switching.stuff);
        // Its 32 bits of CRC field with 7 fixed stuff bits (CRC-21 above 16 bytes) and 6 below.
        let long = transmitted(&pab_core::Frame::fd(id, &[0x55; 20], true).unwrap());
        let short = transmitted(&pab_core::Frame::fd(id, &[0x55; 16], true).unwrap());
        // 0x55 never runs 5 equal bits: no dynamic stuff bit in the data, only in the header.
        assert_eq!(long.data - short.data, 32 + 4 + 1);
        assert_eq!(long.stuff - short.stuff, 1);
        // The time on a 500 kbit/s, 2 Mbit/s bus, and until the end of its EOF.
        let base = TimeBase::new(500_000, Some(2_000_000));
        assert_eq!(
            switching.time(&base),
            switching.nominal * 4 + switching.data
        );
        assert_eq!(
            switching.to_end_of_frame(&base),
            switching.time(&base) - 3 * 4
        );
    }

    /// Classic frames, built bit by bit with their CRC, never exceed Davis et al.'s bound
    /// ([`frame_bits`]), and the patterns that stuff the most come near it.
    #[test]
    fn classic_frames_built_bit_by_bit_stay_within_the_bound() {
        let mut state = 0x0DDB_1A5E_5BAD_5EEDu64;
        for length in 0..=8usize {
            for extended in [false, true] {
                let bound = frame_bits(length as u8, extended);
                let mut worst = 0;
                let mut check = |id: u32, data: &[u8]| {
                    let id = pab_core::frame::raw_id(
                        id & if extended { 0x1FFF_FFFF } else { 0x7FF },
                        extended,
                    )
                    .unwrap();
                    let frame = pab_core::Frame::data(id, data).unwrap();
                    let bits = transmitted(&frame);
                    assert_eq!(bits.data, 0);
                    assert!(bits.nominal <= bound, "{frame:?}: {bits:?} > {bound}");
                    worst = worst.max(bits.nominal);
                };
                for _ in 0..2000 {
                    let id = next(&mut state) as u32;
                    let data: Vec<u8> = (0..length).map(|_| next(&mut state) as u8).collect();
                    check(id, &data);
                }
                for shift in 0..8u32 {
                    for &pattern in &[0x0F0F_0F0Fu32, 0xF0F0_F0F0, 0x8787_8787, 0x7878_7878] {
                        let rotated = pattern.rotate_left(shift);
                        let data: Vec<u8> = (0..length)
                            .map(|i| rotated.rotate_left(8 * i as u32) as u8)
                            .collect();
                        check(rotated, &data);
                        check(0, &data);
                    }
                }
                // The CRC's 15 bits follow from the others, and the extended format's fixed
                // SRR, IDE (recessive), RTR, r1 and r0 (dominant) break the densest runs: the
                // worst frames found come within 7 bits of the bound (2 to 5 in the base
                // format), which takes every bit at its worst.
                assert!(
                    bound - worst <= 7,
                    "{length} bytes, extended {extended}: the worst frame found has {worst} bits, the bound {bound}"
                );
            }
        }
    }

    /// A small deterministic generator (xorshift), for the frames below.
    fn next(state: &mut u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state
    }

    /// Real frames, built bit by bit, never exceed the bound in either phase, and the patterns
    /// that stuff the most (runs of four, the stuff bit starting the next run) come within a
    /// few bits of it: 32 nominal bits are reached in the base format, 53 of the 56 in the
    /// extended one (the fixed SRR, IDE, RRS, FDF, res and BRS bits break the runs of four), and
    /// the data phase's bound within 2 bits.
    #[test]
    fn frames_built_bit_by_bit_stay_within_the_bound() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let lengths = [0usize, 1, 2, 5, 8, 12, 16, 20, 24, 32, 48, 64];
        for &length in &lengths {
            for extended in [false, true] {
                let bound = fd_frame_bits(length as u8, extended);
                let mut worst = (0, 0);
                let mut check = |id: u32, data: &[u8]| {
                    let (n, d) = fd_transmitted(id, extended, data);
                    assert!(
                        n <= bound.nominal && d <= bound.data,
                        "id {id:#x} {data:02x?}: {n} nominal, {d} data > {bound:?}"
                    );
                    worst = (worst.0.max(n), worst.1.max(d));
                };
                // Random frames.
                for _ in 0..2000 {
                    let id = (next(&mut state) as u32) & if extended { 0x1FFF_FFFF } else { 0x7FF };
                    let data: Vec<u8> = (0..length).map(|_| next(&mut state) as u8).collect();
                    check(id, &data);
                }
                // The densest stuffing: identifiers and data of runs of four equal bits after
                // the first run (0x0F, 0xF0 patterns and their shifts).
                for shift in 0..8u32 {
                    for &pattern in &[0x0F0F_0F0Fu32, 0xF0F0_F0F0, 0x8787_8787, 0x7878_7878] {
                        let rotated = pattern.rotate_left(shift);
                        let id = if extended {
                            rotated & 0x1FFF_FFFF
                        } else {
                            rotated & 0x7FF
                        };
                        let data: Vec<u8> = (0..length)
                            .map(|i| rotated.rotate_left(8 * i as u32) as u8)
                            .collect();
                        check(id, &data);
                        check(0, &data);
                    }
                }
                // Real frames come within 3 nominal bits and 2 data bits of the bound: it is
                // tight enough to be worth having.
                assert!(
                    bound.nominal - worst.0 <= 3 && bound.data - worst.1 <= 2,
                    "{length} bytes, extended {extended}: the worst frames found have {} nominal and {} data bits, the bound {bound:?}",
                    worst.0,
                    worst.1
                );
            }
        }
    }
}

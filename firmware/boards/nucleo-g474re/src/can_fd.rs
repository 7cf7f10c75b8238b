//! CAN FD on FDCAN1 (feature `fd`): the data phase's bit timing and the transmitter delay
//! compensation. Derived from the reference manual (RM0440, section 44 "FD controller area
//! network") and ST's AN5348; not run on hardware (docs/nucleo-g474re.md).
//!
//! The data phase runs at [`DATA_BITRATE`], 2 Mbit/s, the rate CiA 601-3 and most CAN FD robot
//! buses use with a 500 kbit/s arbitration phase: 24 MHz (the HSE, the FDCAN's kernel clock) /
//! 2 Mbit/s = 12 time quanta of one clock each, 1 (sync) + 8 + 3, the sample point at 9/12 =
//! 75 % (CiA 601-3 recommends 70-80 % in the data phase), SJW 3. Every node of the bus needs
//! the same data rate and the same sample point within a few per cent: `[bus] data_bitrate` in
//! the network file says what the bus runs, and `pabctl check` computes its response times.
//!
//! Without `fd` the controller stays classic and this module is not built.

use core::num::{NonZeroU8, NonZeroU16};

use embassy_stm32::can::config::DataBitTiming;

use crate::HSE_HZ;

/// The data phase's bit rate, bit/s.
pub const DATA_BITRATE: u32 = 2_000_000;
/// Time quanta per data bit: 1 (sync) + [`DATA_SEG1`] + [`DATA_SEG2`].
const DATA_TQ_PER_BIT: u32 = 12;
const DATA_SEG1: u8 = 8;
const DATA_SEG2: u8 = 3;
/// Resynchronization jump width in the data phase, in time quanta (at most [`DATA_SEG2`]).
const DATA_SJW: u8 = 3;
/// Clock cycles per time quantum in the data phase.
const DATA_PRESCALER: u32 = HSE_HZ / (DATA_BITRATE * DATA_TQ_PER_BIT);
const _: () = assert!(
    1 + DATA_SEG1 as u32 + DATA_SEG2 as u32 == DATA_TQ_PER_BIT
        && DATA_SJW <= DATA_SEG2
        && DATA_PRESCALER * DATA_BITRATE * DATA_TQ_PER_BIT == HSE_HZ,
    "the data bit timing must divide the kernel clock exactly"
);

/// The data phase's bit timing.
pub fn data_bit_timing() -> DataBitTiming {
    DataBitTiming {
        // Not written by embassy-stm32 0.6 on the G4 (its DBTP write leaves TDC clear):
        // [`compensate_transceiver_delay`] sets it.
        transceiver_delay_compensation: true,
        prescaler: NonZeroU16::new(DATA_PRESCALER as u16).unwrap_or(NonZeroU16::MIN),
        seg1: NonZeroU8::new(DATA_SEG1).unwrap_or(NonZeroU8::MIN),
        seg2: NonZeroU8::new(DATA_SEG2).unwrap_or(NonZeroU8::MIN),
        sync_jump_width: NonZeroU8::new(DATA_SJW).unwrap_or(NonZeroU8::MIN),
    }
}

/// The transmitter delay compensation offset, in kernel clock cycles: the data sample point's
/// position in the bit, (1 + [`DATA_SEG1`]) quanta of [`DATA_PRESCALER`] cycles.
///
/// Why it is needed: in the data phase the transmitter checks each bit it sends against what it
/// reads back, and the transceiver's loop delay (typically 100 to 250 ns, TX pin to RX pin) is
/// about half a 2 Mbit/s bit (500 ns): read at the ordinary sample point, the echo of one bit
/// could be taken for the next and flagged as a bit error. With compensation the controller
/// measures the loop delay at each FD frame's FDF-to-res edge and checks at that delay plus this
/// offset (RM0440: secondary sample point = measured delay + TDCO).
const TDC_OFFSET: u8 = (1 + DATA_SEG1) * DATA_PRESCALER as u8;

/// Turns on the transmitter delay compensation (DBTP.TDC, TDCR.TDCO), which embassy-stm32 0.6
/// does not set on the G4: in configuration mode (CCCR.INIT and CCE, which only INIT allows),
/// right after the controller was started, before the node sends anything.
pub fn compensate_transceiver_delay() {
    let regs = embassy_stm32::pac::FDCAN1;
    regs.cccr().modify(|w| w.set_init(true));
    while !regs.cccr().read().init() {}
    regs.cccr().modify(|w| w.set_cce(true));
    regs.dbtp().modify(|w| w.set_tdc(true));
    // TDCF (the filter window) left 0: no filter.
    regs.tdcr().write(|w| w.set_tdco(TDC_OFFSET));
    regs.cccr().modify(|w| w.set_init(false));
}

//! Logging that forwards to `defmt` on the boards and to `log` on Linux (embassy's habit), so the
//! application logs the same way wherever it runs. With neither feature, logging compiles away.
//!
//! Integers are logged as `u32` (`u32::from(byte)`), through [`int`]: under `log` on the emulated
//! board each integer type brings its own `core::fmt` formatter into the flash (u8's and u16's,
//! some 250 bytes), and with [`int`] none does.
#![allow(unused_macros)]

#[cfg(all(feature = "defmt", feature = "log"))]
compile_error!("enable at most one of the `defmt` and `log` features");

macro_rules! debug {
    ($s:literal $(, $x:expr)* $(,)?) => {{
        #[cfg(feature = "defmt")]
        ::defmt::debug!($s $(, $x)*);
        #[cfg(feature = "log")]
        ::log::debug!($s $(, $x)*);
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = ($( & $x ),*);
    }};
}

macro_rules! info {
    ($s:literal $(, $x:expr)* $(,)?) => {{
        #[cfg(feature = "defmt")]
        ::defmt::info!($s $(, $x)*);
        #[cfg(feature = "log")]
        ::log::info!($s $(, $x)*);
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = ($( & $x ),*);
    }};
}

macro_rules! warn {
    ($s:literal $(, $x:expr)* $(,)?) => {{
        #[cfg(feature = "defmt")]
        ::defmt::warn!($s $(, $x)*);
        #[cfg(feature = "log")]
        ::log::warn!($s $(, $x)*);
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = ($( & $x ),*);
    }};
}

/// An integer for a log message: the same digits as `{}` of the `u32`. Under `log`, through
/// [`pab_core::decimal::Decimal`], so that the emulated board needs no `core::fmt` integer
/// formatter (u32's and its padding, some 630 bytes of flash); under `defmt`, the `u32` itself
/// (defmt sends it in binary).
#[cfg(feature = "log")]
pub(crate) const fn int(value: u32) -> pab_core::decimal::Decimal {
    pab_core::decimal::Decimal::new(value)
}

/// An integer for a log message (see the `log` build's): the `u32` itself.
#[cfg(not(feature = "log"))]
pub(crate) const fn int(value: u32) -> u32 {
    value
}

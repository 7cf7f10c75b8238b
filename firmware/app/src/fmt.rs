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
        // Debug's messages may be per frame: compared with the maximum level before their
        // arguments are put together (info's and warn's, a few per boot or table, are compared
        // in `log`).
        #[cfg(feature = "log")]
        if ::log::Level::Debug <= ::log::STATIC_MAX_LEVEL && ::log::Level::Debug <= ::log::max_level() {
            $crate::fmt::log(::log::Level::Debug, module_path!(), format_args!($s $(, $x)*));
        }
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = ($( & $x ),*);
    }};
}

macro_rules! info {
    ($s:literal $(, $x:expr)* $(,)?) => {{
        #[cfg(feature = "defmt")]
        ::defmt::info!($s $(, $x)*);
        #[cfg(feature = "log")]
        $crate::fmt::log(::log::Level::Info, module_path!(), format_args!($s $(, $x)*));
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = ($( & $x ),*);
    }};
}

macro_rules! warn {
    ($s:literal $(, $x:expr)* $(,)?) => {{
        #[cfg(feature = "defmt")]
        ::defmt::warn!($s $(, $x)*);
        #[cfg(feature = "log")]
        $crate::fmt::log(::log::Level::Warn, module_path!(), format_args!($s $(, $x)*));
        #[cfg(not(any(feature = "defmt", feature = "log")))]
        let _ = ($( & $x ),*);
    }};
}

/// A message for `log`, out of line: what `log`'s macros do at each call site (the level compared
/// with the maximum, a [`log::Record`] built and handed to the logger), done here once. `log`'s
/// macros leave at each site the comparison and a tuple of the target, the module path and the
/// caller's [`Location`](core::panic::Location) built on the stack, and a `Location` in the flash:
/// some 70 bytes a site on the emulated board, for a dozen sites. Public for the boards' own
/// messages (the emulated board's boot line), which then share it.
///
/// Hosted (the Linux node, tests), the record is the one `log`'s macros make: the module's path
/// as its target and module path, the caller's file and line (through `#[track_caller]`). On the
/// bare-metal boards, whose logger prints the level and the message only (the emulated board's
/// `logger.rs`; the G474 logs through defmt), the record's target and module path are `pab_app`,
/// whoever calls, and it has no file or line, so that the call sites pass neither.
#[cfg(feature = "log")]
#[inline(never)]
#[cfg_attr(not(target_os = "none"), track_caller)]
pub fn log(level: log::Level, module_path: &'static str, args: core::fmt::Arguments<'_>) {
    if level > log::STATIC_MAX_LEVEL || level > log::max_level() {
        return;
    }
    let mut record = log::Record::builder();
    #[cfg(not(target_os = "none"))]
    {
        let location = core::panic::Location::caller();
        record
            .target(module_path)
            .module_path_static(Some(module_path))
            .file_static(Some(location.file()))
            .line(Some(location.line()));
    }
    #[cfg(target_os = "none")]
    {
        let _ = module_path;
        record.target("pab_app").module_path_static(Some("pab_app"));
    }
    log::logger().log(&record.args(args).level(level).build());
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

/// A protocol code for a log message (a transfer status, an authentication failure, a store
/// error): `value` itself where its words cost the flash nothing, its `number` (the code on the
/// wire, which the protocol document lists, here in decimal) on a bare-metal board that logs
/// through `log`, the emulated board. There the `Display` words of the codes logged took 2 056 bytes of its flash,
/// which defmt keeps out of the NUCLEO boards' (their logs print the names) and a host has room
/// for (`pab-node` prints the words).
#[cfg(all(feature = "log", target_os = "none"))]
pub(crate) fn code<T>(_value: T, number: u8) -> pab_core::decimal::Decimal {
    int(u32::from(number))
}

/// A protocol code for a log message (see the emulated board's): `value` itself.
#[cfg(not(all(feature = "log", target_os = "none")))]
pub(crate) fn code<T>(value: T, _number: u8) -> T {
    value
}

//! The host's services through semihosting: console output and the exit status. Only under
//! QEMU (`-semihosting-config enable=on`) or a debugger; on a bare board a semihosting call
//! halts at a breakpoint.

use core::fmt::Write as _;

use cortex_m_semihosting::{debug, hio};

/// Writes `text` to the host's standard error (QEMU's stderr). Slow: a trap into the emulator
/// per call. Errors are ignored: there is nobody to report them to.
pub fn eprint(text: core::fmt::Arguments<'_>) {
    if let Ok(mut stderr) = hio::hstderr() {
        let _ = stderr.write_fmt(text);
    }
}

/// Writes `text` to the host's standard error as it is, in one call: [`eprint`] without the
/// formatting.
pub fn eprint_str(text: &str) {
    if let Ok(mut stderr) = hio::hstderr() {
        let _ = stderr.write_str(text);
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

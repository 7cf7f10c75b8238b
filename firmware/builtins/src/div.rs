//! `__aeabi_uldivmod`, the unsigned 64-bit division the compiler calls for `u64 / u64` and
//! `u64 % u64` on a 32-bit Arm core: 90 bytes of Thumb-2 instead of compiler_builtins' 930
//! (`__aeabi_uldivmod`, `__udivmoddi4` and the 864-byte `u64_div_rem` behind them).
//!
//! Why it is enough: the boards divide 64-bit values rarely and mostly by small divisors. The
//! FDCAN driver turns each received frame's timestamp into microseconds (nanoseconds / 1 000),
//! the node its uptime into seconds once a heartbeat, the loader a time constant into a rate
//! once per table. When both operands fit 32 bits (the driver's case) it is one `udiv` and one
//! `mls`; otherwise a restoring division, one quotient bit per round (64 rounds of 11
//! instructions, some 700 in all: once a second for the heartbeat).
//!
//! The AEABI contract: numerator in r0:r1, denominator in r2:r3 (low word first); quotient back
//! in r0:r1, remainder in r2:r3. Rust never divides by zero (it checks first, and panics or
//! returns `None`); should a zero come anyway, the quotient is all ones and the remainder the
//! numerator, as the hardware `udiv` would say for the 32-bit case (quotient 0 there: Cortex-M
//! `udiv` by zero gives 0 unless DIV_0_TRP is set). Checked on the emulated board by
//! `pab-an386-builtinscheck` against a reference in Rust.

#[cfg(all(target_arch = "arm", target_os = "none"))]
core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    ".section .text.pab_uldivmod,\"ax\",%progbits",
    ".global __aeabi_uldivmod",
    ".type __aeabi_uldivmod,%function",
    ".thumb_func",
    "__aeabi_uldivmod:",
    // Both high words zero: the 32-bit division of the core.
    "    orrs ip, r1, r3",
    "    bne 1f",
    "    udiv ip, r0, r2",
    "    mls r2, ip, r2, r0",
    "    mov r0, ip",
    "    movs r3, #0",
    "    bx lr",
    "1:  push {{r4, r5, r6, lr}}",
    // A denominator of 2^63 or more: the quotient is 0 or 1 (and the shifted remainder of the
    // loop below could overflow 64 bits).
    "    tst r3, #0x80000000",
    "    bne 4f",
    // Restoring division: the numerator shifts left through the remainder (r5:r4), one bit a
    // round; where the remainder reaches the denominator it is taken off, and the quotient bit
    // (the numerator's bit 0, free after the shift) set. The remainder stays below the
    // denominator (< 2^63), so its shift cannot overflow.
    "    movs r4, #0",
    "    movs r5, #0",
    "    movs r6, #64",
    "2:  adds r0, r0, r0",
    "    adcs r1, r1, r1",
    "    adcs r4, r4, r4",
    "    adc r5, r5, r5",
    "    subs ip, r4, r2",
    "    sbcs lr, r5, r3",
    "    ittt hs",
    "    movhs r4, ip",
    "    movhs r5, lr",
    "    orrhs r0, r0, #1",
    "    subs r6, r6, #1",
    "    bne 2b",
    "    mov r2, r4",
    "    mov r3, r5",
    "    pop {{r4, r5, r6, pc}}",
    // Numerator minus denominator: no borrow means quotient 1 and that difference as remainder.
    "4:  subs ip, r0, r2",
    "    sbcs lr, r1, r3",
    "    ite hs",
    "    movhs r2, ip",
    "    movlo r2, r0",
    "    ite hs",
    "    movhs r3, lr",
    "    movlo r3, r1",
    "    ite hs",
    "    movhs r0, #1",
    "    movlo r0, #0",
    "    movs r1, #0",
    "    pop {{r4, r5, r6, pc}}",
    ".size __aeabi_uldivmod, . - __aeabi_uldivmod",
);

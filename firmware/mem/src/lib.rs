//! # pab-mem: compact `memcpy` and `memset` for the boards
//!
//! The boards' firmware copies and clears memory through the C symbols `memcpy`, `memset` and
//! their AEABI forms (`__aeabi_memcpy`, `__aeabi_memcpy4`/`8`, `__aeabi_memset`,
//! `__aeabi_memset4`/`8`, `__aeabi_memclr`, `__aeabi_memclr4`/`8`), which the compiler calls
//! for struct moves, array initialisation and slice copies. Rust's `compiler_builtins` defines
//! them as weak symbols, tuned for throughput on large blocks: 1 800 bytes of flash on a
//! Cortex-M4. This crate defines them (strong symbols, so the linker takes these) in 150 bytes of
//! Thumb-2: a word loop when the addresses allow it, a byte loop otherwise. `memcmp` and
//! `memmove` stay `compiler_builtins`'.
//!
//! Why it is worth it: 1.6 KB is a quarter of what competitive dynamics needed to fit the
//! boards' 64 KiB, and the boards' copies are small (frames, records, a table's entries): the
//! large ones (a table swap, the node's construction at boot) run once per configuration.
//! Measured on the emulated board (scripts/cortex-m4-cost.sh): no counted path changed by an
//! instruction.
//!
//! Cost: 5 instructions per word (4-byte aligned destination and source), 5 per byte otherwise,
//! plus 6 to 9 per call. `memset` aligns its destination with bytes first, then stores words.
//!
//! Written in assembly rather than Rust because a Rust loop that copies bytes is recognised by
//! LLVM as a copy and compiled into a call to `memcpy`, itself. Checked on the emulated board by
//! `pab-an386-memcheck` (every alignment of destination and source, every length up to 72,
//! the bytes around the destination untouched, the return values).
//!
//! Only for `thumbv7em` targets without an operating system (the boards); on any other target
//! the crate is empty. A board crate links it with `use pab_mem as _;`.

#![no_std]

#[cfg(all(target_arch = "arm", target_os = "none"))]
core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    // memcpy(dest, src, n) -> dest; __aeabi_memcpy(dest, src, n), no result. r0-r3 and ip
    // (r12) are the caller's to lose (AAPCS): ip keeps memcpy's result, r3 the word in transit.
    ".section .text.pab_mem_copy,\"ax\",%progbits",
    ".global memcpy",
    ".global __aeabi_memcpy",
    ".global __aeabi_memcpy4",
    ".global __aeabi_memcpy8",
    ".type memcpy,%function",
    ".type __aeabi_memcpy,%function",
    ".type __aeabi_memcpy4,%function",
    ".type __aeabi_memcpy8,%function",
    ".thumb_func",
    "memcpy:",
    "    mov ip, r0",
    ".thumb_func",
    "__aeabi_memcpy:",
    // Words only when both addresses are 4-byte aligned: an unaligned word access is legal on
    // a Cortex-M4 for normal memory only, and a copy may touch device memory.
    "    orr r3, r0, r1",
    "    lsls r3, r3, #30",
    "    bne 2f",
    ".thumb_func",
    "__aeabi_memcpy4:",
    ".thumb_func",
    "__aeabi_memcpy8:",
    "1:  subs r2, r2, #4",
    "    itt hs",
    "    ldrhs r3, [r1], #4",
    "    strhs r3, [r0], #4",
    "    bhs 1b",
    "    adds r2, r2, #4",
    "2:  subs r2, r2, #1",
    "    itt hs",
    "    ldrbhs r3, [r1], #1",
    "    strbhs r3, [r0], #1",
    "    bhs 2b",
    "    mov r0, ip",
    "    bx lr",
    ".size memcpy, . - memcpy",
    // memset(dest, c, n) -> dest; __aeabi_memset(dest, n, c) (the AEABI swaps the last two);
    // __aeabi_memclr(dest, n) is __aeabi_memset(dest, n, 0).
    ".section .text.pab_mem_set,\"ax\",%progbits",
    ".global memset",
    ".global __aeabi_memset",
    ".global __aeabi_memset4",
    ".global __aeabi_memset8",
    ".global __aeabi_memclr",
    ".global __aeabi_memclr4",
    ".global __aeabi_memclr8",
    ".type memset,%function",
    ".type __aeabi_memset,%function",
    ".type __aeabi_memset4,%function",
    ".type __aeabi_memset8,%function",
    ".type __aeabi_memclr,%function",
    ".type __aeabi_memclr4,%function",
    ".type __aeabi_memclr8,%function",
    ".thumb_func",
    "__aeabi_memclr:",
    ".thumb_func",
    "__aeabi_memclr4:",
    ".thumb_func",
    "__aeabi_memclr8:",
    "    movs r2, #0",
    "    b __aeabi_memset",
    ".thumb_func",
    "memset:",
    "    mov ip, r0",
    "    mov r3, r1",
    "    mov r1, r2",
    "    mov r2, r3",
    ".thumb_func",
    "__aeabi_memset:",
    ".thumb_func",
    "__aeabi_memset4:",
    ".thumb_func",
    "__aeabi_memset8:",
    // The byte (C passes an int) in all four lanes of r2.
    "    uxtb r2, r2",
    "    orr r2, r2, r2, lsl #8",
    "    orr r2, r2, r2, lsl #16",
    // Bytes up to the first 4-byte boundary, then words, then the last bytes.
    "0:  lsls r3, r0, #30",
    "    beq 1f",
    "    subs r1, r1, #1",
    "    blo 3f",
    "    strb r2, [r0], #1",
    "    b 0b",
    "1:  subs r1, r1, #4",
    "    it hs",
    "    strhs r2, [r0], #4",
    "    bhs 1b",
    "    adds r1, r1, #4",
    "2:  subs r1, r1, #1",
    "    it hs",
    "    strbhs r2, [r0], #1",
    "    bhs 2b",
    "3:  mov r0, ip",
    "    bx lr",
    ".size __aeabi_memclr, . - __aeabi_memclr",
);

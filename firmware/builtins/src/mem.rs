//! `memcpy` and `memset` and their AEABI forms (`__aeabi_memcpy`, `__aeabi_memcpy4`/`8`,
//! `__aeabi_memset`, `__aeabi_memset4`/`8`, `__aeabi_memclr`, `__aeabi_memclr4`/`8`), which the
//! compiler calls for struct moves, array initialisation and slice copies: 150 bytes of Thumb-2
//! instead of compiler_builtins' 1 800, tuned for throughput on large blocks; and `memcmp`, byte
//! by byte (what the boards compare is a few bytes: a filter, a key's tag); and `memmove` and
//! its AEABI forms: `memcpy` when the destination does not start inside the source, a byte loop
//! from the end otherwise (28 bytes instead of compiler_builtins' 1 574, which a copy between two
//! fields of one struct, such as the schema server's attractor := measured pose, pulls in).
//!
//! Why it is enough: the boards' copies are small (frames, records, a table's entries); the large
//! ones (a table swap, the node's construction at boot) run once per configuration. Measured on
//! the emulated board (scripts/cortex-m4-cost.sh): no frame path changed by an instruction; the
//! authentication's block copies cost a few per cent more (a command's tag 9 747 -> 10 096
//! instructions).
//!
//! Cost: 5 instructions per word (4-byte aligned destination and source), 5 per byte otherwise,
//! plus 6 to 9 per call. `memset` aligns its destination with bytes first, then stores words.
//!
//! Written in assembly rather than Rust because a Rust loop that copies bytes is recognised by
//! LLVM as a copy and compiled into a call to `memcpy`, itself.

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
    // memmove(dest, src, n) -> dest; __aeabi_memmove*(dest, src, n). dest − src (unsigned) ≥ n
    // means the destination does not start inside the source: a forward copy is right (dest
    // below src wraps to a large difference), and memcpy keeps dest for the result. Otherwise
    // bytes from the last down.
    ".section .text.pab_mem_move,\"ax\",%progbits",
    ".global memmove",
    ".global __aeabi_memmove",
    ".global __aeabi_memmove4",
    ".global __aeabi_memmove8",
    ".type memmove,%function",
    ".type __aeabi_memmove,%function",
    ".type __aeabi_memmove4,%function",
    ".type __aeabi_memmove8,%function",
    ".thumb_func",
    "memmove:",
    ".thumb_func",
    "__aeabi_memmove:",
    ".thumb_func",
    "__aeabi_memmove4:",
    ".thumb_func",
    "__aeabi_memmove8:",
    "    subs r3, r0, r1",
    "    cmp r3, r2",
    "    bhs memcpy",
    "1:  subs r2, r2, #1",
    "    itt hs",
    "    ldrbhs r3, [r1, r2]",
    "    strbhs r3, [r0, r2]",
    "    bhs 1b",
    "    bx lr",
    ".size memmove, . - memmove",
    // memcmp(a, b, n) -> the difference of the first bytes that differ (as unsigned chars),
    // or 0.
    ".section .text.pab_mem_compare,\"ax\",%progbits",
    ".global memcmp",
    ".type memcmp,%function",
    ".thumb_func",
    "memcmp:",
    "1:  subs r2, r2, #1",
    "    blo 2f",
    "    ldrb r3, [r0], #1",
    "    ldrb ip, [r1], #1",
    "    subs r3, r3, ip",
    "    beq 1b",
    "    mov r0, r3",
    "    bx lr",
    "2:  movs r0, #0",
    "    bx lr",
    ".size memcmp, . - memcmp",
);

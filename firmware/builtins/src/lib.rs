//! # pab-builtins: compact runtime routines for the boards
//!
//! The compiler calls a few routines it does not inline: memory copies, fills and comparisons,
//! and 64-bit division on a 32-bit core. Rust's `compiler_builtins` defines them as weak symbols,
//! written for throughput on large operands: 2.8 KB of a board's 64 KiB of flash. This crate
//! defines the ones the boards use as strong symbols (the linker takes these) in some 270 bytes
//! of Thumb-2, fast where the boards' calls are (small copies, divisions whose operands fit 32
//! bits):
//!
//! - [`mem`]: `memcpy`, `memset` and their AEABI forms, `memcmp`;
//! - [`div`]: `__aeabi_uldivmod`, `u64 / u64` and `u64 % u64`.
//!
//! Assembly, not Rust, for two reasons: LLVM recognises a Rust copy loop as a copy and compiles
//! it into a call to `memcpy`, itself; and a division's register contract (AEABI: quotient and
//! remainder back in r0-r3) has no Rust signature. Checked on the emulated board by
//! `pab-an386-builtinscheck` (every alignment and length of the copies, fills and comparisons,
//! the bytes around untouched; divisions against a reference in Rust on edge cases and random operands of
//! every width).
//!
//! Only for Arm targets without an operating system (the boards); elsewhere the crate is empty.
//! A board crate links it with `use pab_builtins as _;`.

#![no_std]

pub mod div;
pub mod mem;

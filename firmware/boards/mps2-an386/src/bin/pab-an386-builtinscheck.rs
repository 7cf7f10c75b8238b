//! Checks pab-builtins' routines on the emulated Cortex-M4, where they run:
//!
//! - `memcpy` and `memset` and their AEABI forms: every entry point, at every alignment of
//!   destination and source (0 to 7 bytes past an 8-byte boundary; the `4`/`8` forms only where
//!   the AEABI promises it), every length from 0 to 72 bytes. Each call must write exactly its
//!   bytes (compared with a reference that copies one volatile byte at a time, so that it cannot
//!   itself become a `memcpy` call), leave the bytes around them alone, and return the
//!   destination where C says it does;
//! - `memmove` and its AEABI forms: within one buffer, every destination and source offset from
//!   0 to 15 (overlapping either way, or not; the `4`/`8` forms where both are so aligned),
//!   every length from 0 to 72: the destination must hold the source's bytes as they were, and
//!   nothing else may change;
//! - `u64 / u64` and `u64 % u64` (`__aeabi_uldivmod`): quotient and remainder against a
//!   shift-and-subtract reference in Rust, on edge cases (0, 1, 2^32 ± 1, 2^63, `u64::MAX`, a
//!   numerator below, equal to or one above the denominator) and on 200 000 pseudo-random pairs
//!   of every width of either operand.
//!
//! Exits 0, or 1 with the first failure on standard error:
//!
//!     cargo run --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
//!         --bin pab-an386-builtinscheck

#![no_std]
#![no_main]

use core::hint::black_box;
use core::ptr::{read_volatile, write_volatile};

use pab_fw_an386::semihosting;

// The entry points under test, as the compiler's calls reach them (pab-builtins, linked through
// pab_fw_an386).
unsafe extern "C" {
    fn memcpy(dest: *mut u8, src: *const u8, n: usize) -> *mut u8;
    fn memset(dest: *mut u8, c: i32, n: usize) -> *mut u8;
    fn memcmp(a: *const u8, b: *const u8, n: usize) -> i32;
    fn memmove(dest: *mut u8, src: *const u8, n: usize) -> *mut u8;
    fn __aeabi_memmove(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memmove4(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memmove8(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memcpy(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memcpy4(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memcpy8(dest: *mut u8, src: *const u8, n: usize);
    fn __aeabi_memset(dest: *mut u8, n: usize, c: i32);
    fn __aeabi_memset4(dest: *mut u8, n: usize, c: i32);
    fn __aeabi_memset8(dest: *mut u8, n: usize, c: i32);
    fn __aeabi_memclr(dest: *mut u8, n: usize);
    fn __aeabi_memclr4(dest: *mut u8, n: usize);
    fn __aeabi_memclr8(dest: *mut u8, n: usize);
}

type Copying = unsafe extern "C" fn(*mut u8, *const u8, usize) -> *mut u8;
type AeabiCopying = unsafe extern "C" fn(*mut u8, *const u8, usize);
type Comparing = unsafe extern "C" fn(*const u8, *const u8, usize) -> i32;
type Setting = unsafe extern "C" fn(*mut u8, i32, usize) -> *mut u8;
type AeabiSetting = unsafe extern "C" fn(*mut u8, usize, i32);
type Clearing = unsafe extern "C" fn(*mut u8, usize);

const MAX_LEN: usize = 72;
const OFFSETS: usize = 8;
/// Room for the largest offset and length, and a guard byte on each side.
const SIZE: usize = MAX_LEN + OFFSETS + 16;
/// What the destination holds outside the bytes written.
const GUARD: u8 = 0xA5;

#[repr(C, align(8))]
struct Buffer([u8; SIZE]);

#[derive(Clone, Copy)]
enum Copy {
    Memcpy,
    Aeabi,
    Aeabi4,
    Aeabi8,
}

#[derive(Clone, Copy)]
enum Set {
    Memset,
    Aeabi,
    Aeabi4,
    Aeabi8,
    Clear,
    Clear4,
    Clear8,
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let mut src = Buffer([0; SIZE]);
    let mut dest = Buffer([0; SIZE]);
    for (i, byte) in src.0.iter_mut().enumerate() {
        // Distinct, and never the guard: a byte written from the wrong place shows.
        *byte = (i as u8).wrapping_mul(7).wrapping_add(1) | 0x40;
    }
    let mut calls: u32 = 0;
    for copy in [Copy::Memcpy, Copy::Aeabi, Copy::Aeabi4, Copy::Aeabi8] {
        let align = match copy {
            Copy::Memcpy | Copy::Aeabi => 1,
            Copy::Aeabi4 => 4,
            Copy::Aeabi8 => 8,
        };
        for d in (0..OFFSETS).step_by(align) {
            for s in (0..OFFSETS).step_by(align) {
                for n in 0..=MAX_LEN {
                    check_copy(copy, &src, &mut dest, 8 + d, 8 + s, n);
                    calls += 1;
                }
            }
        }
    }
    let sets = [
        Set::Memset,
        Set::Aeabi,
        Set::Aeabi4,
        Set::Aeabi8,
        Set::Clear,
        Set::Clear4,
        Set::Clear8,
    ];
    for set in sets {
        let align = match set {
            Set::Memset | Set::Aeabi | Set::Clear => 1,
            Set::Aeabi4 | Set::Clear4 => 4,
            Set::Aeabi8 | Set::Clear8 => 8,
        };
        for d in (0..OFFSETS).step_by(align) {
            for n in 0..=MAX_LEN {
                // An int whose high bits must be ignored, and one whose byte is 0.
                for c in [0x1_5A, 0x3_00] {
                    check_set(set, &mut dest, 8 + d, c, n);
                    calls += 1;
                }
            }
        }
    }
    calls += check_compare(&src);
    calls += check_moves(&src, &mut dest);
    let divisions = check_divisions();
    semihosting::eprint(format_args!(
        "pab-an386-builtinscheck: {calls} calls of memcpy, memset, memcmp, memmove and the AEABI forms, \
         {divisions} 64-bit divisions, all exact\n"
    ));
    semihosting::exit(true)
}

/// memcmp on every length up to 72 and offset pair, equal and with one byte changed at every
/// position (up and down): its sign must say which is greater, and only the bytes before `n`
/// count. Returns how many calls were checked.
fn check_compare(src: &Buffer) -> u32 {
    let compare = black_box(memcmp as Comparing);
    let mut other = Buffer([0; SIZE]);
    let mut calls = 0;
    for a in 0..OFFSETS {
        for b in 0..OFFSETS {
            for n in 0..=MAX_LEN {
                // `other` holds at b the bytes `src` holds at a.
                for i in 0..SIZE {
                    let from = (a + i).wrapping_sub(b);
                    let value = if from < SIZE { byte(src, from) } else { 0x11 };
                    unsafe { write_volatile(&mut other.0[i], value) };
                }
                let (x, y) = (src.0[8 + a..].as_ptr(), other.0[8 + b..].as_ptr());
                if unsafe { compare(x, y, n) } != 0 {
                    fail("memcmp", a, b, n, "equal bytes compared unequal");
                }
                calls += 1;
                for at in 0..n {
                    let original = byte(&other, 8 + b + at);
                    for changed in [original.wrapping_add(1), original.wrapping_sub(1)] {
                        unsafe { write_volatile(&mut other.0[8 + b + at], changed) };
                        let result = unsafe { compare(x, y, n) };
                        let ours = i32::from(byte(src, 8 + a + at));
                        if result.signum() != (ours - i32::from(changed)).signum() {
                            fail("memcmp", a, b, n, "the sign of a difference is wrong");
                        }
                        // A change past the compared bytes does not count.
                        if unsafe { compare(x, y, at) } != 0 {
                            fail("memcmp", a, b, at, "compared a byte past its length");
                        }
                        calls += 2;
                    }
                    unsafe { write_volatile(&mut other.0[8 + b + at], original) };
                }
            }
        }
    }
    calls
}

/// Quotient and remainder by shift and subtract, one bit a round: no division operator, so
/// nothing here calls the routine under test.
fn reference_divmod(n: u64, d: u64) -> (u64, u64) {
    let (mut q, mut r) = (0u64, 0u64);
    for bit in (0..64).rev() {
        let carry = r >> 63;
        r = (r << 1) | ((n >> bit) & 1);
        if carry != 0 || r >= d {
            r = r.wrapping_sub(d);
            q |= 1 << bit;
        }
    }
    (q, r)
}

/// __aeabi_uldivmod called as the AEABI says, its remainder read from r2:r3: compiled `%` may
/// compute the remainder from the quotient instead, and would not check those registers.
fn uldivmod(n: u64, d: u64) -> (u64, u64) {
    let (q0, q1, r0, r1): (u32, u32, u32, u32);
    // SAFETY: the routine follows the AEABI: it reads r0-r3, writes r0-r3, may change r12, lr
    // and the flags (asm! assumes the flags changed), and preserves everything else.
    unsafe {
        core::arch::asm!(
            "bl __aeabi_uldivmod",
            inout("r0") n as u32 => q0,
            inout("r1") (n >> 32) as u32 => q1,
            inout("r2") d as u32 => r0,
            inout("r3") (d >> 32) as u32 => r1,
            out("r12") _,
            out("lr") _,
        );
    }
    (
        u64::from(q0) | u64::from(q1) << 32,
        u64::from(r0) | u64::from(r1) << 32,
    )
}

fn check_division(n: u64, d: u64) {
    let (n, d) = black_box((n, d));
    let expected = reference_divmod(n, d);
    // `/` and `%` on u64 as the compiler calls them (d is never 0 here), and the routine's own
    // remainder.
    let (q, r) = (black_box(n / d), black_box(n % d));
    if (q, r) != expected || uldivmod(n, d) != expected {
        semihosting::eprint(format_args!(
            "pab-an386-builtinscheck: {n} / {d}: quotient {q} remainder {r}, the routine says \
             {:?}, expected {expected:?}\n",
            uldivmod(n, d)
        ));
        semihosting::exit(false)
    }
}

/// Returns how many divisions were checked.
fn check_divisions() -> u32 {
    let edges = [
        0,
        1,
        2,
        3,
        1_000,
        1_000_000,
        (1 << 31) - 1,
        1 << 31,
        (1 << 32) - 1,
        1 << 32,
        (1 << 32) + 1,
        (1 << 62) + 7,
        (1 << 63) - 1,
        1 << 63,
        (1 << 63) + 1,
        u64::MAX - 1,
        u64::MAX,
    ];
    let mut count = 0;
    for n in edges {
        for d in edges.into_iter().filter(|&d| d != 0) {
            check_division(n, d);
            for near in [d.wrapping_sub(1), d.wrapping_add(1)] {
                check_division(near, d);
            }
            count += 3;
        }
    }
    // xorshift64: each operand shifted right by a pseudo-random amount, so that every width from
    // 1 to 64 bits comes for both.
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    for _ in 0..200_000 {
        let (a, b, shifts) = (next(), next(), next());
        let n = a >> (shifts % 64);
        let d = (b >> ((shifts >> 8) % 64)).max(1);
        check_division(n, d);
        count += 1;
    }
    count
}

/// memmove within one buffer at every offset pair up to 15 and length up to 72, through every
/// entry point (the `4`/`8` forms at their alignments): the moved bytes are the source's as they
/// were before the call, and the rest of the buffer is untouched. Returns the calls checked.
fn check_moves(pattern: &Buffer, work: &mut Buffer) -> u32 {
    let mut calls = 0;
    for (entry, align) in [(0, 1), (1, 1), (2, 4), (3, 8)] {
        for d in (0..16).step_by(align) {
            for s in (0..16).step_by(align) {
                for n in 0..=MAX_LEN {
                    for i in 0..SIZE {
                        // Volatile: this loop must not itself become a memcpy call.
                        unsafe { write_volatile(&mut work.0[i], byte(pattern, i)) };
                    }
                    let base = work.0.as_mut_ptr();
                    let to = black_box(unsafe { base.add(d) });
                    let from = black_box(unsafe { base.add(s) } as *const u8);
                    let n = black_box(n);
                    let returned = unsafe {
                        match entry {
                            0 => Some(black_box(memmove as Copying)(to, from, n)),
                            1 => {
                                black_box(__aeabi_memmove as AeabiCopying)(to, from, n);
                                None
                            }
                            2 => {
                                black_box(__aeabi_memmove4 as AeabiCopying)(to, from, n);
                                None
                            }
                            _ => {
                                black_box(__aeabi_memmove8 as AeabiCopying)(to, from, n);
                                None
                            }
                        }
                    };
                    let name = [
                        "memmove",
                        "__aeabi_memmove",
                        "__aeabi_memmove4",
                        "__aeabi_memmove8",
                    ][entry];
                    if returned.is_some_and(|r| r != to) {
                        fail(
                            name,
                            d,
                            s,
                            n,
                            "returned another address than the destination",
                        );
                    }
                    for i in 0..SIZE {
                        let expected = if (d..d + n).contains(&i) {
                            byte(pattern, s + (i - d))
                        } else {
                            byte(pattern, i)
                        };
                        if byte(work, i) != expected {
                            fail(name, d, s, n, "moved a wrong byte, or changed one outside");
                        }
                    }
                    calls += 1;
                }
            }
        }
    }
    calls
}

fn fill(buffer: &mut Buffer, value: u8) {
    for byte in buffer.0.iter_mut() {
        // Volatile, so that this loop is not itself a memset call.
        unsafe { write_volatile(byte, value) };
    }
}

fn byte(buffer: &Buffer, i: usize) -> u8 {
    unsafe { read_volatile(&buffer.0[i]) }
}

fn check_copy(copy: Copy, src: &Buffer, dest: &mut Buffer, d: usize, s: usize, n: usize) {
    fill(dest, GUARD);
    let to = black_box(unsafe { dest.0.as_mut_ptr().add(d) });
    let from = black_box(unsafe { src.0.as_ptr().add(s) });
    let n = black_box(n);
    // Called through pointers the compiler cannot see through: it knows what `memcpy` returns
    // and would not look at the returned register.
    let returned = unsafe {
        match copy {
            Copy::Memcpy => Some(black_box(memcpy as Copying)(to, from, n)),
            Copy::Aeabi => {
                black_box(__aeabi_memcpy as AeabiCopying)(to, from, n);
                None
            }
            Copy::Aeabi4 => {
                black_box(__aeabi_memcpy4 as AeabiCopying)(to, from, n);
                None
            }
            Copy::Aeabi8 => {
                black_box(__aeabi_memcpy8 as AeabiCopying)(to, from, n);
                None
            }
        }
    };
    let name = match copy {
        Copy::Memcpy => "memcpy",
        Copy::Aeabi => "__aeabi_memcpy",
        Copy::Aeabi4 => "__aeabi_memcpy4",
        Copy::Aeabi8 => "__aeabi_memcpy8",
    };
    verify(name, dest, to, returned, (d, s, n), |k| byte(src, s + k));
}

/// Fails unless `returned` (from an entry point that returns one) is `to`, byte `d + k` of
/// `dest` is `inside(k)` for every k below `n`, and every other byte is still [`GUARD`].
fn verify(
    name: &str,
    dest: &Buffer,
    to: *mut u8,
    returned: Option<*mut u8>,
    (d, s, n): (usize, usize, usize),
    inside: impl Fn(usize) -> u8,
) {
    if returned.is_some_and(|r| r != to) {
        fail(
            name,
            d,
            s,
            n,
            "returned another address than the destination",
        );
    }
    for i in 0..SIZE {
        let expected = if (d..d + n).contains(&i) {
            inside(i - d)
        } else {
            GUARD
        };
        if byte(dest, i) != expected {
            fail(
                name,
                d,
                s,
                n,
                "wrote a wrong byte, or one outside the destination",
            );
        }
    }
}

fn check_set(set: Set, dest: &mut Buffer, d: usize, c: i32, n: usize) {
    fill(dest, GUARD);
    let to = black_box(unsafe { dest.0.as_mut_ptr().add(d) });
    let (n, c) = black_box((n, c));
    let clears = matches!(set, Set::Clear | Set::Clear4 | Set::Clear8);
    let returned = unsafe {
        match set {
            Set::Memset => Some(black_box(memset as Setting)(to, c, n)),
            Set::Aeabi => {
                black_box(__aeabi_memset as AeabiSetting)(to, n, c);
                None
            }
            Set::Aeabi4 => {
                black_box(__aeabi_memset4 as AeabiSetting)(to, n, c);
                None
            }
            Set::Aeabi8 => {
                black_box(__aeabi_memset8 as AeabiSetting)(to, n, c);
                None
            }
            Set::Clear => {
                black_box(__aeabi_memclr as Clearing)(to, n);
                None
            }
            Set::Clear4 => {
                black_box(__aeabi_memclr4 as Clearing)(to, n);
                None
            }
            Set::Clear8 => {
                black_box(__aeabi_memclr8 as Clearing)(to, n);
                None
            }
        }
    };
    let name = match set {
        Set::Memset => "memset",
        Set::Aeabi => "__aeabi_memset",
        Set::Aeabi4 => "__aeabi_memset4",
        Set::Aeabi8 => "__aeabi_memset8",
        Set::Clear => "__aeabi_memclr",
        Set::Clear4 => "__aeabi_memclr4",
        Set::Clear8 => "__aeabi_memclr8",
    };
    let value = if clears { 0 } else { c as u8 };
    verify(name, dest, to, returned, (d, 0, n), |_| value);
}

fn fail(name: &str, d: usize, s: usize, n: usize, what: &str) -> ! {
    semihosting::eprint(format_args!(
        "pab-an386-builtinscheck: {name} to offset {d} from offset {s}, {n} bytes: {what}\n"
    ));
    semihosting::exit(false)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    semihosting::eprint(format_args!("pab-an386-builtinscheck: panic: {info}\n"));
    semihosting::exit(false)
}

//! What checking a signed firmware image costs a board (`pab_core::update`, the core's
//! `signature` feature): SHA-512 over the image and its trailer, per KiB, and the Ed25519
//! verification of the digest (strict). Neither is on the frame path: a node checks an image once,
//! before it lets its bootloader swap it in.

use core::hint::black_box;

use pab_core::update;

use crate::{fail, measure, report};

/// Measured repetitions of each case.
const TIMES: usize = 4;

/// The signing key's public half (seed 32 × 0x5E) and its signature of the SHA-512 digest of
/// [`message`]'s 1 KiB (made on a host with ed25519-dalek, as `pabctl sign` does).
const PUBLIC: [u8; 32] = [
    0x81, 0x46, 0x64, 0x0f, 0x02, 0x49, 0x3a, 0xf4, 0xfb, 0xc5, 0x4f, 0xe3, 0x33, 0x88, 0xe7, 0x5d,
    0xc2, 0xc9, 0x37, 0xae, 0x0b, 0x77, 0x27, 0xcc, 0x2b, 0x2a, 0xfb, 0x1b, 0x75, 0x19, 0x9a, 0x3e,
];
const SIGNATURE: [u8; 64] = [
    0x7a, 0x5e, 0x17, 0xd7, 0x5f, 0x78, 0xcd, 0x67, 0xe1, 0x03, 0xbd, 0xd8, 0x01, 0xbc, 0x7a, 0x4d,
    0xfb, 0xa3, 0xe1, 0xe5, 0xcc, 0x53, 0x5d, 0x95, 0x6e, 0xd7, 0x1c, 0x2b, 0xc8, 0x28, 0x6d, 0xf2,
    0xe5, 0xfb, 0x01, 0x4d, 0x21, 0x0f, 0x17, 0xa5, 0xb9, 0x34, 0xec, 0x00, 0x78, 0x56, 0x41, 0xa5,
    0x7a, 0x81, 0xc4, 0xc1, 0x5b, 0x3c, 0x11, 0x5e, 0xda, 0x0d, 0x8f, 0x06, 0xa9, 0x3a, 0x2f, 0x0c,
];

/// 1 KiB: byte i is 7 i (mod 256).
fn message() -> [u8; 1024] {
    let mut bytes = [0u8; 1024];
    for (i, byte) in bytes.iter_mut().enumerate() {
        *byte = (i * 7) as u8;
    }
    bytes
}

pub fn run() {
    let bytes = black_box(message());
    let mut digest = [0u8; 64];
    for _ in 0..TIMES {
        digest = black_box(measure(|| update::digest(black_box(&bytes))));
        report("update", "sha512-1k");
    }
    for _ in 0..TIMES {
        let verdict = black_box(measure(|| {
            update::verify(
                black_box(&digest),
                black_box(&SIGNATURE),
                black_box(&PUBLIC),
            )
        }));
        report("update", "ed25519-verify");
        if verdict.is_err() {
            fail(format_args!(
                "update: the test vector's signature does not verify"
            ));
        }
    }
}

//! What authenticated configuration costs a board (issue 11): AES-128-CMAC as `pab_core::auth`
//! runs it on the boards (core/src/auth/aes_cmac.rs: byte-oriented, its S-box in RAM). None of
//! it is on the frame path: it runs once per configuration frame, and per table transfer over
//! the image.

use core::hint::black_box;

use pab_core::auth::{Authenticator, Key};

use crate::{measure, report};

/// Measured repetitions of each case (they cost the same each time: no data-dependent branch).
const TIMES: usize = 4;
/// Bytes of the Take and Return arm node's image, whose MAC a push checks.
const IMAGE_LEN: usize = 181;

pub fn run() {
    let key = Key::from_bytes(black_box([0x2B; 16]));
    for _ in 0..TIMES {
        black_box(measure(|| Authenticator::new(black_box(&key))));
        report("auth", "key-schedule");
    }
    let authenticator = Authenticator::new(&key);
    let nonce = black_box(0x0000_0001_0000_0002_u64);
    // A new challenge: the node nonce from salt and counter, and the exchange (its nonce and the
    // binding) from both nonces.
    for _ in 0..TIMES {
        black_box(measure(|| {
            let node = authenticator.node_nonce(5, black_box(7), black_box(1));
            authenticator.exchange(5, black_box(0x0102_0304_0506_0708), node)
        }));
        report("auth", "challenge");
    }
    // A DiagnosticControl's 4 bytes and a (wrong) tag: the check costs the same either way.
    let payload = black_box([10u8, 0, 0xFF, 0xFF]);
    let tag = black_box([0u8; 4]);
    for _ in 0..TIMES {
        black_box(measure(|| {
            authenticator.verify_command(5, 0x10, nonce, &payload, &tag)
        }));
        report("auth", "command-tag");
    }
    let image = black_box([0x5Au8; IMAGE_LEN]);
    let mac = black_box([0u8; 16]);
    for _ in 0..TIMES {
        black_box(measure(|| {
            authenticator.verify_image(5, nonce, 0, &image, &mac)
        }));
        report("auth", "image-181");
    }
    let status = black_box([0u8; 8]);
    for _ in 0..TIMES {
        black_box(measure(|| {
            authenticator.receipt_tag(5, nonce, &status, 0x1234_5678, true)
        }));
        report("auth", "receipt");
    }
}

//! What authenticated configuration costs a board (issue 11): AES-128-CMAC as `pab_core::auth`
//! runs it on the boards (core/src/auth/aes_cmac.rs: byte-oriented, its S-box in RAM). None of
//! it is on the frame path: it runs once per configuration frame, and per table transfer over
//! the image.

use core::hint::black_box;

use pab_core::Instant;
use pab_core::auth::{Authenticator, Key};
use pab_core::protocol::{BROADCAST, Gates, Message};
use pab_core::seal::{Sealer, Verdict, Verifier};

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
    seal(&authenticator);
}

/// Sealed coordination (`pab_core::seal`): a Gates frame's seal made by its sender, and the
/// receiver's whole path for it (held, then its seal matched, its counter taken and its tag
/// checked) from a sender it is synchronised with.
fn seal(authenticator: &Authenticator) {
    let (owner, reader) = (1u8, 5u8);
    let gates = Message::Gates(Gates {
        group: 0,
        behaviours: 2,
        mask: 1,
        changes: 1,
    })
    .to_frame(owner, BROADCAST);
    let mut sender = Sealer::new(black_box(3));
    for _ in 0..TIMES {
        black_box(measure(|| sender.seal(authenticator, owner, &gates)));
        report("auth", "seal-make");
    }
    // Synchronise the reader with the owner, as on the bus: a first seal refused, the request,
    // the answer and its seal.
    let mut verifier = Verifier::new();
    let mut own = Sealer::new(9);
    let now = Instant::from_micros(1_000);
    let seal_of = |sender: &mut Sealer| {
        let frame = sender.seal(authenticator, owner, &gates);
        match frame.map(|frame| Message::decode(&frame)) {
            Some(Ok((_, Message::Seal(seal)))) => seal,
            _ => panic!("no seal"),
        }
    };
    verifier.hold(owner, 0x07, &gates, now);
    let first = seal_of(&mut sender);
    let (_, request) = verifier.on_seal(authenticator, &mut own, reader, owner, &first, now);
    let Some(Ok((_, Message::FreshnessRequest { nonce }))) = request.map(|r| Message::decode(&r))
    else {
        panic!("no request");
    };
    let Some([answer, answer_seal]) = sender.answer(authenticator, owner, reader, nonce) else {
        panic!("no answer");
    };
    verifier.hold(owner, 0x20, &answer, now);
    let Ok((_, Message::Seal(answer_seal))) = Message::decode(&answer_seal) else {
        panic!("no answer seal");
    };
    let (synchronised, _) =
        verifier.on_seal(authenticator, &mut own, reader, owner, &answer_seal, now);
    assert!(synchronised == Verdict::Synchronised);
    for _ in 0..TIMES {
        let seal = seal_of(&mut sender);
        let verdict = measure(|| {
            verifier.hold(owner, 0x07, black_box(&gates), now);
            verifier
                .on_seal(
                    authenticator,
                    &mut own,
                    reader,
                    owner,
                    black_box(&seal),
                    now,
                )
                .0
        });
        assert!(matches!(verdict, Verdict::Accepted(_)));
        report("auth", "seal-check");
    }
}

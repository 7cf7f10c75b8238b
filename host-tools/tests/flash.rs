//! `pabctl flash` against real node code: the board application (`pab-app` with its `update`
//! feature) on a thread, in real time, on the in-process bus, with an update slot over
//! in-memory flash (tests/common: `LiveNode` with `Update`); and the command line.
//!
//! The bootloader is not here: when the node restarts, the test stands in for it (it writes the
//! verdict into the request page, as the bootloader does, and starts the node again as the
//! firmware it decided on). scripts/boot-test.sh runs the real bootloader's checks in QEMU.

use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use ed25519_dalek::SigningKey;
use embedded_storage::nor_flash::NorFlash;
use pab_core::auth::{Authenticator, Key};
use pab_core::identity::Firmware;
use pab_core::protocol::{Message, UpdateStatusCode};
use pab_core::update::stored::{self, VERDICT_OFFSET};
use pab_core::update::{MANIFEST_LEN, SignedImage, UpdateRefusal};
use pabctl::bus::memory::MemoryHub;
use pabctl::flash::{self, Outcome, Refusal, Timeouts};
use pabctl::signing::{self, Signed};

use crate::common::{LiveNode, SLOT_LEN, Shared, Update};

const NODE: u8 = 5;

fn old() -> Firmware {
    Firmware::new("fw-test", "1.0.0", "1111111111111111")
}

fn new() -> Firmware {
    Firmware::new("fw-test", "1.1.0", "2222222222222222")
}

/// `len` bytes that are not all alike: a misplaced chunk shows.
fn image(len: usize) -> Vec<u8> {
    (0..len)
        .map(|i| (i as u32).wrapping_mul(2_654_435_761).to_le_bytes()[3])
        .collect()
}

/// `image` signed as `firmware`, as `pabctl sign` signs it.
fn signed(image: &[u8], firmware: Firmware) -> Vec<u8> {
    let key = SigningKey::from_bytes(&[7; 32]);
    signing::sign(
        &key,
        image,
        Signed {
            firmware,
            downgrade: false,
        },
    )
    .unwrap()
}

fn timeouts() -> Timeouts {
    Timeouts {
        restart: Duration::from_secs(10),
        ..Timeouts::default()
    }
}

fn key() -> Key {
    Key::from_bytes([0x5A; pab_core::auth::KEY_LEN])
}

/// A node's update partition and request page, erased.
fn flashes() -> (
    Shared<crate::common::DfuFlash>,
    Shared<crate::common::RequestFlash>,
) {
    (Shared::erased(), Shared::erased())
}

/// What the old node left when it restarted: its update partition's and request page's bytes.
struct Left {
    dfu: Vec<u8>,
    request: Vec<u8>,
}

/// Stands in for the bootloader (scripts/boot-test.sh runs the real one in QEMU): waits for the
/// node to restart into it, keeps what the node left in its flash, writes `verdict` into the
/// request page as the bootloader does, and starts the node again running `comes_back_as`.
/// `None` when the tool was `done` and the node had not restarted.
fn bootloader(
    hub: &MemoryHub,
    node: LiveNode,
    update: Update,
    key: Option<Key>,
    verdict: Result<(), UpdateRefusal>,
    comes_back_as: Firmware,
    done: Arc<AtomicBool>,
) -> JoinHandle<Option<(Left, LiveNode)>> {
    let hub = hub.clone();
    std::thread::spawn(move || {
        while !node.wait_restart(Duration::from_millis(10)) {
            if done.load(Ordering::SeqCst) {
                return None;
            }
        }
        drop(node);
        let left = Left {
            dfu: update.dfu.bytes(),
            request: update.request.bytes(),
        };
        update
            .request
            .clone()
            .write(VERDICT_OFFSET, &stored::verdict(verdict))
            .unwrap();
        let again = LiveNode::spawn_updatable(
            &hub,
            NODE,
            None,
            key,
            Some(Update {
                firmware: comes_back_as,
                ..update
            }),
        );
        Some((left, again))
    })
}

/// Flashes `bytes` (a signed file) to a node that runs `old()`, whose bootloader says `verdict`
/// and which comes back as `comes_back_as`: the outcome, the progress reported and what the
/// node left in its flash at its restart.
fn flash_and_restart(
    bytes: &[u8],
    key: Option<Key>,
    verdict: Result<(), UpdateRefusal>,
    comes_back_as: Firmware,
) -> (Outcome, Vec<(usize, usize)>, Left, Duration) {
    let hub = MemoryHub::new();
    let (dfu, request) = flashes();
    let update = Update {
        firmware: old(),
        dfu,
        request,
    };
    let node = LiveNode::spawn_updatable(&hub, NODE, None, key, Some(update.clone()));
    let done = Arc::new(AtomicBool::new(false));
    let board = bootloader(
        &hub,
        node,
        update,
        key,
        verdict,
        comes_back_as,
        done.clone(),
    );
    let mut tool = hub.connect();
    let signed = SignedImage::parse(bytes).unwrap();
    let auth = key.as_ref().map(Authenticator::new);
    let mut progress = Vec::new();
    let started = std::time::Instant::now();
    let mut transferred = Duration::ZERO;
    let outcome = flash::flash(
        &mut tool,
        NODE,
        &signed,
        auth.as_ref(),
        timeouts(),
        &mut |sent, total| {
            progress.push((sent, total));
            transferred = started.elapsed();
        },
    )
    .unwrap();
    done.store(true, Ordering::SeqCst);
    let Some((left, _again)) = board.join().unwrap() else {
        panic!("the node did not restart into its bootloader; the tool's outcome: {outcome}");
    };
    (outcome, progress, left, transferred)
}

/// The slot holds the image at offset 0 and the manifest in its last 96 bytes; the request page
/// holds the request.
fn assert_requested(left: &Left, bytes: &[u8]) {
    let signed = SignedImage::parse(bytes).unwrap();
    let image = signed.image();
    assert!(left.dfu[..image.len()] == *image, "the image at offset 0");
    let manifest = &left.dfu[SLOT_LEN as usize - MANIFEST_LEN..SLOT_LEN as usize];
    assert_eq!(manifest, &bytes[bytes.len() - MANIFEST_LEN..]);
    assert_eq!(left.request[..8], stored::REQUEST);
}

#[test]
fn a_signed_image_goes_to_the_slot_the_node_restarts_and_comes_back_running_it() {
    // 5 003 bytes: four chunks of 1 024 and a last one of 907, not a multiple of 8.
    let bytes = signed(&image(5_003), new());
    let (outcome, progress, left, took) = flash_and_restart(&bytes, None, Ok(()), new());
    assert_eq!(outcome, Outcome::Running { firmware: new() }, "{outcome}");
    // The transfer's time, Begin to the last Ack, on the in-process bus (no bit rate: the
    // node's handling and the threads' scheduling only); `-- --nocapture` shows it.
    eprintln!(
        "flash: 5003 bytes in {:.1} ms ({:.0} B/s) on the in-process bus",
        took.as_secs_f64() * 1e3,
        5003.0 / took.as_secs_f64()
    );
    assert_requested(&left, &bytes);
    assert_eq!(progress.first(), Some(&(0, 5_003)));
    assert_eq!(progress.last(), Some(&(5_003, 5_003)));
    let sent: Vec<usize> = progress.iter().map(|(sent, _)| *sent).collect();
    assert_eq!(sent, [0, 1024, 2048, 3072, 4096, 5003]);
}

#[test]
fn a_node_that_comes_back_on_its_old_firmware_is_a_failure_naming_both_versions() {
    let bytes = signed(&image(3_000), new());
    // The bootloader swapped, then reverted (or never swapped): the old firmware answers.
    let (outcome, _, left, _) = flash_and_restart(&bytes, None, Ok(()), old());
    assert_requested(&left, &bytes);
    assert_eq!(
        outcome,
        Outcome::NotRunning {
            expected: new(),
            running: old()
        }
    );
    assert!(!outcome.is_success() && outcome.after_commit());
    let text = outcome.to_string();
    assert!(
        text.contains("fw-test 1.0.0") && text.contains("fw-test 1.1.0"),
        "{text}"
    );

    // The bootloader refused the signature: its reason, decoded.
    let (outcome, _, _, _) =
        flash_and_restart(&bytes, None, Err(UpdateRefusal::BadSignature), old());
    assert_eq!(
        outcome,
        Outcome::BootloaderRefused(Refusal::Image(UpdateRefusal::BadSignature))
    );
    assert!(
        outcome.to_string().contains("signature does not verify"),
        "{outcome}"
    );
}

#[test]
fn an_image_for_another_board_or_a_downgrade_is_refused_at_the_begin_and_nothing_is_written() {
    for (firmware, refusal) in [
        (
            Firmware::new("fw-other", "1.1.0", "2222222222222222"),
            UpdateRefusal::OtherBoard,
        ),
        (
            Firmware::new("fw-test", "0.9.0", "2222222222222222"),
            UpdateRefusal::Downgrade,
        ),
    ] {
        let hub = MemoryHub::new();
        let (dfu, request) = flashes();
        let node = LiveNode::spawn_updatable(
            &hub,
            NODE,
            None,
            None,
            Some(Update {
                firmware: old(),
                dfu: dfu.clone(),
                request: request.clone(),
            }),
        );
        let bytes = signed(&image(2_048), firmware);
        let mut tool = hub.connect();
        let mut progress = Vec::new();
        let outcome = flash::flash(
            &mut tool,
            NODE,
            &SignedImage::parse(&bytes).unwrap(),
            None,
            timeouts(),
            &mut |sent, total| progress.push((sent, total)),
        )
        .unwrap();
        assert_eq!(outcome, Outcome::Refused(Refusal::Image(refusal)));
        assert!(outcome.to_string().contains(&refusal.to_string()));
        assert!(progress.is_empty(), "no chunk sent: {progress:?}");
        assert!(dfu.bytes().iter().all(|&b| b == 0xFF), "nothing written");
        assert!(request.bytes().iter().all(|&b| b == 0xFF), "no request");
        assert!(!node.restarted.load(Ordering::SeqCst));
    }
}

#[test]
fn a_keyed_node_takes_an_update_only_with_its_key() {
    let bytes = signed(&image(2_500), new());
    // Without the key: the node refuses the Begin (no TransferOpen), and nothing is written.
    let hub = MemoryHub::new();
    let (dfu, request) = flashes();
    let _node = LiveNode::spawn_updatable(
        &hub,
        NODE,
        None,
        Some(key()),
        Some(Update {
            firmware: old(),
            dfu: dfu.clone(),
            request,
        }),
    );
    let mut tool = hub.connect();
    let outcome = flash::flash(
        &mut tool,
        NODE,
        &SignedImage::parse(&bytes).unwrap(),
        None,
        timeouts(),
        &mut |_, _| {},
    )
    .unwrap();
    let Outcome::Unauthenticated(why) = &outcome else {
        panic!("{outcome}");
    };
    assert!(why.contains("--key"), "{why}");
    assert!(dfu.bytes().iter().all(|&b| b == 0xFF), "nothing written");

    // With it: the whole update.
    let (outcome, _, left, _) = flash_and_restart(&bytes, Some(key()), Ok(()), new());
    assert_eq!(outcome, Outcome::Running { firmware: new() }, "{outcome}");
    assert_requested(&left, &bytes);
}

/// The tool's bus, losing the first Ack that names offset `lose`: the answer to a chunk lost.
struct LosesAnAck {
    bus: pabctl::bus::memory::MemoryBus,
    lose: u32,
    lost: u32,
}

impl pabctl::bus::Bus for LosesAnAck {
    fn send(&mut self, frame: &pab_core::Frame) -> std::io::Result<()> {
        self.bus.send(frame)
    }

    fn receive(&mut self, timeout: Duration) -> std::io::Result<Option<pab_core::Frame>> {
        let frame = self.bus.receive(timeout)?;
        if let Some(Ok((_, Message::UpdateStatus(status)))) = frame.as_ref().map(Message::decode)
            && status.status == UpdateStatusCode::Ack
            && status.offset == self.lose
            && self.lost == 0
        {
            self.lost += 1;
            // Nothing more within the time, as when the frame never came.
            return self.bus.receive(timeout);
        }
        Ok(frame)
    }
}

#[test]
fn a_chunk_whose_ack_is_lost_is_sent_again_and_acknowledged_without_being_written_twice() {
    let hub = MemoryHub::new();
    let (dfu, request) = flashes();
    let update = Update {
        firmware: old(),
        dfu: dfu.clone(),
        request,
    };
    let node = LiveNode::spawn_updatable(&hub, NODE, None, None, Some(update.clone()));
    let done = Arc::new(AtomicBool::new(false));
    let board = bootloader(&hub, node, update, None, Ok(()), new(), done.clone());
    let bytes = signed(&image(4_000), new());
    let mut tool = LosesAnAck {
        bus: hub.connect(),
        lose: 2048,
        lost: 0,
    };
    let mut progress = Vec::new();
    let outcome = flash::flash(
        &mut tool,
        NODE,
        &SignedImage::parse(&bytes).unwrap(),
        None,
        Timeouts {
            answer: Duration::from_millis(300),
            ..timeouts()
        },
        &mut |sent, _| progress.push(sent),
    )
    .unwrap();
    done.store(true, Ordering::SeqCst);
    assert_eq!(tool.lost, 1, "an Ack was lost");
    assert_eq!(outcome, Outcome::Running { firmware: new() }, "{outcome}");
    assert_eq!(progress, [0, 1024, 2048, 3072, 4000]);
    let (left, _again) = board.join().unwrap().expect("the node restarted");
    assert_requested(&left, &bytes);
}

fn pabctl(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_pabctl"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn flash_help_teaches_and_a_file_that_is_not_signed_fails_before_the_bus() {
    let help = pabctl(&["flash", "--help"]);
    assert!(help.status.success());
    let text = String::from_utf8(help.stdout).unwrap();
    for needed in [
        "bootloader",
        "update key",
        "key page",
        "signed",
        "pabctl sign",
        "--key",
        "Examples:",
        "pabctl flash --iface can0 --node 3 fw-1.2.0.signed",
    ] {
        assert!(text.contains(needed), "{needed:?} in:\n{text}");
    }

    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("fw.bin");
    std::fs::write(&plain, image(4_000)).unwrap();
    // An interface that does not exist: were it opened first, the error would be about it.
    let out = pabctl(&[
        "flash",
        "--iface",
        "nosuchcan7",
        "--node",
        "3",
        plain.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(stderr.contains("fw.bin"), "{stderr}");
    assert!(stderr.contains("not a signed firmware image"), "{stderr}");
    assert!(!stderr.contains("nosuchcan7"), "{stderr}");
    assert!(Path::new(&plain).exists());

    // A name without a network file: said before the bus too.
    let good = dir.path().join("fw.signed");
    std::fs::write(&good, signed(&image(64), new())).unwrap();
    let out = pabctl(&[
        "flash",
        "--iface",
        "nosuchcan7",
        "--node",
        "arm",
        good.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(stderr.contains("--network"), "{stderr}");
}

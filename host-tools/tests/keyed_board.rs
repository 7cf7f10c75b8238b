//! A keyed emulated board, end to end: the firmware (`pab-fw-an386`) in QEMU's `mps2-an386` with
//! a key page made by `pabctl keygen` and `pabctl keypage`, planted by QEMU's loader as the
//! docs/keys.md says, talked to over its SLCAN serial line with pabctl's own push code:
//!
//! - its TableStatus says keyed;
//! - a plain DiagnosticControl and a plain push are refused (`Unauthenticated` fault, no
//!   stream, no table);
//! - `pabctl push --key`'s code (`push::push_authenticated`: challenge, open, image and MAC,
//!   receipt, heartbeat) succeeds, and a tagged DiagnosticControl switches the stream;
//! - after a system reset (QEMU's monitor), the board boots with the stored table and its
//!   challenges carry the next boot count as salt.
//!
//! Needs QEMU and the firmware: ignored by plain `cargo test`, run by
//! `scripts/keyed-board-test.sh` (from `./test.sh`), which builds the firmware and passes its
//! path in `PAB_AN386_ELF`.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use pab_core::Frame;
use pab_core::auth::{Authenticator, Key};
use pab_core::protocol::{self, DiagnosticControl, FaultCode, Message, Service};
use pabctl::bus::Bus;
use pabctl::push::{self, Credentials, Outcome, Timeouts};

const KEY_PAGE_ADDRESS: u32 = 0x0004_E000;
const ARM_TABLE: &str = "firmware/boards/mps2-an386/tables/take-and-return/arm.pab";

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The board in QEMU: UART0 (SLCAN) on QEMU's stdin and stdout, the semihosting log on its
/// stderr, the human monitor on a unix socket.
struct Board {
    qemu: Child,
    uart: ChildStdin,
    frames: Receiver<Frame>,
    log: Arc<Mutex<Vec<String>>>,
    monitor: PathBuf,
}

impl Board {
    fn start(elf: &Path, key_page: &Path, dir: &Path) -> Board {
        let monitor = dir.join("monitor.sock");
        let mut qemu = Command::new("qemu-system-arm")
            .args(["-M", "mps2-an386", "-display", "none", "-nic", "none"])
            .args(["-semihosting-config", "enable=on,target=native"])
            .args(["-serial", "stdio", "-monitor"])
            .arg(format!("unix:{},server=on,wait=off", monitor.display()))
            .arg("-device")
            .arg(format!(
                "loader,file={},addr={KEY_PAGE_ADDRESS:#x},force-raw=on",
                key_page.display()
            ))
            .arg("-kernel")
            .arg(elf)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start qemu-system-arm ({e})"));
        let uart = qemu.stdin.take().unwrap();
        let mut stdout = qemu.stdout.take().unwrap();
        let stderr = qemu.stderr.take().unwrap();
        let (sender, frames) = mpsc::channel();
        // SLCAN lines from the board: frames go to the channel, the adapter's answers (CR, BEL)
        // are dropped.
        std::thread::spawn(move || {
            let mut line = Vec::new();
            let mut byte = [0u8; 1];
            while stdout.read_exact(&mut byte).is_ok() {
                match byte[0] {
                    b'\r' | 0x07 => {
                        if let Ok(pab_slcan::Command::Frame(frame)) = pab_slcan::parse(&line)
                            && sender.send(frame).is_err()
                        {
                            return;
                        }
                        line.clear();
                    }
                    other => line.push(other),
                }
            }
        });
        let log = Arc::new(Mutex::new(Vec::new()));
        let lines = Arc::clone(&log);
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { return };
                eprintln!("board: {line}");
                lines.lock().unwrap().push(line);
            }
        });
        Board {
            qemu,
            uart,
            frames,
            log,
            monitor,
        }
    }

    /// Waits until the board's log has `count` lines containing `text`; returns the last.
    fn wait_log(&self, text: &str, count: usize, timeout: Duration) -> String {
        let end = Instant::now() + timeout;
        loop {
            {
                let log = self.log.lock().unwrap();
                let found: Vec<&String> = log.iter().filter(|l| l.contains(text)).collect();
                if found.len() >= count {
                    return found[count - 1].clone();
                }
            }
            assert!(
                Instant::now() < end,
                "the board did not log {text:?} ({count} times) within {timeout:?}: {:?}",
                self.log.lock().unwrap()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn open_channel(&mut self) {
        self.uart.write_all(b"S6\rO\r").unwrap();
        self.uart.flush().unwrap();
    }

    /// Every frame the board sends within `duration`.
    fn collect(&mut self, duration: Duration) -> Vec<Frame> {
        let end = Instant::now() + duration;
        let mut frames = Vec::new();
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            if let Ok(Some(frame)) = self.receive(left) {
                frames.push(frame);
            }
        }
        frames
    }

    fn system_reset(&mut self) {
        let mut socket = UnixStream::connect(&self.monitor).expect("QEMU's monitor");
        socket.write_all(b"system_reset\n").unwrap();
        socket.flush().unwrap();
        // Let the monitor take the command before the socket closes.
        std::thread::sleep(Duration::from_millis(300));
    }
}

impl Drop for Board {
    fn drop(&mut self) {
        let _ = self.qemu.kill();
        let _ = self.qemu.wait();
    }
}

impl Bus for Board {
    fn send(&mut self, frame: &Frame) -> std::io::Result<()> {
        self.uart.write_all(
            pab_slcan::format_frame(frame)
                .ok_or_else(|| std::io::Error::other("SLCAN carries classic frames only"))?
                .as_bytes(),
        )?;
        self.uart.flush()
    }

    fn receive(&mut self, timeout: Duration) -> std::io::Result<Option<Frame>> {
        match self.frames.recv_timeout(timeout) {
            Ok(frame) => Ok(Some(frame)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(std::io::Error::other("QEMU exited")),
        }
    }
}

fn messages_from(frames: &[Frame], node: u8) -> Vec<Message> {
    frames
        .iter()
        .filter_map(|frame| Message::decode(frame).ok())
        .filter(|(id, _)| id.source == node)
        .map(|(_, message)| message)
        .collect()
}

fn pabctl(args: &[&str]) {
    let status = Command::new(env!("CARGO_BIN_EXE_pabctl"))
        .args(args)
        .status()
        .unwrap();
    assert!(status.success(), "pabctl {args:?}");
}

#[test]
#[ignore = "needs QEMU and the firmware: scripts/keyed-board-test.sh"]
fn a_keyed_emulated_board_takes_configuration_from_the_key_holder_only() {
    let elf =
        PathBuf::from(std::env::var("PAB_AN386_ELF").expect("PAB_AN386_ELF: the pab-fw-an386 ELF"));
    let dir = tempfile::tempdir().unwrap();
    let key_file = dir.path().join("node1.key");
    let page = dir.path().join("node1.keypage.bin");
    pabctl(&["keygen", "-o", key_file.to_str().unwrap()]);
    pabctl(&[
        "keypage",
        key_file.to_str().unwrap(),
        "-o",
        page.to_str().unwrap(),
    ]);
    let key = Key::from_hex(&std::fs::read_to_string(&key_file).unwrap()).unwrap();
    let image = std::fs::read(root().join(ARM_TABLE)).unwrap();
    let header = pab_core::image::read_header(&image).unwrap();
    let node = header.node_id;

    let mut board = Board::start(&elf, &page, dir.path());
    board.wait_log(
        "keyed: only authenticated configuration",
        1,
        Duration::from_secs(30),
    );
    board.open_channel();

    // Keyed, in its heartbeat group.
    let heard = board.collect(Duration::from_millis(2500));
    let statuses: Vec<_> = messages_from(&heard, node)
        .into_iter()
        .filter_map(|m| match m {
            Message::TableStatus(status) => Some(status),
            _ => None,
        })
        .collect();
    assert!(
        !statuses.is_empty() && statuses.iter().all(|s| s.keyed),
        "{statuses:?}"
    );

    // A plain command is refused.
    let control = DiagnosticControl {
        rate_hz: 10,
        ports: u16::MAX,
    };
    board
        .send(&Message::DiagnosticControl(control).to_frame(protocol::TOOL, node))
        .unwrap();
    let heard = board.collect(Duration::from_millis(2500));
    let messages = messages_from(&heard, node);
    assert!(
        messages
            .iter()
            .any(|m| matches!(m, Message::Fault(f) if f.code == FaultCode::Unauthenticated)),
        "no Unauthenticated fault: {messages:?}"
    );
    assert!(
        !messages
            .iter()
            .any(|m| matches!(m, Message::TableStatus(s) if s.diagnostic)),
        "the plain command switched the stream"
    );

    // A plain push is refused: no table runs.
    let plain = push::push(
        &mut board,
        node,
        &image,
        &header,
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    assert!(!plain.is_success(), "a plain push succeeded: {plain}");
    let heard = board.collect(Duration::from_millis(1500));
    assert!(
        messages_from(&heard, node)
            .iter()
            .any(|m| matches!(m, Message::Heartbeat(h) if h.table_version == 0)),
        "the board runs a table after a plain push"
    );

    // The key holder pushes (pabctl push --key's code: the receipt must verify).
    let credentials = Credentials {
        authenticator: Authenticator::new(&key),
        replace: false,
    };
    let keyed = push::push_authenticated(
        &mut board,
        node,
        &image,
        &header,
        &credentials,
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(
        keyed,
        Outcome::Confirmed {
            version: header.table_version,
            stored: true
        },
        "{keyed}"
    );

    // And switches the stream with a tagged command.
    let salt_first = boot_salt(&board.wait_log(KEYED, 1, Duration::from_secs(1)));
    assert_eq!(salt_first, 1, "a fresh QEMU counts its first boot");
    let auth = Authenticator::new(&key);
    let nonce = board_challenge(&mut board, &auth, node);
    let mut payload = [0u8; 4];
    payload[..2].copy_from_slice(&control.rate_hz.to_le_bytes());
    payload[2..].copy_from_slice(&control.ports.to_le_bytes());
    let tag = auth.command_tag(node, Service::DiagnosticControl.code(), nonce, &payload);
    board
        .send(
            &Message::AuthenticatedDiagnosticControl { control, tag }
                .to_frame(protocol::TOOL, node),
        )
        .unwrap();
    let heard = board.collect(Duration::from_millis(2500));
    assert!(
        messages_from(&heard, node)
            .iter()
            .any(|m| matches!(m, Message::TableStatus(s) if s.diagnostic && s.keyed)),
        "the tagged command did not switch the stream"
    );

    // A system reset: the next boot has the next salt, and the stored table.
    board.system_reset();
    let second_boot = board.wait_log(KEYED, 2, Duration::from_secs(30));
    board.wait_log(
        "booted with stored table version",
        1,
        Duration::from_secs(10),
    );
    // Frames of the first boot still in the pipe are not the second boot's answers.
    let _ = board.collect(Duration::from_millis(500));
    let salt_second = boot_salt(&second_boot);
    println!("boot salts: {salt_first} then {salt_second} after a system reset");
    assert_eq!(salt_second, salt_first + 1);
    // The second boot's challenges answer too (its counter starts again, its salt does not).
    let again = board_challenge(&mut board, &auth, node);
    assert_ne!(again, nonce);
}

/// The line the board logs at boot with a key; it ends with "(boot N)", the boot salt.
const KEYED: &str = "keyed: only authenticated configuration";

fn boot_salt(line: &str) -> u32 {
    line.rsplit_once("(boot ")
        .and_then(|(_, rest)| rest.split(')').next())
        .and_then(|number| number.parse().ok())
        .unwrap_or_else(|| panic!("no boot number in {line:?}"))
}

/// A challenge of the board, bound to the tool's request: the exchange nonce.
fn board_challenge(board: &mut Board, auth: &Authenticator, node: u8) -> u64 {
    match push::challenge(board, auth, node, Duration::from_secs(2)).unwrap() {
        push::Challenged::Bound(nonce) => nonce,
        other => panic!("a keyed board answers a challenge request: {other:?}"),
    }
}

//! The Take and Return nodes under the example's own traffic, every frame measured.
//!
//! The tables are the images `pabctl compile examples/take-and-return.toml` writes (kept in
//! `tables/take-and-return/`; `tests/tests/board_tables.rs` checks that they are still what the
//! compiler makes). The traffic is the example's `[[events]]`: each behaviour's topic at its rate
//! over its interval, simultaneous frames in bus order (lower identifier first). Every node sees
//! every frame, as on the bus: the frames of topics it has a connection for, and the others.

use embedded_can::StandardId;
use heapless::Vec;
use pab_app::{BoardNode, Config, Recipient};
use pab_core::image;
use pab_core::{
    BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, BoardArbiter, Frame, Id, Instant,
};

use crate::{fail, measure, measured_receive};

const ARM: &[u8] = include_bytes!("../../../tables/take-and-return/arm.pab");
const GAZE: &[u8] = include_bytes!("../../../tables/take-and-return/gaze.pab");
const HAND: &[u8] = include_bytes!("../../../tables/take-and-return/hand.pab");

/// One `[[events]]` entry of `examples/take-and-return.toml`: a topic's identifier, its period
/// and the interval [from, to) in which it publishes, in µs.
struct Event {
    id: u16,
    period_us: u64,
    from_us: u64,
    to_us: u64,
}

const fn event(id: u16, rate_hz: u64, from_ms: u64, to_ms: u64) -> Event {
    Event {
        id,
        period_us: 1_000_000 / rate_hz,
        from_us: from_ms * 1_000,
        to_us: to_ms * 1_000,
    }
}

/// Both cycles of the example (A to F and back, then the person taking the object back).
const EVENTS: [Event; 16] = [
    event(0x112, 1, 0, 78_000),       // Look Around
    event(0x113, 5, 0, 16_000),       // Rest Arm, pose
    event(0x122, 5, 0, 16_000),       // Rest Arm, open hand
    event(0x110, 10, 10_000, 18_000), // Object Detector, cycle 1
    event(0x120, 10, 14_000, 17_000), // Grasp Detect, cycle 1
    event(0x130, 10, 16_000, 31_500), // Grasped, cycle 1
    event(0x111, 10, 26_000, 36_000), // Face Detector, cycle 1
    event(0x121, 10, 30_000, 32_000), // Release Detect, cycle 1
    event(0x113, 5, 31_500, 56_000),  // Rest Arm resumes
    event(0x122, 5, 31_500, 56_000),
    event(0x110, 10, 50_000, 58_000), // Object Detector, cycle 2
    event(0x120, 10, 54_000, 57_000), // Grasp Detect, cycle 2
    event(0x130, 10, 56_000, 68_000), // Grasped, cycle 2
    event(0x111, 10, 64_000, 69_000), // Face Detector, cycle 2
    event(0x113, 5, 68_000, 78_000),  // Rest Arm resumes
    event(0x122, 5, 68_000, 78_000),
];

/// The example's frames in time order: (time, identifier), ties by identifier.
struct Traffic {
    /// Frames already sent per event.
    sent: [u64; EVENTS.len()],
}

impl Traffic {
    fn new() -> Self {
        Traffic {
            sent: [0; EVENTS.len()],
        }
    }
}

impl Iterator for Traffic {
    type Item = (Instant, Id);

    fn next(&mut self) -> Option<(Instant, Id)> {
        let mut best: Option<(u64, u16, usize)> = None;
        for (index, (event, sent)) in EVENTS.iter().zip(self.sent.iter()).enumerate() {
            let at = event.from_us + sent * event.period_us;
            if at >= event.to_us {
                continue;
            }
            if best.is_none_or(|(t, id, _)| (at, event.id) < (t, id)) {
                best = Some((at, event.id, index));
            }
        }
        let (at, id, index) = best?;
        if let Some(sent) = self.sent.get_mut(index) {
            *sent += 1;
        }
        let id = StandardId::new(id).unwrap_or_else(|| fail(format_args!("id {id:#x}")));
        Some((Instant::from_micros(at), Id::Standard(id)))
    }
}

fn arbiter(name: &str, bytes: &[u8]) -> BoardArbiter {
    let loaded = image::load::<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>(bytes)
        .unwrap_or_else(|error| fail(format_args!("{name} image: {error:?}")));
    BoardArbiter::new(loaded.table).unwrap_or_else(|error| fail(format_args!("{name}: {error}")))
}

/// `Arbiter::receive` on node `name` for every frame of the example; class `fed` for a frame the
/// node has a connection for, `none` for the others.
fn arbitrate(case: &str, name: &str, bytes: &[u8]) {
    let mut arbiter = arbiter(name, bytes);
    for (now, id) in Traffic::new() {
        let reception = measured_receive(&mut arbiter, &id, now);
        crate::report(
            case,
            if reception.fed.is_empty() {
                "none"
            } else {
                "fed"
            },
        );
    }
}

/// Counts what the node application hands to the local recipient, so the call is not optimised
/// away.
struct Counting {
    delivered: u32,
}

impl Recipient for Counting {
    fn deliver(&mut self, _port: u8, _frame: &Frame, _now: Instant) {
        self.delivered = self.delivered.wrapping_add(1);
    }
}

/// `BoardNode::on_frame` of the arm node (node id 1, booted with its image) for every frame of the
/// example: the whole frame path of the node application. Classes: `delivered` (recipient called,
/// re-publication queued), `discarded` (fed, delivered to no port), `none` (no connection), with
/// `+heartbeat` when the node's poll also queued its heartbeat group.
#[inline(never)]
fn node_path(case: &str) {
    let Ok(config) = Config::new(1) else {
        fail(format_args!("config"))
    };
    let mut node = BoardNode::new(config, Instant::from_micros(0));
    let len = ARM.len();
    match node.boot_buffer().get_mut(..len) {
        Some(buffer) => buffer.copy_from_slice(ARM),
        None => fail(format_args!("boot buffer")),
    }
    node.boot(Some(len), Instant::from_micros(0));
    if node.arbiter().is_none() {
        fail(format_args!("the arm node refused its image"));
    }
    while node.next_outgoing().is_some() {}
    let mut recipient = Counting { delivered: 0 };
    let mut outgoing: Vec<Frame, 16> = Vec::new();
    for (now, id) in Traffic::new() {
        let frame = Frame::data(id, &[1, 2, 3, 4, 5, 6, 7, 8])
            .unwrap_or_else(|| fail(format_args!("frame")));
        let before = node.counters();
        measure(|| {
            on_frame(&mut node, &frame, now, &mut recipient);
        });
        let after = node.counters();
        outgoing.clear();
        while let Some(sent) = node.next_outgoing() {
            let _ = outgoing.push(sent);
        }
        let delivered = after.delivered != before.delivered;
        let class = if delivered {
            "delivered"
        } else if after.discarded != before.discarded {
            "discarded"
        } else {
            "none"
        };
        // A delivery re-publishes one frame; anything more is the heartbeat group.
        let heartbeat = outgoing.len() > usize::from(delivered);
        match (class, heartbeat) {
            ("delivered", true) => crate::report(case, "delivered+heartbeat"),
            ("discarded", true) => crate::report(case, "discarded+heartbeat"),
            ("none", true) => crate::report(case, "none+heartbeat"),
            _ => crate::report(case, class),
        }
    }
    if recipient.delivered == 0 {
        fail(format_args!("the arm node delivered nothing"));
    }
}

#[inline(never)]
fn on_frame(node: &mut BoardNode, frame: &Frame, now: Instant, recipient: &mut Counting) {
    node.on_frame(frame, now, recipient);
}

pub fn run() {
    arbitrate("tr-arm", "arm", ARM);
    arbitrate("tr-gaze", "gaze", GAZE);
    arbitrate("tr-hand", "hand", HAND);
    node_path("tr-arm-node");
}

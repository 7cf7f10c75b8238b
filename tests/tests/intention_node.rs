//! pab-intent (HBBA's intention node, on the setup `pabctl compile` writes) on an in-process bus with the tour guide's nodes as `pab-app` nodes (their compiled
//! tables, their own code), in virtual time: every frame any of them sends reaches all the others
//! at once. The nodes apply the filter commands and acknowledge them (FilterStatus), and their
//! arbiters then filter as commanded; a node whose table has no filters refuses them
//! (FilterRefused, detail 3), which pab-intent reports, publishing the intention all the same; a
//! desire whose lease runs out is dropped and the intention recomputed; a node that restarts gets
//! its filters again. On a keyed network, the nodes apply only the commands pab-intent seals with
//! their key, and pab-intent without it is refused and says what to do. Last, the async loop
//! (`pab_intent::run`) on a channel bus in real time.

use pab_app::{BoardNode, Config, Step};
use pab_core::auth::Key;
use pab_core::protocol::{
    self, BROADCAST, DesireFrame, Fault, FaultCode, FrameId, INTENTION, Message,
};
use pab_core::{Frame, Instant};
use pab_intent::{IntentNode, Report, Setup};
use pab_lang::compile;
use pab_lang::diagnostic::Source;
use pab_lang::network::Network;

fn tour_guide() -> Network {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/tour-guide.toml");
    let text = std::fs::read_to_string(path).unwrap();
    Network::parse(Source::new("tour-guide.toml", text)).unwrap_or_else(|e| panic!("{e}"))
}

const S: u64 = 1_000_000;
/// The motivation that sends desires.
const MOTIVATION: u8 = 9;

/// Strategy bits of the tour guide (file order).
const FACE_FULL: u64 = 1 << 0;
const QR_FULL: u64 = 1 << 2;
const VOICE_LOCALISE: u64 = 1 << 3;
const NAV_FOLLOW: u64 = 1 << 4;
const AVOID_LASER: u64 = 1 << 5;
const TOURING: u64 = FACE_FULL | QR_FULL | NAV_FOLLOW | AVOID_LASER;

struct Bus<'a> {
    now: u64,
    intent: IntentNode<'a>,
    /// (id, image, node).
    nodes: Vec<(u8, Vec<u8>, Box<BoardNode>)>,
    /// Every frame on the bus: (µs, frame).
    frames: Vec<(u64, Frame)>,
    reports: Vec<(u64, Report)>,
}

fn boot(id: u8, image: &[u8], now: u64) -> Box<BoardNode> {
    boot_keyed(id, image, now, None)
}

/// [`boot`], with `key` (and a boot salt of the node's own) when given.
fn boot_keyed(id: u8, image: &[u8], now: u64, key: Option<&Key>) -> Box<BoardNode> {
    let at = Instant::from_micros(now);
    let mut node = Box::new(BoardNode::new(Config::new(id).unwrap(), at));
    if let Some(key) = key {
        node.set_key(key, 0x0100 + u32::from(id));
    }
    node.boot_buffer()[..image.len()].copy_from_slice(image);
    node.boot(Some(image.len()), at);
    node
}

/// `image` with its table's message filters taken out: a node that runs no filters.
fn without_filters(image: &[u8]) -> Vec<u8> {
    let loaded = pab_core::image::load::<4, 64, 256>(image).unwrap();
    let mut table = loaded.table;
    table.set_filters(Default::default()).unwrap();
    let mut out = vec![0u8; pab_core::image::MAX_IMAGE_LEN];
    let len = pab_core::image::encode(
        &table,
        loaded.header.node_id,
        loaded.header.table_version,
        &mut out,
    )
    .unwrap();
    out.truncate(len);
    out
}

impl<'a> Bus<'a> {
    fn new(network: &Network, setup: &'a Setup) -> Bus<'a> {
        Bus::with_images(network, setup, |image| image.to_vec())
    }

    /// The nodes booted with `image(compiled image)`.
    fn with_images(
        network: &Network,
        setup: &'a Setup,
        image: impl Fn(&[u8]) -> Vec<u8>,
    ) -> Bus<'a> {
        Bus::keyed(network, setup, image, None, None)
    }

    /// [`Bus::with_images`], the nodes with `nodes_key`, pab-intent with `intent_key`.
    fn keyed(
        network: &Network,
        setup: &'a Setup,
        image: impl Fn(&[u8]) -> Vec<u8>,
        nodes_key: Option<&Key>,
        intent_key: Option<&Key>,
    ) -> Bus<'a> {
        let compiled = compile::compile(network).unwrap_or_else(|e| panic!("{e:?}"));
        let nodes = compiled
            .iter()
            .map(|c| {
                let image = image(&c.image);
                let node = boot_keyed(c.id, &image, 0, nodes_key);
                (c.id, image, node)
            })
            .collect();
        let mut intent = IntentNode::new(setup, INTENTION).unwrap();
        if let Some(key) = intent_key {
            intent.set_key(key, 0xABCD, Instant::from_micros(0));
        }
        let mut bus = Bus {
            now: 0,
            intent,
            nodes,
            frames: Vec::new(),
            reports: Vec::new(),
        };
        bus.exchange();
        bus
    }

    fn at(&self) -> Instant {
        Instant::from_micros(self.now)
    }

    /// Every frame sent goes to everyone else, until nobody has anything to send.
    fn exchange(&mut self) {
        loop {
            let mut batch: Vec<(Option<usize>, Frame)> = Vec::new();
            while let Some(frame) = self.intent.next_outgoing() {
                batch.push((None, frame));
            }
            for (k, (_, _, node)) in self.nodes.iter_mut().enumerate() {
                while let Some(frame) = node.next_outgoing() {
                    batch.push((Some(k), frame));
                }
            }
            while let Some(report) = self.intent.next_report() {
                self.reports.push((self.now, report));
            }
            if batch.is_empty() {
                break;
            }
            for (from, frame) in batch {
                self.deliver(from, &frame);
            }
        }
    }

    fn deliver(&mut self, from: Option<usize>, frame: &Frame) {
        let now = self.at();
        self.frames.push((self.now, *frame));
        if from.is_some() {
            self.intent.on_frame(frame, now);
        }
        for (k, (_, _, node)) in self.nodes.iter_mut().enumerate() {
            if from != Some(k) && node.on_frame(frame, now, &mut ()) == Step::Store {
                node.stored(true, now);
            }
        }
    }

    /// A frame from a participant that is not simulated here (a motivation).
    fn send(&mut self, frame: &Frame) {
        self.deliver(None, frame);
        self.intent.on_frame(frame, self.at());
        self.exchange();
    }

    fn desire(&mut self, id: u16, class: &str, intensity: u16, lease_ms: u16) {
        let class = ["face", "qr", "voice", "nav", "avoid"]
            .iter()
            .position(|c| *c == class)
            .unwrap() as u8;
        let desire = Message::Desire(DesireFrame {
            class,
            intensity,
            lease_ms,
            id,
        });
        self.send(&desire.to_frame(MOTIVATION, BROADCAST));
    }

    fn advance_to(&mut self, t: u64) {
        let mut guard = 0;
        loop {
            guard += 1;
            assert!(guard < 100_000, "stuck at {} µs", self.now);
            let now = self.at();
            let next = self
                .nodes
                .iter()
                .map(|(_, _, n)| n.deadline(now).as_micros())
                .chain([self.intent.deadline(now).as_micros()])
                .min()
                .unwrap()
                .max(self.now);
            if next > t {
                break;
            }
            self.now = next;
            self.poll_all();
        }
        self.now = t;
        self.poll_all();
    }

    fn poll_all(&mut self) {
        let now = self.at();
        self.intent.poll(now);
        for (_, _, node) in self.nodes.iter_mut() {
            // Nothing is pushed here, so no image waits to be stored; a runner would store it.
            if node.poll(now, &mut ()) == Step::Store {
                node.stored(true, now);
            }
        }
        self.exchange();
    }

    /// Node `id` starts again, with its table, now.
    fn restart(&mut self, id: u8) {
        let now = self.now;
        let entry = self.nodes.iter_mut().find(|(n, ..)| *n == id).unwrap();
        entry.2 = boot(id, &entry.1.clone(), now);
        self.exchange();
    }

    /// Our messages since `from` µs: (µs, id, message).
    fn messages(&self, from: u64) -> Vec<(u64, FrameId, Message)> {
        self.frames
            .iter()
            .filter(|(t, _)| *t >= from)
            .filter_map(|(t, f)| Message::decode(f).ok().map(|(id, m)| (*t, id, m)))
            .collect()
    }

    /// The intentions published since `from` µs: (µs, strategies).
    fn intentions(&self, from: u64) -> Vec<(u64, u64)> {
        self.messages(from)
            .into_iter()
            .filter_map(|(t, id, m)| match m {
                Message::Intention(i) if id.source == INTENTION => Some((t, i.strategies)),
                _ => None,
            })
            .collect()
    }

    /// The FilterSets sent since `from` µs: (destination, port, connection, φ).
    fn filter_sets(&self, from: u64) -> Vec<(u8, u8, u8, u8)> {
        self.messages(from)
            .into_iter()
            .filter_map(|(_, id, m)| match m {
                Message::FilterSet(set) => {
                    Some((id.destination, set.port, set.connection, set.phi))
                }
                _ => None,
            })
            .collect()
    }

    fn reports_since(&self, from: u64) -> Vec<&Report> {
        self.reports
            .iter()
            .filter(|(t, _)| *t >= from)
            .map(|(_, r)| r)
            .collect()
    }
}

fn touring(bus: &mut Bus) {
    bus.desire(1, "face", 2, 10_000);
    bus.desire(2, "qr", 1, 10_000);
    bus.desire(3, "nav", 2, 10_000);
}

#[test]
fn the_nodes_apply_the_commands_and_filter_as_commanded() {
    let network = tour_guide();
    let setup = compile::intention_setup(&network).unwrap();
    let mut bus = Bus::new(&network, &setup);
    // At boot every filtered connection is closed.
    let phi = |bus: &Bus, node: usize, port: u8, connection: u8| {
        bus.nodes[node]
            .2
            .arbiter()
            .unwrap()
            .filter_phi(port, connection)
    };
    assert_eq!(phi(&bus, 0, 0, 0), Some(0));
    bus.advance_to(S / 2);
    touring(&mut bus);
    bus.advance_to(S);
    // Touring: FACE (head port 0, connection 0), QR (head port 1) and NAV, AVOID (base) open;
    // VOICE (head port 0, connection 1) stays closed.
    assert_eq!(
        (phi(&bus, 0, 0, 0), phi(&bus, 0, 0, 1), phi(&bus, 0, 1, 0)),
        (Some(1), Some(0), Some(1))
    );
    assert_eq!((phi(&bus, 1, 0, 0), phi(&bus, 1, 0, 1)), (Some(1), Some(1)));
    // Acknowledged: each node answered with FilterStatus, nothing was refused or sent again.
    let statuses = bus
        .messages(S / 2)
        .into_iter()
        .filter(|(_, _, m)| matches!(m, Message::FilterStatus(_)))
        .count();
    assert!(statuses >= 4, "{statuses}");
    let warnings: Vec<String> = bus
        .reports_since(S / 2)
        .into_iter()
        .filter(|r| r.warning)
        .map(|r| r.text.clone())
        .collect();
    assert!(warnings.is_empty(), "{warnings:#?}");
    // The noise: voice opens, QR closes, faces one in three.
    bus.desire(7, "voice", 3, 60_000);
    bus.advance_to(2 * S);
    assert_eq!(
        (phi(&bus, 0, 0, 0), phi(&bus, 0, 0, 1), phi(&bus, 0, 1, 0)),
        (Some(3), Some(1), Some(0))
    );
}

const NETWORK_KEY: Key = Key::from_bytes(*b"tour-guide-key16");

/// Every filter of the tour guide's nodes as (head port 0 connection 0, connection 1, head port 1
/// connection 0, base port 0 connection 0, connection 1).
fn filters(bus: &Bus) -> [Option<u8>; 5] {
    let phi = |node: usize, port: u8, connection: u8| {
        bus.nodes[node]
            .2
            .arbiter()
            .unwrap()
            .filter_phi(port, connection)
    };
    [
        phi(0, 0, 0),
        phi(0, 0, 1),
        phi(0, 1, 0),
        phi(1, 0, 0),
        phi(1, 0, 1),
    ]
}

#[test]
fn keyed_nodes_apply_the_commands_pab_intent_seals_with_their_key() {
    let network = tour_guide();
    let setup = compile::intention_setup(&network).unwrap();
    let mut bus = Bus::keyed(
        &network,
        &setup,
        |image| image.to_vec(),
        Some(&NETWORK_KEY),
        Some(&NETWORK_KEY),
    );
    bus.advance_to(S / 2);
    touring(&mut bus);
    bus.advance_to(2 * S);
    // Each node's first command was refused unsynchronised (it asked, pab-intent answered) and
    // the command sent again 250 ms later applied: touring's filters, as without keys.
    assert_eq!(filters(&bus), [Some(1), Some(0), Some(1), Some(1), Some(1)]);
    let sealed = bus
        .messages(S / 2)
        .into_iter()
        .filter(|(_, id, m)| matches!(m, Message::Seal(_)) && id.source == INTENTION)
        .count();
    assert!(
        sealed >= bus.filter_sets(S / 2).len(),
        "every command sealed"
    );
    let warnings: Vec<String> = bus
        .reports_since(0)
        .into_iter()
        .filter(|r| r.warning)
        .map(|r| r.text.clone())
        .collect();
    assert!(
        warnings.iter().all(|w| w.contains("again (send")),
        "{warnings:#?}"
    );
    assert!(
        bus.reports_since(0)
            .iter()
            .any(|r| r.text.contains("asked where our seals stand")),
        "the synchronisation said"
    );
}

#[test]
fn keyed_nodes_refuse_a_pab_intent_without_their_key_and_it_says_so() {
    let network = tour_guide();
    let setup = compile::intention_setup(&network).unwrap();
    let other = Key::from_bytes(*b"not-the-nodes-k!");
    for intent_key in [None, Some(&other)] {
        let mut bus = Bus::keyed(
            &network,
            &setup,
            |image| image.to_vec(),
            Some(&NETWORK_KEY),
            intent_key,
        );
        bus.advance_to(S / 2);
        touring(&mut bus);
        bus.advance_to(3 * S);
        // Nothing applied: every filtered connection stays closed, as at boot.
        assert_eq!(filters(&bus), [Some(0); 5], "with {intent_key:?}");
        let hint = if intent_key.is_some() {
            "is pab-intent's key the node's?"
        } else {
            "start pab-intent with --key"
        };
        assert!(
            bus.reports_since(0).iter().any(|r| r.warning
                && r.text.contains("refused a frame of ours")
                && r.text.contains(hint)),
            "{:#?}",
            bus.reports_since(0)
        );
    }
}

#[test]
fn a_refusal_is_reported_clearly_and_the_intention_still_published() {
    let network = tour_guide();
    let setup = compile::intention_setup(&network).unwrap();
    // Nodes whose tables carry no message filters (say, pushed from a file without `[hbba]`).
    let mut bus = Bus::with_images(&network, &setup, without_filters);
    bus.advance_to(S / 2);
    touring(&mut bus);
    bus.advance_to(3 * S);
    // The head (node 1) refuses FACE and QR, the base (node 2) NAV and AVOID: each reported
    // with its node, connection, port, φ and reason.
    let warnings: Vec<String> = bus
        .reports_since(S / 2)
        .into_iter()
        .filter(|r| r.warning)
        .map(|r| r.text.clone())
        .collect();
    for expected in [
        "head (node 1) refused FACE (head.gaze) φ 1: its table has no message filters (FilterRefused, detail 3); the intention is not in force there",
        "head (node 1) refused QR (head.display) φ 1: its table has no message filters",
        "base (node 2) refused NAV (base.drive) φ 1: its table has no message filters",
        "base (node 2) refused AVOID (base.drive) φ 1: its table has no message filters",
        "filters settled: 4 refused, 0 unanswered",
    ] {
        assert!(
            warnings.iter().any(|w| w.starts_with(expected)),
            "no {expected:?} in {warnings:#?}"
        );
    }
    // Refused, not lost: nothing was sent again.
    assert!(
        !warnings.iter().any(|w| w.contains("again")),
        "{warnings:#?}"
    );
    // VOICE stays closed: its closing, refused at start, is not asked again.
    assert_eq!(
        bus.filter_sets(S / 2),
        [(1, 0, 0, 1), (1, 1, 0, 1), (2, 0, 0, 1), (2, 0, 1, 1)]
    );
    // The intention: published at the change, then every second.
    let intentions = bus.intentions(S / 2);
    assert_eq!(intentions.first(), Some(&(S / 2, TOURING)));
    let times: Vec<u64> = intentions.iter().map(|(t, _)| *t).collect();
    assert_eq!(times, [S / 2, 3 * S / 2, 5 * S / 2]);
    assert!(intentions.iter().all(|(_, s)| *s == TOURING));
}

#[test]
fn a_desire_whose_lease_runs_out_is_dropped_and_the_intention_recomputed() {
    let network = tour_guide();
    let setup = compile::intention_setup(&network).unwrap();
    let mut bus = Bus::new(&network, &setup);
    bus.advance_to(S / 2);
    bus.desire(7, "voice", 3, 400);
    bus.advance_to(S / 2 + 399_999);
    assert_eq!(bus.intentions(S / 2).last(), Some(&(S / 2, VOICE_LOCALISE)));
    let before = bus.now + 1;
    bus.advance_to(2 * S);
    // At the lease's end: the intention without it, published at once, and VOICE closed.
    assert_eq!(
        bus.intentions(before).first(),
        Some(&(S / 2 + 400_000, 0)),
        "{:?}",
        bus.intentions(0)
    );
    let texts: Vec<String> = bus
        .reports_since(before)
        .into_iter()
        .map(|r| r.text.clone())
        .collect();
    assert_eq!(texts[0], "a desire's lease ran out: recomputing");
    assert_eq!(texts[1], "selected: none (objective 0)");
    assert_eq!(bus.filter_sets(before), [(1, 0, 1, 0)]);
    assert!(bus.intent.workspace().desires().held().is_empty());
}

#[test]
fn a_restarted_node_gets_its_filters_again() {
    let network = tour_guide();
    let setup = compile::intention_setup(&network).unwrap();
    let mut bus = Bus::new(&network, &setup);
    bus.advance_to(S / 2);
    touring(&mut bus);
    bus.advance_to(2 * S + S / 2);
    let restart = bus.now;
    bus.restart(1);
    bus.advance_to(3 * S);
    let texts: Vec<String> = bus
        .reports_since(restart)
        .into_iter()
        .map(|r| r.text.clone())
        .collect();
    assert!(
        texts
            .iter()
            .any(|t| t == "head (node 1) restarted or was heard first: re-applying its filters"),
        "{texts:#?}"
    );
    // Every filter of the head, the closed VOICE included (first, as a reduction), and none of
    // the base's.
    assert_eq!(
        bus.filter_sets(restart),
        [(1, 0, 1, 0), (1, 0, 0, 1), (1, 1, 0, 1)]
    );
    // Its heartbeat showed the restart: uptime back to 0.
    assert!(
        bus.messages(restart)
            .iter()
            .any(|(_, id, m)| id.source == 1
                && matches!(m, Message::Heartbeat(h) if h.uptime_s == 0))
    );
}

mod async_loop {
    use std::cell::RefCell;

    use embassy_futures::select::{Either, select};
    use pab_app::CanBus;
    use pab_app::testing::{Endpoint, TestBus};
    use pab_intent::{SystemClock, run};

    use super::*;

    /// The intention node's end and the boards' (the test's).
    type Bus = TestBus<2, 256>;

    /// The next message from the intention node within 2 s that `wanted` picks.
    async fn next<T>(
        from: &mut Endpoint<'_, 2, 256>,
        mut wanted: impl FnMut(FrameId, Message) -> Option<T>,
    ) -> T {
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(2);
        loop {
            let timer = async_io::Timer::at(deadline);
            let frame = match select(from.receive(), timer).await {
                Either::First(Ok(frame)) => frame,
                Either::First(Err(error)) => panic!("the boards' end of the bus: {error:?}"),
                Either::Second(_) => panic!("nothing wanted from the intention node in 2 s"),
            };
            if let Ok((id, message)) = Message::decode(&frame)
                && let Some(found) = wanted(id, message)
            {
                return found;
            }
        }
    }

    #[test]
    fn the_loop_sends_commands_publishes_and_reports_a_refusal() {
        let network = tour_guide();
        let setup = compile::intention_setup(&network).unwrap();
        let mut node = IntentNode::new(&setup, INTENTION).unwrap();
        let test_bus = Bus::new();
        let mut bus = test_bus.endpoint(0).unwrap();
        let mut boards = test_bus.endpoint(1).unwrap();
        let reports: RefCell<Vec<Report>> = RefCell::new(Vec::new());
        let mut clock = SystemClock::new();
        let mut report = |r: Report| reports.borrow_mut().push(r);
        let script = async {
            // The first plan closes every filter (nothing desired).
            let first = next(&mut boards, |_, m| match m {
                Message::FilterSet(set) => Some(set),
                _ => None,
            })
            .await;
            assert_eq!(first.phi, 0);
            let voice = Message::Desire(DesireFrame {
                class: 2,
                intensity: 3,
                lease_ms: 5000,
                id: 1,
            });
            boards.send(&voice.to_frame(MOTIVATION, BROADCAST));
            let published = next(&mut boards, |id, m| match m {
                Message::Intention(i) if id.source == INTENTION && i.strategies != 0 => {
                    Some(i.strategies)
                }
                _ => None,
            })
            .await;
            assert_eq!(published, VOICE_LOCALISE);
            let (node, set) = next(&mut boards, |id, m| match m {
                Message::FilterSet(set) if set.phi == 1 => Some((id.destination, set)),
                _ => None,
            })
            .await;
            assert_eq!((node, set.port, set.connection), (1, 0, 1));
            // The head refuses it, as every node does today.
            let [s0, s1] = set.sequence.to_le_bytes();
            let refusal = Message::Fault(Fault {
                code: FaultCode::FilterRefused,
                count: 1,
                detail: [3, set.port, set.connection, s0, s1],
            });
            boards.send(&refusal.to_frame(1, protocol::BROADCAST));
            // Published again within the second, all the same.
            let again = next(&mut boards, |id, m| match m {
                Message::Intention(i) if id.source == INTENTION => Some(i.strategies),
                _ => None,
            })
            .await;
            assert_eq!(again, VOICE_LOCALISE);
        };
        futures::executor::block_on(async {
            match select(run(&mut node, &mut bus, &mut clock, &mut report), script).await {
                Either::First(never) => match never {},
                Either::Second(()) => {}
            }
        });
        let reports = reports.into_inner();
        assert!(
            reports.iter().any(|r| r.warning
                && r.text.starts_with(
                    "head (node 1) refused VOICE (head.gaze) φ 1: its table has no message filters"
                )),
            "{reports:#?}"
        );
        assert!(
            reports
                .iter()
                .any(|r| r.text == "selected: voice_localise (objective 9)"),
            "{reports:#?}"
        );
    }
}

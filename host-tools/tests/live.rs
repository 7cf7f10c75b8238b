//! `pabctl push`, `nodes` and `monitor` against real node code: each node is the board
//! application (`pab-app`, full capacities) on a thread, in real time, on an in-process bus.
//! Only the SocketCAN socket is left out (this kernel has none; the HIL suite covers it).

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use pab_core::Frame;
use pab_core::isotp::{RxEvent, Sender, TxConfig, TxEvent};
use pab_core::protocol::{self, Message, TransferStatus, TransferStatusCode};
use pab_lang::compile::{self, CompiledNode};
use pab_lang::network::Network;
use pabctl::bus::Bus;
use pabctl::bus::memory::{MemoryBus, MemoryHub};

mod common;
use common::LiveNode;
use pabctl::monitor;
use pabctl::observe::{self, Observer};
use pabctl::push::{self, Outcome, Timeouts};

fn take_and_return() -> (Network, Vec<CompiledNode>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/take-and-return.toml");
    let network = Network::load(&path).unwrap();
    let nodes = compile::compile(&network).unwrap();
    (network, nodes)
}

fn header(image: &[u8]) -> pab_core::image::Header {
    pab_core::image::read_header(image).unwrap()
}

#[test]
fn push_reaches_every_node_which_confirms_stores_and_reports_it() {
    let (network, compiled) = take_and_return();
    let hub = MemoryHub::new();
    let nodes: Vec<LiveNode> = compiled
        .iter()
        .map(|node| LiveNode::spawn(&hub, node.id, None))
        .collect();
    let mut tool = hub.connect();
    for (node, live) in compiled.iter().zip(&nodes) {
        let mut progress = Vec::new();
        let outcome = push::push(
            &mut tool,
            node.id,
            &node.image,
            &header(&node.image),
            Timeouts::default(),
            &mut |sent, total| progress.push((sent, total)),
        )
        .unwrap();
        assert_eq!(
            outcome,
            Outcome::Confirmed {
                version: network.version,
                stored: true
            },
            "node {}",
            node.name
        );
        assert_eq!(progress.last(), Some(&(node.image.len(), node.image.len())));
        assert_eq!(*live.stored.lock().unwrap(), vec![node.image.clone()]);
    }
    // `pabctl nodes`: every node, operational, with the version and CRC pushed.
    let mut observer = Observer::new();
    observe::listen(&mut tool, &mut observer, Duration::from_millis(1_200)).unwrap();
    for node in &compiled {
        let view = observer.node(node.id).expect("heard from every node");
        let (heartbeat, _) = view.heartbeat.unwrap();
        assert_eq!(heartbeat.state, pab_core::protocol::NodeState::Operational);
        assert_eq!(heartbeat.table_version, network.version);
        assert_eq!(view.table.unwrap().crc, header(&node.image).crc);
        assert!(view.table.unwrap().stored);
    }
    let names = compiled.iter().map(|n| (n.id, n.name.clone())).collect();
    let table = observe::nodes_table(&observer, &names, Instant::now());
    for node in &compiled {
        assert!(table.contains(&node.name), "{table}");
    }
    assert!(table.contains("operational"), "{table}");
    // Pushing the same tables again changes nothing.
    let again = push::push(
        &mut tool,
        compiled[0].id,
        &compiled[0].image,
        &header(&compiled[0].image),
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(
        again,
        Outcome::AlreadyCurrent {
            version: network.version
        }
    );
    assert_eq!(nodes[0].stored.lock().unwrap().len(), 1);
}

/// The same push in CAN FD frames (`pabctl push --fd`): every node confirms, every data frame is
/// a CAN FD one with the bit-rate switch, each node's flow control answers in CAN FD, and the
/// push takes a fifth of the frames of a classic one or fewer (63 bytes a frame against 7).
#[test]
fn a_push_in_can_fd_frames_reaches_every_node_in_fewer_frames() {
    let (network, compiled) = take_and_return();
    let hub = MemoryHub::new();
    let _nodes: Vec<LiveNode> = compiled
        .iter()
        .map(|node| LiveNode::spawn(&hub, node.id, None))
        .collect();
    let mut tool = hub.connect().with_framing(pabctl::bus::Framing::Fd);
    let mut watcher = hub.connect();
    for node in &compiled {
        let mut frames = 0;
        let outcome = push::push(
            &mut tool,
            node.id,
            &node.image,
            &header(&node.image),
            Timeouts::default(),
            &mut |_, _| frames += 1,
        )
        .unwrap();
        assert_eq!(
            outcome,
            Outcome::Confirmed {
                version: network.version,
                stored: true
            },
            "node {}",
            node.name
        );
        let len = node.image.len();
        assert_eq!(frames, 1 + (len - 62).div_ceil(63), "node {}", node.name);
        assert!(frames * 5 < 1 + (len - 6).div_ceil(7), "node {}", node.name);
    }
    // What went over the bus: the transfers' frames, each of them CAN FD with its bit-rate switch.
    let mut transfer_frames = 0;
    while let Some(frame) = watcher.try_receive() {
        if let Ok((id, Message::TableTransfer { .. })) = Message::decode(&frame) {
            transfer_frames += 1;
            assert!(frame.is_fd() && frame.is_brs(), "{id:?}: {frame:?}");
        }
    }
    assert!(transfer_frames > compiled.len() * 2, "{transfer_frames}");
}

/// A CAN FD push nobody answers says what a classic node does with CAN FD frames.
#[test]
fn an_unanswered_can_fd_push_says_a_classic_node_ignores_it() {
    let (_, compiled) = take_and_return();
    let hub = MemoryHub::new();
    let mut tool = hub.connect().with_framing(pabctl::bus::Framing::Fd);
    let node = &compiled[0];
    let outcome = push::push(
        &mut tool,
        node.id,
        &node.image,
        &header(&node.image),
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    let Outcome::NoAnswer(why) = outcome else {
        panic!("{outcome:?}");
    };
    assert!(
        why.contains("CAN FD") && why.contains("without --fd"),
        "{why}"
    );
}

#[test]
fn refusals_and_silence_are_reported_with_their_reason() {
    // The arm runs version 2 of its table.
    let (mut network, older) = take_and_return();
    network.version += 1;
    let compiled = compile::compile(&network).unwrap();
    let arm = &compiled[0];
    let hub = MemoryHub::new();
    let _arm = LiveNode::spawn(&hub, arm.id, Some(arm.image.clone()));
    let mut tool = hub.connect();
    // Another node's table.
    let other = &compiled[1];
    let outcome = push::push(
        &mut tool,
        arm.id,
        &other.image,
        &header(&other.image),
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(
        outcome,
        Outcome::Refused {
            status: TransferStatusCode::WrongNode,
            detail: other.id,
            running_version: network.version
        }
    );
    assert!(outcome.to_string().contains("another node"), "{outcome}");
    // An older version of its own table.
    let outcome = push::push(
        &mut tool,
        arm.id,
        &older[0].image,
        &header(&older[0].image),
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    assert!(
        matches!(
            outcome,
            Outcome::Refused {
                status: TransferStatusCode::OlderVersion,
                ..
            }
        ),
        "{outcome:?}"
    );
    // Nobody home at id 99.
    let started = Instant::now();
    let outcome = push::push(
        &mut tool,
        99,
        &arm.image,
        &header(&arm.image),
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    assert!(
        matches!(&outcome, Outcome::NoAnswer(why) if why.contains("no flow control")),
        "{outcome:?}"
    );
    assert!(started.elapsed() < Duration::from_secs(3));
}

#[test]
fn monitor_shows_who_delivers_from_the_diagnostic_stream() {
    let (network, compiled) = take_and_return();
    let hub = MemoryHub::new();
    let _nodes: Vec<LiveNode> = compiled
        .iter()
        .map(|node| LiveNode::spawn(&hub, node.id, Some(node.image.clone())))
        .collect();
    // Rest Arm publishes at 50 Hz: C14 becomes active and delivers at arm.target.
    let publishing = Arc::new(AtomicBool::new(true));
    let publisher = {
        let mut bus = hub.connect();
        let publishing = publishing.clone();
        std::thread::spawn(move || {
            let rest_pose = Frame::with_raw_id(0x113, false, &[0; 8]).unwrap();
            while publishing.load(Ordering::SeqCst) {
                bus.send(&rest_pose).unwrap();
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };
    let mut tool = hub.connect();
    let mut screens = Vec::new();
    let observer = monitor::run(
        &mut tool,
        &network,
        20,
        Duration::from_millis(100),
        Some(Duration::from_millis(1_500)),
        &|| false,
        &mut |screen| screens.push(screen.to_string()),
        None,
    )
    .unwrap();
    publishing.store(false, Ordering::SeqCst);
    publisher.join().unwrap();
    let last = screens.last().expect("the monitor drew");
    let c14 = last
        .lines()
        .find(|line| line.trim_start().starts_with("C14"))
        .unwrap();
    assert!(
        c14.contains("ACTIVE") && c14.contains("◀ delivering"),
        "{last}"
    );
    let c1 = last
        .lines()
        .find(|line| line.trim_start().starts_with("C1 "))
        .unwrap();
    assert!(!c1.contains("delivering"), "{last}");
    // Every connection of every node was sampled.
    for node in &compiled {
        let view = observer.node(node.id).unwrap();
        assert_eq!(view.samples.len(), node.connections, "node {}", node.name);
    }
    // At the end the monitor switched the streams off: no samples arrive any more.
    std::thread::sleep(Duration::from_millis(200));
    while tool.try_receive().is_some() {}
    std::thread::sleep(Duration::from_millis(300));
    let mut late = Observer::new();
    while let Some(frame) = tool.try_receive() {
        late.observe(&frame, Instant::now());
    }
    assert!(late.nodes().values().all(|view| view.samples.is_empty()));
}

/// A participant that speaks for an absent node: `answer` sees each ISO-TP frame the tool sends
/// to `node` (with the bytes the node's receiver would take) and returns the frames to answer
/// with, as (service message) from `node` to the tool.
fn impostor(
    hub: &MemoryHub,
    node: u8,
    mut answer: impl FnMut(&[u8], &mut pab_core::isotp::Receiver<32768>) -> Vec<Message>
    + Send
    + 'static,
) -> (Arc<AtomicBool>, JoinHandle<()>) {
    let stop = Arc::new(AtomicBool::new(false));
    let mut bus = hub.connect();
    let stop_flag = stop.clone();
    let thread = std::thread::spawn(move || {
        // Flow control every 8 frames, as the nodes do: the tool reads the bus between blocks.
        let mut receiver = pab_core::isotp::Receiver::<32768>::new(pab_core::isotp::RxConfig {
            block_size: 8,
            ..Default::default()
        });
        while !stop_flag.load(Ordering::SeqCst) {
            let Ok(Some(frame)) = bus.receive(Duration::from_millis(5)) else {
                continue;
            };
            if let Ok((id, Message::TableTransfer { data, len })) = Message::decode(&frame)
                && id.destination == node
                && id.source == protocol::TOOL
            {
                for message in answer(&data[..usize::from(len)], &mut receiver) {
                    bus.send(&message.to_frame(node, protocol::TOOL)).unwrap();
                }
            }
        }
    });
    (stop, thread)
}

fn status(status: TransferStatusCode, running_version: u32) -> Message {
    Message::TransferStatus(TransferStatus {
        status,
        detail: 0,
        running_version,
    })
}

/// Take and Return's arm table, at version `version`.
fn arm_image(version: u32) -> Vec<u8> {
    let (mut network, _) = take_and_return();
    network.version = version;
    compile::compile(&network).unwrap().remove(0).image
}

#[test]
fn an_early_applied_from_an_impostor_is_not_a_push_done() {
    // Node 7 is absent. Something answers the first frame with a flow control (block size 1)
    // and at once a TransferStatus "applied" for the pushed version, and then falls silent: no
    // more flow control, no heartbeat. The push must not count as done.
    let hub = MemoryHub::new();
    let (stop, thread) = impostor(&hub, 7, |data, _| {
        if data[0] >> 4 != 1 {
            return Vec::new();
        }
        let mut flow_control = [0xCC; 8];
        flow_control[..3].copy_from_slice(&[0x30, 1, 0]);
        vec![
            Message::TableTransfer {
                data: flow_control,
                len: 8,
            },
            status(TransferStatusCode::Applied, 9),
        ]
    });
    let image = arm_image(9);
    let mut tool = hub.connect();
    let outcome = push::push(
        &mut tool,
        7,
        &image,
        &header(&image),
        Timeouts {
            answer: Duration::from_millis(500),
            confirm: Duration::from_millis(1_500),
        },
        &mut |_, _| {},
    )
    .unwrap();
    stop.store(true, Ordering::SeqCst);
    thread.join().unwrap();
    assert!(!outcome.is_success(), "{outcome}");
    assert!(
        matches!(&outcome, Outcome::NoAnswer(why) if why.contains("no flow control from node 7")),
        "{outcome:?}"
    );
}

#[test]
fn a_late_applied_from_an_earlier_push_does_not_count() {
    // Node 7 takes the transfer (flow control, every frame) but an answer of an earlier,
    // interrupted push (version 8 applied) reaches the tool during the transfer and again after
    // it. The node itself refuses the new image. The push reports the node's refusal.
    let hub = MemoryHub::new();
    let (stop, thread) = impostor(&hub, 7, |data, receiver| {
        let first = data[0] >> 4 == 1;
        let outcome = receiver.on_frame(data, pab_core::Instant::from_micros(0));
        match outcome.event {
            RxEvent::SendFlowControl(flow_control) if first => vec![
                Message::TableTransfer {
                    data: flow_control,
                    len: 8,
                },
                status(TransferStatusCode::Applied, 8),
            ],
            RxEvent::SendFlowControl(flow_control) => vec![Message::TableTransfer {
                data: flow_control,
                len: 8,
            }],
            RxEvent::Complete(_) => vec![
                status(TransferStatusCode::Applied, 8),
                status(TransferStatusCode::CrcMismatch, 8),
            ],
            _ => Vec::new(),
        }
    });
    let image = arm_image(9);
    let mut tool = hub.connect();
    let outcome = push::push(
        &mut tool,
        7,
        &image,
        &header(&image),
        Timeouts {
            answer: Duration::from_millis(1_000),
            confirm: Duration::from_millis(1_500),
        },
        &mut |_, _| {},
    )
    .unwrap();
    stop.store(true, Ordering::SeqCst);
    thread.join().unwrap();
    assert_eq!(
        outcome,
        Outcome::Refused {
            status: TransferStatusCode::CrcMismatch,
            detail: 0,
            running_version: 8
        }
    );
}

#[test]
fn an_applied_without_the_heartbeat_is_not_confirmed() {
    // The right answer for the right version, but no heartbeat ever shows it: not done.
    let hub = MemoryHub::new();
    let (stop, thread) = impostor(&hub, 7, |data, receiver| {
        let outcome = receiver.on_frame(data, pab_core::Instant::from_micros(0));
        match outcome.event {
            RxEvent::SendFlowControl(flow_control) => vec![Message::TableTransfer {
                data: flow_control,
                len: 8,
            }],
            RxEvent::Complete(_) => vec![status(TransferStatusCode::Applied, 9)],
            _ => Vec::new(),
        }
    });
    let image = arm_image(9);
    let mut tool = hub.connect();
    let outcome = push::push(
        &mut tool,
        7,
        &image,
        &header(&image),
        Timeouts {
            answer: Duration::from_millis(1_000),
            confirm: Duration::from_millis(800),
        },
        &mut |_, _| {},
    )
    .unwrap();
    stop.store(true, Ordering::SeqCst);
    thread.join().unwrap();
    assert!(!outcome.is_success(), "{outcome}");
    assert_eq!(
        outcome.to_string(),
        "not confirmed: no heartbeat within 0.8 s"
    );
}

#[test]
fn nodes_shows_why_a_node_booted_without_a_table_even_long_after_its_boot() {
    // Node 2 started with the arm's table (compiled for node 1).
    let (_, compiled) = take_and_return();
    let hub = MemoryHub::new();
    let _hand = LiveNode::spawn(&hub, 2, Some(compiled[0].image.clone()));
    let mut tool = hub.connect();
    // The tool comes later than the boot.
    std::thread::sleep(Duration::from_millis(1_200));
    while tool.try_receive().is_some() {}
    let mut observer = Observer::new();
    observe::listen(&mut tool, &mut observer, Duration::from_millis(1_200)).unwrap();
    let table = observe::nodes_table(&observer, &Default::default(), Instant::now());
    let line = table
        .lines()
        .find(|line| line.trim_start().starts_with("2 "))
        .unwrap_or_else(|| panic!("node 2 heard:\n{table}"));
    assert!(line.contains("no table"), "{table}");
    assert!(
        line.contains("stored table refused at boot: image is for another node (node 1)"),
        "{table}"
    );
}

#[test]
fn a_push_right_after_an_interrupted_one_is_not_refused_for_the_old_ones_end() {
    let (network, compiled) = take_and_return();
    let arm = &compiled[0];
    let hub = MemoryHub::new();
    let node = LiveNode::spawn(&hub, arm.id, None);
    // An earlier push, killed after its first frame and one consecutive frame.
    {
        let mut killed = hub.connect();
        let start = Instant::now();
        let now = || pab_core::Instant::from_micros(start.elapsed().as_micros() as u64);
        let mut sender = Sender::new(&arm.image, TxConfig::default()).unwrap();
        let mut sent = 0;
        while sent < 2 {
            match sender.poll(now()) {
                TxEvent::Send(data) => {
                    let frame =
                        Message::TableTransfer { data, len: 8 }.to_frame(protocol::TOOL, arm.id);
                    killed.send(&frame).unwrap();
                    sent += 1;
                }
                TxEvent::WaitUntil(_) => {
                    let frame = killed.receive(Duration::from_secs(1)).unwrap().unwrap();
                    if let Ok((_, Message::TableTransfer { data, len })) = Message::decode(&frame) {
                        sender.on_flow_control(&data[..usize::from(len)], now());
                    }
                }
                other => panic!("{other:?}"),
            }
        }
    }
    // At once (well within the node's 1 s N_Cr), a new pabctl pushes again.
    let mut tool = hub.connect();
    let outcome = push::push(
        &mut tool,
        arm.id,
        &arm.image,
        &header(&arm.image),
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(
        outcome,
        Outcome::Confirmed {
            version: network.version,
            stored: true
        }
    );
    assert_eq!(*node.stored.lock().unwrap(), vec![arm.image.clone()]);
}

/// Attack: answer for an absent node 8 so that pabctl believes a push succeeded: flow control,
/// `Applied`, a receipt it cannot compute, and a heartbeat group showing the pushed version and
/// CRC. Without a key pabctl is fooled (the limit the threat model states); with `--key` the
/// receipt does not verify and the push is not done.
#[test]
fn a_forged_confirmation_does_not_count_with_a_key() {
    let image = arm_image(9);
    let crc = header(&image).crc;
    let run = |keyed: bool| {
        let hub = MemoryHub::new();
        let stop = Arc::new(AtomicBool::new(false));
        let mut bus = hub.connect();
        let stop_flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut receiver = pab_core::isotp::Receiver::<32768>::new(pab_core::isotp::RxConfig {
                block_size: 8,
                ..Default::default()
            });
            let send = |bus: &mut MemoryBus, message: Message, to: u8| {
                bus.send(&message.to_frame(8, to)).unwrap();
            };
            while !stop_flag.load(Ordering::SeqCst) {
                let Ok(Some(frame)) = bus.receive(Duration::from_millis(5)) else {
                    continue;
                };
                let Ok((id, message)) = Message::decode(&frame) else {
                    continue;
                };
                if id.destination != 8 {
                    continue;
                }
                match message {
                    Message::ChallengeRequest { .. } => send(
                        &mut bus,
                        Message::Challenge {
                            node_nonce: 77,
                            binding: [0, 0],
                        },
                        protocol::TOOL,
                    ),
                    Message::TableTransfer { data, len } => {
                        let now = pab_core::Instant::from_micros(0);
                        match receiver.on_frame(&data[..usize::from(len)], now).event {
                            RxEvent::SendFlowControl(fc) => send(
                                &mut bus,
                                Message::TableTransfer { data: fc, len: 8 },
                                protocol::TOOL,
                            ),
                            RxEvent::Complete(_) => {
                                send(&mut bus, status(TransferStatusCode::Applied, 9), 0);
                                send(&mut bus, Message::Receipt { tag: [0x42; 8] }, 0);
                                for _ in 0..3 {
                                    send(
                                        &mut bus,
                                        Message::Heartbeat(protocol::Heartbeat {
                                            state: protocol::NodeState::Operational,
                                            uptime_s: 5,
                                            table_version: 9,
                                        }),
                                        protocol::BROADCAST,
                                    );
                                    send(
                                        &mut bus,
                                        Message::TableStatus(protocol::TableStatus {
                                            crc,
                                            image_len: 100,
                                            ports: 1,
                                            stored: true,
                                            diagnostic: false,
                                            keyed: true,
                                        }),
                                        protocol::BROADCAST,
                                    );
                                    std::thread::sleep(Duration::from_millis(100));
                                }
                            }
                            _ => {}
                        }
                    }
                    _ => {}
                }
            }
        });
        let mut tool = hub.connect();
        let timeouts = Timeouts {
            answer: Duration::from_millis(500),
            confirm: Duration::from_millis(1_000),
        };
        let outcome = if keyed {
            let credentials = push::Credentials {
                authenticator: pab_core::auth::Authenticator::new(
                    &pab_core::auth::Key::from_bytes([3; 16]),
                ),
                replace: false,
            };
            push::push_authenticated(
                &mut tool,
                8,
                &image,
                &header(&image),
                &credentials,
                timeouts,
                &mut |_, _| {},
            )
        } else {
            push::push(
                &mut tool,
                8,
                &image,
                &header(&image),
                timeouts,
                &mut |_, _| {},
            )
        }
        .unwrap();
        stop.store(true, Ordering::SeqCst);
        thread.join().unwrap();
        outcome
    };
    let fooled = run(false);
    assert!(
        fooled.is_success(),
        "without a key the impostor wins: {fooled}"
    );
    // With a key the impostor is caught at once: its challenge does not answer the tool's
    // request (it cannot bind it without the key), so the tool tags nothing.
    let keyed = run(true);
    assert!(!keyed.is_success(), "{keyed}");
    assert!(
        matches!(&keyed, Outcome::NoAnswer(why) if why.contains("1 challenge(s) in its name that did not")),
        "{keyed:?}"
    );
}

/// A participant floods a keyed node with bad tags (it asks for the node's challenge, then
/// tags commands over it with zeros, ten a millisecond): the node's checks for each second are
/// used up, the tool's open is refused unchecked, and `pabctl push --key` says that the node
/// refused that many tags because someone floods it, not "is it on the bus?".
#[test]
fn a_keyed_push_under_a_flood_of_bad_tags_says_the_node_refused_them() {
    let hub = MemoryHub::new();
    let key = pab_core::auth::Key::from_bytes([7; 16]);
    let _node = LiveNode::spawn_with(&hub, 1, None, Some(key));
    let flood = common::TagFlood::start(&hub, 1);
    std::thread::sleep(Duration::from_millis(200));
    let image = arm_image(5);
    let credentials = push::Credentials {
        authenticator: pab_core::auth::Authenticator::new(&key),
        replace: false,
    };
    let timeouts = Timeouts {
        answer: Duration::from_millis(500),
        confirm: Duration::from_millis(1_000),
    };
    let mut tool = hub.connect();
    // The window after each second's reset lets a few checks through before the flood uses them
    // up again: a push may land in it. Of five, one fails, and every failure says why.
    let mut failures = Vec::new();
    for _ in 0..5 {
        let outcome = push::push_authenticated(
            &mut tool,
            1,
            &image,
            &header(&image),
            &credentials,
            timeouts,
            &mut |_, _| {},
        )
        .unwrap();
        if !outcome.is_success() {
            failures.push(outcome.to_string());
            break;
        }
    }
    drop(flood);
    assert!(!failures.is_empty(), "every push got through the flood");
    for failure in &failures {
        assert!(
            failure.contains("the node refused") && failure.contains("someone is flooding"),
            "{failure}"
        );
    }
}

/// The same flood against `pabctl monitor --key`: the node refuses the monitor's challenge
/// request unchecked, and the monitor says under the node's name that it refused that many tags
/// because someone floods it, instead of showing connections without samples. Once the flood
/// stops, the request goes through.
#[test]
fn a_keyed_monitor_under_a_flood_of_bad_tags_says_the_node_refused_them() {
    let (mut network, _) = take_and_return();
    network.nodes.retain(|node| node.id == 1);
    let hub = MemoryHub::new();
    let key = pab_core::auth::Key::from_bytes([7; 16]);
    let _node = LiveNode::spawn_with(&hub, 1, None, Some(key));
    let authenticator = pab_core::auth::Authenticator::new(&key);
    let mut tool = hub.connect();
    let flood = common::TagFlood::start(&hub, 1);
    std::thread::sleep(Duration::from_millis(200));
    // As for the push: a request may land in the window after the node's second resets.
    let mut notes = Vec::new();
    for _ in 0..5 {
        let unasked =
            monitor::request_stream_keyed(&mut tool, &network, 10, &authenticator).unwrap();
        if let Some(why) = unasked.get(&1) {
            notes.push(why.clone());
            break;
        }
    }
    drop(flood);
    assert!(!notes.is_empty(), "every request got through the flood");
    for why in &notes {
        assert!(
            why.contains("the node refused") && why.contains("someone is flooding"),
            "{why}"
        );
    }
    // The node's checks come back with the next second.
    std::thread::sleep(Duration::from_millis(1_100));
    let unasked = monitor::request_stream_keyed(&mut tool, &network, 10, &authenticator).unwrap();
    assert!(unasked.is_empty(), "{unasked:?}");
}

/// Attack (pre-play): a participant answers the tool's challenge requests first, with challenges
/// it made up, to harvest the tool's tags over a nonce of its choosing and replay them later.
/// The tool takes only the Challenge bound to its own request: it tags nothing over the forged
/// ones, the push lands on the node's own challenge, and the node applies it once. (Before the
/// tool had a nonce of its own, it took the first Challenge that came and tagged it.)
#[test]
fn a_keyed_push_tags_no_challenge_a_participant_made_up() {
    let hub = MemoryHub::new();
    let key = pab_core::auth::Key::from_bytes([7; 16]);
    let node = LiveNode::spawn_with(&hub, 1, None, Some(key));
    let stop = Arc::new(AtomicBool::new(false));
    let mut rogue = hub.connect();
    let answering = stop.clone();
    let forger = std::thread::spawn(move || {
        let (mut forged, mut opens, mut requests, mut genuine) = (0u32, vec![], vec![], vec![]);
        while !answering.load(Ordering::SeqCst) {
            let Ok(Some(frame)) = rogue.receive(Duration::from_millis(5)) else {
                continue;
            };
            match Message::decode(&frame) {
                Ok((id, Message::Challenge { node_nonce, .. })) if id.source == 1 => {
                    genuine.push(node_nonce)
                }
                Ok((id, Message::ChallengeRequest { tool_nonce })) if id.destination == 1 => {
                    requests.push(tool_nonce);
                    // Ahead of the node (which answers within its own loop's turn).
                    let made_up = Message::Challenge {
                        node_nonce: 0x0000_1234_5678_9ABC,
                        binding: [0xA5, 0x5A],
                    };
                    rogue.send(&made_up.to_frame(1, protocol::TOOL)).unwrap();
                    forged += 1;
                }
                Ok((id, Message::TransferOpen(open))) if id.destination == 1 => opens.push(open),
                _ => {}
            }
        }
        (forged, opens, requests, genuine)
    });
    std::thread::sleep(Duration::from_millis(50));
    let image = arm_image(4);
    let credentials = push::Credentials {
        authenticator: pab_core::auth::Authenticator::new(&key),
        replace: false,
    };
    let mut tool = hub.connect();
    let outcome = push::push_authenticated(
        &mut tool,
        1,
        &image,
        &header(&image),
        &credentials,
        Timeouts::default(),
        &mut |_, _| {},
    )
    .unwrap();
    stop.store(true, Ordering::SeqCst);
    let (forged, opens, requests, genuine) = forger.join().unwrap();
    assert!(forged >= 1, "the participant answered no request");
    assert!(outcome.is_success(), "{outcome}");
    assert_eq!(
        node.stored.lock().unwrap().len(),
        1,
        "applied and stored once"
    );
    // One request, one open, whose tag is over the exchange of the node's own challenge and not
    // over the made-up one's.
    let ([tool_nonce], [node_nonce], [open]) = (&requests[..], &genuine[..], &opens[..]) else {
        panic!("one request, challenge and open: {requests:?} {genuine:?} {opens:?}");
    };
    let auth = pab_core::auth::Authenticator::new(&key);
    let over = |node_nonce: u64| {
        let nonce = auth.exchange(1, *tool_nonce, node_nonce).nonce;
        auth.open_tag(1, nonce, open.length, open.flags)
    };
    assert_eq!(open.tag, over(*node_nonce));
    assert_ne!(open.tag, over(0x0000_1234_5678_9ABC));
}

/// Attack (receipt replay): a participant records a keyed push (the node's Challenge, its
/// TransferStatus and Receipt, its heartbeat), and when the same image is pushed again to a node
/// that is no longer on the bus, replays them. The tool's nonce is new for every exchange and the
/// receipt covers it: the old challenge does not answer the new request, and the push is not
/// reported done. (Before, the replayed Challenge and Receipt made it report success.)
#[test]
fn a_replayed_challenge_and_receipt_do_not_confirm_a_push() {
    let hub = MemoryHub::new();
    let key = pab_core::auth::Key::from_bytes([7; 16]);
    let image = arm_image(6);
    let credentials = push::Credentials {
        authenticator: pab_core::auth::Authenticator::new(&key),
        replace: false,
    };
    let timeouts = Timeouts {
        answer: Duration::from_millis(500),
        confirm: Duration::from_millis(1_000),
    };
    // The genuine push, recorded by the participant.
    let mut recorder = hub.connect();
    let node = LiveNode::spawn_with(&hub, 1, None, Some(key));
    let mut tool = hub.connect();
    let first = push::push_authenticated(
        &mut tool,
        1,
        &image,
        &header(&image),
        &credentials,
        timeouts,
        &mut |_, _| {},
    )
    .unwrap();
    assert!(first.is_success(), "{first}");
    drop(node);
    let mut recorded = Vec::new();
    while let Ok(Some(frame)) = recorder.receive(Duration::ZERO) {
        if let Ok((id, message)) = Message::decode(&frame)
            && id.source == 1
            && matches!(
                message,
                Message::Challenge { .. }
                    | Message::TransferStatus(_)
                    | Message::Receipt { .. }
                    | Message::Heartbeat(_)
                    | Message::TableStatus(_)
            )
        {
            recorded.push((message, frame));
        }
    }
    assert!(
        recorded
            .iter()
            .any(|(m, _)| matches!(m, Message::Receipt { .. })),
        "the genuine push had a receipt to record"
    );
    // The node is gone; the participant replays the recording to the second push.
    let stop = Arc::new(AtomicBool::new(false));
    let replaying = stop.clone();
    let mut rogue = hub.connect();
    let replayer = std::thread::spawn(move || {
        while !replaying.load(Ordering::SeqCst) {
            let Ok(Some(frame)) = rogue.receive(Duration::from_millis(5)) else {
                continue;
            };
            match Message::decode(&frame) {
                Ok((_, Message::ChallengeRequest { .. })) => {
                    for (message, frame) in &recorded {
                        if matches!(message, Message::Challenge { .. }) {
                            rogue.send(frame).unwrap();
                        }
                    }
                }
                // The transfer's end (its last frame, or any: the recording answers at once).
                Ok((_, Message::TableTransfer { .. } | Message::TransferOpen(_))) => {
                    for (message, frame) in &recorded {
                        if !matches!(message, Message::Challenge { .. }) {
                            rogue.send(frame).unwrap();
                        }
                    }
                }
                _ => {}
            }
        }
    });
    let second = push::push_authenticated(
        &mut tool,
        1,
        &image,
        &header(&image),
        &credentials,
        timeouts,
        &mut |_, _| {},
    )
    .unwrap();
    stop.store(true, Ordering::SeqCst);
    replayer.join().unwrap();
    assert!(
        !second.is_success(),
        "a node off the bus reported done: {second}"
    );
    assert!(
        matches!(&second, Outcome::NoAnswer(why) if why.contains("that did not")),
        "{second:?}"
    );
}

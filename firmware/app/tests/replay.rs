//! The verdict hook of the node application and the replay record it feeds: what a replay runner
//! (the Linux node's, the emulated board's) writes for each frame.

use crate::common;

use common::*;
use pab_app::replay::{self, Recorder, job::TimedFrame};
use pab_app::{Config, Recipient};
use pab_core::{
    Arbiter, Connection, DecisionNode, Filter, Frame, Instant, NodeRef, PortVerdict, Stimulation,
};

/// Everything the node showed its recipient, in order.
#[derive(Default)]
struct Observer {
    /// (port, delivered connection, selected, fed bits, active bits, level of each fed
    /// connection) per verdict, or a delivery (port).
    events: Vec<String>,
}

impl Recipient for Observer {
    const OBSERVES_VERDICTS: bool = true;

    fn deliver(&mut self, port: u8, _frame: &Frame, _now: Instant) {
        self.events.push(format!("deliver {port}"));
    }

    fn verdict<const P: usize, const C: usize, const N: usize>(
        &mut self,
        _frame: &Frame,
        now: Instant,
        verdict: &PortVerdict,
        arbiter: &Arbiter<P, C, N>,
    ) {
        let levels: Vec<u32> = verdict
            .fed
            .iter()
            .map(|c| arbiter.level(verdict.port, c, now).unwrap().raw())
            .collect();
        self.events.push(format!(
            "verdict {} fed {:b} active {:b} selected {:?} delivered {:?} levels {levels:?}",
            verdict.port,
            verdict.fed.bits(),
            verdict.active.bits(),
            verdict.selected,
            verdict.delivered
        ));
    }
}

/// A recipient that does not observe: its `verdict` must never be called.
#[derive(Default)]
struct Blind {
    verdicts: usize,
    deliveries: usize,
}

impl Recipient for Blind {
    fn deliver(&mut self, _port: u8, _frame: &Frame, _now: Instant) {
        self.deliveries += 1;
    }

    fn verdict<const P: usize, const C: usize, const N: usize>(
        &mut self,
        _frame: &Frame,
        _now: Instant,
        _verdict: &PortVerdict,
        _arbiter: &Arbiter<P, C, N>,
    ) {
        self.verdicts += 1;
    }
}

/// Two ports fed by TOPIC_A (fan-out): port 0 with A (σ = 0.5) then B in priority, port 1 with A
/// alone (σ = 1).
fn fan_out_table() -> TestTable {
    let half = Stimulation::from_seconds(0.5, 1.0, 0.0).unwrap();
    let full = Stimulation::from_seconds(1.0, 1.0, 0.0).unwrap();
    let a = Filter::exact(TOPIC_A, false).unwrap();
    let b = Filter::exact(TOPIC_B, false).unwrap();
    let mut table = TestTable::new();
    let chain = [
        DecisionNode {
            var: 0,
            high: NodeRef::deliver(0).unwrap(),
            low: NodeRef::node(1).unwrap(),
        },
        DecisionNode {
            var: 1,
            high: NodeRef::deliver(1).unwrap(),
            low: NodeRef::NOBODY,
        },
    ];
    table
        .push_port(
            &[
                Connection {
                    filter: a,
                    stimulation: half,
                },
                Connection {
                    filter: b,
                    stimulation: full,
                },
            ],
            &chain,
            NodeRef::node(0).unwrap(),
        )
        .unwrap();
    table
        .push_port(
            &[Connection {
                filter: a,
                stimulation: full,
            }],
            &[],
            NodeRef::deliver(0).unwrap(),
        )
        .unwrap();
    table
}

fn booted(table: &TestTable) -> TestNode {
    let bytes = image(table, Harness::NODE_ID, 3);
    let mut node = TestNode::new(
        Config::new(Harness::NODE_ID).unwrap(),
        Instant::from_micros(0),
    );
    node.boot_buffer()[..bytes.len()].copy_from_slice(&bytes);
    node.boot(Some(bytes.len()), Instant::from_micros(0));
    node
}

#[test]
fn every_verdict_is_shown_before_the_deliveries_with_the_levels_after_the_frame() {
    let mut node = booted(&fan_out_table());
    let mut observer = Observer::default();
    let at = Instant::from_micros(1000);
    node.on_frame(&frame(TOPIC_A, &[1]), at, &mut observer);
    node.on_frame(&frame(TOPIC_A, &[2]), at, &mut observer);
    // A frame no connection matches: no verdict.
    node.on_frame(&frame(0x7AB, &[3]), at, &mut observer);
    node.on_frame(&frame(TOPIC_B, &[4]), at, &mut observer);
    let half = 1u32 << 30;
    let full = 1u32 << 31;
    assert_eq!(
        observer.events,
        [
            // A's first frame: port 0 at S = 0.5 (inactive), port 1 at S = 1 (delivers).
            format!("verdict 0 fed 1 active 0 selected None delivered None levels [{half}]"),
            format!("verdict 1 fed 1 active 1 selected Some(0) delivered Some(0) levels [{full}]"),
            "deliver 1".to_string(),
            // Its second: port 0 at S = 1, A delivers at both.
            format!("verdict 0 fed 1 active 1 selected Some(0) delivered Some(0) levels [{full}]"),
            format!("verdict 1 fed 1 active 1 selected Some(0) delivered Some(0) levels [{full}]"),
            "deliver 0".to_string(),
            "deliver 1".to_string(),
            // B: active, but A wins port 0.
            format!("verdict 0 fed 10 active 11 selected Some(0) delivered None levels [{full}]"),
        ]
    );
}

#[test]
fn a_consumer_that_does_not_observe_is_never_shown_a_verdict() {
    let mut node = booted(&fan_out_table());
    let mut blind = Blind::default();
    for _ in 0..4 {
        node.on_frame(&frame(TOPIC_A, &[]), Instant::from_micros(0), &mut blind);
    }
    assert_eq!((blind.verdicts, blind.deliveries), (0, 7));
}

#[test]
fn the_record_of_a_replay_is_exact_text() {
    let table = fan_out_table();
    let bytes = image(&table, Harness::NODE_ID, 3);
    let crc = pab_core::image::read_header(&bytes).unwrap().crc;
    let mut node = TestNode::new(
        Config::new(Harness::NODE_ID).unwrap(),
        Instant::from_micros(0),
    );
    node.boot_buffer()[..bytes.len()].copy_from_slice(&bytes);
    let mut out = String::new();
    replay::records::write_preamble(&mut out).unwrap();
    let header = replay::boot(&mut node, bytes.len(), Instant::from_micros(0), &mut out).unwrap();
    assert_eq!(header.table_version, 3);
    replay::records::write_columns(&mut out).unwrap();
    let mut recorder = Recorder::new(out);
    let frames = [
        (0, Frame::with_raw_id(TOPIC_A, false, &[1]).unwrap()),
        (250_000, Frame::with_raw_id(TOPIC_B, false, &[]).unwrap()),
        (250_000, Frame::with_raw_id(0x1ABC_DEF0, true, &[]).unwrap()),
        (2_000_000, Frame::with_raw_id(TOPIC_A, false, &[]).unwrap()),
    ];
    for (t_us, frame) in frames {
        assert!(!replay::feed(
            &mut node,
            &TimedFrame { t_us, frame },
            &mut recorder
        ));
    }
    let text = recorder.finish(frames.len() as u64).unwrap();
    let expected = format!(
        "# pab replay records 2\n\
         # node 5: table version 3, crc 0x{crc:08x}\n\
         t_us,id,ext,node,port,fed,resting,active,selected,delivered,levels\n\
         0,100,0,5,0,00000001,00000000,00000000,-,-,0:1073741824\n\
         0,100,0,5,1,00000001,00000000,00000001,0,0,0:2147483648\n\
         250000,101,0,5,0,00000002,00000000,00000002,1,1,1:2147483648\n\
         2000000,100,0,5,0,00000001,00000000,00000000,-,-,0:1073741824\n\
         2000000,100,0,5,1,00000001,00000000,00000001,0,0,0:2147483648\n\
         # end: 4 frames, 5 verdicts, 0 sent\n"
    );
    assert_eq!(text, expected);
}

#[test]
fn a_refused_image_is_recorded_with_its_reason() {
    let mut bytes = image(&fan_out_table(), Harness::NODE_ID, 3);
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    let mut node = TestNode::new(
        Config::new(Harness::NODE_ID).unwrap(),
        Instant::from_micros(0),
    );
    node.boot_buffer()[..bytes.len()].copy_from_slice(&bytes);
    let mut out = String::new();
    let outcome = replay::boot(&mut node, bytes.len(), Instant::from_micros(0), &mut out);
    assert!(outcome.is_err());
    assert!(node.running().is_none());
    assert_eq!(
        out,
        "# node 5: image refused: CRC mismatch (status 0x16, detail 0)\n"
    );
}

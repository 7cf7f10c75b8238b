//! What `pab-node` says on stderr (its log, through env_logger) when it refuses the table it
//! boots with. The node application is `pab-app`'s, as in the binary; only the log is captured
//! here instead of written to stderr. (The process itself needs a CAN interface, which this
//! kernel lacks: the hardware-in-the-loop suite runs it.)

use std::sync::Mutex;

use pab_app::{Config, FullNode};
use pab_core::decision::{DecisionNode, NodeRef};
use pab_core::protocol::NodeState;
use pab_core::{Connection, Filter, Instant, Stimulation, Table};

static LINES: Mutex<Vec<String>> = Mutex::new(Vec::new());

struct Capture;

impl log::Log for Capture {
    fn enabled(&self, _: &log::Metadata) -> bool {
        true
    }

    fn log(&self, record: &log::Record) {
        LINES
            .lock()
            .unwrap()
            .push(format!("{} {}", record.level(), record.args()));
    }

    fn flush(&self) {}
}

/// A one-port, one-connection table compiled for node `node_id`.
fn image_for(node_id: u8) -> Vec<u8> {
    let mut table = Table::<1, 1, 1>::new();
    let connection = Connection {
        filter: Filter::exact(0x100, false).unwrap(),
        stimulation: Stimulation::from_seconds(1.0, 0.5, 0.0).unwrap(),
    };
    let decision = DecisionNode {
        var: 0,
        high: NodeRef::deliver(0).unwrap(),
        low: NodeRef::NOBODY,
    };
    table
        .push_port(&[connection], &[decision], NodeRef::node(0).unwrap())
        .unwrap();
    let mut out = vec![0u8; pab_core::image::MAX_IMAGE_LEN];
    let len = pab_core::image::encode(&table, node_id, 1, &mut out).unwrap();
    out.truncate(len);
    out
}

#[test]
fn a_table_for_another_node_is_refused_at_boot_and_the_log_names_both_ids() {
    log::set_logger(&Capture).unwrap();
    log::set_max_level(log::LevelFilter::Info);
    // `pab-node --node-id 2 --table arm.pab`, arm.pab compiled for node 1.
    let image = image_for(1);
    let mut node = Box::new(FullNode::new(
        Config::new(2).unwrap(),
        Instant::from_micros(0),
    ));
    node.boot_buffer()[..image.len()].copy_from_slice(&image);
    node.boot(Some(image.len()), Instant::from_micros(0));
    assert_eq!(node.state(), NodeState::NoTable);
    let lines = LINES.lock().unwrap();
    assert!(
        lines.iter().any(|line| line.starts_with("WARN ")
            && line.contains("the image is for node 1, this node is 2")),
        "{lines:#?}"
    );
}

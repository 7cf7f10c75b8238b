//! A node on the simulated bus: the node application itself (`pab_app::FullNode`, the Linux
//! node's capacities), booted from its compiled image as a node boots from its store, and the
//! [`Observer`] it hands its verdicts and deliveries to.
//!
//! Nothing here decides anything: the node does (arbitration, BLE claims, dynamics steps and
//! Gates, filter commands, heartbeats, faults, re-publication), with the code a board runs. The
//! simulator only tells it the time, hands it the bus's frames and reads it.

use pab_app::replay::{self, Recorder};
use pab_app::{FullNode, Step};
use pab_core::{Arbiter, Frame, Instant, PortVerdict};

use super::SimError;

/// A node of the network, running.
pub(super) struct Station {
    /// Its index in the network's nodes.
    pub node: usize,
    /// Its node id.
    pub id: u8,
    /// The node application (about 82 KiB: boxed).
    pub app: Box<FullNode>,
    /// When it stops (`[[faults]]`), µs.
    pub stop_us: Option<u64>,
    /// The last instant it was handed a frame or polled, µs.
    pub served_us: u64,
    /// The deadline it was last polled for, µs: a deadline that polling did not move is not
    /// polled again (the node has nothing more due then), as `pab_app::replay::feed` does.
    pub polled_for: Option<u64>,
    /// Per group it runs (its table's order), the instant of the last step recorded, µs.
    pub stepped: Vec<Option<u64>>,
}

impl Station {
    /// Node `node` of `network` booted at time 0 from `image` with its configuration
    /// ([`crate::network::Node::config`]), its `# node` record line written to `records`.
    pub fn boot(
        node: usize,
        network_node: &crate::network::Node,
        image: &[u8],
        stop_us: Option<u64>,
        records: &mut String,
    ) -> Result<Station, SimError> {
        let (id, name) = (network_node.id, network_node.name.as_str());
        let config = network_node.config();
        config
            .validate()
            .map_err(|error| SimError(format!("node `{name}`: {error}")))?;
        let mut app = Box::new(FullNode::new(config, Instant::from_micros(0)));
        let buffer = app.boot_buffer();
        let capacity = buffer.len();
        let room = buffer.get_mut(..image.len()).ok_or_else(|| {
            SimError(format!(
                "node `{name}`: its image ({} bytes) exceeds the node's buffer ({capacity} bytes)",
                image.len(),
            ))
        })?;
        room.copy_from_slice(image);
        replay::boot(&mut app, image.len(), Instant::from_micros(0), records).map_err(
            |(status, detail)| {
                SimError(format!(
                    "node `{name}`: its image does not load: {status} (detail {detail})"
                ))
            },
        )?;
        Ok(Station {
            node,
            id,
            app,
            stop_us,
            served_us: 0,
            polled_for: None,
            stepped: Vec::new(),
        })
    }

    /// Whether it has stopped by `t_us`.
    pub fn stopped(&self, t_us: u64) -> bool {
        self.stop_us.is_some_and(|stop| stop <= t_us)
    }

    /// Its arbiter (it always runs a table: [`Station::boot`] refuses an image it cannot run).
    pub fn arbiter(&self) -> Option<&Arbiter> {
        self.app.arbiter()
    }

    /// Hands it `frame` at `now_us`, its verdicts and deliveries to `recipient`. What the frame
    /// made due is polled for anew, as `pab_app::replay::feed` does after each frame. No table
    /// transfer is simulated: were one stored, it would be at once.
    pub fn feed(&mut self, frame: &Frame, now_us: u64, recipient: &mut impl pab_app::Recipient) {
        let now = Instant::from_micros(now_us);
        if self.app.on_frame(frame, now, recipient) == Step::Store {
            self.app.stored(true, now);
        }
        self.served_us = now_us;
        self.polled_for = None;
    }

    /// Polls it at `now_us` for the deadline `due` ([`Station::due`]), which is then not polled
    /// again unless polling moves it.
    pub fn poll(&mut self, due: u64, now_us: u64, recipient: &mut impl pab_app::Recipient) {
        self.polled_for = Some(due);
        let now = Instant::from_micros(now_us);
        if self.app.poll(now, recipient) == Step::Store {
            self.app.stored(true, now);
        }
        self.served_us = now_us;
    }

    /// When it next asks to be polled, µs: its deadline, unless that is the one it was last
    /// polled for; `None` once it has stopped.
    pub fn due(&self) -> Option<u64> {
        let deadline = self
            .app
            .deadline(Instant::from_micros(self.served_us))
            .as_micros();
        Some(deadline).filter(|&d| self.polled_for != Some(d) && !self.stopped(d))
    }
}

/// What the simulator sees of one call into a node: each verdict with the levels of the
/// connections it fed (read from the node's arbiter right after the frame, as a record line
/// reads them), the ports something was delivered at, and the record lines.
pub(super) struct Observer<'a> {
    /// The run's record, if it keeps one.
    pub recorder: Option<&'a mut Recorder<String>>,
    /// The verdicts, in port order, with (local connection, level) per fed connection.
    pub verdicts: Vec<(PortVerdict, Vec<(u8, f64)>)>,
    /// The ports the node delivered at, in the order it did.
    pub delivered: Vec<u8>,
}

impl<'a> Observer<'a> {
    pub fn new(mut recorder: Option<&'a mut Recorder<String>>, node_id: u8) -> Self {
        if let Some(recorder) = recorder.as_deref_mut() {
            recorder.node_id = node_id;
        }
        Observer {
            recorder,
            verdicts: Vec::new(),
            delivered: Vec::new(),
        }
    }
}

impl pab_app::Recipient for Observer<'_> {
    const OBSERVES_VERDICTS: bool = true;

    fn deliver(&mut self, port: u8, _frame: &Frame, _now: Instant) {
        self.delivered.push(port);
    }

    fn verdict<const P: usize, const C: usize, const N: usize>(
        &mut self,
        frame: &Frame,
        now: Instant,
        verdict: &PortVerdict,
        arbiter: &Arbiter<P, C, N>,
    ) {
        if let Some(recorder) = self.recorder.as_deref_mut() {
            recorder.verdict(frame, now, verdict, arbiter);
        }
        let levels = verdict
            .fed
            .iter()
            .map(|local| {
                let level = arbiter.level(verdict.port, local, now);
                (local, level.map_or(0.0, |level| level.to_f64()))
            })
            .collect();
        self.verdicts.push((*verdict, levels));
    }
}

/// HBBA's intention node on the simulated bus: the intention node itself
/// (`pab_intent::IntentNode`), and what the simulator records of it.
pub(super) struct IntentStation<'a> {
    pub node: pab_intent::IntentNode<'a>,
    /// Where each filtered connection is (the setup's).
    pub targets: &'a [pab_core::hbba::intention::Target],
    /// The last instant it was handed a frame or polled, µs.
    pub served_us: u64,
    /// The deadline it was last polled for, µs (as [`Station::polled_for`]).
    pub polled_for: Option<u64>,
    /// What it selected and commanded.
    pub run: super::IntentionRun,
}

impl<'a> IntentStation<'a> {
    /// The intention node of `setup`, from address [`pab_core::protocol::INTENTION`], observed.
    pub fn new(setup: &'a pab_intent::Setup) -> Result<IntentStation<'a>, SimError> {
        let mut node = pab_intent::IntentNode::new(setup, pab_core::protocol::INTENTION)
            .map_err(|error| SimError(format!("[hbba]: {error}")))?;
        node.observe();
        Ok(IntentStation {
            node,
            targets: &setup.targets,
            served_us: 0,
            polled_for: None,
            run: super::IntentionRun::new(setup),
        })
    }

    /// When it next asks to be polled, µs (as [`Station::due`]).
    pub fn due(&self) -> Option<u64> {
        let deadline = self
            .node
            .deadline(Instant::from_micros(self.served_us))
            .as_micros();
        Some(deadline).filter(|&d| self.polled_for != Some(d))
    }
}

//! `[nodes.NAME]`: the boards (or their Linux stand-ins), their ids on the bus and what they are.

use std::collections::HashMap;
use std::ops::Range;

use indexmap::IndexMap;
use schemars::JsonSchema;
use serde::Deserialize;

use super::spanned::Spanned;
use super::{Builder, Bus, PLAIN_NAME, is_plain_name};

/// `[nodes.NAME]`: a node; its name is used in port names and image file names.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawNode {
    /// Required: the node's id on the bus, 1..=127, unique.
    id: Spanned<i64>,
    /// Optional: what the board is; its node comment in the DBC export.
    description: Option<Spanned<String>>,
    /// Optional, default true: the node's CAN controller handles CAN FD frames. `false` for a
    /// classic-only controller (or a bridge that carries classic frames only, as the emulated
    /// board's SLCAN): refused on a CAN FD bus (`[bus] data_bitrate`), where a classic
    /// controller destroys every FD frame with an error frame.
    fd: Option<Spanned<bool>>,
    /// Optional, default 1: seconds between the node's heartbeats, 0.01 to 3600 (whole
    /// microseconds), as its configuration sets them (`pab-node --heartbeat-ms`). `pabctl check`
    /// analyses its heartbeat group at this period, and the simulator's node beats at it.
    heartbeat: Option<Spanned<f64>>,
}

/// A node: a controller board or its Linux stand-in.
#[derive(Clone, Debug)]
pub struct Node {
    /// Its name in the file (`[nodes.<name>]`).
    pub name: String,
    /// Its node id on the bus, 1..=127.
    pub id: u8,
    /// Its ports, as indices into [`Network::ports`](super::Network::ports), in file order.
    pub ports: Vec<usize>,
    /// What the file says it is (`description`): the DBC export's comment on it.
    pub description: Option<String>,
    /// Its controller handles CAN FD frames (`fd`, default true).
    pub fd: bool,
    /// Time between its heartbeats, µs (`heartbeat`, default the node's: 1 s).
    pub heartbeat_us: u64,
    /// Where it is defined.
    pub span: Range<usize>,
}

impl Builder<'_> {
    pub(super) fn nodes(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawNode>>,
        bus: Option<&Bus>,
    ) -> Vec<Node> {
        let mut nodes: Vec<Node> = Vec::new();
        let mut ids: HashMap<u8, String> = HashMap::new();
        for (name, node) in raw {
            if self.printable(name, "node name") && !is_plain_name(name.get_ref()) {
                self.error(
                    name.span(),
                    format!("node name `{}`: {PLAIN_NAME}", name.get_ref()),
                );
            }
            let id = node.get_ref().id.get_ref();
            let Some(id) = u8::try_from(*id).ok().filter(|id| (1..=127).contains(id)) else {
                self.error(
                    node.get_ref().id.span(),
                    format!("node id {id} is not in 1..=127"),
                );
                continue;
            };
            if let Some(other) = ids.get(&id) {
                self.error(
                    node.get_ref().id.span(),
                    format!("node id {id} is already used by node `{other}`"),
                );
                continue;
            }
            ids.insert(id, name.get_ref().clone());
            let description = self.description(node.get_ref().description.as_ref());
            let fd = node.get_ref().fd.as_ref();
            if let (Some(written), Some(rate)) = (
                fd.filter(|fd| !*fd.get_ref()),
                bus.and_then(|bus| bus.data_bitrate),
            ) {
                self.error(
                    written.span(),
                    format!(
                        "node `{}` has a classic CAN controller (`fd = false`), but the bus is CAN FD (`data_bitrate = {rate}` in [bus]): a classic controller that is not FD-tolerant destroys every CAN FD frame with an error frame; put the node on a classic bus (no `data_bitrate`), or give it a CAN FD controller and remove `fd = false`",
                        name.get_ref()
                    ),
                );
            }
            let Some(heartbeat_us) = self.heartbeat(id, node.get_ref().heartbeat.as_ref()) else {
                continue;
            };
            nodes.push(Node {
                name: name.get_ref().clone(),
                id,
                ports: Vec::new(),
                description,
                fd: fd.is_none_or(|fd| *fd.get_ref()),
                heartbeat_us,
                span: node.span(),
            });
        }
        nodes
    }

    /// A node's `heartbeat`, in µs: the node's default without one, `None` after reporting a
    /// value its configuration refuses (`pab_app::Config::validate` says what a node takes).
    fn heartbeat(&mut self, id: u8, written: Option<&Spanned<f64>>) -> Option<u64> {
        let default = pab_app::Config::unassigned().heartbeat_period_us;
        let Some(written) = written else {
            return Some(default);
        };
        let seconds = *written.get_ref();
        let us = (seconds * 1e6).round();
        let mut config = pab_app::Config::unassigned();
        config.node_id = id;
        if seconds.is_finite() && (0.0..=u64::MAX as f64).contains(&us) {
            config.heartbeat_period_us = us as u64;
            if config.validate().is_ok() {
                return Some(config.heartbeat_period_us);
            }
        }
        self.error(
            written.span(),
            format!(
                "heartbeat = {seconds}: seconds between the node's heartbeats, 0.01 to 3600 (what a node's configuration takes; default {} s)",
                default as f64 / 1e6
            ),
        );
        None
    }
}

impl Node {
    /// The node's configuration as the network file says it (its id, its `heartbeat`), the
    /// rest the node's defaults: what the simulator's and the replay's nodes run with, and
    /// what `pabctl check` analyses.
    pub fn config(&self) -> pab_app::Config {
        let mut config =
            pab_app::Config::new(self.id).unwrap_or_else(|_| pab_app::Config::unassigned());
        config.heartbeat_period_us = self.heartbeat_us;
        config
    }
}

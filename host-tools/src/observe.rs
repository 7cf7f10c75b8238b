//! What the tool knows about the nodes on a bus, built from the frames they send: heartbeat
//! groups, faults, diagnostic samples. `pabctl nodes`, `push` and `monitor` all read the bus
//! through an [`Observer`].

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::{Duration, Instant};

use pab_core::Frame;
use pab_core::identity::{Identity, IdentityPart, IdentityParts};
use pab_core::protocol::{
    ConfigStatus, DiagnosticSample, Errors, Fault, FaultCode, FilterStatus, FrameId, Gates,
    Heartbeat, Message, STORE_UNREADABLE, SchemaAck, SchemaState, SchemaTransition, StoreFailure,
    TableStatus, Traffic, TransferStatus, TransferStatusCode, UpdateStatus,
};

/// The latest of everything a node said.
#[derive(Clone, Debug, Default)]
pub struct NodeView {
    /// Its latest heartbeat and when it arrived.
    pub heartbeat: Option<(Heartbeat, Instant)>,
    /// Its latest table status.
    pub table: Option<TableStatus>,
    /// Its latest traffic counters.
    pub traffic: Option<Traffic>,
    /// Its latest error counters.
    pub errors: Option<Errors>,
    /// Its latest fault and when it arrived.
    pub last_fault: Option<(Fault, Instant)>,
    /// Its latest transfer status and when it arrived.
    pub transfer: Option<(TransferStatus, Instant)>,
    /// Its latest diagnostic sample per (port, connection).
    pub samples: BTreeMap<(u8, u8), DiagnosticSample>,
    /// Its latest Gates frame per competitive-dynamics group it runs, and when it arrived.
    pub gates: BTreeMap<u8, (Gates, Instant)>,
    /// Its latest message filters' status, and when it arrived.
    pub filters: Option<(FilterStatus, Instant)>,
    /// Its schema server's latest state, and when it arrived.
    pub schema_state: Option<(SchemaState, Instant)>,
    /// Its schema server's latest schema change, and when it arrived.
    pub schema_transition: Option<(SchemaTransition, Instant)>,
    /// Its latest answer to a schema, and when it arrived.
    pub schema_ack: Option<(SchemaAck, Instant)>,
    /// Its identity, once all six frames of one answer arrived, and when the last did.
    pub identity: Option<(Identity, Instant)>,
    /// The identity frames of the answer in progress.
    pub identity_parts: IdentityParts,
    /// Its latest answer to an Assign or a Configure, and when it arrived.
    pub config_status: Option<(ConfigStatus, Instant)>,
    /// Its latest firmware-update status (an answer to an UpdateTransfer message, or its report
    /// at start), and when it arrived.
    pub update_status: Option<(UpdateStatus, Instant)>,
}

/// Every node heard from, by id.
#[derive(Clone, Debug, Default)]
pub struct Observer {
    nodes: BTreeMap<u8, NodeView>,
}

impl Observer {
    /// An observer that has heard nothing.
    pub fn new() -> Observer {
        Observer::default()
    }

    /// Takes in one frame read at `at`; returns it decoded if it is one of ours.
    pub fn observe(&mut self, frame: &Frame, at: Instant) -> Option<(FrameId, Message)> {
        let (id, message) = Message::decode(frame).ok()?;
        if id.source == pab_core::protocol::TOOL {
            return Some((id, message));
        }
        let view = self.nodes.entry(id.source).or_default();
        match message {
            Message::Heartbeat(heartbeat) => view.heartbeat = Some((heartbeat, at)),
            Message::TableStatus(status) => view.table = Some(status),
            Message::Traffic(traffic) => view.traffic = Some(traffic),
            Message::Errors(errors) => view.errors = Some(errors),
            Message::Fault(fault) => view.last_fault = Some((fault, at)),
            Message::TransferStatus(status) => view.transfer = Some((status, at)),
            Message::Diagnostic(sample) => {
                view.samples
                    .insert((sample.port, sample.connection), sample);
            }
            Message::Gates(gates) => {
                view.gates.insert(gates.group, (gates, at));
            }
            Message::FilterStatus(status) => view.filters = Some((status, at)),
            Message::SchemaState(state) => view.schema_state = Some((state, at)),
            Message::SchemaTransition(change) => view.schema_transition = Some((change, at)),
            Message::SchemaAck(ack) => view.schema_ack = Some((ack, at)),
            Message::Identity { part, payload } => {
                // An answer starts with its uid frame: parts of an earlier, cut answer (or of
                // another unassigned node behind the same address) are not mixed in.
                if part == IdentityPart::Uid {
                    view.identity_parts = IdentityParts::new();
                }
                view.identity_parts.add(part, payload);
                if let Some(identity) = view.identity_parts.complete() {
                    view.identity = Some((identity, at));
                }
            }
            Message::ConfigStatus(status) => view.config_status = Some((status, at)),
            Message::UpdateStatus(status) => view.update_status = Some((status, at)),
            Message::IdentityRequest | Message::Assign(_) | Message::Configure(_) => {}
            Message::EmergencyStop
            | Message::SchemaAbort
            | Message::SchemaTransfer { .. }
            | Message::DiagnosticControl(_)
            | Message::Desire(_)
            | Message::Intention(_)
            | Message::Exploitation(_)
            | Message::FilterProfile(_)
            | Message::FilterSet(_)
            | Message::AuthenticatedDiagnosticControl { .. }
            | Message::TableTransfer { .. }
            | Message::UpdateTransfer { .. }
            | Message::ChallengeRequest { .. }
            | Message::Challenge { .. }
            | Message::TransferOpen(_)
            | Message::Receipt { .. }
            | Message::Seal(_)
            | Message::FreshnessRequest { .. }
            | Message::Freshness { .. } => {}
        }
        Some((id, message))
    }

    /// The nodes heard from, by id.
    pub fn nodes(&self) -> &BTreeMap<u8, NodeView> {
        &self.nodes
    }

    /// One node.
    pub fn node(&self, id: u8) -> Option<&NodeView> {
        self.nodes.get(&id)
    }

    /// Forgets what node `id` said (before waiting for fresh news from it).
    pub fn forget(&mut self, id: u8) {
        self.nodes.remove(&id);
    }
}

/// Reads `bus` into `observer` until `duration` has passed.
pub fn listen(
    bus: &mut dyn crate::bus::Bus,
    observer: &mut Observer,
    duration: Duration,
) -> std::io::Result<()> {
    let end = Instant::now() + duration;
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        if let Some(frame) = bus.receive(left)? {
            observer.observe(&frame, Instant::now());
        }
    }
    Ok(())
}

/// The table `pabctl nodes` prints: one line per node, `names` mapping ids to the network's node
/// names where known.
pub fn nodes_table(observer: &Observer, names: &BTreeMap<u8, String>, now: Instant) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:>4}  {:<10} {:<12} {:>9} {:>8}  {:<10} {:<7} {:>10} {:>10} {:>9} {:>7}  {:<16} {:<24}  last fault",
        "id",
        "name",
        "state",
        "uptime",
        "version",
        "crc",
        "stored",
        "received",
        "delivered",
        "discarded",
        "errors",
        "firmware",
        "uid"
    );
    for (id, view) in observer.nodes() {
        let unassigned = pab_core::identity::is_provisional(*id);
        let name = names
            .get(id)
            .filter(|_| !unassigned)
            .map_or("?", String::as_str);
        let shown_id = if unassigned {
            "-".to_string()
        } else {
            id.to_string()
        };
        let (firmware, uid) = match view.identity {
            Some((identity, _)) => (
                format!(
                    "{} {}",
                    identity.firmware.name_str().unwrap_or("?"),
                    version_text(&identity)
                ),
                crate::identity::uid_text(&identity.uid),
            ),
            None => ("?".to_string(), "?".to_string()),
        };
        let (state, uptime, version) = match view.heartbeat {
            Some((heartbeat, _)) => (
                heartbeat.state.description().to_string(),
                format!("{} s", heartbeat.uptime_s),
                heartbeat.table_version.to_string(),
            ),
            None if unassigned => ("unassigned".into(), "-".into(), "-".into()),
            None => ("(no heartbeat)".into(), "-".into(), "-".into()),
        };
        let (crc, stored) = match view.table {
            Some(table) if table.crc != 0 => (
                format!("{:08x}", table.crc),
                if table.stored { "yes" } else { "NO" }.to_string(),
            ),
            Some(_) => ("-".into(), "-".into()),
            None => ("?".into(), "?".into()),
        };
        let count = |value: Option<u32>| value.map_or("?".to_string(), |v| v.to_string());
        let fault = view.last_fault.map_or("-".to_string(), |(fault, at)| {
            format!(
                "{} (x{}, {:.0} s ago)",
                describe_fault(&fault),
                fault.count,
                now.saturating_duration_since(at).as_secs_f64()
            )
        });
        let _ = writeln!(
            out,
            "{shown_id:>4}  {name:<10} {state:<12} {uptime:>9} {version:>8}  {crc:<10} {stored:<7} {:>10} {:>10} {:>9} {:>7}  {firmware:<16} {uid:<24}  {fault}",
            count(view.traffic.map(|t| t.received)),
            count(view.traffic.map(|t| t.delivered)),
            count(view.errors.map(|e| e.discarded)),
            count(view.errors.map(|e| e.errors)),
        );
    }
    for (id, view) in observer.nodes() {
        if view.table.is_some_and(|table| !table.keyed) {
            let name = names
                .get(id)
                .map_or(String::new(), |name| format!(" ({name})"));
            let _ = writeln!(
                out,
                "warning: node {id}{name} has no key: it accepts configuration from anyone on the \
                 bus (docs/keys.md: pabctl keygen, pab-node --key, the board's key page)"
            );
        }
    }
    out
}

/// A firmware's semantic version, `1.2.3`.
pub fn version_text(identity: &Identity) -> String {
    let [major, minor, patch] = identity.firmware.version;
    format!("{major}.{minor}.{patch}")
}

/// A fault in words, with what its detail bytes say where the protocol defines them: why a stored
/// or pushed table was refused, which store failure, which service was malformed.
pub fn describe_fault(fault: &Fault) -> String {
    let [first, second, ..] = fault.detail;
    let what = fault.code.description();
    match fault.code {
        FaultCode::BadStoredTable if first == STORE_UNREADABLE => {
            match StoreFailure::from_code(second) {
                Some(failure) => format!("{what}: {failure}"),
                None => format!("{what}: the store could not be read (failure {second})"),
            }
        }
        FaultCode::BadStoredTable | FaultCode::TableRefused => {
            match TransferStatusCode::from_code(first) {
                Some(TransferStatusCode::WrongNode) => {
                    format!("{what}: {} (node {second})", TransferStatusCode::WrongNode)
                }
                Some(status) if second != 0 => format!("{what}: {status} (detail {second})"),
                Some(status) => format!("{what}: {status}"),
                None => format!("{what} (status {first:#04x})"),
            }
        }
        FaultCode::BusError => format!("{what} (kind {first})"),
        FaultCode::BadCommand => format!("{what} (service {first:#04x})"),
        FaultCode::Unauthenticated => {
            let source = fault.detail[2];
            match pab_core::protocol::AuthFailure::from_code(first) {
                Some(failure) => {
                    format!("{what}: {failure} (service {second:#04x} from {source})")
                }
                None => format!("{what} (reason {first:#04x})"),
            }
        }
        FaultCode::KeyPageInvalid => format!("{what} (reason {first})"),
        _ => what.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fault(code: FaultCode, detail: [u8; 5]) -> Fault {
        Fault {
            code,
            count: 1,
            detail,
        }
    }

    #[test]
    fn faults_say_why_a_table_was_refused() {
        let wrong_node = fault(
            FaultCode::BadStoredTable,
            [TransferStatusCode::WrongNode.code(), 1, 0, 0, 0],
        );
        assert_eq!(
            describe_fault(&wrong_node),
            "stored table refused at boot: image is for another node (node 1)"
        );
        let unreadable = fault(
            FaultCode::BadStoredTable,
            [STORE_UNREADABLE, StoreFailure::TooLarge.code(), 0, 0, 0],
        );
        assert_eq!(
            describe_fault(&unreadable),
            "stored table refused at boot: the stored image is too large for this node"
        );
        let crc = fault(
            FaultCode::TableRefused,
            [TransferStatusCode::CrcMismatch.code(), 0, 0, 0, 0],
        );
        assert_eq!(describe_fault(&crc), "pushed table refused: CRC mismatch");
        let odd = fault(FaultCode::BadStoredTable, [0x77, 0, 0, 0, 0]);
        assert_eq!(
            describe_fault(&odd),
            "stored table refused at boot (status 0x77)"
        );
    }
}

//! Who is on the bus, and configuring them over it: identity requests (`pabctl nodes`, the
//! check before `pabctl push`), node ids by uid (`pabctl assign`) and bit rates (`pabctl
//! config`). The frames are pab-core's ([`pab_core::identity`], docs/can-protocol.md,
//! "Identity and configuration").

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use pab_core::auth::Authenticator;
use pab_core::identity::{Identity, IdentityPart, IdentityParts, UID_LEN};
use pab_core::protocol::{
    self, Assign, ConfigStatus, ConfigStatusCode, Configure, FaultCode, Message, Service,
};

use crate::bus::Bus;
use crate::push::{Challenged, challenge, no_challenge_reason};

/// How long a node takes to answer an identity request, at most (it answers from its frame
/// handler; six frames at the bus's pace): what the tool waits for one node.
pub const ANSWER_TIMEOUT: Duration = Duration::from_millis(500);

/// A uid as `pabctl nodes` prints it and `pabctl assign --uid` takes it: 24 hexadecimal digits,
/// or 16 when its last 4 bytes are zero (a `pab-node`'s 64-bit uid).
pub fn uid_text(uid: &[u8; UID_LEN]) -> String {
    let digits = if uid[8..] == [0; 4] { 8 } else { UID_LEN };
    uid[..digits].iter().map(|b| format!("{b:02x}")).collect()
}

/// A uid from its text: 24 or 16 hexadecimal digits (16: the last 4 bytes zero).
pub fn parse_uid(text: &str) -> Result<[u8; UID_LEN], String> {
    let text = text.trim();
    if !(text.len() == 16 || text.len() == 24) || !text.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!(
            "`{text}` is not a uid: 24 hexadecimal digits (16 for a pab-node), as `pabctl \
             nodes` prints it"
        ));
    }
    let mut uid = [0u8; UID_LEN];
    for (slot, pair) in uid.iter_mut().zip(text.as_bytes().chunks(2)) {
        let pair = std::str::from_utf8(pair).map_err(|e| e.to_string())?;
        *slot = u8::from_str_radix(pair, 16).map_err(|e| e.to_string())?;
    }
    Ok(uid)
}

/// Drains what the bus holds before a request, so that old answers are not read as new ones.
fn drain(bus: &mut dyn Bus) -> std::io::Result<()> {
    for _ in 0..4096 {
        if bus.receive(Duration::ZERO)?.is_none() {
            break;
        }
    }
    Ok(())
}

/// Asks `destination` (a node, or [`protocol::BROADCAST`]) who it is and collects the
/// identities that arrive within `wait`, by the address they came from (an unassigned node's
/// provisional address included). For one node, returns as soon as its answer is complete.
pub fn request(
    bus: &mut dyn Bus,
    destination: u8,
    wait: Duration,
) -> std::io::Result<BTreeMap<u8, Identity>> {
    drain(bus)?;
    bus.send(&Message::IdentityRequest.to_frame(protocol::TOOL, destination))?;
    let mut parts: BTreeMap<u8, IdentityParts> = BTreeMap::new();
    let mut found = BTreeMap::new();
    let end = Instant::now() + wait;
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        let Some(frame) = bus.receive(left)? else {
            break;
        };
        let Ok((id, Message::Identity { part, payload })) = Message::decode(&frame) else {
            continue;
        };
        let entry = parts.entry(id.source).or_default();
        if part == IdentityPart::Uid {
            *entry = IdentityParts::new();
        }
        entry.add(part, payload);
        if let Some(identity) = entry.complete() {
            found.insert(id.source, identity);
            if destination != protocol::BROADCAST && id.source == destination {
                break;
            }
        }
    }
    Ok(found)
}

/// What a table needs of the node it goes to, to be checked against its identity before a push.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Needs {
    /// The image's bytes.
    pub image_len: usize,
    /// The image's format ([`pab_core::image::FORMAT_VERSION`] of the tool that compiled it).
    pub format: u16,
    /// Ports, connections and decision nodes of its table.
    pub ports: usize,
    /// Connections over all ports.
    pub connections: usize,
    /// Decision nodes over all ports.
    pub decision_nodes: usize,
    /// `Identity::FEATURE_*` bits its table uses.
    pub features: u16,
}

/// The mechanisms (feature names: `ble`, `dynamics`, `filters`, `schema`) the table in `image`
/// uses: a node built without one of them refuses it (docs/footprint.md). Fails, saying why,
/// when the image does not load.
pub fn mechanisms(image: &[u8]) -> Result<Vec<&'static str>, String> {
    let needs = Needs::of_image(image)?;
    Ok(pab_core::identity::FEATURES
        .iter()
        .filter(|(bit, _)| needs.features & bit != 0)
        .map(|(_, name)| *name)
        .collect())
}

impl Needs {
    /// What the table in `image` needs: its sizes and the mechanisms its sections use (read by
    /// loading it at the largest capacities).
    pub fn of_image(image: &[u8]) -> Result<Needs, String> {
        let format = image
            .get(4..6)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .ok_or("the image is shorter than its header")?;
        let loaded: pab_core::image::Loaded = pab_core::image::load(image)
            .map_err(|error| format!("the image does not load: {error}"))?;
        let table = &loaded.table;
        let mut features = 0;
        if !table.groups().is_empty() {
            features |= Identity::FEATURE_BLE;
        }
        if !table.dynamics().is_empty() {
            features |= Identity::FEATURE_DYNAMICS;
        }
        if !table.filters().is_empty() {
            features |= Identity::FEATURE_FILTERS;
        }
        if table.schema().is_some() {
            features |= Identity::FEATURE_SCHEMA;
        }
        Ok(Needs {
            image_len: image.len(),
            format,
            ports: table.port_count(),
            connections: table.connection_count(),
            decision_nodes: table.node_count(),
            features,
        })
    }

    /// Why a node with `identity` cannot load this table, in one line; `None` if it can.
    pub fn refusal(&self, identity: &Identity) -> Option<String> {
        let c = &identity.capacity;
        let [low, high] = identity.formats;
        let format_ok = (u16::from(low)..=u16::from(high)).contains(&self.format);
        let too_many = |what: &str, needed: usize, has: u16| {
            (needed > usize::from(has))
                .then(|| format!("the table has {needed} {what}, the node takes at most {has}"))
        };
        let missing: Vec<&str> = pab_core::identity::FEATURES
            .iter()
            .filter(|(bit, _)| self.features & bit != 0 && identity.features & bit == 0)
            .map(|(_, name)| *name)
            .collect();
        if !format_ok {
            Some(format!(
                "the image has format {}, the node's firmware loads formats {low}..={high}: \
                 update pabctl or the firmware so they match",
                self.format
            ))
        } else if let Some(why) = too_many("ports", self.ports, u16::from(c.ports))
            .or_else(|| too_many("connections", self.connections, c.connections))
            .or_else(|| too_many("decision nodes", self.decision_nodes, c.decision_nodes))
        {
            Some(why)
        } else if self.image_len > usize::from(c.image_len) {
            Some(format!(
                "the image has {} bytes, the node takes at most {}",
                self.image_len, c.image_len
            ))
        } else if !missing.is_empty() {
            Some(format!(
                "the table uses {}, which the node's firmware was built without",
                missing.join(" and ")
            ))
        } else {
            None
        }
    }
}

/// How an [`assign`] or a [`configure`] ended, other than with the node's answer.
#[derive(Debug)]
pub enum ConfigError {
    /// The bus failed.
    Io(std::io::Error),
    /// Something the tool found before sending, or the node refused, in one line.
    Refused(String),
}

impl From<std::io::Error> for ConfigError {
    fn from(error: std::io::Error) -> Self {
        ConfigError::Io(error)
    }
}

/// The tag for a keyed node's command, over a fresh challenge of `address`.
fn tag_for(
    bus: &mut dyn Bus,
    auth: &Authenticator,
    address: u8,
    service: Service,
    payload: &[u8; 4],
) -> Result<[u8; 4], ConfigError> {
    match challenge(bus, auth, address, Duration::from_secs(1))? {
        Challenged::Bound(nonce) => Ok(auth.command_tag(address, service.code(), nonce, payload)),
        Challenged::Nothing { unbound } => {
            Err(ConfigError::Refused(no_challenge_reason(address, unbound)))
        }
    }
}

/// Sends `message` to `address` and waits for the answer of `service`'s command (from
/// `answer_from`, or any address when `None`), or the node's refusal fault.
fn exchange(
    bus: &mut dyn Bus,
    message: Message,
    address: u8,
    service: Service,
    answer_from: Option<u8>,
) -> Result<(u8, ConfigStatus), ConfigError> {
    drain(bus)?;
    bus.send(&message.to_frame(protocol::TOOL, address))?;
    let end = Instant::now() + Duration::from_secs(3);
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        let Some(frame) = bus.receive(left)? else {
            break;
        };
        match Message::decode(&frame) {
            Ok((id, Message::ConfigStatus(status)))
                if status.command == service.code()
                    && id.destination == protocol::TOOL
                    && answer_from.is_none_or(|from| from == id.source) =>
            {
                return Ok((id.source, status));
            }
            Ok((id, Message::Fault(fault)))
                if id.source == address
                    && fault.code == FaultCode::Unauthenticated
                    && fault.detail[1] == service.code() =>
            {
                return Err(ConfigError::Refused(format!(
                    "the node refused it: {} (a keyed node needs --key with its key)",
                    crate::observe::describe_fault(&fault)
                )));
            }
            _ => {}
        }
    }
    Err(ConfigError::Refused(format!(
        "no answer from address {address} within 3 s (is the node on the bus? `pabctl nodes`)"
    )))
}

/// Gives the node with `uid` node id `node_id`: finds it by identity (refusing an id that
/// another node answers to), authenticates the command on a keyed node with `key`, and returns
/// the node's answer.
pub fn assign(
    bus: &mut dyn Bus,
    uid: &[u8; UID_LEN],
    node_id: u8,
    key: Option<&Authenticator>,
) -> Result<ConfigStatus, ConfigError> {
    let everyone = request(bus, protocol::BROADCAST, ANSWER_TIMEOUT)?;
    let Some((&address, identity)) = everyone.iter().find(|(_, identity)| identity.uid == *uid)
    else {
        let heard: Vec<String> = everyone.values().map(|i| uid_text(&i.uid)).collect();
        return Err(ConfigError::Refused(format!(
            "no node with uid {} answered (heard: {})",
            uid_text(uid),
            if heard.is_empty() {
                "none".to_string()
            } else {
                heard.join(", ")
            }
        )));
    };
    if let Some(other) = everyone.get(&node_id)
        && other.uid != *uid
    {
        return Err(ConfigError::Refused(format!(
            "node id {node_id} is taken: the node with uid {} answers to it",
            uid_text(&other.uid)
        )));
    }
    if identity.keyed() && key.is_none() {
        return Err(ConfigError::Refused(format!(
            "the node with uid {} is keyed: pass --key with its key file",
            uid_text(uid)
        )));
    }
    let mut command = Assign {
        uid_check: pab_core::identity::uid_check(uid),
        node_id,
        tag: None,
    };
    if let Some(auth) = key.filter(|_| identity.keyed()) {
        command.tag = Some(tag_for(
            bus,
            auth,
            address,
            Service::Assign,
            &command.payload(),
        )?);
    }
    let (_, status) = exchange(
        bus,
        Message::Assign(command),
        address,
        Service::Assign,
        None,
    )?;
    Ok(status)
}

/// Sets node `node`'s bit rate from its next start.
pub fn configure(
    bus: &mut dyn Bus,
    node: u8,
    bitrate_kbps: u16,
    key: Option<&Authenticator>,
) -> Result<ConfigStatus, ConfigError> {
    let identity = request(bus, node, ANSWER_TIMEOUT)?
        .remove(&node)
        .ok_or_else(|| {
            ConfigError::Refused(format!(
                "node {node} does not answer (no identity within 500 ms)"
            ))
        })?;
    if identity.keyed() && key.is_none() {
        return Err(ConfigError::Refused(format!(
            "node {node} is keyed: pass --key with its key file"
        )));
    }
    let mut command = Configure {
        bitrate_kbps,
        tag: None,
    };
    if let Some(auth) = key.filter(|_| identity.keyed()) {
        command.tag = Some(tag_for(
            bus,
            auth,
            node,
            Service::Configure,
            &command.payload(),
        )?);
    }
    let (_, status) = exchange(
        bus,
        Message::Configure(command),
        node,
        Service::Configure,
        Some(node),
    )?;
    Ok(status)
}

/// The node's answer in words.
pub fn describe_status(status: &ConfigStatus) -> String {
    match status.status {
        ConfigStatusCode::Stored if status.command == Service::Assign.code() => {
            format!("node id {} stored and in force", status.node_id)
        }
        ConfigStatusCode::Stored => format!(
            "{} kbit/s stored, in force from the node's next start (it goes back to the \
             current rate if it hears nothing within 5 s)",
            status.bitrate_kbps
        ),
        other => other.description().to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uids_print_and_parse_both_ways() {
        let g474 = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12];
        assert_eq!(uid_text(&g474), "0102030405060708090a0b0c");
        assert_eq!(parse_uid("0102030405060708090A0B0C"), Ok(g474));
        let linux = [0xAB, 0, 0, 0, 0, 0, 0, 0xCD, 0, 0, 0, 0];
        assert_eq!(uid_text(&linux), "ab000000000000cd");
        assert_eq!(parse_uid("ab000000000000cd"), Ok(linux));
        assert!(parse_uid("ab00").unwrap_err().contains("not a uid"));
        assert!(parse_uid("zz000000000000cd").is_err());
    }

    /// The image of node `node` of example `example`, compiled as `pabctl compile` does.
    fn image_of(example: &str, node: &str) -> Vec<u8> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../examples")
            .join(example);
        let network = pab_lang::network::Network::load(&path).expect("the example parses");
        let nodes = pab_lang::compile::compile(&network).expect("the example compiles");
        nodes
            .into_iter()
            .find(|n| n.name == node)
            .unwrap_or_else(|| panic!("{example} has no node {node}"))
            .image
    }

    /// A node with the boards' capacities and the features `features`.
    fn board(features: u16) -> Identity {
        let format = u8::try_from(pab_core::image::FORMAT_VERSION).unwrap();
        Identity {
            uid: [0; pab_core::identity::UID_LEN],
            firmware: pab_core::identity::Firmware::new("fw-g474", "0.1.0", "0123456789abcdef"),
            protocol: pab_core::identity::PROTOCOL_VERSION,
            formats: [format, format],
            capacity: pab_core::identity::Capacity {
                ports: pab_core::BOARD_PORTS as u8,
                connections: pab_core::BOARD_CONNECTIONS as u16,
                decision_nodes: pab_core::BOARD_DECISION_NODES as u16,
                image_len: 8192,
            },
            features,
            flags: 0,
            bitrate_kbps: 500,
        }
    }

    /// What a table uses is read from its image, and a node built without one of those
    /// mechanisms (a board's minimal build, docs/footprint.md) is refused it by name, before
    /// any transfer frame; a node with them takes it.
    #[test]
    fn a_table_is_refused_to_a_node_built_without_a_mechanism_it_uses() {
        let claims = Needs::of_image(&image_of("multi-target-observation.toml", "r1")).unwrap();
        assert_eq!(claims.features, Identity::FEATURE_BLE, "{claims:?}");
        let all = Identity::FEATURE_BLE
            | Identity::FEATURE_DYNAMICS
            | Identity::FEATURE_FILTERS
            | Identity::FEATURE_SCHEMA;
        assert_eq!(claims.refusal(&board(all)), None);
        assert_eq!(
            claims
                .refusal(&board(all & !Identity::FEATURE_BLE))
                .as_deref(),
            Some("the table uses ble, which the node's firmware was built without")
        );

        let gates = Needs::of_image(&image_of("take-and-return-dynamics.toml", "arm")).unwrap();
        assert_ne!(gates.features & Identity::FEATURE_DYNAMICS, 0, "{gates:?}");
        assert_eq!(gates.refusal(&board(all)), None);
        let why = gates
            .refusal(&board(0))
            .expect("refused to the minimal node");
        assert!(why.contains("dynamics"), "{why}");

        // A plain table needs no mechanism: the minimal node takes it.
        let plain = Needs::of_image(&image_of("take-and-return.toml", "hand")).unwrap();
        assert_eq!(plain.features, 0, "{plain:?}");
        assert_eq!(plain.refusal(&board(0)), None);
    }
}

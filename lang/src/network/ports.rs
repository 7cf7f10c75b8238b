//! `[ports."NODE.PORT"]`: a node's inputs, arbitrated (one winner) or value ports (a combination
//! of their connections' values), with the fields a value port reads and the identifier a port
//! re-publishes on.

use std::ops::Range;

use indexmap::IndexMap;
use pab_core::filter::{MAX_EXTENDED_ID, MAX_STANDARD_ID};
use pab_core::value_port::{MAX_VALUE_CONNECTIONS, MAX_VALUE_PORTS};
use pab_core::{Combine, Consumer, Endian, Field, MAX_PORTS, OutputId, ValueSpec};
use schemars::JsonSchema;
use serde::Deserialize;

use super::spanned::Spanned;
use super::{Builder, Node, PLAIN_NAME, is_plain_name, list_or_none, suggest};
use crate::can_frame::{CLASSIC_DATA_LEN, FD_DATA_LEN};
use crate::shown;

/// The network file's word for a combination (`combine = "min"`).
pub fn combine_name(combine: Combine) -> &'static str {
    match combine {
        Combine::Max => "max",
        Combine::Min => "min",
        Combine::Sum => "sum",
        Combine::Priority => "priority",
    }
}

/// A value port's combinations, as the file writes them (`combine = "..."`): what the parser
/// takes and the JSON Schema lists.
const COMBINES: [(&str, Combine); 4] = [
    ("max", Combine::Max),
    ("min", Combine::Min),
    ("sum", Combine::Sum),
    ("priority", Combine::Priority),
];

/// A field's byte orders (`endian = "..."`; "little" when not written), as [`COMBINES`].
const ENDIANS: [(&str, Endian); 2] = [("little", Endian::Little), ("big", Endian::Big)];

/// `[ports."NODE.PORT"]`: an input of a node; an arbitrated port (one winner) unless `combine`
/// makes it a value port.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPort {
    /// Optional: the node also re-publishes the frames this port delivers on this id (a gateway in
    /// front of an actuator that cannot be changed). Default: the node's application only.
    republish: Option<Spanned<RawRepublish>>,
    /// Optional: a value port and how it combines its connections' values. Default: an
    /// arbitrated port (one winner).
    #[schemars(extend("enum" = COMBINES.map(|(name, _)| name)))]
    combine: Option<Spanned<String>>,
    /// The field a value port combines: required with `combine`, refused without.
    value: Option<Spanned<RawField>>,
    /// The field that ranks frames: required for `combine = "priority"` and only there.
    priority: Option<Spanned<RawField>>,
}

/// `value = { offset = 0, size = 2, signed = false, endian = "little" }` (or `priority = ...`)
/// on a value port: where an integer is in a frame's data.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawField {
    /// Required: the field's first byte, offset + size <= 8 (on a CAN FD bus <= 64); within
    /// the `length` of every topic it is read from.
    pub(super) offset: Spanned<i64>,
    /// Required: its size in bytes, 1, 2 or 4 (1 or 2 for a BLE group's eligibility).
    pub(super) size: Spanned<i64>,
    /// Optional, default false: a two's-complement integer.
    #[serde(default)]
    pub(super) signed: bool,
    /// Optional, default "little": its byte order.
    #[schemars(extend("enum" = ENDIANS.map(|(name, _)| name)))]
    pub(super) endian: Option<Spanned<String>>,
}

/// `republish = { can_id = 0x300, extended = false }` on a port.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawRepublish {
    /// Required: the identifier, 11-bit up to 0x7FF, or 29-bit up to 0x1FFFFFFF with `extended`.
    can_id: Spanned<i64>,
    /// Optional, default false: a 29-bit identifier.
    #[serde(default)]
    extended: bool,
}

/// An arbitrated input of a node.
#[derive(Clone, Debug)]
pub struct Port {
    /// Its full name, `<node>.<port>`.
    pub name: String,
    /// Its node, as an index into [`Network::nodes`](super::Network::nodes).
    pub node: usize,
    /// Its connections, as indices into [`Network::connections`](super::Network::connections),
    /// in file order: the variables of its rules.
    pub connections: Vec<usize>,
    /// Who receives what it delivers (`republish = { ... }` in the file; default: the node's
    /// application only).
    pub consumer: Consumer,
    /// For a value port (`combine = ...`), what it reads and how it combines; `None` for an
    /// ordinary port.
    pub value: Option<ValueSpec>,
    /// Where it is defined.
    pub span: Range<usize>,
}

impl Builder<'_> {
    pub(super) fn ports(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawPort>>,
        nodes: &[Node],
    ) -> Vec<Port> {
        let mut ports: Vec<Port> = Vec::new();
        for (name, port) in raw {
            if !self.printable(name, "port name") {
                continue;
            }
            let full = name.get_ref();
            let Some((node_name, local)) = full.split_once('.') else {
                self.error(
                    name.span(),
                    format!("port name `{full}` must be `<node>.<port>`, e.g. \"arm.target\""),
                );
                continue;
            };
            if !is_plain_name(local) {
                self.error(
                    name.span(),
                    format!("port name `{local}` in `{full}`: {PLAIN_NAME}"),
                );
                continue;
            }
            let Some(node) = nodes.iter().position(|node| node.name == node_name) else {
                if self.declared.nodes.contains(node_name) {
                    continue;
                }
                let known: Vec<&str> = nodes.iter().map(|node| node.name.as_str()).collect();
                self.error(
                    name.span(),
                    format!(
                        "port `{full}` is on node `{node_name}`, which is not defined (nodes: {}){}",
                        list_or_none(&known),
                        suggest(node_name, &known)
                    ),
                );
                continue;
            };
            let on_node = ports.iter().filter(|port| port.node == node).count();
            if on_node >= MAX_PORTS {
                self.error(
                    name.span(),
                    format!("node `{node_name}` has more than {MAX_PORTS} ports"),
                );
                continue;
            }
            let consumer = match &port.get_ref().republish {
                None => Consumer::Local,
                // A bad id is reported; the port is kept so that its connections are checked too.
                Some(republish) => self
                    .output_id(republish.get_ref())
                    .map_or(Consumer::Local, Consumer::Republish),
            };
            let value = self.value_spec(port.get_ref(), port.span());
            ports.push(Port {
                name: full.clone(),
                node,
                connections: Vec::new(),
                consumer,
                value,
                span: port.span(),
            });
        }
        ports
    }

    /// The `combine`, `value` and `priority` keys of a port: `None` for an ordinary port (and
    /// after reporting any mistake).
    fn value_spec(&mut self, raw: &RawPort, span: Range<usize>) -> Option<ValueSpec> {
        let Some(combine_text) = &raw.combine else {
            for (key, field) in [("value", &raw.value), ("priority", &raw.priority)] {
                if let Some(field) = field {
                    self.error(
                        field.span(),
                        format!(
                            "`{key}` belongs to a value port: add `combine = \"max\"` (or \"min\", \"sum\", \"priority\")"
                        ),
                    );
                }
            }
            return None;
        };
        let written = combine_text.get_ref().as_str();
        let combine = match COMBINES.iter().find(|(name, _)| *name == written) {
            Some(&(_, combine)) => Some(combine),
            None => {
                self.error(
                    combine_text.span(),
                    format!(
                        "combine = \"{}\" is not a combination: \"max\", \"min\", \"sum\" or \"priority\"",
                        shown::escaped(written)
                    ),
                );
                None
            }
        };
        let value = match &raw.value {
            Some(field) => self.field(field, "value"),
            None => {
                self.error(
                    span.clone(),
                    "a value port needs the field it combines: `value = { offset = 0, size = 2 }` (size 1, 2 or 4; signed = false and endian = \"little\" by default)",
                );
                None
            }
        };
        let priority = match (&raw.priority, combine) {
            (Some(field), Some(Combine::Priority)) => Some(self.field(field, "priority")?),
            (None, Some(Combine::Priority)) => {
                self.error(
                    combine_text.span(),
                    "combine = \"priority\" needs the field that ranks the frames: `priority = { offset = 2, size = 1 }`",
                );
                return None;
            }
            (Some(field), Some(_)) => {
                self.error(
                    field.span(),
                    "`priority` is only for `combine = \"priority\"`: the other combinations read `value` alone",
                );
                return None;
            }
            (_, _) => None,
        };
        Some(ValueSpec {
            combine: combine?,
            value: value?,
            priority,
        })
    }

    /// A `value` or `priority` field, or `None` after reporting why not.
    pub(super) fn field(&mut self, raw: &Spanned<RawField>, key: &str) -> Option<Field> {
        let field = raw.get_ref();
        let mut ok = true;
        let size = *field.size.get_ref();
        if !matches!(size, 1 | 2 | 4) {
            self.error(
                field.size.span(),
                format!("{key}: size = {size} is not 1, 2 or 4 (bytes)"),
            );
            ok = false;
        }
        let offset = *field.offset.get_ref();
        // A classic bus's frames carry 8 bytes at most; a CAN FD bus's up to 64, and each
        // field is then checked against its topic's `length` (fields_within_lengths).
        let (frame, bytes) = if self.data_bitrate.is_some() {
            ("a CAN FD frame", FD_DATA_LEN as i64)
        } else {
            ("a frame", CLASSIC_DATA_LEN as i64)
        };
        if !(0..bytes).contains(&offset) {
            self.error(
                field.offset.span(),
                format!(
                    "{key}: offset = {offset} is not a byte of {frame} (0 to {})",
                    bytes - 1
                ),
            );
            ok = false;
        } else if ok && offset + size > bytes {
            self.error(
                raw.span(),
                format!(
                    "{key}: offset {offset} + size {size} = {} is beyond the {bytes} bytes of {frame}",
                    offset + size
                ),
            );
            ok = false;
        }
        let endian = match &field.endian {
            None => Endian::Little,
            Some(written) => match ENDIANS.iter().find(|(name, _)| name == written.get_ref()) {
                Some(&(_, endian)) => endian,
                None => {
                    self.error(
                        written.span(),
                        format!(
                            "{key}: endian = \"{}\" is not \"little\" or \"big\"",
                            shown::escaped(written.get_ref())
                        ),
                    );
                    return None;
                }
            },
        };
        if !ok {
            return None;
        }
        Some(Field {
            offset: u8::try_from(offset).ok()?,
            size: u8::try_from(size).ok()?,
            signed: field.signed,
            endian,
        })
    }

    /// Each node's value ports within the board runtime's fixed capacities.
    pub(super) fn value_capacities(&mut self, ports: &[Port], nodes: &[Node]) {
        for (index, node) in nodes.iter().enumerate() {
            let mut count = 0usize;
            let mut connections = 0usize;
            for port in ports
                .iter()
                .filter(|port| port.node == index && port.value.is_some())
            {
                count += 1;
                connections += port.connections.len();
                if count > MAX_VALUE_PORTS {
                    self.error(
                        port.span.clone(),
                        format!(
                            "node `{}` has more than {MAX_VALUE_PORTS} value ports (a node keeps the values of at most {MAX_VALUE_PORTS} ports)",
                            node.name
                        ),
                    );
                } else if connections > MAX_VALUE_CONNECTIONS {
                    self.error(
                        port.span.clone(),
                        format!(
                            "node `{}`: its value ports have {connections} connections in all, more than {MAX_VALUE_CONNECTIONS} (a node keeps the last frame of at most {MAX_VALUE_CONNECTIONS})",
                            node.name
                        ),
                    );
                }
            }
        }
    }

    /// The identifier of a `republish` table, or `None` after reporting why not.
    fn output_id(&mut self, raw: &RawRepublish) -> Option<OutputId> {
        let id = *raw.can_id.get_ref();
        let (widest, format, hint) = if raw.extended {
            (MAX_EXTENDED_ID, "an extended (29-bit)", "")
        } else {
            (
                MAX_STANDARD_ID,
                "a standard (11-bit)",
                "; write `extended = true` for a 29-bit id",
            )
        };
        let output = u32::try_from(id)
            .ok()
            .and_then(|id| OutputId::new(id, raw.extended).ok());
        if output.is_none() {
            self.error(
                raw.can_id.span(),
                format!(
                    "republish can_id {id:#x} does not fit {format} id (at most {widest:#x}){hint}"
                ),
            );
        }
        output
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::tests::{FIGURE_1, errors, parse};

    #[test]
    fn ports_may_republish_what_they_deliver() {
        let text = FIGURE_1.replace(
            "[ports.\"gaze.target\"]\n",
            "[ports.\"gaze.target\"]\nrepublish = { can_id = 0x300 }\n[ports.\"gaze.other\"]\nrepublish = { can_id = 0x1ABCDEF, extended = true }\n[ports.\"gaze.third\"]\n",
        );
        let network = parse(&text).unwrap();
        assert_eq!(
            network.ports[0].consumer,
            Consumer::Republish(OutputId::new(0x300, false).unwrap())
        );
        assert_eq!(
            network.ports[1].consumer,
            Consumer::Republish(OutputId::new(0x1AB_CDEF, true).unwrap())
        );
        assert_eq!(network.ports[2].consumer, Consumer::Local);
    }

    #[test]
    fn bad_republish_values_are_reported_where_they_are() {
        let with = |republish: &str| {
            errors(&FIGURE_1.replace(
                "[ports.\"gaze.target\"]\n",
                &format!("[ports.\"gaze.target\"]\nrepublish = {republish}\n"),
            ))
        };
        // The port header is on line 11, so `republish` is on line 12.
        let errors = with("{ can_id = 0x800 }");
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            errors[0].starts_with(
                "net.toml:12:24: error: republish can_id 0x800 does not fit a standard (11-bit) id (at most 0x7ff); write `extended = true`"
            ),
            "{errors:?}"
        );
        let errors = with("{ can_id = 0x20000000, extended = true }");
        assert!(
            errors[0].starts_with(
                "net.toml:12:24: error: republish can_id 0x20000000 does not fit an extended (29-bit) id (at most 0x1fffffff)"
            ),
            "{errors:?}"
        );
        let errors = with("{ can_id = -1 }");
        assert!(
            errors[0].starts_with("net.toml:12:24: error: republish can_id"),
            "{errors:?}"
        );
        let errors = with("{ can_id = 0x300, priority = 1 }");
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            errors[0].starts_with("net.toml:12:31: error: unknown key `priority`"),
            "{errors:?}"
        );
        let errors = with("{ extended = true }");
        assert!(
            errors[0].starts_with("net.toml:12:13: error: missing key `can_id`"),
            "{errors:?}"
        );
    }
}

//! What the network reads from a topic's frames: the fields that value ports combine, BLE groups
//! rank and dynamics behaviours take as context.
//!
//! One list serves the checks (a field must lie within its topic's `length`) and the DBC export
//! (each field is a signal of its topic's message), so neither can miss a reader the other sees.

use pab_core::Endian;

use super::{Context, Network};

/// One field of a topic's frames that a part of the network reads.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TopicField {
    /// A name for it, unique among the topic's fields and usable as a DBC signal name:
    /// `nearest` for a value port's value (the port's name after the node), `nearest_priority`
    /// for its priority, `eligibility_task` for BLE group `task`, `context_search` for dynamics
    /// behaviour `search`.
    pub name: String,
    /// Its first byte.
    pub offset: u8,
    /// Its length in bytes.
    pub size: u8,
    /// Two's complement (true) or unsigned.
    pub signed: bool,
    /// Most significant byte first.
    pub big_endian: bool,
    /// Who reads it, in words: "port `base.nearest` (combine = min)".
    pub reader: String,
}

impl Network {
    /// The fields of topic `topic`'s frames that the network reads, in the file's order of
    /// ports, BLE groups and dynamics groups; a field read twice (two ports on one topic) is
    /// listed for each reader. Costs a pass over connections, groups and behaviours.
    pub fn topic_fields(&self, topic: usize) -> Vec<TopicField> {
        let mut fields = Vec::new();
        for port in &self.ports {
            let Some(spec) = &port.value else { continue };
            if !port
                .connections
                .iter()
                .any(|&c| self.connections.get(c).is_some_and(|c| c.topic == topic))
            {
                continue;
            }
            let short = port.name.rsplit('.').next().unwrap_or(&port.name);
            let reader = format!(
                "port `{}` (combine = \"{}\")",
                port.name,
                super::combine_name(spec.combine)
            );
            let field = |name: String, field: &pab_core::Field, reader: String| TopicField {
                name,
                offset: field.offset,
                size: field.size,
                signed: field.signed,
                big_endian: field.endian == Endian::Big,
                reader,
            };
            fields.push(field(short.to_string(), &spec.value, reader.clone()));
            if let Some(priority) = &spec.priority {
                fields.push(field(format!("{short}_priority"), priority, reader));
            }
        }
        for group in &self.groups {
            if group.members.iter().any(|m| m.topic == topic) {
                fields.push(TopicField {
                    name: format!("eligibility_{}", group.name),
                    offset: group.field.offset,
                    size: group.field.size,
                    signed: false,
                    big_endian: group.field.big_endian,
                    reader: format!("BLE group `{}` (the eligibility)", group.name),
                });
            }
        }
        for group in &self.dynamics {
            for behaviour in &group.behaviours {
                let Context::Topic {
                    topic: read, field, ..
                } = &behaviour.context
                else {
                    continue;
                };
                if *read != topic {
                    continue;
                }
                let short = behaviour.name.rsplit('.').next().unwrap_or(&behaviour.name);
                fields.push(TopicField {
                    name: format!("context_{short}"),
                    offset: field.offset,
                    size: field.size,
                    signed: field.signed,
                    big_endian: field.endian == Endian::Big,
                    reader: format!(
                        "dynamics behaviour `{}` of group `{}` (its context)",
                        behaviour.name, group.name
                    ),
                });
            }
        }
        // Two readers of one name (ports `a.v` and `b.v` on one topic): numbered after the first.
        for index in 1..fields.len() {
            let base = fields[index].name.clone();
            let mut suffix = 2;
            while fields[..index].iter().any(|f| f.name == fields[index].name) {
                fields[index].name = format!("{base}_{suffix}");
                suffix += 1;
            }
        }
        fields
    }
}

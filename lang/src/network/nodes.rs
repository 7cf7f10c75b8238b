//! `[nodes.NAME]`: the boards (or their Linux stand-ins), their ids on the bus and what they are.

use std::collections::HashMap;
use std::ops::Range;

use indexmap::IndexMap;
use schemars::JsonSchema;
use serde::Deserialize;

use super::spanned::Spanned;
use super::{Builder, PLAIN_NAME, is_plain_name};

/// `[nodes.NAME]`: a node; its name is used in port names and image file names.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawNode {
    /// Required: the node's id on the bus, 1..=127, unique.
    id: Spanned<i64>,
    /// Optional: what the board is; its node comment in the DBC export.
    description: Option<Spanned<String>>,
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
    /// Where it is defined.
    pub span: Range<usize>,
}

impl Builder<'_> {
    pub(super) fn nodes(&mut self, raw: &IndexMap<Spanned<String>, Spanned<RawNode>>) -> Vec<Node> {
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
            nodes.push(Node {
                name: name.get_ref().clone(),
                id,
                ports: Vec::new(),
                description,
                span: node.span(),
            });
        }
        nodes
    }
}

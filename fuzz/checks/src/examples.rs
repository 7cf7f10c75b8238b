//! The repository's example networks, compiled once per process: real table images to mutate and
//! push, and the CAN ids their tables arbitrate.

use std::sync::OnceLock;

use pab_lang::diagnostic::Source;
use pab_lang::network::Network;

/// The example files, compiled into the checks so that a run needs no working directory.
pub const NETWORKS: [(&str, &str); 7] = [
    (
        "examples/figure-1.toml",
        include_str!("../../../examples/figure-1.toml"),
    ),
    (
        "examples/take-an-object.toml",
        include_str!("../../../examples/take-an-object.toml"),
    ),
    (
        "examples/return-an-object.toml",
        include_str!("../../../examples/return-an-object.toml"),
    ),
    (
        "examples/take-and-return.toml",
        include_str!("../../../examples/take-and-return.toml"),
    ),
    (
        "examples/value-ports.toml",
        include_str!("../../../examples/value-ports.toml"),
    ),
    (
        "examples/multi-target-observation.toml",
        include_str!("../../../examples/multi-target-observation.toml"),
    ),
    (
        "examples/door-dynamics.toml",
        include_str!("../../../examples/door-dynamics.toml"),
    ),
];

/// What the examples give the checks.
pub struct Examples {
    /// Every node's image, as `pabctl compile` writes it but for node id
    /// [`crate::node::NODE_ID`] (its BLE groups' claims carry the node id, which must be the
    /// image's, so the table is compiled for that id rather than its header rewritten).
    pub images: Vec<Vec<u8>>,
    /// Every topic's (id, extended), as frames the tables arbitrate carry them.
    pub topics: Vec<(u32, bool)>,
}

/// The examples, compiled at the first call.
pub fn examples() -> &'static Examples {
    static EXAMPLES: OnceLock<Examples> = OnceLock::new();
    EXAMPLES.get_or_init(|| {
        let mut images = Vec::new();
        let mut topics = Vec::new();
        for (path, text) in NETWORKS {
            let network = Network::parse(Source::new(path, text))
                .unwrap_or_else(|error| panic!("{path} does not parse: {error:?}"));
            for index in 0..network.nodes.len() {
                images.push(image_as(&network, index, crate::node::NODE_ID));
            }
            topics.extend(
                network
                    .topics
                    .iter()
                    .map(|topic| (topic.filter.id(), topic.filter.is_extended())),
            );
        }
        topics.sort_unstable();
        topics.dedup();
        Examples { images, topics }
    })
}

/// Node `index` of `network`'s image, compiled with node id `id` (a node that had `id` takes
/// its old one).
pub(crate) fn image_as(network: &Network, index: usize, id: u8) -> Vec<u8> {
    let mut network = network.clone();
    let old = network.nodes[index].id;
    for node in network.nodes.iter_mut() {
        if node.id == id {
            node.id = old;
        }
    }
    network.nodes[index].id = id;
    let name = network.nodes[index].name.clone();
    pab_lang::compile::compile(&network)
        .unwrap_or_else(|error| panic!("{name} as node {id} does not compile: {error:?}"))
        .into_iter()
        .find(|node| node.name == name)
        .map(|node| node.image)
        .unwrap_or_else(|| panic!("no image for {name}"))
}

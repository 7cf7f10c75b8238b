//! Writes the seed inputs of every fuzz target into `fuzz/corpus/<target>/seed-*` (run once when
//! the corpus was made; the committed corpus is this plus what campaigns found, minimised):
//!
//!     cargo run -p pab-fuzz-checks --example seeds [TARGET...]
//!
//! (only the named targets' seeds, when targets are named: `-- ble` writes the `ble` seeds alone).
//!
//! Images and network files are the examples' own (`pabctl compile` of `examples/*.toml`); the
//! structured targets get a few pseudo-random byte strings (a fixed-seed generator), which their
//! `Unstructured` readers turn into scripts and campaigns then grow. The `ble` and `gates` targets'
//! seeds are chosen among a few thousand such strings: each is kept when its script reaches
//! something no kept one reached (`pab_fuzz_checks::ble::features`: a reading, a claim held, a
//! grid restart, a refused claim, the counter's wrap, ...; `pab_fuzz_checks::gates::features`: a
//! step, a change sent, a backlog dropped, a loss, a refused count, ...), then the ones reaching
//! the most up to 20.

use std::collections::BTreeSet;
use std::path::Path;

use pab_fuzz_checks::TARGETS;
use pab_lang::diagnostic::Source;
use pab_lang::network::Network;

const NETWORKS: [&str; 7] = [
    "figure-1",
    "take-an-object",
    "return-an-object",
    "take-and-return",
    "value-ports",
    "subsumption",
    "tour-guide",
];

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let corpus = root.join("fuzz/corpus");
    let only: Vec<String> = std::env::args().skip(1).collect();
    let wanted = |target: &str| only.is_empty() || only.iter().any(|name| name == target);
    let write = |target: &str, name: &str, bytes: &[u8]| {
        if !wanted(target) {
            return;
        }
        let dir = corpus.join(target);
        std::fs::create_dir_all(&dir).expect("corpus directory");
        std::fs::write(dir.join(format!("seed-{name}")), bytes).expect("seed written");
    };
    let images = ["network", "image_raw", "image_fixed_crc"];
    for name in NETWORKS
        .into_iter()
        .filter(|_| images.iter().any(|t| wanted(t)))
    {
        let path = root.join("examples").join(format!("{name}.toml"));
        let text = std::fs::read_to_string(&path).expect("example readable");
        write("network", name, text.as_bytes());
        let network = Network::parse(Source::new(&path, text)).expect("example parses");
        for node in pab_lang::compile::compile(&network).expect("example compiles") {
            let id = format!("{name}-{}", node.name);
            write("image_raw", &id, &node.image);
            write("image_fixed_crc", &id, &node.image);
        }
    }
    // A little xorshift: the same seeds on every machine.
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for target in TARGETS {
        if matches!(target.name, "network" | "image_raw" | "image_fixed_crc") {
            continue;
        }
        for (i, len) in [16usize, 64, 256, 1024].into_iter().enumerate() {
            let bytes: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            write(target.name, &format!("random-{i}"), &bytes);
        }
    }
    if wanted("ble") {
        script_seeds(
            &write,
            "ble",
            0xB1E5_EED5_0000_0001,
            pab_fuzz_checks::ble::features,
        );
    }
    if wanted("gates") {
        script_seeds(
            &write,
            "gates",
            0x6A7E_5EED_0000_0001,
            pab_fuzz_checks::gates::features,
        );
    }
}

/// The seeds of a structured target (`ble`, `gates`): scripts that reach something new
/// (`features`), then the ones that reach the most, up to 20.
fn script_seeds(
    write: &dyn Fn(&str, &str, &[u8]),
    target: &str,
    mut state: u64,
    features: fn(&[u8]) -> BTreeSet<&'static str>,
) {
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut reached = BTreeSet::new();
    let mut kept: Vec<Vec<u8>> = Vec::new();
    let mut others: Vec<(usize, Vec<u8>)> = Vec::new();
    for i in 0..3_000 {
        let len = [48usize, 96, 192, 384, 768, 1536][i % 6];
        let bytes: Vec<u8> = (0..len).map(|_| next() as u8).collect();
        let features = features(&bytes);
        if features.is_subset(&reached) {
            others.push((features.len(), bytes));
        } else {
            reached.extend(features);
            kept.push(bytes);
        }
    }
    others.sort_by_key(|(count, _)| std::cmp::Reverse(*count));
    let room = 20usize.saturating_sub(kept.len());
    kept.extend(others.into_iter().take(room).map(|(_, bytes)| bytes));
    for (i, bytes) in kept.iter().enumerate() {
        write(target, &format!("script-{i:02}"), bytes);
    }
    println!(
        "{target}: {} seeds reaching {} features: {reached:?}",
        kept.len(),
        reached.len()
    );
}

//! Writes the seed inputs of every fuzz target into `fuzz/corpus/<target>/seed-*` (run once when
//! the corpus was made; the committed corpus is this plus what campaigns found, minimised):
//!
//!     cargo run -p pab-fuzz-checks --example seeds
//!
//! Images and network files are the examples' own (`pabctl compile` of `examples/*.toml`); the
//! structured targets get a few pseudo-random byte strings (a fixed-seed generator), which their
//! `Unstructured` readers turn into scripts and campaigns then grow.

use std::path::Path;

use pab_fuzz_checks::TARGETS;
use pabctl::diagnostic::Source;
use pabctl::network::Network;

const NETWORKS: [&str; 6] = [
    "figure-1",
    "take-an-object",
    "return-an-object",
    "take-and-return",
    "value-ports",
    "subsumption",
];

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let corpus = root.join("fuzz/corpus");
    let write = |target: &str, name: &str, bytes: &[u8]| {
        let dir = corpus.join(target);
        std::fs::create_dir_all(&dir).expect("corpus directory");
        std::fs::write(dir.join(format!("seed-{name}")), bytes).expect("seed written");
    };
    for name in NETWORKS {
        let path = root.join("examples").join(format!("{name}.toml"));
        let text = std::fs::read_to_string(&path).expect("example readable");
        write("network", name, text.as_bytes());
        let network = Network::parse(Source::new(&path, text)).expect("example parses");
        for node in pabctl::compile::compile(&network).expect("example compiles") {
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
}

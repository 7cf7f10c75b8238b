//! Replays the committed fuzz corpus (`fuzz/corpus/<target>/`) and every crash reproducer
//! (`fuzz/artifacts/<target>/`) through the targets' checks, on stable: an input that once
//! found a bug stays a test, and so does every seed. One test per target; each fails if its
//! corpus is missing or empty, and names every input whose check failed.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

use pab_fuzz_checks::{TARGETS, Target};

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn inputs(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .map(|entry| entry.expect("a readable directory entry").path())
        .filter(|path| path.is_file())
        .collect();
    files.sort();
    files
}

fn replay(name: &str) {
    let target: &Target = TARGETS
        .iter()
        .find(|target| target.name == name)
        .unwrap_or_else(|| panic!("no target {name}"));
    let corpus = inputs(&fuzz_dir().join("corpus").join(name));
    assert!(
        !corpus.is_empty(),
        "fuzz/corpus/{name} is missing or empty: nothing would be replayed"
    );
    let artifacts = inputs(&fuzz_dir().join("artifacts").join(name));
    let mut failed = Vec::new();
    for path in corpus.iter().chain(&artifacts) {
        let data =
            std::fs::read(path).unwrap_or_else(|error| panic!("{}: {error}", path.display()));
        if catch_unwind(AssertUnwindSafe(|| (target.check)(&data))).is_err() {
            failed.push(path.display().to_string());
        }
    }
    assert!(
        failed.is_empty(),
        "{name}: {} of {} inputs fail their check (reproduce one with `cargo fuzz run {name} FILE` \
         in fuzz/, or this test):\n{}",
        failed.len(),
        corpus.len() + artifacts.len(),
        failed.join("\n")
    );
}

#[test]
fn every_target_has_a_replay_test() {
    let names: Vec<&str> = TARGETS.iter().map(|target| target.name).collect();
    assert_eq!(
        names,
        [
            "image_raw",
            "image_fixed_crc",
            "isotp_rx",
            "isotp_tx",
            "protocol_decode",
            "protocol_encode",
            "node",
            "network",
            "ble",
            "gates",
            "intention",
            "schema",
            "aes_cmac",
            "node_keyed",
            "node_schema",
            "seal",
            "update",
            "update_session",
            "node_update",
            "isotp_fd",
            "node_fd"
        ]
    );
}

#[test]
fn image_raw() {
    replay("image_raw");
}

#[test]
fn image_fixed_crc() {
    replay("image_fixed_crc");
}

#[test]
fn isotp_rx() {
    replay("isotp_rx");
}

#[test]
fn isotp_tx() {
    replay("isotp_tx");
}

#[test]
fn protocol_decode() {
    replay("protocol_decode");
}

#[test]
fn protocol_encode() {
    replay("protocol_encode");
}

#[test]
fn node() {
    replay("node");
}

#[test]
fn network() {
    replay("network");
}

#[test]
fn ble() {
    replay("ble");
}

#[test]
fn gates() {
    replay("gates");
}

#[test]
fn intention() {
    replay("intention");
}

#[test]
fn schema() {
    replay("schema");
}

#[test]
fn aes_cmac() {
    replay("aes_cmac");
}

#[test]
fn node_keyed() {
    replay("node_keyed");
}

#[test]
fn node_schema() {
    replay("node_schema");
}

#[test]
fn seal() {
    replay("seal");
}

#[test]
fn update() {
    replay("update");
}

#[test]
fn update_session() {
    replay("update_session");
}

#[test]
fn node_update() {
    replay("node_update");
}

#[test]
fn isotp_fd() {
    replay("isotp_fd");
}

#[test]
fn node_fd() {
    replay("node_fd");
}

//! Fuzz target `node_fd`: the check is `pab_fuzz_checks::TARGETS`' entry of that name (its
//! documentation says what it asserts); `cargo test -p pab-fuzz-checks` replays its corpus.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| (pab_fuzz_checks::target("node_fd").check)(data));

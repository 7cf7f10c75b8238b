//! Linker scripts for the binary only: cortex-m-rt's `link.x` (which includes this crate's
//! `memory.x`) and defmt's `defmt.x`. Doing it here rather than in a `.cargo/config.toml` keeps
//! them off the libraries built for the same target.

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    // Put memory.x where the linker finds it (memory-boot.x with the feature `boot`: the program
    // behind the bootloader, at its active partition), and rebuild when either changes.
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let memory: &[u8] = if env::var_os("CARGO_FEATURE_BOOT").is_some() {
        include_bytes!("memory-boot.x")
    } else {
        include_bytes!("memory.x")
    };
    fs::write(out.join("memory.x"), memory).expect("writing memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory-boot.x");
    println!("cargo:rerun-if-changed=build.rs");
    // The node id is compiled in (see src/main.rs): rebuild when it changes.
    println!("cargo:rerun-if-env-changed=PAB_NODE_ID");
    // A panic's location (file and line) only in a build that asks for it: every panic site
    // passes a `Location` (12 bytes) and its file name lives in flash: 996 bytes of the
    // NUCLEO-F446RE's (the NUCLEO-G474RE's main.rs, its panic handler, says more).
    println!("cargo:rerun-if-env-changed=PAB_PANIC_LOCATION");
    println!("cargo::rustc-check-cfg=cfg(panic_location)");
    if env::var_os("PAB_PANIC_LOCATION").is_some_and(|value| value == "1") {
        println!("cargo:rustc-cfg=panic_location");
    }

    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}

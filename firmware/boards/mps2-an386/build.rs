//! Linker scripts for the binaries only: cortex-m-rt's `link.x`, which includes this crate's
//! `memory.x` (`memory-boot.x` with the feature `boot`: the program behind the bootloader) and
//! (cortex-m-rt's `device` feature) `device.x`, the interrupt handlers' default
//! names. Doing it here rather than in a `.cargo/config.toml` keeps them off the libraries built
//! for the same target.

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    // With the bootloader (feature `boot`) the program starts at the active partition.
    let memory: &[u8] = if env::var_os("CARGO_FEATURE_BOOT").is_some() {
        include_bytes!("memory-boot.x")
    } else {
        include_bytes!("memory.x")
    };
    fs::write(out.join("memory.x"), memory).expect("writing memory.x");
    fs::write(out.join("device.x"), include_bytes!("device.x")).expect("writing device.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory-boot.x");
    println!("cargo:rerun-if-changed=device.x");
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=PAB_NODE_ID");
    // A panic's location (file and line) only in a build that asks for it: every panic site
    // passes a `Location` (12 bytes) and its file name lives in flash, 1.7 KB of the NUCLEO-G474RE
    // and 1.2 KB of the emulated board (src/main.rs, the panic handler, says more).
    println!("cargo:rerun-if-env-changed=PAB_PANIC_LOCATION");
    println!("cargo::rustc-check-cfg=cfg(panic_location)");
    if env::var_os("PAB_PANIC_LOCATION").is_some_and(|value| value == "1") {
        println!("cargo:rustc-cfg=panic_location");
    }

    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
}

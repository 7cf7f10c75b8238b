//! The bootloader's linker scripts, for its binary only: cortex-m-rt's `link.x`, which includes
//! this crate's `memory.x` and `device.x` (as firmware/boot/mps2-an386's build.rs does).
use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::write(out.join("memory.x"), include_bytes!("memory.x")).expect("writing memory.x");
    fs::write(out.join("device.x"), include_bytes!("device.x")).expect("writing device.x");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=device.x");
    println!("cargo:rerun-if-changed=build.rs");
    // Two arguments: flip-link (the linker, .cargo/config.toml) finds memory.x through a
    // separate `-L DIR` only.
    println!("cargo:rustc-link-arg-bins=-L");
    println!("cargo:rustc-link-arg-bins={}", out.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
}

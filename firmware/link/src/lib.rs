//! # pab-link: what the firmware crates' build scripts do
//!
//! Every board and bootloader crate links its binary with cortex-m-rt's `link.x`, which
//! `INCLUDE`s a `memory.x` (and, with cortex-m-rt's `device` feature, a `device.x`) that the
//! linker must find. Each crate's `build.rs` copies its own scripts into `OUT_DIR`, tells the
//! linker where they are and which scripts to read, and sets the `panic_location` cfg; this crate
//! is that, written once:
//!
//! ```ignore
//! fn main() {
//!     let scripts = pab_link::Scripts::from_env();
//!     scripts.memory();            // memory.x, or memory-boot.x with the feature `boot`
//!     scripts.place("device.x");
//!     scripts.search();            // for every crate linked with this one
//!     scripts.link(&["link.x"]);   // the binaries: --nmagic, -Tlink.x
//!     pab_link::panic_location();
//! }
//! ```
//!
//! Why in `build.rs` and not in `.cargo/config.toml`: the link arguments reach this crate's
//! binaries only (`rustc-link-arg-bins`), never the libraries built for the same target.

use std::env;
use std::fs;
use std::path::PathBuf;

/// A crate's linker scripts, between its directory and `OUT_DIR`.
#[derive(Debug)]
pub struct Scripts {
    /// The crate's directory (`CARGO_MANIFEST_DIR`): where its scripts are written.
    dir: PathBuf,
    /// Cargo's `OUT_DIR` for the crate: where the linker reads them.
    out: PathBuf,
}

impl Scripts {
    /// The running build script's crate and `OUT_DIR`.
    ///
    /// # Panics
    ///
    /// Outside a build script (cargo sets both variables for one): a build script's panic is
    /// cargo's error message.
    pub fn from_env() -> Scripts {
        let dir = env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
        let out = env::var_os("OUT_DIR").expect("cargo sets OUT_DIR");
        println!("cargo:rerun-if-changed=build.rs");
        Scripts {
            dir: PathBuf::from(dir),
            out: PathBuf::from(out),
        }
    }

    /// Copies the crate's `file` into `OUT_DIR` under the same name; the crate is built again
    /// when it changes.
    ///
    /// # Panics
    ///
    /// When the file cannot be read or written (the message names it).
    pub fn place(&self, file: &str) -> &Scripts {
        self.place_as(file, file)
    }

    /// Copies the crate's `file` into `OUT_DIR` as `name`.
    ///
    /// # Panics
    ///
    /// When the file cannot be read or written (the message names it).
    pub fn place_as(&self, file: &str, name: &str) -> &Scripts {
        let from = self.dir.join(file);
        let bytes =
            fs::read(&from).unwrap_or_else(|error| panic!("reading {}: {error}", from.display()));
        let to = self.out.join(name);
        fs::write(&to, bytes).unwrap_or_else(|error| panic!("writing {}: {error}", to.display()));
        println!("cargo:rerun-if-changed={file}");
        self
    }

    /// The crate's memory map as `memory.x`: its `memory-boot.x` when the crate's feature `boot`
    /// is on (the program behind the bootloader, linked at the active partition), else its
    /// `memory.x`. Both are watched.
    ///
    /// # Panics
    ///
    /// When the chosen file cannot be read or written.
    pub fn memory(&self) -> &Scripts {
        let boot = env::var_os("CARGO_FEATURE_BOOT").is_some();
        println!("cargo:rerun-if-changed=memory.x");
        println!("cargo:rerun-if-changed=memory-boot.x");
        self.place_as(if boot { "memory-boot.x" } else { "memory.x" }, "memory.x")
    }

    /// `OUT_DIR` on the library search path of every link this crate takes part in (its
    /// binaries, and those of crates that depend on it).
    pub fn search(&self) -> &Scripts {
        println!("cargo:rustc-link-search={}", self.out.display());
        self
    }

    /// `OUT_DIR` on the search path of this crate's binaries only: for a crate whose library
    /// another board's binary links (a bootloader's flash map), whose `memory.x` must not reach
    /// that link. Two arguments: flip-link (the linker, `.cargo/config.toml`) finds `memory.x`
    /// through a separate `-L DIR` only.
    pub fn search_for_binaries(&self) -> &Scripts {
        println!("cargo:rustc-link-arg-bins=-L");
        println!("cargo:rustc-link-arg-bins={}", self.out.display());
        self
    }

    /// The binaries' link: `--nmagic` (sections at their addresses, not page-aligned in the
    /// file), then `-T` each of `scripts` in order (`link.x` first; `defmt.x` where defmt logs).
    pub fn link(&self, scripts: &[&str]) {
        println!("cargo:rustc-link-arg-bins=--nmagic");
        for script in scripts {
            println!("cargo:rustc-link-arg-bins=-T{script}");
        }
    }
}

/// The `panic_location` cfg, on when the build's environment has `PAB_PANIC_LOCATION=1`: a
/// panic's file and line only in a build that asks for it (`scripts/panic-check.sh`), since every
/// panic site then passes a `Location` (12 bytes) and its file name lives in flash: 1.7 KB of
/// the NUCLEO-G474RE's, 1.2 KB of the emulated board's (the boards' panic handlers say more).
pub fn panic_location() {
    println!("cargo:rerun-if-env-changed=PAB_PANIC_LOCATION");
    println!("cargo::rustc-check-cfg=cfg(panic_location)");
    if env::var_os("PAB_PANIC_LOCATION").is_some_and(|value| value == "1") {
        println!("cargo:rustc-cfg=panic_location");
    }
}

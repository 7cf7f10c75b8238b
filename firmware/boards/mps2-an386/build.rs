//! Linker scripts for the binaries only (pab-link): cortex-m-rt's `link.x`, which includes this
//! crate's `memory.x` (`memory-boot.x` with the feature `boot`: the program behind the
//! bootloader) and (cortex-m-rt's `device` feature) `device.x`, the interrupt handlers' default
//! names; the `panic_location` build.

fn main() {
    pab_link::Scripts::from_env()
        .memory()
        .place("device.x")
        .search()
        .link(&["link.x"]);
    // The node id is compiled in (see src/main.rs): rebuild when it changes.
    println!("cargo:rerun-if-env-changed=PAB_NODE_ID");
    pab_link::panic_location();
}

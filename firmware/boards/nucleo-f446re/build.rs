//! Linker scripts for the binary only (pab-link): cortex-m-rt's `link.x` (which includes this
//! crate's `memory.x`, or `memory-boot.x` with the feature `boot`: the program behind the
//! bootloader, at its active partition) and defmt's `defmt.x`; the `panic_location` build.

fn main() {
    pab_link::Scripts::from_env()
        .memory()
        .search()
        .link(&["link.x", "defmt.x"]);
    // The node id is compiled in (see src/main.rs): rebuild when it changes.
    println!("cargo:rerun-if-env-changed=PAB_NODE_ID");
    pab_link::panic_location();
}

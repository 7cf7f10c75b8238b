//! The bootloader's linker scripts, for its binary only: cortex-m-rt's `link.x`, which includes
//! this crate's `memory.x` and `device.x` (pab-link). On the binaries' search path only, not the
//! library's: the board's application depends on this crate's library (its flash map), and a
//! search path would carry this `memory.x` into its link, beside its own.

fn main() {
    pab_link::Scripts::from_env()
        .place("memory.x")
        .place("device.x")
        .search_for_binaries()
        .link(&["link.x"]);
}

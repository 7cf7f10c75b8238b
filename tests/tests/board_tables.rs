//! The table images built into the emulated board's instruction-count program
//! (`firmware/boards/mps2-an386/tables/`) are exactly what `pabctl compile` makes of the example
//! today, so the Cortex-M4 figures measure the tables users get. When the compiler or the image
//! format changes, regenerate them:
//!
//!     cargo run -p pabctl -- compile examples/take-and-return.toml \
//!         -o firmware/boards/mps2-an386/tables/take-and-return

use std::path::PathBuf;

use pab_lang::compile;
use pab_tests::{example_text, network};

#[test]
fn the_boards_take_and_return_images_are_what_pabctl_compiles() {
    let network = network("take-and-return", &example_text("take-and-return"));
    let nodes = compile::compile(&network).unwrap_or_else(|errors| panic!("{errors:?}"));
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../firmware/boards/mps2-an386/tables/take-and-return");
    let mut names: Vec<_> = nodes.iter().map(|node| node.name.as_str()).collect();
    names.sort_unstable();
    assert_eq!(names, ["arm", "gaze", "hand"]);
    for node in &nodes {
        let path = dir.join(format!("{}.pab", node.name));
        let stored =
            std::fs::read(&path).unwrap_or_else(|error| panic!("{}: {error}", path.display()));
        assert!(
            stored == node.image,
            "{} differs from what pabctl compiles now: regenerate it (see this test's doc)",
            path.display()
        );
    }
}

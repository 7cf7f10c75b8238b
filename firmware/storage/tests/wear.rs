//! Erase counts over many saves: each save erases the pages of one slot its image needs
//! (alternating slots), and the commit log's erases are spread evenly over its pages.

mod common;

use common::*;

#[test]
fn erase_counts_over_1000_saves() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    for k in 0..1000 {
        save(&mut store, if k % 2 == 0 { &v1 } else { &v2 }).expect("save");
    }
    let counts = *store.flash_mut().erase_counts();
    println!("erase counts per 4 KiB page after 1000 saves: {counts:?}");
    // Slot 0 = pages 0..4, slot 1 = pages 4..8: small images use the first page of each.
    assert_eq!(counts[0], 500);
    assert_eq!(counts[4], 500);
    assert!(counts[1..4].iter().chain(&counts[5..8]).all(|&c| c == 0));
    // The log's two pages: spread evenly, a handful each.
    let log = &counts[8..10];
    let (min, max) = (*log.iter().min().unwrap(), *log.iter().max().unwrap());
    assert!(max - min <= 1 && (1..=10).contains(&max), "{log:?}");
}

#[test]
fn erase_counts_small_pages() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(SmallFlash::new(), SMALL_RANGE, SMALL_SLOT);
    for k in 0..1000 {
        save(&mut store, if k % 2 == 0 { &v1 } else { &v2 }).expect("save");
    }
    let counts = *store.flash_mut().erase_counts();
    println!("erase counts per 256 B page after 1000 saves: {counts:?}");
    let log = &counts[4..7];
    let (min, max) = (*log.iter().min().unwrap(), *log.iter().max().unwrap());
    assert!(max - min <= 1, "{log:?}");
}

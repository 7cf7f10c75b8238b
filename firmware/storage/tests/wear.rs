//! Erase counts over many saves: each save erases the pages of one slot that its header and
//! image need, and the slots take turns (each page erased once every K saves).

use crate::common;

use common::*;

#[test]
fn erase_counts_over_1000_saves() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    for k in 0..1000 {
        save(&mut store, if k % 2 == 0 { &v1 } else { &v2 }).expect("save");
    }
    let counts = *store.flash_mut().erase_counts();
    println!("erase counts per 4 KiB page after 1000 saves of small images: {counts:?}");
    // 5 slots of 2 pages: small images use the first page of each slot, in turn.
    for (page, &count) in counts.iter().enumerate() {
        let expected = if page % 2 == 0 { 1000 / BOARD_SLOTS } else { 0 };
        assert_eq!(count, expected, "page {page}: {counts:?}");
    }
}

#[test]
fn erase_counts_of_two_page_images() {
    let (a, b) = (image_ports(5, 1), image_ports(5, 2));
    assert!(a.len() as u32 + BOARD_HEADER > 4096);
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    for k in 0..1000 {
        save(&mut store, if k % 2 == 0 { &a } else { &b }).expect("save");
    }
    let counts = *store.flash_mut().erase_counts();
    println!("erase counts per 4 KiB page after 1000 saves of 4.8 KB images: {counts:?}");
    assert!(
        counts.iter().all(|&count| count == 1000 / BOARD_SLOTS),
        "{counts:?}"
    );
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
    for (page, &count) in counts.iter().enumerate() {
        let expected = if page % 2 == 0 { 1000 / SMALL_SLOTS } else { 0 };
        assert_eq!(count, expected, "page {page}: {counts:?}");
    }
}

//! Power lost at every program or erase operation of a save, from many states of the commit
//! log: after a reboot, `load` returns exactly the old image or exactly the new one, the image
//! passes `pab_core::image::load`, and the store accepts the next save.

mod common;

use common::*;
use pab_storage::testing::MemFlash;

#[derive(Default, Debug)]
struct Figures {
    points: u32,
    old: u32,
    new: u32,
    sweeps: u32,
}

/// Saves `new` over the store in `base`, cutting the power at operation 0, 1, ... until a save
/// completes untouched; after each cut, reboots and checks what loads.
fn sweep<const P: usize, const E: usize, const W: usize>(
    base: &MemFlash<P, E, W>,
    range: core::ops::Range<u32>,
    slot: u32,
    old: Option<&[u8]>,
    new: &[u8],
    seed: u64,
    figures: &mut Figures,
) {
    figures.sweeps += 1;
    for n in 0u32.. {
        let mut flash = base.clone();
        flash.set_seed(seed.wrapping_mul(1_000_003).wrapping_add(u64::from(n)));
        flash.fail_after(n);
        let mut store = store(flash, range.clone(), slot);
        let result = save(&mut store, new);
        let mut flash = store.into_flash();
        let lost = flash.power_lost();
        flash.reboot();
        let mut store = common::store(flash, range.clone(), slot);
        let loaded = load(&mut store).unwrap_or_else(|e| panic!("cut at {n}: load failed: {e}"));
        if !lost {
            result.unwrap_or_else(|e| panic!("save without power loss failed: {e}"));
            assert_eq!(loaded.as_deref(), Some(new), "completed save");
            return;
        }
        figures.points += 1;
        if result.is_ok() {
            // Returned Ok although the power went: then the new image must be there.
            assert_eq!(loaded.as_deref(), Some(new), "cut at {n} after Ok");
        }
        match loaded.as_deref() {
            Some(bytes) if bytes == new => figures.new += 1,
            bytes if bytes == old => figures.old += 1,
            Some(bytes) => panic!(
                "cut at {n}: loaded {} bytes that are neither image (version {})",
                bytes.len(),
                version(bytes)
            ),
            None => panic!("cut at {n}: the old image is lost"),
        }
        // The store is not stuck: the save is retried after the reboot and sticks.
        save(&mut store, new).unwrap_or_else(|e| panic!("cut at {n}: retried save: {e}"));
        let mut store = common::store(store.into_flash(), range.clone(), slot);
        assert_eq!(load(&mut store).expect("load").as_deref(), Some(new));
    }
}

#[test]
#[ignore = "FAILS: sequential-storage 8.0.2 loses both commit records when the erase of its oldest log page is cut (half-erased page); see README Storage"]
fn power_loss_at_every_operation_board_geometry() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut figures = Figures::default();
    let mut base = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    // From an empty store: a cut save leaves nothing or the new image.
    sweep(
        &base.flash_mut().clone(),
        BOARD_RANGE,
        BOARD_SLOT,
        None,
        &v1,
        0,
        &mut figures,
    );
    // From histories of h saves, including the commit log's page changes (170 records a page)
    // and wrap-around (two pages: the first erase of a log page happens near 340 saves).
    let checked: Vec<u32> = (1..=12)
        .chain(166..=176)
        .chain(336..=348)
        .chain(505..=512)
        .collect();
    let mut old: Option<Vec<u8>> = None;
    for h in 1..=512u32 {
        let image = if h % 2 == 1 { &v1 } else { &v2 };
        save(&mut base, image).expect("history save");
        old = Some(image.clone());
        if checked.contains(&h) {
            let new = if h % 2 == 1 { &v2 } else { &v1 };
            let flash = base.flash_mut().clone();
            sweep(
                &flash,
                BOARD_RANGE,
                BOARD_SLOT,
                old.as_deref(),
                new,
                u64::from(h),
                &mut figures,
            );
        }
    }
    assert!(old.is_some());
    println!("board geometry: {figures:?}");
    assert!(figures.old > 0 && figures.new > 0);
}

#[test]
#[ignore = "FAILS: sequential-storage 8.0.2 loses both commit records when the erase of its oldest log page is cut (half-erased page); see README Storage"]
fn power_loss_at_every_operation_small_pages() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut figures = Figures::default();
    let mut base = store(SmallFlash::new(), SMALL_RANGE, SMALL_SLOT);
    sweep(
        &base.flash_mut().clone(),
        SMALL_RANGE,
        SMALL_SLOT,
        None,
        &v1,
        0,
        &mut figures,
    );
    // 10 records per log page, 3 pages: 80 histories cover many log wraps and migrations.
    for h in 1..=80u32 {
        let image = if h % 2 == 1 { &v1 } else { &v2 };
        save(&mut base, image).expect("history save");
        let new = if h % 2 == 1 { &v2 } else { &v1 };
        let flash = base.flash_mut().clone();
        sweep(
            &flash,
            SMALL_RANGE,
            SMALL_SLOT,
            Some(image),
            new,
            u64::from(h),
            &mut figures,
        );
    }
    println!("small pages: {figures:?}");
    assert!(figures.old > 0 && figures.new > 0);
}

#[test]
fn power_loss_at_every_operation_large_image() {
    let (a, b) = (image_large(1), image_large(2));
    let mut figures = Figures::default();
    let mut base = store(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT);
    save(&mut base, &a).expect("save a");
    let flash = base.flash_mut().clone();
    sweep(
        &flash,
        LARGE_RANGE,
        LARGE_SLOT,
        Some(&a),
        &b,
        7,
        &mut figures,
    );
    println!("large image ({} bytes): {figures:?}", b.len());
    assert!(figures.points > 60, "one write per 256 bytes");
}

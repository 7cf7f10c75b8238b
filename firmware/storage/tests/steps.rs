//! The step-wise save (`start_save`, then `continue_save` until `Done`): each step does at most one
//! flash operation (one page erase started, or one chunk of at most `SAVE_CHUNK` bytes
//! programmed), waits for no erase, and a save interrupted by anything (another save, a wrong
//! image, a power loss between two steps) leaves `load` returning the previous image.

use crate::common;

use common::*;
use pab_storage::{FlashStore, SAVE_CHUNK, SaveProgress, StoreError, TableStore};

/// Runs a save to its end, one step at a time; returns each step's progress and the flash
/// operations (program or erase calls) it made.
fn steps(store: &mut FlashStore<LargeFlash>, image: &[u8]) -> Vec<(SaveProgress, u32)> {
    store.start_save(image).expect("start");
    let mut out = Vec::new();
    loop {
        let before = store.flash_mut().operations();
        let progress = store.continue_save(image).expect("step");
        out.push((progress, store.flash_mut().operations() - before));
        if progress == SaveProgress::Done {
            return out;
        }
        assert!(out.len() < 10_000, "the save never ends");
    }
}

#[test]
fn every_step_does_one_flash_operation_at_most_and_waits_for_no_erase() {
    for polls in [0, 1, 5] {
        let mut flash = LargeFlash::new();
        flash.set_erase_polls(polls);
        let mut store = FlashStore::new(flash, LARGE_RANGE, LARGE_SLOT).expect("layout");
        // About 15 KB: four of the 4 KiB pages with the header, 122 chunks.
        let image = image_large(3);
        let pages = (24 + image.len()).div_ceil(4096);
        assert_eq!(pages, 4, "{}", image.len());
        let done = steps(&mut store, &image);
        assert!(
            done.iter().all(|&(_, operations)| operations <= 1),
            "{done:?}"
        );
        let erasing = done
            .iter()
            .filter(|(p, _)| *p == SaveProgress::Erasing)
            .count();
        // Each page: the step that starts it and `polls` checks while it runs.
        assert_eq!(erasing, pages * (1 + polls as usize), "{done:?}");
        let chunks = image.len().div_ceil(SAVE_CHUNK);
        // The erases, the chunks and the header: every operation of the save, one per step.
        let operations: u32 = done.iter().map(|&(_, n)| n).sum();
        assert_eq!(operations as usize, pages + chunks + 1);
        assert_eq!(load(&mut store), Ok(Some(image.clone())));
    }
}

#[test]
fn a_save_step_by_step_commits_what_save_at_once_commits() {
    let images = [image_v1(), image_large(4), image_v2(), image_ports(3, 5)];
    let mut stepped = FlashStore::new(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT).expect("layout");
    let mut at_once = FlashStore::new(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT).expect("layout");
    for image in &images {
        steps(&mut stepped, image);
        at_once.save(image).expect("save");
        assert_eq!(load(&mut stepped), Ok(Some(image.clone())));
        assert_eq!(
            stepped.flash_mut().pages(),
            at_once.flash_mut().pages(),
            "the same bytes in the same places"
        );
    }
}

#[test]
fn an_abandoned_save_leaves_the_previous_image() {
    let mut store = FlashStore::new(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT).expect("layout");
    store.save(&image_v1()).expect("first");
    let next = image_large(2);
    // Stopped at every step of a save, then another save from the start: the first image until
    // the second's commit, then the second.
    let total = steps(
        &mut FlashStore::new(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT).expect("layout"),
        &next,
    )
    .len();
    for stop in 0..total {
        let mut store =
            FlashStore::new(store.flash_mut().clone(), LARGE_RANGE, LARGE_SLOT).expect("layout");
        store.start_save(&next).expect("start");
        for _ in 0..stop {
            assert_ne!(store.continue_save(&next), Ok(SaveProgress::Done));
        }
        assert_eq!(
            load(&mut store),
            Ok(Some(image_v1())),
            "stopped after {stop} steps"
        );
        // A node that restarts (a new store over the same flash) finds the first image too.
        let mut rebooted =
            FlashStore::new(store.flash_mut().clone(), LARGE_RANGE, LARGE_SLOT).expect("layout");
        assert_eq!(load(&mut rebooted), Ok(Some(image_v1())));
        let third = image_v2();
        steps(&mut store, &third);
        assert_eq!(load(&mut store), Ok(Some(third)));
    }
}

#[test]
fn a_step_without_its_save_or_with_another_image_commits_nothing() {
    let mut store = FlashStore::new(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT).expect("layout");
    assert_eq!(store.continue_save(&image_v1()), Err(StoreError::NoSave));
    store.save(&image_v1()).expect("first");
    assert_eq!(
        store.continue_save(&image_v1()),
        Err(StoreError::NoSave),
        "after Done"
    );

    // Another length: refused at once.
    let next = image_large(2);
    store.start_save(&next).expect("start");
    assert_eq!(store.continue_save(&image_v1()), Err(StoreError::NoSave));
    assert_eq!(
        store.continue_save(&next),
        Err(StoreError::NoSave),
        "the save ended"
    );

    // The same length, other bytes (a buffer overwritten under the save): never committed.
    let mut other = next.clone();
    *other.last_mut().expect("bytes") ^= 0x55;
    store.start_save(&next).expect("start");
    let mut result = store.continue_save(&next);
    while result == Ok(SaveProgress::Ready) || result == Ok(SaveProgress::Erasing) {
        result = store.continue_save(&other);
    }
    assert_ne!(result, Ok(SaveProgress::Done));
    assert_eq!(load(&mut store), Ok(Some(image_v1())));
}

#[test]
fn a_power_loss_at_any_step_leaves_the_old_or_the_new_image() {
    let old = image_v2();
    let new = image_large(7);
    let mut base = FlashStore::new(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT).expect("layout");
    base.save(&old).expect("old");
    let operations = {
        let mut probe =
            FlashStore::new(base.flash_mut().clone(), LARGE_RANGE, LARGE_SLOT).expect("layout");
        let before = probe.flash_mut().operations();
        steps(&mut probe, &new);
        probe.flash_mut().operations() - before
    };
    for cut in 0..operations {
        let mut flash = base.flash_mut().clone();
        flash.set_seed(u64::from(cut) * 7 + 1);
        flash.fail_after(cut);
        let mut store = FlashStore::new(flash, LARGE_RANGE, LARGE_SLOT).expect("layout");
        store.start_save(&new).expect("start reads only");
        let mut result = store.continue_save(&new);
        while matches!(result, Ok(SaveProgress::Ready | SaveProgress::Erasing)) {
            result = store.continue_save(&new);
        }
        assert!(result.is_err(), "cut {cut}: the cut call fails");
        let mut flash = store.into_flash();
        flash.reboot();
        let mut store = FlashStore::new(flash, LARGE_RANGE, LARGE_SLOT).expect("layout");
        let loaded = load(&mut store).expect("load after the cut");
        assert!(
            loaded == Some(old.clone()) || loaded == Some(new.clone()),
            "cut {cut}: neither image"
        );
        // And the store goes on working.
        store.save(&new).expect("save after reboot");
        assert_eq!(load(&mut store), Ok(Some(new.clone())));
    }
}

//! Power lost at every program or erase operation of a save, after every save of long histories
//! (the ring of slots wraps many times): after a reboot, `load` returns exactly the old image or
//! exactly the new one, the image passes `pab_core::image::load`, and the store goes on working,
//! also when the power is cut again during the next save.

use crate::common;

use common::*;
use pab_storage::testing::MemFlash;

#[derive(Default, Debug)]
struct Figures {
    /// Power cuts during a save, each followed by a reboot and a load.
    points: u32,
    /// Of those, the loads that returned the old image, and the new one.
    old: u32,
    new: u32,
    /// Second cuts, during the save retried after the first cut.
    second_cuts: u32,
    /// Saves swept (one per history state).
    sweeps: u32,
}

/// What `load` returns must be exactly `old` or exactly `new`.
fn check_old_or_new(loaded: Option<&[u8]>, old: Option<&[u8]>, new: &[u8], what: &str) -> bool {
    match loaded {
        Some(bytes) if bytes == new => true,
        bytes if bytes == old => false,
        Some(bytes) => panic!(
            "{what}: loaded {} bytes that are neither image (version {})",
            bytes.len(),
            version(bytes)
        ),
        None => panic!("{what}: the old image is lost"),
    }
}

/// Saves `new` over the store in `base`, cutting the power at operation 0, 1, ... until a save
/// completes untouched; after each cut, reboots and checks what loads, then retries the save
/// with a second cut, reboots, checks again, and saves for good.
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
        let what = format!("seed {seed}, cut at {n}");
        let mut flash = base.clone();
        flash.set_seed(seed.wrapping_mul(1_000_003).wrapping_add(u64::from(n)));
        flash.fail_after(n);
        let mut store = store(flash, range.clone(), slot);
        let result = save(&mut store, new);
        let mut flash = store.into_flash();
        let lost = flash.power_lost();
        flash.reboot();
        let mut store = common::store(flash, range.clone(), slot);
        let loaded = load(&mut store).unwrap_or_else(|e| panic!("{what}: load failed: {e}"));
        if !lost {
            result.unwrap_or_else(|e| panic!("save without power loss failed: {e}"));
            assert_eq!(loaded.as_deref(), Some(new), "completed save");
            return;
        }
        figures.points += 1;
        assert!(result.is_err(), "{what}: Ok although the power went");
        let committed = check_old_or_new(loaded.as_deref(), old, new, &what);
        if committed {
            figures.new += 1;
        } else {
            figures.old += 1;
        }
        // What loads now is the "old" image of the retried save.
        let old_now = loaded.clone();
        // The retried save is cut again, at one of its first operations.
        let mut flash = store.into_flash();
        flash.fail_after(n % 3);
        let mut store = common::store(flash, range.clone(), slot);
        let second = save(&mut store, new);
        let mut flash = store.into_flash();
        if flash.power_lost() {
            figures.second_cuts += 1;
            assert!(second.is_err(), "{what}: second cut returned Ok");
        }
        flash.reboot();
        let mut store = common::store(flash, range.clone(), slot);
        let loaded = load(&mut store).unwrap_or_else(|e| panic!("{what}, second cut: {e}"));
        check_old_or_new(loaded.as_deref(), old_now.as_deref(), new, &what);
        // The store is not stuck: a save after the reboots sticks.
        save(&mut store, new).unwrap_or_else(|e| panic!("{what}: retried save: {e}"));
        let mut store = common::store(store.into_flash(), range.clone(), slot);
        assert_eq!(load(&mut store).expect("load").as_deref(), Some(new));
    }
}

/// Saves `history(1)`, `history(2)`, ... `history(saves)` in turn; before each, sweeps the
/// power loss over that save.
fn sweep_history<const P: usize, const E: usize, const W: usize>(
    range: core::ops::Range<u32>,
    slot: u32,
    saves: u32,
    history: impl Fn(u32) -> Vec<u8>,
) -> Figures {
    let mut figures = Figures::default();
    let mut base = store(MemFlash::<P, E, W>::new(), range.clone(), slot);
    let mut old: Option<Vec<u8>> = None;
    for h in 1..=saves {
        let new = history(h);
        let flash = base.flash_mut().clone();
        sweep(
            &flash,
            range.clone(),
            slot,
            old.as_deref(),
            &new,
            u64::from(h),
            &mut figures,
        );
        save(&mut base, &new).expect("history save");
        old = Some(new);
    }
    figures
}

/// Images of one or two 256-byte pages (with the slot header), all distinct.
fn small_history(h: u32) -> Vec<u8> {
    match h % 5 {
        0 => image_v1(),
        1 => image_v2(),
        2 => image_connections(6, h),
        3 => image_connections(12, h),
        _ => image_connections(15, h),
    }
}

/// Images of one or two 4 KiB pages (with the slot header), all distinct.
fn board_history(h: u32) -> Vec<u8> {
    match h % 6 {
        0 => image_v1(),
        1 => image_v2(),
        2 => image_connections(20, h),
        3 => image_ports(4, h),
        4 => image_ports(5, h),
        _ => image_ports(8, h),
    }
}

#[test]
fn power_loss_at_every_operation_board_geometry() {
    // 400 saves over 5 slots: the ring wraps 80 times.
    let figures = sweep_history::<10, 4096, 8>(BOARD_RANGE, BOARD_SLOT, 400, board_history);
    println!("board geometry (4 KiB pages, 8-byte words, 5 slots): {figures:?}");
    assert_eq!(figures.sweeps, 400);
    assert!(figures.old > 0 && figures.new > 0);
    assert!(figures.points > 4000, "{figures:?}");
}

#[test]
fn power_loss_at_every_operation_small_pages() {
    // 600 saves over 4 slots: the ring wraps 150 times.
    let figures = sweep_history::<8, 256, 4>(SMALL_RANGE, SMALL_SLOT, 600, small_history);
    println!("small pages (256 B pages, 4-byte words, 4 slots): {figures:?}");
    assert_eq!(figures.sweeps, 600);
    assert!(figures.old > 0 && figures.new > 0);
}

#[test]
fn power_loss_at_every_operation_large_image() {
    let (a, b) = (image_large(1), image_large(2));
    let mut figures = Figures::default();
    let mut base = store(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT);
    for k in 0..6 {
        let (old, new) = if k % 2 == 0 { (&a, &b) } else { (&b, &a) };
        save(&mut base, old).expect("save");
        let flash = base.flash_mut().clone();
        sweep(
            &flash,
            LARGE_RANGE,
            LARGE_SLOT,
            Some(old),
            new,
            7 + k,
            &mut figures,
        );
    }
    println!("large image ({} bytes): {figures:?}", b.len());
    assert!(figures.points > 6 * 60, "one write per 256 bytes");
}

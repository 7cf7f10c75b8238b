//! The store's contract outside power loss: round trips, sizes, layouts, a fresh or garbage
//! flash, and flash corrupted behind the store's back.

mod common;

use common::*;
use embassy_futures::block_on;
use pab_storage::testing::MemFlash;
use pab_storage::{FlashStore, LayoutError, LogErrorKind, StoreError, TableStore};

#[test]
fn a_fresh_flash_holds_nothing() {
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    assert_eq!(load(&mut store), Ok(None));
    // Loading wrote nothing.
    assert_eq!(store.flash_mut().operations(), 0);
}

#[test]
fn round_trip_and_reboots() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v1).expect("save v1");
    assert_eq!(load(&mut store), Ok(Some(v1.clone())));
    save(&mut store, &v2).expect("save v2");
    assert_eq!(load(&mut store), Ok(Some(v2.clone())));
    // Reboot: a new store over the same memory.
    let mut store = common::store(store.into_flash(), BOARD_RANGE, BOARD_SLOT);
    assert_eq!(load(&mut store), Ok(Some(v2.clone())));
    for k in 0..20 {
        let image = if k % 2 == 0 { &v1 } else { &v2 };
        save(&mut store, image).expect("save");
        let mut rebooted = common::store(store.into_flash(), BOARD_RANGE, BOARD_SLOT);
        assert_eq!(load(&mut rebooted), Ok(Some(image.clone())));
        store = rebooted;
    }
}

#[test]
fn small_pages_round_trip_across_log_wraps() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(SmallFlash::new(), SMALL_RANGE, SMALL_SLOT);
    for k in 0..200 {
        let image = if k % 2 == 0 { &v1 } else { &v2 };
        save(&mut store, image).expect("save");
        assert_eq!(load(&mut store), Ok(Some(image.clone())), "save {k}");
    }
}

#[test]
fn a_large_image_spans_pages() {
    let (a, b) = (image_large(1), image_large(2));
    assert!(a.len() > 3 * 4096, "{} bytes", a.len());
    let mut store = store(LargeFlash::new(), LARGE_RANGE, LARGE_SLOT);
    save(&mut store, &a).expect("save a");
    save(&mut store, &b).expect("save b");
    let mut store = common::store(store.into_flash(), LARGE_RANGE, LARGE_SLOT);
    assert_eq!(load(&mut store), Ok(Some(b)));
}

#[test]
fn an_image_larger_than_a_slot_is_refused() {
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &image_v1()).expect("save v1");
    let operations = store.flash_mut().operations();
    let big = vec![0x11; BOARD_SLOT as usize + 4096];
    assert_eq!(
        save(&mut store, &big),
        Err(StoreError::ImageTooLarge {
            len: big.len(),
            slot_size: BOARD_SLOT
        })
    );
    // Refused before touching the flash; the old image stays.
    assert_eq!(store.flash_mut().operations(), operations);
    assert_eq!(load(&mut store), Ok(Some(image_v1())));
    // Exactly a slot fits.
    let exact = vec![0x5A; BOARD_SLOT as usize];
    save(&mut store, &exact).expect("a slot-sized image");
    let mut buf = vec![0u8; BOARD_SLOT as usize];
    assert_eq!(block_on(store.load(&mut buf)), Ok(Some(&exact[..])));
    assert!(matches!(
        save(&mut store, &vec![0; BOARD_SLOT as usize + 1]),
        Err(StoreError::ImageTooLarge { .. })
    ));
}

#[test]
fn a_buffer_too_small_is_reported() {
    let v2 = image_v2();
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v2).expect("save");
    let mut buf = [0u8; 16];
    assert_eq!(
        block_on(store.load(&mut buf)),
        Err(StoreError::BufferTooSmall {
            needed: v2.len(),
            got: 16
        })
    );
}

#[test]
fn bad_layouts_are_typed_errors() {
    fn new(range: core::ops::Range<u32>, slot: u32) -> Result<(), StoreError> {
        FlashStore::new(BoardFlash::new(), range, slot).map(|_| ())
    }
    let layout = |e| Err(StoreError::Layout(e));
    assert_eq!(new(0..40960, 16384), Ok(()));
    assert_eq!(
        new(100..40960, 16384),
        layout(LayoutError::RangeNotPageAligned)
    );
    assert_eq!(
        new(0..40000, 16384),
        layout(LayoutError::RangeNotPageAligned)
    );
    assert_eq!(new(0..45056, 4096), layout(LayoutError::RangeOutOfBounds));
    assert_eq!(new(4096..4096, 4096), layout(LayoutError::RangeOutOfBounds));
    assert_eq!(
        new(0..40960, 0),
        layout(LayoutError::SlotSizeNotPageMultiple)
    );
    assert_eq!(
        new(0..40960, 5000),
        layout(LayoutError::SlotSizeNotPageMultiple)
    );
    // Two slots of 16 KiB leave one page: the log needs two.
    assert_eq!(new(0..36864, 16384), layout(LayoutError::RangeTooSmall));
    assert_eq!(new(0..40960, 20480), layout(LayoutError::RangeTooSmall));
    assert_eq!(
        new(0..40960, u32::MAX - 4095),
        layout(LayoutError::RangeTooSmall)
    );
    // 32-byte words in 32-byte pages: sequential-storage refuses pages it cannot use.
    assert_eq!(
        FlashStore::new(MemFlash::<8, 32, 32>::new(), 0..256, 32).map(|_| ()),
        layout(LayoutError::LogRefused)
    );
    let message = StoreError::Layout(LayoutError::RangeTooSmall).to_string();
    assert!(message.contains("two log pages"), "{message}");
}

#[test]
fn a_flipped_bit_in_the_newest_slot_falls_back_to_the_previous_image() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v1).expect("save v1"); // slot 0
    save(&mut store, &v2).expect("save v2"); // slot 1
    // Every bit of the newest image, one at a time.
    for bit in 0..v2.len() * 8 {
        let offset = BOARD_SLOT + (bit / 8) as u32;
        assert!(store.flash_mut().flip_bit(offset, (bit % 8) as u8));
        assert_eq!(load(&mut store), Ok(Some(v1.clone())), "bit {bit}");
        store.flash_mut().flip_bit(offset, (bit % 8) as u8);
    }
    assert_eq!(load(&mut store), Ok(Some(v2.clone())));
    // A flip beyond the image's end changes nothing.
    store
        .flash_mut()
        .flip_bit(BOARD_SLOT + v2.len() as u32 + 1, 0);
    assert_eq!(load(&mut store), Ok(Some(v2.clone())));
}

#[test]
fn after_a_fallback_a_save_keeps_the_only_good_copy() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v1).expect("save v1"); // slot 0
    save(&mut store, &v2).expect("save v2"); // slot 1
    store.flash_mut().flip_bit(BOARD_SLOT + 30, 3); // v2 damaged: load gives v1
    assert_eq!(load(&mut store), Ok(Some(v1.clone())));
    // The next save must go to slot 1 (the damaged one), not over v1: cut the power in its
    // first operation (the erase of slot 1's page) and v1 must still be there.
    let mut flash = store.into_flash();
    flash.fail_after(0);
    let mut store = common::store(flash, BOARD_RANGE, BOARD_SLOT);
    assert!(save(&mut store, &v2).is_err());
    let mut flash = store.into_flash();
    flash.reboot();
    assert_eq!(flash.pages()[0][..v1.len()], v1[..], "slot 0 untouched");
    let mut store = common::store(flash, BOARD_RANGE, BOARD_SLOT);
    assert_eq!(load(&mut store), Ok(Some(v1.clone())));
    save(&mut store, &v2).expect("save v2 again");
    assert_eq!(load(&mut store), Ok(Some(v2)));
}

#[test]
fn both_copies_damaged_is_reported_as_corrupt() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v1).expect("save v1");
    store.flash_mut().flip_bit(7, 0);
    assert_eq!(load(&mut store), Err(StoreError::Corrupt));
    store.flash_mut().flip_bit(7, 0);
    save(&mut store, &v2).expect("save v2");
    store.flash_mut().flip_bit(7, 0);
    store.flash_mut().flip_bit(BOARD_SLOT + 7, 0);
    assert_eq!(load(&mut store), Err(StoreError::Corrupt));
    // Saving still works, and what it saved loads.
    save(&mut store, &v1).expect("save over damaged copies");
    assert_eq!(load(&mut store), Ok(Some(v1)));
}

#[test]
fn flipped_bits_in_the_commit_log_never_yield_bad_bytes() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut base = store(SmallFlash::new(), SMALL_RANGE, SMALL_SLOT);
    for k in 0..7 {
        save(&mut base, if k % 2 == 0 { &v1 } else { &v2 }).expect("save");
    }
    let base = base.into_flash();
    let log = 2 * SMALL_SLOT..SMALL_RANGE.end;
    let (mut newest, mut older, mut errors, mut nothing) = (0, 0, 0, 0);
    for offset in log {
        for bit in 0..8 {
            let mut flash = base.clone();
            flash.flip_bit(offset, bit);
            let mut store = common::store(flash, SMALL_RANGE, SMALL_SLOT);
            match load(&mut store) {
                Ok(Some(bytes)) if bytes == v1 => newest += 1,
                Ok(Some(bytes)) if bytes == v2 => older += 1,
                Ok(Some(bytes)) => panic!("offset {offset} bit {bit}: unexpected {bytes:?}"),
                Ok(None) => nothing += 1,
                Err(_) => errors += 1,
            }
        }
    }
    println!(
        "log bit flips: newest {newest}, previous {older}, nothing {nothing}, errors {errors}"
    );
    assert!(newest > 0);
}

#[test]
fn a_flash_full_of_garbage_gives_a_typed_answer_and_can_be_formatted() {
    let v1 = image_v1();
    for seed in 0..50 {
        let mut store = store(BoardFlash::garbage(seed), BOARD_RANGE, BOARD_SLOT);
        match load(&mut store) {
            Ok(None) | Err(_) => {}
            Ok(Some(bytes)) => panic!("seed {seed}: garbage loaded as {} bytes", bytes.len()),
        }
        // A save over garbage either works or reports; after `format` it works.
        if save(&mut store, &v1).is_ok() {
            assert_eq!(load(&mut store), Ok(Some(v1.clone())), "seed {seed}");
        }
        block_on(store.format()).expect("format");
        assert_eq!(load(&mut store), Ok(None));
        save(&mut store, &v1).expect("save after format");
        let mut store = common::store(store.into_flash(), BOARD_RANGE, BOARD_SLOT);
        assert_eq!(load(&mut store), Ok(Some(v1.clone())), "seed {seed}");
    }
    for seed in 0..50 {
        let mut store = store(SmallFlash::garbage(seed), SMALL_RANGE, SMALL_SLOT);
        assert!(!matches!(load(&mut store), Ok(Some(_))), "seed {seed}");
    }
}

#[test]
fn errors_display() {
    let errors = [
        StoreError::Flash(pab_storage::FlashErrorKind::Other),
        StoreError::ImageTooLarge {
            len: 20000,
            slot_size: 16384,
        },
        StoreError::BufferTooSmall {
            needed: 73,
            got: 16,
        },
        StoreError::Corrupt,
        StoreError::Log(LogErrorKind::Corrupted),
        StoreError::VerifyFailed,
    ];
    for error in errors {
        assert!(!error.to_string().is_empty());
    }
    assert_eq!(
        StoreError::ImageTooLarge {
            len: 20000,
            slot_size: 16384
        }
        .to_string(),
        "image of 20000 bytes exceeds the 16384-byte slot"
    );
}

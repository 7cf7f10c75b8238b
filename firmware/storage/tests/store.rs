//! The store's contract outside power loss: round trips, sizes, layouts, a fresh or garbage
//! flash, and flash corrupted behind the store's back.

use crate::common;

use common::*;
use embedded_storage::nor_flash::NorFlash;
use pab_storage::testing::MemFlash;
use pab_storage::{Blocking, FlashStore, LayoutError, StoreError, TableStore};

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
fn small_pages_round_trip_across_ring_wraps() {
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
    let capacity = BOARD_SLOT - BOARD_HEADER;
    assert_eq!(store.capacity(), capacity);
    assert_eq!(store.slot_count(), BOARD_SLOTS);
    assert_eq!(store.slot_size(), BOARD_SLOT);
    save(&mut store, &image_v1()).expect("save v1");
    let operations = store.flash_mut().operations();
    let big = vec![0x11; BOARD_SLOT as usize + 4096];
    assert_eq!(
        save(&mut store, &big),
        Err(StoreError::ImageTooLarge {
            len: big.len(),
            capacity
        })
    );
    // Refused before touching the flash; the old image stays.
    assert_eq!(store.flash_mut().operations(), operations);
    assert_eq!(load(&mut store), Ok(Some(image_v1())));
    // Exactly the capacity fits.
    let exact = vec![0x5A; capacity as usize];
    save(&mut store, &exact).expect("a capacity-sized image");
    let mut buf = vec![0u8; BOARD_SLOT as usize];
    assert_eq!(store.load(&mut buf), Ok(Some(&exact[..])));
    assert!(matches!(
        save(&mut store, &vec![0; capacity as usize + 1]),
        Err(StoreError::ImageTooLarge { .. })
    ));
    // An empty image is an image.
    save(&mut store, &[]).expect("empty image");
    assert_eq!(store.load(&mut buf), Ok(Some(&[][..])));
}

#[test]
fn a_buffer_too_small_is_reported() {
    let v2 = image_v2();
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v2).expect("save");
    let mut buf = [0u8; 16];
    assert_eq!(
        store.load(&mut buf),
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
    assert_eq!(new(0..40960, 8192), Ok(()));
    assert_eq!(new(0..40960, 20480), Ok(()));
    assert_eq!(new(0..40960, 4096), Ok(()));
    assert_eq!(new(8192..40960, 16384), Ok(()));
    assert_eq!(
        new(100..40960, 8192),
        layout(LayoutError::RangeNotPageAligned)
    );
    assert_eq!(
        new(0..40000, 8192),
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
    assert_eq!(
        new(0..40960, 16384),
        layout(LayoutError::RangeNotSlotMultiple)
    );
    // One slot is not a ring.
    assert_eq!(new(0..40960, 40960), layout(LayoutError::RangeTooSmall));
    assert_eq!(new(0..36864, 20480), layout(LayoutError::RangeTooSmall));
    assert_eq!(
        new(0..40960, u32::MAX - 4095),
        layout(LayoutError::RangeTooSmall)
    );
    // 32-byte words in 32-byte pages: the header takes a whole page, images need two-page slots.
    let mut tiny = FlashStore::new(MemFlash::<8, 32, 32>::new(), 0..256, 64).expect("layout");
    assert_eq!(tiny.capacity(), 32);
    tiny.save(&[7; 32]).expect("save");
    let mut buf = [0u8; 32];
    assert_eq!(tiny.load(&mut buf), Ok(Some(&[7u8; 32][..])));
    let message = StoreError::Layout(LayoutError::RangeTooSmall).to_string();
    assert!(message.contains("two slots"), "{message}");
}

#[test]
fn a_flipped_bit_in_the_newest_slot_falls_back_to_the_previous_image() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v1).expect("save v1"); // slot 0
    save(&mut store, &v2).expect("save v2"); // slot 1
    // Every bit of the newest slot's header and image, one at a time.
    let used = (BOARD_HEADER as usize + v2.len()) * 8;
    for bit in 0..used {
        let offset = BOARD_SLOT + (bit / 8) as u32;
        assert!(store.flash_mut().flip_bit(offset, (bit % 8) as u8));
        assert_eq!(load(&mut store), Ok(Some(v1.clone())), "bit {bit}");
        store.flash_mut().flip_bit(offset, (bit % 8) as u8);
    }
    assert_eq!(load(&mut store), Ok(Some(v2.clone())));
    // A flip beyond the image's end changes nothing.
    store
        .flash_mut()
        .flip_bit(BOARD_SLOT + BOARD_HEADER + v2.len() as u32 + 1, 0);
    assert_eq!(load(&mut store), Ok(Some(v2.clone())));
}

#[test]
fn after_a_fallback_a_save_keeps_the_only_good_copy() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v1).expect("save v1"); // slot 0
    save(&mut store, &v2).expect("save v2"); // slot 1
    store
        .flash_mut()
        .flip_bit(BOARD_SLOT + BOARD_HEADER + 30, 3); // v2 damaged: load gives v1
    assert_eq!(load(&mut store), Ok(Some(v1.clone())));
    // The next save goes to the slot after v1's (slot 1, the damaged one), not over v1: cut the
    // power in its first operation (the erase of slot 1's page) and v1 must still be there.
    let mut flash = store.into_flash();
    flash.fail_after(0);
    let mut store = common::store(flash, BOARD_RANGE, BOARD_SLOT);
    assert!(save(&mut store, &v2).is_err());
    let mut flash = store.into_flash();
    flash.reboot();
    let image = BOARD_HEADER as usize;
    assert_eq!(
        flash.pages()[0][image..image + v1.len()],
        v1[..],
        "slot 0 untouched"
    );
    assert!(
        flash.pages()[4].iter().all(|&byte| byte == 0xFF),
        "slot 2 untouched"
    );
    let mut store = common::store(flash, BOARD_RANGE, BOARD_SLOT);
    assert_eq!(load(&mut store), Ok(Some(v1.clone())));
    save(&mut store, &v2).expect("save v2 again");
    assert_eq!(load(&mut store), Ok(Some(v2)));
}

#[test]
fn committed_slots_that_all_fail_are_reported_as_corrupt() {
    let (v1, v2) = (image_v1(), image_v2());
    let image = BOARD_HEADER + 7;
    let mut store = store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v1).expect("save v1");
    store.flash_mut().flip_bit(image, 0);
    assert_eq!(load(&mut store), Err(StoreError::Corrupt));
    store.flash_mut().flip_bit(image, 0);
    save(&mut store, &v2).expect("save v2");
    store.flash_mut().flip_bit(image, 0);
    store.flash_mut().flip_bit(BOARD_SLOT + image, 0);
    assert_eq!(load(&mut store), Err(StoreError::Corrupt));
    // Saving still works, and what it saved loads.
    save(&mut store, &v1).expect("save over damaged copies");
    assert_eq!(load(&mut store), Ok(Some(v1.clone())));
    // A damaged header alone is no commit: with no other slot, nothing is stored.
    let mut store = common::store(BoardFlash::new(), BOARD_RANGE, BOARD_SLOT);
    save(&mut store, &v1).expect("save v1");
    store.flash_mut().flip_bit(9, 0); // the sequence number
    assert_eq!(load(&mut store), Ok(None));
}

#[test]
fn flipped_bits_in_the_headers_never_yield_bad_bytes() {
    let mut base = store(SmallFlash::new(), SMALL_RANGE, SMALL_SLOT);
    let images: Vec<Vec<u8>> = (0..7)
        .map(|k| image_connections(1 + k, 10 + k as u32))
        .collect();
    for image in &images {
        save(&mut base, image).expect("save");
    }
    // The four slots hold saves 4..=7 (the newest, save 7, in slot 2).
    let newest = images.last().expect("images").clone();
    let base = base.into_flash();
    let (mut as_newest, mut older, mut bits) = (0, 0, 0);
    for slot in 0..SMALL_SLOTS {
        for offset in slot * SMALL_SLOT..slot * SMALL_SLOT + 24 {
            for bit in 0..8 {
                bits += 1;
                let mut flash = base.clone();
                flash.flip_bit(offset, bit);
                let mut store = common::store(flash, SMALL_RANGE, SMALL_SLOT);
                match load(&mut store) {
                    Ok(Some(bytes)) if bytes == newest => as_newest += 1,
                    Ok(Some(bytes)) if images.contains(&bytes) => older += 1,
                    other => panic!("offset {offset} bit {bit}: {other:?}"),
                }
            }
        }
    }
    println!("{bits} header bit flips: newest {as_newest}, the previous image {older}");
    // Only the newest slot's header falls back.
    assert_eq!(older, 24 * 8);
}

#[test]
fn a_flash_full_of_garbage_holds_nothing_and_takes_a_save() {
    let v1 = image_v1();
    for seed in 0..50 {
        let mut store = store(BoardFlash::garbage(seed), BOARD_RANGE, BOARD_SLOT);
        assert_eq!(load(&mut store), Ok(None), "seed {seed}");
        save(&mut store, &v1).expect("save over garbage");
        assert_eq!(load(&mut store), Ok(Some(v1.clone())), "seed {seed}");
        store.format().expect("format");
        assert_eq!(load(&mut store), Ok(None));
        save(&mut store, &v1).expect("save after format");
        let mut store = common::store(store.into_flash(), BOARD_RANGE, BOARD_SLOT);
        assert_eq!(load(&mut store), Ok(Some(v1.clone())), "seed {seed}");
    }
    for seed in 0..50 {
        let mut store = store(SmallFlash::garbage(seed), SMALL_RANGE, SMALL_SLOT);
        assert_eq!(load(&mut store), Ok(None), "seed {seed}");
    }
}

/// A slot header as the crate documents it.
fn header(sequence: u32, image: &[u8]) -> [u8; 24] {
    let mut out = [0u8; 24];
    out[..4].copy_from_slice(b"PABS");
    out[4..6].copy_from_slice(&1u16.to_le_bytes());
    out[8..12].copy_from_slice(&sequence.to_le_bytes());
    out[12..16].copy_from_slice(&(image.len() as u32).to_le_bytes());
    out[16..20].copy_from_slice(&pab_core::crc32::crc32(image).to_le_bytes());
    let crc = pab_core::crc32::crc32(&out[..20]);
    out[20..].copy_from_slice(&crc.to_le_bytes());
    out
}

/// Writes a committed slot by hand, as the documented format says.
fn plant(flash: &mut BoardFlash, slot: u32, sequence: u32, image: &[u8]) {
    let start = slot * BOARD_SLOT;
    flash.erase(start, start + BOARD_SLOT).expect("erase");
    let mut padded = image.to_vec();
    padded.resize(image.len().next_multiple_of(8), 0xFF);
    flash.write(start + BOARD_HEADER, &padded).expect("image");
    flash
        .write(start, &header(sequence, image))
        .expect("header");
}

#[test]
fn the_documented_header_format_loads_and_orders_by_sequence() {
    let (v1, v2) = (image_v1(), image_v2());
    let mut flash = BoardFlash::new();
    // The newest is the highest sequence number, wherever it sits in the ring.
    plant(&mut flash, 3, 7, &v1);
    plant(&mut flash, 1, 9, &v2);
    plant(&mut flash, 4, 8, &v1);
    let mut store = common::store(flash, BOARD_RANGE, BOARD_SLOT);
    assert_eq!(load(&mut store), Ok(Some(v2.clone())));
    // The next save goes after it (slot 2), with sequence 10.
    save(&mut store, &v1).expect("save");
    assert_eq!(load(&mut store), Ok(Some(v1.clone())));
    let page = &store.flash_mut().pages()[4];
    assert_eq!(page[..24], header(10, &v1));
}

#[test]
fn exhausted_sequence_numbers_are_reported() {
    let v1 = image_v1();
    let mut flash = BoardFlash::new();
    plant(&mut flash, 0, u32::MAX, &v1);
    let mut store = common::store(flash, BOARD_RANGE, BOARD_SLOT);
    assert_eq!(load(&mut store), Ok(Some(v1.clone())));
    let operations = store.flash_mut().operations();
    assert_eq!(save(&mut store, &v1), Err(StoreError::SequenceExhausted));
    assert_eq!(
        store.flash_mut().operations(),
        operations,
        "nothing written"
    );
    store.format().expect("format");
    save(&mut store, &v1).expect("save after format");
    assert_eq!(load(&mut store), Ok(Some(v1)));
}

#[test]
fn errors_display() {
    let errors = [
        StoreError::Flash(pab_storage::FlashErrorKind::Other),
        StoreError::ImageTooLarge {
            len: 20000,
            capacity: 8168,
        },
        StoreError::BufferTooSmall {
            needed: 73,
            got: 16,
        },
        StoreError::Corrupt,
        StoreError::SequenceExhausted,
        StoreError::VerifyFailed,
    ];
    for error in errors {
        assert!(!error.to_string().is_empty());
    }
    assert_eq!(
        StoreError::ImageTooLarge {
            len: 20000,
            capacity: 8168
        }
        .to_string(),
        "image of 20000 bytes exceeds the 8168 bytes a slot holds"
    );
}

/// A flash that reads whole 4-byte words only (`READ_SIZE` 4), over a board's memory: every read
/// the store makes must start and end on a word.
struct WordReads(BoardFlash);

impl embedded_storage::nor_flash::ErrorType for WordReads {
    type Error = pab_storage::testing::MemFlashError;
}

impl embedded_storage::nor_flash::ReadNorFlash for WordReads {
    const READ_SIZE: usize = 4;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        assert!(
            offset.is_multiple_of(4) && bytes.len().is_multiple_of(4),
            "read of {} bytes at {offset}",
            bytes.len()
        );
        self.0.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl NorFlash for WordReads {
    const WRITE_SIZE: usize = BoardFlash::WRITE_SIZE;
    const ERASE_SIZE: usize = BoardFlash::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.erase(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.write(offset, bytes)
    }
}

#[test]
fn images_of_any_length_round_trip_through_word_reads() {
    let mut store = FlashStore::new(
        Blocking(WordReads(BoardFlash::new())),
        BOARD_RANGE,
        BOARD_SLOT,
    )
    .expect("layout");
    let images = [
        image_v1(),
        image_v2(),
        image_ports(3, 3),
        image_connections(5, 4),
    ];
    assert!(images.iter().any(|image| image.len() % 4 != 0));
    for image in &images {
        save(&mut store, image).expect("save");
        assert_eq!(load(&mut store), Ok(Some(image.clone())));
    }
    let mut store = FlashStore::new(store.into_flash(), BOARD_RANGE, BOARD_SLOT).expect("layout");
    assert_eq!(load(&mut store), Ok(Some(images[3].clone())));
}

//! The boot counter: counts from fresh, garbage and zeroed flash, across many page fills; the
//! power cut at every program and erase of an increment (and again during the retry), and long
//! random histories of cuts: no value is ever returned twice and the count never goes backwards.

use embedded_storage::nor_flash::NorFlash;
use pab_storage::testing::MemFlash;
use pab_storage::{BootCounter, CounterError, LayoutError};

/// The STM32G474's geometry (4 KiB pages, 8-byte words), two pages as on the board: 256 records
/// of 16 bytes a page, so 512 boots between two erases of a page.
type BoardFlash = MemFlash<2, 4096, 8>;
const BOARD_RANGE: core::ops::Range<u32> = 0..2 * 4096;

/// Small pages and 4-byte words, three pages: 16 records a page, so histories fill pages often.
type SmallFlash = MemFlash<3, 256, 4>;
const SMALL_RANGE: core::ops::Range<u32> = 0..3 * 256;
const SMALL_RECORDS: u32 = 16;

fn new_counter<const P: usize, const E: usize, const W: usize>(
    flash: MemFlash<P, E, W>,
    range: core::ops::Range<u32>,
) -> BootCounter<MemFlash<P, E, W>> {
    BootCounter::new(flash, range).expect("valid layout")
}

/// A record as the counter writes it (magic, count, complement, CRC-32), for planting.
fn record(count: u32) -> [u8; 16] {
    let mut out = [0u8; 16];
    out[..4].copy_from_slice(b"PABB");
    out[4..8].copy_from_slice(&count.to_le_bytes());
    out[8..12].copy_from_slice(&(!count).to_le_bytes());
    let crc = pab_core::crc32::crc32(&out[..12]);
    out[12..].copy_from_slice(&crc.to_le_bytes());
    out
}

#[test]
fn fresh_flash_counts_from_one_across_many_page_fills() {
    let mut flash = BoardFlash::new();
    for boot in 1..=2000u32 {
        let mut counter = new_counter(flash, BOARD_RANGE);
        assert_eq!(counter.increment(), Ok(boot));
        assert_eq!(counter.current(), Ok(boot));
        flash = counter.into_flash();
    }
    // Erases at boots 1, 257, 513, ...: one per 256 boots, the pages taking turns.
    let erases = *flash.erase_counts();
    println!("erase counts of the two 4 KiB pages after 2000 boots: {erases:?}");
    assert_eq!(erases, [4, 4]);
    let operations = flash.operations();
    assert_eq!(
        operations,
        2000 + 8,
        "one program per boot, plus the erases"
    );
}

#[test]
fn small_pages_wrap_the_ring_many_times() {
    let mut counter = new_counter(SmallFlash::new(), SMALL_RANGE);
    for boot in 1..=(SMALL_RECORDS * 3 * 20) {
        assert_eq!(counter.increment(), Ok(boot));
    }
    // 960 boots, 16 records a page: 60 page fills, 20 per page.
    assert_eq!(*counter.flash_mut().erase_counts(), [20, 20, 20]);
}

#[test]
fn garbage_and_zeroed_flash_count_from_one() {
    for seed in 1..=20u64 {
        let mut counter = new_counter(SmallFlash::garbage(seed), SMALL_RANGE);
        assert_eq!(counter.current(), Ok(0), "seed {seed}");
        for boot in 1..=100 {
            assert_eq!(counter.increment(), Ok(boot), "seed {seed}");
        }
    }
    let mut counter = new_counter(BoardFlash::garbage(7), BOARD_RANGE);
    for boot in 1..=600 {
        assert_eq!(counter.increment(), Ok(boot));
    }
    // The emulated board's RAM-backed flash starts zeroed (QEMU's fresh RAM).
    let mut zeroed = BoardFlash::new();
    zeroed.write(0, &[0; 2 * 4096]).expect("zeros");
    let mut counter = new_counter(zeroed, BOARD_RANGE);
    assert_eq!(counter.current(), Ok(0));
    assert_eq!(counter.increment(), Ok(1));
    assert_eq!(counter.increment(), Ok(2));
}

#[test]
fn a_planted_count_goes_on_and_the_last_value_is_exhausted_until_formatted() {
    let mut flash = SmallFlash::new();
    flash.write(256 + 32, &record(u32::MAX - 1)).expect("plant");
    let mut counter = new_counter(flash, SMALL_RANGE);
    assert_eq!(counter.current(), Ok(u32::MAX - 1));
    assert_eq!(counter.increment(), Ok(u32::MAX));
    assert_eq!(counter.increment(), Err(CounterError::Exhausted));
    assert_eq!(counter.current(), Ok(u32::MAX));
    counter.format().expect("format");
    assert_eq!(counter.increment(), Ok(1));
}

#[test]
fn records_after_the_newest_that_do_not_verify_are_skipped_not_overwritten() {
    let mut flash = SmallFlash::new();
    flash.write(0, &record(5)).expect("plant");
    // A cut record after it (its magic only), then erased space.
    flash.write(16, b"PABB").expect("plant");
    let mut counter = new_counter(flash, SMALL_RANGE);
    assert_eq!(counter.increment(), Ok(6));
    let page = counter.flash_mut().pages()[0];
    assert_eq!(&page[32..48], &record(6));
    // A garbage word in a page's last record: the page counts as full.
    let mut flash = SmallFlash::new();
    flash.write(0, &record(9)).expect("plant");
    flash
        .write(256 - 4, &[0x12, 0x34, 0x56, 0x78])
        .expect("plant");
    let mut counter = new_counter(flash, SMALL_RANGE);
    assert_eq!(counter.increment(), Ok(10));
    assert_eq!(&counter.flash_mut().pages()[1][..16], &record(10));
    assert_eq!(counter.flash_mut().pages()[0][..16], record(9), "page kept");
}

#[test]
fn layouts_that_cannot_hold_a_counter_are_refused() {
    let layout = |range| BootCounter::new(SmallFlash::new(), range).err();
    assert_eq!(
        layout(0..256),
        Some(CounterError::Layout(LayoutError::RangeTooSmall))
    );
    assert_eq!(
        layout(0..3 * 256 + 256),
        Some(CounterError::Layout(LayoutError::RangeOutOfBounds))
    );
    assert_eq!(
        layout(16..3 * 256),
        Some(CounterError::Layout(LayoutError::RangeNotPageAligned))
    );
    assert_eq!(
        layout(256..256),
        Some(CounterError::Layout(LayoutError::RangeOutOfBounds))
    );
    assert!(layout(256..3 * 256).is_none());
}

#[derive(Default, Debug)]
struct Figures {
    /// Power cuts during an increment, each followed by a reboot.
    cuts: u32,
    /// Of those, the cut increments whose value counted anyway (its record verifies).
    counted: u32,
    /// Second cuts, during the increment retried after the first.
    second_cuts: u32,
    /// Cuts during a page erase.
    erase_cuts: u32,
}

/// From every state of a history of `boots` clean boots, cuts the power at every program and
/// erase of the next increment (with `seeds` different cut patterns each), reboots, checks the
/// count, cuts the retried increment again, and checks that the boot after that returns a new
/// value, larger than all returned before.
fn sweep<const P: usize, const E: usize, const W: usize>(
    range: core::ops::Range<u32>,
    boots: u32,
    seeds: u64,
) -> Figures {
    let mut figures = Figures::default();
    let mut base = new_counter(MemFlash::<P, E, W>::new(), range.clone());
    for returned in 0..boots {
        // `returned`: the largest value returned so far (the history returned 1..=returned).
        for n in 0u32.. {
            let mut completed = false;
            for seed in 0..seeds {
                let what = format!("after {returned} boots, cut at {n}, seed {seed}");
                let mut flash = base.flash_mut().clone();
                let erases = flash.erase_counts().iter().sum::<u32>();
                flash.set_seed(u64::from(returned) * 1_000_003 + u64::from(n) * 31 + seed);
                flash.fail_after(n);
                let mut cut = new_counter(flash, range.clone());
                let result = cut.increment();
                let mut flash = cut.into_flash();
                if !flash.power_lost() {
                    assert_eq!(result, Ok(returned + 1), "{what}: a clean boot");
                    completed = true;
                    break;
                }
                figures.cuts += 1;
                if flash.erase_counts().iter().sum::<u32>() > erases && n == 0 {
                    figures.erase_cuts += 1;
                }
                assert!(result.is_err(), "{what}: Ok although the power went");
                flash.reboot();
                let mut rebooted = new_counter(flash, range.clone());
                let now = rebooted.current().expect("current");
                assert!(
                    now == returned || now == returned + 1,
                    "{what}: count {now}, {returned} returned before"
                );
                if now == returned + 1 {
                    figures.counted += 1;
                }
                // The retry is cut too, at one of its first operations.
                let mut flash = rebooted.into_flash();
                flash.fail_after(n % 2);
                let mut retried = new_counter(flash, range.clone());
                let second = retried.increment();
                let mut flash = retried.into_flash();
                if flash.power_lost() {
                    figures.second_cuts += 1;
                    assert!(second.is_err(), "{what}: second cut returned Ok");
                    flash.reboot();
                } else {
                    assert_eq!(second, Ok(now + 1), "{what}: the retry");
                    // The cut was armed past the retry's operations: disarm it.
                    flash.reboot();
                }
                let mut last = new_counter(flash, range.clone());
                let before = last.current().expect("current");
                assert!(before >= now, "{what}: went back from {now} to {before}");
                let value = last.increment().expect("the boot after the cuts");
                assert!(
                    value > returned && value > before,
                    "{what}: returned {value}"
                );
                assert_eq!(last.current(), Ok(value));
            }
            if completed {
                break;
            }
        }
        assert_eq!(base.increment(), Ok(returned + 1), "the history");
    }
    figures
}

#[test]
fn power_cut_at_every_operation_board_geometry() {
    // 600 boots: the two 256-record pages fill 2.3 times.
    let figures = sweep::<2, 4096, 8>(BOARD_RANGE, 600, 3);
    println!("board geometry (4 KiB pages, 8-byte words, 2 pages): {figures:?}");
    assert!(figures.cuts >= 600 * 3, "{figures:?}");
    assert!(figures.counted > 0 && figures.second_cuts > 0 && figures.erase_cuts > 0);
}

#[test]
fn power_cut_at_every_operation_small_pages() {
    // 200 boots over three 16-record pages: the ring wraps four times.
    let figures = sweep::<3, 256, 4>(SMALL_RANGE, 200, 8);
    println!("small pages (256 B pages, 4-byte words, 3 pages): {figures:?}");
    assert!(figures.cuts >= 200 * 8, "{figures:?}");
    assert!(figures.counted > 0 && figures.second_cuts > 0 && figures.erase_cuts > 0);
}

/// A long history in which the damage stays: a seeded walk cuts the power during about one
/// increment in three (at a random operation), and never reboots into a clean flash. Every
/// value returned must be larger than all returned before.
#[test]
fn random_histories_of_cuts_never_repeat_a_value() {
    for walk in 1..=8u64 {
        let mut flash = SmallFlash::new();
        let mut rng = walk.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let mut returned = 0u32;
        let mut values = 0u32;
        let mut cuts = 0u32;
        for boot in 0..3000u32 {
            flash.set_seed(next());
            if next() % 3 == 0 {
                flash.fail_after((next() % 2) as u32);
            }
            let mut counter = new_counter(flash, SMALL_RANGE);
            let result = counter.increment();
            flash = counter.into_flash();
            if flash.power_lost() {
                cuts += 1;
                assert!(result.is_err(), "walk {walk}, boot {boot}");
                flash.reboot();
                continue;
            }
            // Armed but not reached (the increment needed one operation): disarm.
            flash.reboot();
            let value = result.unwrap_or_else(|e| panic!("walk {walk}, boot {boot}: {e}"));
            assert!(
                value > returned,
                "walk {walk}, boot {boot}: {value} after {returned}"
            );
            returned = value;
            values += 1;
        }
        println!("walk {walk}: {values} values returned, {cuts} cuts, count {returned}");
        assert!(cuts > 500 && values > 2000);
    }
}

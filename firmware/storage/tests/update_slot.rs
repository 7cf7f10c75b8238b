//! The update slot (`pab_storage::UpdateSlot`): an image written chunk by chunk over another
//! firmware, its manifest and request after it; and the power cut at every erase and program of
//! a whole update: after any cut, the request page holds no request, or the slot holds exactly
//! the image and its manifest.

use pab_core::identity::Firmware;
use pab_core::update::stored::{self, Request, Verdict};
use pab_core::update::{MANIFEST_LEN, Trailer};
use pab_storage::testing::MemFlash;
use pab_storage::{StoreError, UpdateSlot};

/// The G474's geometry: 2 KiB pages, double words. A slot of four pages, the DFU partition one
/// page more (embassy-boot's swap page).
type Dfu = MemFlash<5, 2048, 8>;
type Page = MemFlash<1, 2048, 8>;
const SLOT: u32 = 4 * 2048;

fn image(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 7 + 3) as u8).collect()
}

fn trailer() -> Trailer {
    Trailer {
        firmware: Firmware::new("fw-g474", "2.1.0", "0123456789abcdef"),
        downgrade: false,
        image_len: 5000,
    }
}

fn manifest() -> [u8; MANIFEST_LEN] {
    stored::Manifest {
        trailer: trailer(),
        signature: core::array::from_fn(|i| (i as u8) ^ 0xA7),
    }
    .encode()
}

/// Writes `image` in 1 KiB chunks and asks for it.
fn update(slot: &mut UpdateSlot<&mut Dfu, &mut Page>, image: &[u8]) -> Result<(), StoreError> {
    for (n, chunk) in image.chunks(1024).enumerate() {
        slot.write((n * 1024) as u32, chunk)?;
    }
    slot.request(&manifest())
}

fn slot_bytes(dfu: &Dfu) -> Vec<u8> {
    dfu.pages()
        .iter()
        .flatten()
        .copied()
        .take(SLOT as usize)
        .collect()
}

fn request_head(page: &Page) -> [u8; 16] {
    page.pages()[0][..16].try_into().unwrap()
}

#[test]
fn an_image_over_another_firmware_lands_whole_with_its_manifest_and_request() {
    for len in [8, 1000, 2048, 5000, SLOT as usize - MANIFEST_LEN] {
        // The partition holds another firmware (garbage), the request page an old verdict.
        let mut dfu = Dfu::garbage(len as u64);
        let mut page = Page::garbage(1);
        let image = image(len);
        let mut slot = UpdateSlot::new(&mut dfu, &mut page, SLOT).unwrap();
        update(&mut slot, &image).unwrap();
        let bytes = slot_bytes(&dfu);
        assert_eq!(&bytes[..len], &image[..], "{len}");
        assert_eq!(
            &bytes[SLOT as usize - MANIFEST_LEN..],
            &manifest()[..],
            "{len}"
        );
        assert_eq!(Request::read(&request_head(&page)), Request::Pending);
        // Every page the image reaches was erased once, and the manifest's once more only if
        // the image did not reach it.
        let reaches_last = len > 3 * 2048;
        let erases = dfu.erase_counts();
        assert_eq!(
            erases[..len.div_ceil(2048)],
            vec![1; len.div_ceil(2048)][..],
            "{len}"
        );
        assert_eq!(
            erases[3], 1,
            "{len}: the manifest's page erased once (reaches: {reaches_last})"
        );
        assert_eq!(erases[4], 0, "the swap page is the bootloader's");
    }
}

#[test]
fn a_last_chunk_of_odd_length_is_padded_with_erased_bytes_and_nothing_goes_past_the_capacity() {
    let mut dfu = Dfu::garbage(3);
    let mut page = Page::new();
    let mut slot = UpdateSlot::new(&mut dfu, &mut page, SLOT).unwrap();
    slot.write(0, &[1, 2, 3]).unwrap();
    let capacity = stored::capacity(SLOT);
    assert!(
        slot.write(capacity - 8, &[0; 9]).is_err(),
        "into the manifest"
    );
    assert!(slot.write(u32::MAX - 2, &[0; 8]).is_err());
    assert_eq!(
        &slot_bytes(&dfu)[..8],
        &[1, 2, 3, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]
    );
}

#[test]
fn the_verdict_is_taken_once_and_a_slot_that_is_not_whole_pages_is_refused() {
    let mut dfu = Dfu::new();
    let mut page = Page::new();
    let mut slot = UpdateSlot::new(&mut dfu, &mut page, SLOT).unwrap();
    assert_eq!(slot.take_verdict(), Ok(None));
    update(&mut slot, &image(100)).unwrap();
    assert_eq!(
        slot.take_verdict(),
        Ok(None),
        "pending: the bootloader has not decided"
    );
    let _ = slot;
    use embedded_storage::nor_flash::NorFlash;
    page.write(stored::VERDICT_OFFSET, &stored::verdict(Ok(())))
        .unwrap();
    let mut slot = UpdateSlot::new(&mut dfu, &mut page, SLOT).unwrap();
    assert_eq!(
        slot.take_verdict(),
        Ok(Some(Verdict {
            outcome: Ok(()),
            requested: Some(trailer()),
        }))
    );
    assert_eq!(slot.take_verdict(), Ok(None), "taken once");

    let mut dfu = Dfu::new();
    let mut page = Page::new();
    assert!(UpdateSlot::new(&mut dfu, &mut page, SLOT + 8).is_err());
    assert!(
        UpdateSlot::new(&mut dfu, &mut page, 6 * 2048).is_err(),
        "larger than the partition"
    );
    assert!(UpdateSlot::new(&mut dfu, &mut page, 0).is_err());
}

#[test]
fn a_power_cut_at_any_flash_operation_leaves_no_request_or_the_whole_update() {
    let image = image(5000);
    let mut points = 0;
    let mut requests = 0;
    for cut in 0.. {
        let mut dfu = Dfu::garbage(cut as u64);
        let mut page = Page::garbage(cut as u64 + 1);
        // Both flashes fail at the same count of operations: the cut is one instant.
        dfu.fail_after(cut);
        page.fail_after(u32::MAX);
        let outcome = {
            let mut slot = UpdateSlot::new(&mut dfu, &mut page, SLOT).unwrap();
            update(&mut slot, &image)
        };
        // The request page's own operations come last: cut them too, from the first.
        let done = outcome.is_ok();
        dfu.reboot();
        page.reboot();
        let head = request_head(&page);
        match Request::read(&head) {
            Request::None => {}
            Request::Pending => {
                requests += 1;
                let bytes = slot_bytes(&dfu);
                assert_eq!(
                    &bytes[..5000],
                    &image[..],
                    "cut {cut}: a request for another image"
                );
                assert_eq!(
                    &bytes[SLOT as usize - MANIFEST_LEN..],
                    &manifest()[..],
                    "cut {cut}"
                );
            }
            Request::Decided(_) => panic!("cut {cut}: a verdict nobody wrote"),
        }
        points += 1;
        if done {
            break;
        }
    }
    // The request page's erase and write, cut in turn after a whole slot.
    for cut in 0..2 {
        let mut dfu = Dfu::new();
        let mut page = Page::garbage(9);
        page.fail_after(cut);
        let outcome = {
            let mut slot = UpdateSlot::new(&mut dfu, &mut page, SLOT).unwrap();
            update(&mut slot, &image)
        };
        assert!(outcome.is_err());
        page.reboot();
        // Cut in its erase: no request. Cut in its program: none, or the record whole (the
        // cut came after its bits), which asks for the whole update written before it.
        let request = Request::read(&request_head(&page));
        assert!(
            request == Request::None || (cut == 1 && request == Request::Pending),
            "request cut {cut}: {request:?}"
        );
        points += 1;
    }
    assert!(
        points > 10 && requests >= 1,
        "{points} cuts, {requests} requests"
    );
}

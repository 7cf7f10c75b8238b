//! The signed image as a node leaves it for its bootloader, and the bootloader's check of it.
//!
//! **Where the check runs.** A signed image's signature is checked by the bootloader, before it
//! swaps, not by the application before it asks for the swap: SHA-512 and Ed25519 verification
//! take 17 KB of flash on a Cortex-M4, more than the full application has left under its 64 KiB
//! goal, while the bootloader is its own image. The application checks what is cheap before it
//! takes a byte (the trailer: board kind, version, length: [`super::Trailer::admits`]), stores
//! the image and asks; the bootloader checks the signature and the board kind, swaps only an
//! image that passes, and leaves its verdict where the application finds it after the reset.
//!
//! **In the update (DFU) partition's slot** (the first `slot_len` bytes, the active partition's
//! length): the image at offset 0, as the swap copies it page by page to the same offsets of the
//! active partition; the manifest, the trailer and the signature ([`MANIFEST_LEN`] bytes), in the
//! slot's last bytes ([`manifest_offset`]). The signature covers the image and the trailer (the
//! digest of `image ‖ trailer`, as in the signed file), so they need not lie together. The swap
//! carries the manifest to the active partition's end too, where the running firmware's own
//! trailer can be read.
//!
//! **The request page**: two 8-byte records, each written once on erased flash (the G474
//! programs double words, and a word is written once between erases), so that every step
//! survives a reset:
//!
//! ```text
//! offset 0:  REQUEST       the application: the slot holds an image and its manifest; swap it
//! offset 8:  the verdict   the bootloader: "PABUOUT" and 0 (swapped) or a refusal's code
//! offset 16: the trailer   the application, before the request: what it asked for (32 bytes)
//! ```
//!
//! The bootloader acts on a request without a verdict: it checks, writes the verdict, and only
//! then marks the swap (a reset between the two loses the update, and the old firmware runs);
//! the application reads the verdict at start, reports it and erases the page. The trailer tells
//! the application whether what it runs is what was asked for: an accepted image that did not
//! confirm itself is reverted before anyone reads the verdict.

use super::{MANIFEST_LEN, PUBLIC_KEY_LEN, SIGNATURE_LEN, TRAILER_LEN, Trailer, UpdateRefusal};
use crate::crc32::crc32;

/// The request record: the slot holds an image to check and swap in.
pub const REQUEST: [u8; 8] = *b"PABUREQ1";
/// The verdict record's first seven bytes; the eighth is 0 (accepted) or a refusal's code.
pub const VERDICT: [u8; 7] = *b"PABUOUT";
/// Where the verdict record lies in the request page.
pub const VERDICT_OFFSET: u32 = 8;
/// Where the requested image's trailer lies in the request page.
pub const TRAILER_OFFSET: u32 = 16;

/// The bootloader's verdict on the last request, as the application finds it at start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Verdict {
    /// `Ok`: the bootloader accepted the image and marked the swap; `Err`: the refusal's code.
    pub outcome: Result<(), u8>,
    /// What was asked for: the trailer the application stored with the request, if it reads as
    /// one.
    pub requested: Option<Trailer>,
}

/// Where the manifest lies in a slot of `slot_len` bytes (`None` if the slot cannot hold one).
pub const fn manifest_offset(slot_len: u32) -> Option<u32> {
    slot_len.checked_sub(MANIFEST_LEN as u32)
}

/// The largest image a slot of `slot_len` bytes takes: what lies before its manifest.
pub const fn capacity(slot_len: u32) -> u32 {
    slot_len.saturating_sub(MANIFEST_LEN as u32)
}

/// The verdict record for `outcome`.
pub const fn verdict(outcome: Result<(), UpdateRefusal>) -> [u8; 8] {
    let [a, b, c, d, e, f, g] = VERDICT;
    let code = match outcome {
        Ok(()) => 0,
        Err(refusal) => refusal.code(),
    };
    [a, b, c, d, e, f, g, code]
}

/// What a request page's first 16 bytes say.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Request {
    /// No request (erased, or anything that is not one: a page never written reads so).
    None,
    /// A request the bootloader has not decided on.
    Pending,
    /// The bootloader's verdict: `Ok` swapped, `Err` the refusal's code (1 to 7).
    Decided(Result<(), u8>),
}

impl Request {
    /// Reads a request page's first 16 bytes. A verdict that is not one (a reset while it was
    /// written: the G474 writes a double word at once, but other flashes need not) reads as
    /// pending, so that the bootloader decides again; the slot has not changed.
    pub fn read(head: &[u8; 16]) -> Request {
        let (request, verdict) = head.split_at(8);
        if request != REQUEST {
            return Request::None;
        }
        match verdict.split_last() {
            Some((&0, prefix)) if prefix == VERDICT => Request::Decided(Ok(())),
            Some((&code, prefix)) if prefix == VERDICT && (1..=7).contains(&code) => {
                Request::Decided(Err(code))
            }
            _ => Request::Pending,
        }
    }
}

/// Where the update key's record lies in the key page: after the node key's record
/// (`auth::page`, 32 bytes), at a double word's boundary.
pub const KEY_RECORD_OFFSET: usize = 64;
/// The update key record's length: magic "PABS", format 1, three zeros, the Ed25519 public key
/// (32 bytes), the CRC-32 of the 40 bytes before it (little endian), four zeros.
pub const KEY_RECORD_LEN: usize = 48;
const KEY_MAGIC: [u8; 4] = *b"PABS";

/// The update key's record in the key page, for `public_key` (`pabctl keypage --update-key`
/// writes it). The bootloader reads it; it cannot be changed over the bus.
pub fn encode_key(public_key: &[u8; PUBLIC_KEY_LEN]) -> [u8; KEY_RECORD_LEN] {
    let mut out = [0u8; KEY_RECORD_LEN];
    let (head, tail) = out.split_at_mut(40);
    let (magic, rest) = head.split_at_mut(4);
    magic.copy_from_slice(&KEY_MAGIC);
    let (format, key) = rest.split_at_mut(4);
    format.copy_from_slice(&[1, 0, 0, 0]);
    key.copy_from_slice(public_key);
    let crc = crc32(head).to_le_bytes();
    let (crc_field, _) = tail.split_at_mut(4);
    crc_field.copy_from_slice(&crc);
    out
}

/// Reads the update key's record from the key page's bytes at [`KEY_RECORD_OFFSET`]: `None`
/// when there is none or it does not verify (erased, another magic or format, a reserved byte
/// set, a CRC that does not match). A board without an update key takes no update.
pub fn decode_key(record: &[u8]) -> Option<[u8; PUBLIC_KEY_LEN]> {
    let record = <&[u8; KEY_RECORD_LEN]>::try_from(record.get(..KEY_RECORD_LEN)?).ok()?;
    let (head, tail) = record.split_at(40);
    let (prefix, key) = head.split_at(8);
    let (crc_field, reserved) = tail.split_at(4);
    let valid = prefix == [b'P', b'A', b'B', b'S', 1, 0, 0, 0]
        && crc32(head).to_le_bytes() == crc_field
        && reserved == [0; 4];
    if valid {
        <[u8; PUBLIC_KEY_LEN]>::try_from(key).ok()
    } else {
        None
    }
}

/// The trailer and signature in a slot's last [`MANIFEST_LEN`] bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Manifest {
    /// The trailer, read.
    pub trailer: Trailer,
    /// The signature over `image ‖ trailer`.
    pub signature: [u8; SIGNATURE_LEN],
}

impl Manifest {
    /// The manifest's bytes: the trailer, then the signature.
    pub fn encode(&self) -> [u8; MANIFEST_LEN] {
        let mut out = [0u8; MANIFEST_LEN];
        let (trailer, signature) = out.split_at_mut(TRAILER_LEN);
        trailer.copy_from_slice(&self.trailer.encode());
        signature.copy_from_slice(&self.signature);
        out
    }

    /// Reads a manifest; the trailer must be well formed ([`Trailer::decode`]).
    pub fn decode(bytes: &[u8; MANIFEST_LEN]) -> Result<Manifest, UpdateRefusal> {
        let (trailer, signature) = bytes.split_at(TRAILER_LEN);
        let trailer =
            <&[u8; TRAILER_LEN]>::try_from(trailer).map_err(|_| UpdateRefusal::Truncated)?;
        let signature =
            <[u8; SIGNATURE_LEN]>::try_from(signature).map_err(|_| UpdateRefusal::Truncated)?;
        Ok(Manifest {
            trailer: Trailer::decode(trailer)?,
            signature,
        })
    }
}

/// The bootloader's check of the image in a slot of `slot_len` bytes, read through `read`
/// (offset in the slot, buffer to fill): the manifest well formed, the image within the slot's
/// capacity and built for `board` (the firmware's name), and the signature verified under
/// `public_key` over the image's digest, hashed 256 bytes at a time (the stack holds no more).
/// A read that fails is [`UpdateRefusal::Unreadable`]. Costs, on the emulated Cortex-M4: about
/// 115 000 instructions per KiB of image and 1.85 million for the signature
/// (`scripts/cortex-m4-cost.sh`, case `update`).
#[cfg(feature = "signature")]
pub fn check<E>(
    slot_len: u32,
    board: &[u8; 8],
    public_key: &[u8; super::PUBLIC_KEY_LEN],
    mut read: impl FnMut(u32, &mut [u8]) -> Result<(), E>,
) -> Result<Trailer, UpdateRefusal> {
    use sha2::Digest as _;
    let at = manifest_offset(slot_len).ok_or(UpdateRefusal::Truncated)?;
    let mut bytes = [0u8; MANIFEST_LEN];
    read(at, &mut bytes).map_err(|_| UpdateRefusal::Unreadable)?;
    let manifest = Manifest::decode(&bytes)?;
    let len = manifest.trailer.image_len;
    if len > capacity(slot_len) {
        return Err(UpdateRefusal::TooLarge {
            len,
            capacity: capacity(slot_len),
        });
    }
    if len < super::MIN_IMAGE_LEN {
        return Err(UpdateRefusal::Truncated);
    }
    if manifest.trailer.firmware.name != *board {
        return Err(UpdateRefusal::OtherBoard);
    }
    let mut hash = sha2::Sha512::new();
    let mut chunk = [0u8; 256];
    let mut offset = 0u32;
    while offset < len {
        let n = (len - offset).min(chunk.len() as u32);
        let part = chunk
            .get_mut(..n as usize)
            .ok_or(UpdateRefusal::Unreadable)?;
        read(offset, part).map_err(|_| UpdateRefusal::Unreadable)?;
        hash.update(&*part);
        offset += n;
    }
    hash.update(manifest.trailer.encode());
    super::verify(&hash.finalize().into(), &manifest.signature, public_key)?;
    Ok(manifest.trailer)
}

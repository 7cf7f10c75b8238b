//! Authenticated configuration: AES-128-CMAC tags over what the tool sends and what the node
//! answers, in the manner of AUTOSAR SecOC (payload + freshness + truncated MAC).
//!
//! Freshness comes from both ends of an exchange: the tool asks with a random 64-bit nonce of its
//! own, the node answers with a 48-bit nonce nobody can predict (a CMAC under its key of a boot
//! salt that never repeats for one key and a counter, [`Authenticator::node_nonce`]), and every
//! tag of the exchange is over the **exchange nonce**, a CMAC of the two
//! ([`Authenticator::exchange`]), whose other bytes bind the node's Challenge to the request it
//! answers. A tag computed over a challenge a rogue made up is worthless (the node never issues
//! that nonce), and a recorded exchange cannot be replayed (the tool's next nonce differs). Every
//! MAC input starts with a [domain](Domain) byte and the node id, so that no tag can be moved
//! from one use to another, nor from one node to another (even if two nodes share a key).
//!
//! Cost: a tag is one CMAC over at most 24 bytes (two AES blocks and the subkey step; the key
//! schedule is computed once, in [`Authenticator::new`]); an image MAC is one AES block per 16
//! bytes of the image. `docs/can-protocol.md` ("Threat model") says what this protects against.

#[cfg(not(target_os = "none"))]
use cmac::{Mac, digest::KeyInit};

use crate::crc32::crc32;

// The boards' AES-128-CMAC (2 KB less flash than RustCrypto's); hosts keep RustCrypto's, which
// is constant-time on cached memory (the module says why). Compiled for the host's tests too,
// and for the fuzz target that holds it to RustCrypto's (feature `board-cmac`).
#[cfg(any(target_os = "none", test, feature = "board-cmac"))]
mod aes_cmac;

/// The boards' AES-128-CMAC (not the one [`Authenticator`] uses on hosts) of the concatenation of
/// `parts` under `key`: for the differential fuzz target `aes_cmac` (fuzz/checks), which holds it
/// to RustCrypto's. Not an API: only with the feature `board-cmac`.
#[cfg(feature = "board-cmac")]
#[doc(hidden)]
pub fn board_cmac(key: &[u8; KEY_LEN], parts: &[&[u8]]) -> [u8; 16] {
    aes_cmac::Cmac::new(key).mac(parts)
}

/// Length of a key in bytes (AES-128).
pub const KEY_LEN: usize = 16;
/// Length of a command tag (appended to a command's plain payload).
pub const COMMAND_TAG_LEN: usize = 4;
/// Length of a TransferOpen tag.
pub const OPEN_TAG_LEN: usize = 5;
/// Length of the MAC that follows an image in an authenticated transfer.
pub const IMAGE_MAC_LEN: usize = 16;
/// Length of a Receipt tag.
pub const RECEIPT_TAG_LEN: usize = 8;
/// Length of a node's nonce on the wire: 48 bits.
pub const NODE_NONCE_LEN: usize = 6;
/// Length of a Challenge's binding to the request it answers.
pub const BINDING_LEN: usize = 2;
/// Length of a seal's tag ([`crate::seal`]).
pub const SEAL_TAG_LEN: usize = 4;
/// The largest node nonce (48 bits).
pub const NODE_NONCE_MAX: u64 = (1 << (8 * NODE_NONCE_LEN)) - 1;

/// What a MAC authenticates: the first byte of every MAC input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Domain {
    /// A configuration command (DiagnosticControl, ...).
    Command = 0x01,
    /// A TransferOpen.
    Open = 0x02,
    /// A table image.
    Image = 0x03,
    /// A node's Receipt.
    Receipt = 0x04,
    /// An exchange: its nonce and the Challenge's binding, from both nonces.
    Exchange = 0x05,
    /// A node nonce, from the boot salt and the challenge counter.
    NodeNonce = 0x06,
    /// A coordination frame's seal ([`crate::seal`]).
    Seal = 0x07,
}

/// What the node's Challenge and both ends derive from the tool's nonce and the node's: the
/// nonce every tag of the exchange is over, and the binding the Challenge carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Exchange {
    /// The exchange nonce: bytes 0-7 (LE) of CMAC(Exchange, node, tool nonce u64 LE, node nonce
    /// 48 bits LE).
    pub nonce: u64,
    /// Bytes 8-9 of the same CMAC: the tool takes only a Challenge whose binding is this for its
    /// own nonce.
    pub binding: [u8; BINDING_LEN],
}

/// A 128-bit node key. `Debug` does not show it.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Key([u8; KEY_LEN]);

impl core::fmt::Debug for Key {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Key(..)")
    }
}

/// Why a key file's text was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum KeyTextError {
    /// Not 32 characters (after an optional trailing newline): the length found.
    Length(usize),
    /// A character that is not a hexadecimal digit, at this (0-based) position.
    NotHex(usize),
}

impl core::fmt::Display for KeyTextError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            KeyTextError::Length(len) => write!(
                f,
                "a key is 32 hexadecimal characters (128 bits), this has {len}"
            ),
            KeyTextError::NotHex(at) => write!(
                f,
                "character {} is not a hexadecimal digit (a key is 32 of 0-9, a-f)",
                at + 1
            ),
        }
    }
}

impl core::error::Error for KeyTextError {}

impl Key {
    /// A key from its bytes.
    pub const fn from_bytes(bytes: [u8; KEY_LEN]) -> Key {
        Key(bytes)
    }

    /// The key's bytes.
    pub const fn bytes(&self) -> &[u8; KEY_LEN] {
        &self.0
    }

    /// Parses a key file's text: 32 hexadecimal characters (either case), optionally followed by
    /// one newline (`\n` or `\r\n`).
    pub fn from_hex(text: &str) -> Result<Key, KeyTextError> {
        let text = text
            .strip_suffix('\n')
            .map_or(text, |rest| rest.strip_suffix('\r').unwrap_or(rest));
        let digits = text.as_bytes();
        if digits.len() != 2 * KEY_LEN {
            return Err(KeyTextError::Length(text.chars().count()));
        }
        let mut key = [0u8; KEY_LEN];
        for (index, (byte, pair)) in key.iter_mut().zip(digits.chunks_exact(2)).enumerate() {
            let high = hex_value(pair.first().copied().unwrap_or(0))
                .ok_or(KeyTextError::NotHex(2 * index))?;
            let low = hex_value(pair.get(1).copied().unwrap_or(0))
                .ok_or(KeyTextError::NotHex(2 * index + 1))?;
            *byte = high << 4 | low;
        }
        Ok(Key(key))
    }

    /// The key file's text: 32 lowercase hexadecimal characters, without a newline.
    pub fn to_hex(&self) -> [u8; 2 * KEY_LEN] {
        const DIGITS: &[u8; 16] = b"0123456789abcdef";
        let mut out = [0u8; 2 * KEY_LEN];
        for (pair, byte) in out.chunks_exact_mut(2).zip(self.0) {
            for (slot, nibble) in pair.iter_mut().zip([byte >> 4, byte & 0x0F]) {
                *slot = DIGITS.get(usize::from(nibble)).copied().unwrap_or(b'0');
            }
        }
        out
    }
}

fn hex_value(digit: u8) -> Option<u8> {
    match digit {
        b'0'..=b'9' => Some(digit - b'0'),
        b'a'..=b'f' => Some(digit - b'a' + 10),
        b'A'..=b'F' => Some(digit - b'A' + 10),
        _ => None,
    }
}

/// Computes and checks the tags of one node's key. Holds the key schedule (a few hundred bytes);
/// build it once.
#[derive(Clone)]
pub struct Authenticator {
    #[cfg(target_os = "none")]
    mac: aes_cmac::Cmac,
    #[cfg(not(target_os = "none"))]
    mac: cmac::Cmac<aes::Aes128>,
}

impl core::fmt::Debug for Authenticator {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Authenticator(..)")
    }
}

/// The first 8 bytes of a CMAC as a little-endian word.
fn word(full: &[u8; 16]) -> u64 {
    let [b0, b1, b2, b3, b4, b5, b6, b7, ..] = *full;
    u64::from_le_bytes([b0, b1, b2, b3, b4, b5, b6, b7])
}

/// Compares two byte strings in time independent of where they differ.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

impl Authenticator {
    /// The authenticator of `key`: expands the AES key schedule.
    pub fn new(key: &Key) -> Authenticator {
        Authenticator {
            #[cfg(target_os = "none")]
            mac: aes_cmac::Cmac::new(&key.0),
            #[cfg(not(target_os = "none"))]
            mac: <cmac::Cmac<aes::Aes128> as KeyInit>::new(&key.0.into()),
        }
    }

    /// The full 128-bit CMAC of the concatenation of `parts`.
    #[cfg(target_os = "none")]
    fn cmac(&self, parts: &[&[u8]]) -> [u8; 16] {
        self.mac.mac(parts)
    }

    /// The full 128-bit CMAC of the concatenation of `parts`.
    #[cfg(not(target_os = "none"))]
    fn cmac(&self, parts: &[&[u8]]) -> [u8; 16] {
        let mut mac = self.mac.clone();
        for part in parts {
            mac.update(part);
        }
        mac.finalize().into_bytes().into()
    }

    fn truncated<const T: usize>(&self, parts: &[&[u8]]) -> [u8; T] {
        let full = self.cmac(parts);
        let mut out = [0u8; T];
        for (slot, byte) in out.iter_mut().zip(full) {
            *slot = byte;
        }
        out
    }

    /// A node's nonce: the first 48 bits (LE) of CMAC(NodeNonce, node, boot salt u32 LE,
    /// counter u32 LE). A pseudo-random function of a pair that never repeats for one key, so
    /// nobody without the key can tell which nonce comes next (a counter could be predicted, and
    /// tags harvested over a predicted nonce replayed once the node issued it).
    pub fn node_nonce(&self, node: u8, boot_salt: u32, counter: u32) -> u64 {
        let full = self.cmac(&[
            &[Domain::NodeNonce as u8, node],
            &boot_salt.to_le_bytes(),
            &counter.to_le_bytes(),
        ]);
        word(&full) & NODE_NONCE_MAX
    }

    /// The exchange of a tool nonce and a node nonce ([`Exchange`]): one CMAC. Its nonce covers
    /// both (a receipt recorded from an earlier push of the same image does not verify for the
    /// next: the tool's nonce differs); its binding tells the tool that a Challenge answers its
    /// own request: not one a rogue made up (but for one chance in 65 536, and then it only makes
    /// the tool's tags worthless: the node never issues that nonce), nor one the node gave another
    /// requester.
    pub fn exchange(&self, node: u8, tool_nonce: u64, node_nonce: u64) -> Exchange {
        let node_bytes = node_nonce.to_le_bytes();
        let full = self.cmac(&[
            &[Domain::Exchange as u8, node],
            &tool_nonce.to_le_bytes(),
            node_bytes.get(..NODE_NONCE_LEN).unwrap_or(&node_bytes),
        ]);
        let [.., b8, b9, _, _, _, _, _, _] = full;
        Exchange {
            nonce: word(&full),
            binding: [b8, b9],
        }
    }

    /// The tag of a command: over (Command, node, service code, nonce, plain payload).
    pub fn command_tag(
        &self,
        node: u8,
        service: u8,
        nonce: u64,
        payload: &[u8],
    ) -> [u8; COMMAND_TAG_LEN] {
        self.truncated(&[
            &[Domain::Command as u8, node, service],
            &nonce.to_le_bytes(),
            payload,
        ])
    }

    /// Whether `tag` is [`Authenticator::command_tag`] of these fields.
    pub fn verify_command(
        &self,
        node: u8,
        service: u8,
        nonce: u64,
        payload: &[u8],
        tag: &[u8],
    ) -> bool {
        same(&self.command_tag(node, service, nonce, payload), tag)
    }

    /// The tag of a TransferOpen: over (Open, node, nonce, message length, flags).
    pub fn open_tag(&self, node: u8, nonce: u64, length: u16, flags: u8) -> [u8; OPEN_TAG_LEN] {
        self.truncated(&[
            &[Domain::Open as u8, node],
            &nonce.to_le_bytes(),
            &length.to_le_bytes(),
            &[flags],
        ])
    }

    /// Whether `tag` is [`Authenticator::open_tag`] of these fields.
    pub fn verify_open(&self, node: u8, nonce: u64, length: u16, flags: u8, tag: &[u8]) -> bool {
        same(&self.open_tag(node, nonce, length, flags), tag)
    }

    /// The MAC that follows an image: over (Image, node, nonce, flags, image). Costs one AES block
    /// per 16 bytes of the image.
    pub fn image_mac(&self, node: u8, nonce: u64, flags: u8, image: &[u8]) -> [u8; IMAGE_MAC_LEN] {
        self.cmac(&[
            &[Domain::Image as u8, node],
            &nonce.to_le_bytes(),
            &[flags],
            image,
        ])
    }

    /// Whether `mac` is [`Authenticator::image_mac`] of these fields.
    pub fn verify_image(&self, node: u8, nonce: u64, flags: u8, image: &[u8], mac: &[u8]) -> bool {
        same(&self.image_mac(node, nonce, flags, image), mac)
    }

    /// The tag of a Receipt: over (Receipt, node, nonce, the TransferStatus payload it confirms,
    /// the running image's CRC, its stored flag).
    pub fn receipt_tag(
        &self,
        node: u8,
        nonce: u64,
        status: &[u8; 8],
        running_crc: u32,
        stored: bool,
    ) -> [u8; RECEIPT_TAG_LEN] {
        self.truncated(&[
            &[Domain::Receipt as u8, node],
            &nonce.to_le_bytes(),
            status,
            &running_crc.to_le_bytes(),
            &[u8::from(stored)],
        ])
    }

    /// The tag of a seal ([`crate::seal`]): the first 4 bytes of CMAC(Seal, sender, the sealed
    /// frame's identifier u32 LE, its length, its payload, freshness u64 LE). The freshness is
    /// the sender's (epoch << 32 | counter) for a coordination frame, the requester's nonce for
    /// a Freshness answer. One CMAC of two AES blocks (a payload of up to 8 bytes).
    pub fn seal_tag(
        &self,
        sender: u8,
        raw_id: u32,
        payload: &[u8],
        freshness: u64,
    ) -> [u8; SEAL_TAG_LEN] {
        // At most 8 bytes: the length always fits.
        let len = u8::try_from(payload.len()).unwrap_or(u8::MAX);
        self.truncated(&[
            &[Domain::Seal as u8, sender],
            &raw_id.to_le_bytes(),
            &[len],
            payload,
            &freshness.to_le_bytes(),
        ])
    }

    /// Whether `tag` is [`Authenticator::seal_tag`] of these fields.
    pub fn verify_seal(
        &self,
        sender: u8,
        raw_id: u32,
        payload: &[u8],
        freshness: u64,
        tag: &[u8],
    ) -> bool {
        same(&self.seal_tag(sender, raw_id, payload, freshness), tag)
    }

    /// Whether `tag` is [`Authenticator::receipt_tag`] of these fields.
    pub fn verify_receipt(
        &self,
        node: u8,
        nonce: u64,
        status: &[u8; 8],
        running_crc: u32,
        stored: bool,
        tag: &[u8],
    ) -> bool {
        same(
            &self.receipt_tag(node, nonce, status, running_crc, stored),
            tag,
        )
    }
}

/// The key page of a board: where its key lives in flash.
///
/// ```text
/// bytes 0-3    magic "PABK"
/// byte 4       format, 1
/// bytes 5-7    reserved, 0
/// bytes 8-23   the key
/// bytes 24-27  CRC-32 (the image CRC) of bytes 0-23, u32 LE
/// bytes 28-31  reserved, 0
/// ```
///
/// An erased page (the first 32 bytes all 0xFF) means "no key". Anything else that does not
/// verify is refused: a board then fails closed (accepts no configuration at all).
pub mod page {
    use super::{KEY_LEN, Key, crc32};

    /// Bytes of the key record at the start of the page.
    pub const LEN: usize = 32;
    /// The magic.
    pub const MAGIC: [u8; 4] = *b"PABK";
    /// The format this code writes and reads.
    pub const FORMAT: u8 = 1;

    /// Why a key page was refused.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    #[cfg_attr(feature = "defmt", derive(defmt::Format))]
    #[non_exhaustive]
    pub enum PageError {
        /// Fewer than [`LEN`] bytes.
        Truncated,
        /// Not erased and no magic.
        BadMagic,
        /// A format this code does not know.
        UnsupportedFormat,
        /// A reserved byte is not 0.
        Reserved,
        /// The CRC does not match.
        Crc,
    }

    impl core::fmt::Display for PageError {
        fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
            match self {
                PageError::Truncated => write!(f, "key page shorter than {LEN} bytes"),
                PageError::BadMagic => f.write_str("key page neither erased nor with its magic"),
                PageError::UnsupportedFormat => f.write_str("key page of an unknown format"),
                PageError::Reserved => f.write_str("key page with a reserved byte set"),
                PageError::Crc => f.write_str("key page whose CRC does not match"),
            }
        }
    }

    impl core::error::Error for PageError {}

    impl PageError {
        /// The number reported in the `KeyPageInvalid` fault's detail byte 0.
        pub const fn code(self) -> u8 {
            match self {
                PageError::Truncated => 1,
                PageError::BadMagic => 2,
                PageError::UnsupportedFormat => 3,
                PageError::Reserved => 4,
                PageError::Crc => 5,
            }
        }
    }

    /// The page record of `key`.
    pub fn encode(key: &Key) -> [u8; LEN] {
        let mut out = [0u8; LEN];
        let (head, tail) = out.split_at_mut(24);
        for (slot, byte) in head
            .iter_mut()
            .zip(MAGIC.iter().chain(&[FORMAT, 0, 0, 0]).chain(key.bytes()))
        {
            *slot = *byte;
        }
        let crc = crc32(head).to_le_bytes();
        for (slot, byte) in tail.iter_mut().zip(crc) {
            *slot = byte;
        }
        out
    }

    /// Reads a key page: `Ok(None)` when erased, `Ok(Some(key))` when it verifies.
    pub fn decode(bytes: &[u8]) -> Result<Option<Key>, PageError> {
        let record = bytes.get(..LEN).ok_or(PageError::Truncated)?;
        if record.iter().all(|&byte| byte == 0xFF) {
            return Ok(None);
        }
        let field = |range: core::ops::Range<usize>| record.get(range).unwrap_or(&[]);
        if field(0..4) != MAGIC {
            return Err(PageError::BadMagic);
        }
        if field(4..5) != [FORMAT] {
            return Err(PageError::UnsupportedFormat);
        }
        // Two comparisons: `any` over a chain compiled a loop per half.
        if field(5..8) != [0; 3] || field(28..32) != [0; 4] {
            return Err(PageError::Reserved);
        }
        if crc32(field(0..24)).to_le_bytes() != field(24..28) {
            return Err(PageError::Crc);
        }
        let mut key = [0u8; KEY_LEN];
        key.copy_from_slice(field(8..24));
        Ok(Some(Key::from_bytes(key)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cmac_matches_rfc_4493() {
        // RFC 4493, section 4: key 2b7e1516..., example 2 (16 bytes) and 3 (40 bytes).
        let key = Key::from_hex("2b7e151628aed2a6abf7158809cf4f3c").unwrap();
        let auth = Authenticator::new(&key);
        let m = [
            0x6b, 0xc1, 0xbe, 0xe2, 0x2e, 0x40, 0x9f, 0x96, 0xe9, 0x3d, 0x7e, 0x11, 0x73, 0x93,
            0x17, 0x2a, 0xae, 0x2d, 0x8a, 0x57, 0x1e, 0x03, 0xac, 0x9c, 0x9e, 0xb7, 0x6f, 0xac,
            0x45, 0xaf, 0x8e, 0x51, 0x30, 0xc8, 0x1c, 0x46, 0xa3, 0x5c, 0xe4, 0x11,
        ];
        assert_eq!(
            auth.cmac(&[&m[..16]]),
            [
                0x07, 0x0a, 0x16, 0xb4, 0x6b, 0x4d, 0x41, 0x44, 0xf7, 0x9b, 0xdd, 0x9d, 0xd0, 0x4a,
                0x28, 0x7c
            ]
        );
        // Split across parts: the same MAC.
        assert_eq!(
            auth.cmac(&[&m[..5], &m[5..40]]),
            [
                0xdf, 0xa6, 0x67, 0x47, 0xde, 0x9a, 0xe6, 0x30, 0x30, 0xca, 0x32, 0x61, 0x14, 0x97,
                0xc8, 0x27
            ]
        );
    }

    #[test]
    fn key_text_round_trips_and_errors_say_where() {
        let key = Key::from_hex("00112233445566778899AABBCCDDEEFF\n").unwrap();
        assert_eq!(&key.to_hex(), b"00112233445566778899aabbccddeeff");
        assert_eq!(
            Key::from_hex(core::str::from_utf8(&key.to_hex()).unwrap()),
            Ok(key)
        );
        assert!(Key::from_hex("00112233445566778899aabbccddeeff\r\n").is_ok());
        assert_eq!(Key::from_hex("0011"), Err(KeyTextError::Length(4)));
        assert_eq!(
            Key::from_hex("00112233445566778899aabbccddeefg"),
            Err(KeyTextError::NotHex(31))
        );
        assert_eq!(format!("{key:?}"), "Key(..)");
    }

    #[test]
    fn tags_bind_domain_node_nonce_and_content() {
        let auth = Authenticator::new(&Key::from_bytes([7; 16]));
        let tag = auth.command_tag(3, 0x10, 42, &[1, 2, 3, 4]);
        assert!(auth.verify_command(3, 0x10, 42, &[1, 2, 3, 4], &tag));
        assert!(!auth.verify_command(4, 0x10, 42, &[1, 2, 3, 4], &tag));
        assert!(!auth.verify_command(3, 0x11, 42, &[1, 2, 3, 4], &tag));
        assert!(!auth.verify_command(3, 0x10, 43, &[1, 2, 3, 4], &tag));
        assert!(!auth.verify_command(3, 0x10, 42, &[1, 2, 3, 5], &tag));
        assert!(!auth.verify_command(3, 0x10, 42, &[1, 2, 3, 4], &tag[..3]));
        let other = Authenticator::new(&Key::from_bytes([8; 16]));
        assert!(!other.verify_command(3, 0x10, 42, &[1, 2, 3, 4], &tag));
        let open = auth.open_tag(3, 42, 100, 0);
        assert!(auth.verify_open(3, 42, 100, 0, &open));
        assert!(!auth.verify_open(3, 42, 100, 1, &open));
        assert!(!auth.verify_open(3, 42, 101, 0, &open));
        let mac = auth.image_mac(3, 42, 0, b"image");
        assert!(auth.verify_image(3, 42, 0, b"image", &mac));
        assert!(!auth.verify_image(3, 42, 1, b"image", &mac));
        assert!(!auth.verify_image(3, 42, 0, b"imagf", &mac));
        let receipt = auth.receipt_tag(3, 42, &[0; 8], 0xABCD, true);
        assert!(auth.verify_receipt(3, 42, &[0; 8], 0xABCD, true, &receipt));
        assert!(!auth.verify_receipt(3, 42, &[0; 8], 0xABCD, false, &receipt));
        assert!(!auth.verify_receipt(3, 42, &[1, 0, 0, 0, 0, 0, 0, 0], 0xABCD, true, &receipt));
    }

    #[test]
    fn key_pages_round_trip_and_fail_closed() {
        let key = Key::from_bytes(*b"0123456789abcdef");
        let record = page::encode(&key);
        assert_eq!(page::decode(&record), Ok(Some(key)));
        assert_eq!(page::decode(&[0xFF; 2048]), Ok(None));
        assert_eq!(page::decode(&record[..31]), Err(page::PageError::Truncated));
        for at in 0..page::LEN {
            let mut bad = record;
            bad[at] ^= 0x01;
            assert!(
                page::decode(&bad).is_err(),
                "a flip at byte {at} must not verify"
            );
        }
        let mut zeros = [0u8; 32];
        assert_eq!(page::decode(&zeros), Err(page::PageError::BadMagic));
        zeros[..4].copy_from_slice(b"PABK");
        assert_eq!(
            page::decode(&zeros),
            Err(page::PageError::UnsupportedFormat)
        );
    }

    #[test]
    fn node_nonces_are_48_bits_that_differ_with_salt_counter_node_and_key() {
        let auth = Authenticator::new(&Key::from_bytes([7; 16]));
        let nonce = auth.node_nonce(3, 0x0102_0304, 5);
        assert!(nonce <= NODE_NONCE_MAX);
        // The first 6 bytes of the CMAC, little-endian.
        let full = auth.cmac(&[
            &[Domain::NodeNonce as u8, 3],
            &0x0102_0304u32.to_le_bytes(),
            &5u32.to_le_bytes(),
        ]);
        assert_eq!(
            nonce.to_le_bytes()[..NODE_NONCE_LEN],
            full[..NODE_NONCE_LEN]
        );
        let mut seen = std::collections::BTreeSet::new();
        for counter in 0..1000 {
            assert!(seen.insert(auth.node_nonce(3, 0x0102_0304, counter)));
        }
        assert!(seen.insert(auth.node_nonce(3, 0x0102_0305, 5)));
        assert!(seen.insert(auth.node_nonce(4, 0x0102_0304, 5)));
        let other = Authenticator::new(&Key::from_bytes([8; 16]));
        assert!(seen.insert(other.node_nonce(3, 0x0102_0304, 5)));
    }

    #[test]
    fn an_exchange_covers_both_nonces_the_node_and_the_key() {
        let auth = Authenticator::new(&Key::from_bytes([7; 16]));
        let exchange = auth.exchange(3, 0x0102_0304_0506_0708, 42);
        let full = auth.cmac(&[
            &[Domain::Exchange as u8, 3],
            &[8, 7, 6, 5, 4, 3, 2, 1],
            &[42, 0, 0, 0, 0, 0],
        ]);
        assert_eq!(exchange.nonce.to_le_bytes(), full[..8]);
        assert_eq!(exchange.binding, full[8..10]);
        for other in [
            auth.exchange(3, 0x0102_0304_0506_0709, 42),
            auth.exchange(3, 0x0102_0304_0506_0708, 43),
            auth.exchange(4, 0x0102_0304_0506_0708, 42),
            Authenticator::new(&Key::from_bytes([8; 16])).exchange(3, 0x0102_0304_0506_0708, 42),
        ] {
            assert_ne!(other.nonce, exchange.nonce);
            assert_ne!(other.binding, exchange.binding);
        }
        // The node nonce's bits above 48 are not on the wire, nor in the MAC input.
        assert_eq!(
            auth.exchange(3, 0x0102_0304_0506_0708, 42 | 1 << 50),
            exchange
        );
    }
}

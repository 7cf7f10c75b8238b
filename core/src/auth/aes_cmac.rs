//! AES-128 (FIPS 197, encryption only) and CMAC (RFC 4493) for the boards, in some 700 bytes of
//! Cortex-M4 code and data instead of the 2.8 KB RustCrypto's `aes` (fixsliced, compact form) and
//! `cmac` took: what let competitive dynamics fit the boards' 64 KiB.
//!
//! Byte-oriented: the S-box is a 256-byte table, the state 16 bytes, the key schedule 176 bytes
//! expanded once. A table indexed by secret bytes can leak them through the time its look-ups
//! take where memory has caches; the boards have none for RAM (a Cortex-M4 has no data cache,
//! and the STM32G4's ART accelerator caches flash only), so the table is built in RAM, in the
//! key's own state ([`Aes128::new`]), and every look-up takes the same time. Hosts, whose caches
//! would leak, keep RustCrypto's constant-time implementation (`super::Authenticator` picks by
//! target); this one is also compiled for the host's tests, which hold it to RustCrypto's on
//! random keys and messages and to the standards' vectors.
//!
//! Cost on the emulated Cortex-M4 (`scripts/cortex-m4-cost.sh`, case `auth`): the key's set-up,
//! S-box included, 14 895 instructions (once, at boot); a command's tag 5 462; an image MAC
//! over 181 bytes 62 447 (RustCrypto's compact AES: 6 552, 10 096 and 55 678).

/// The S-box: for every x ≠ 0 its multiplicative inverse in GF(2^8) through the affine map,
/// 0 to 0x63. Walks the field's elements as powers of the generator 3 (p = 3^k) and their
/// inverses at the same time (q = 3^-k), so that each inverse comes with its element: 255 rounds
/// of a few instructions, and no table in flash.
fn sbox() -> [u8; 256] {
    let mut table = [0x63u8; 256];
    let (mut p, mut q) = (1u8, 1u8);
    loop {
        // p · 3, and q / 3 (multiplying by 3's inverse, 0xf6, as shifts: q ^= q << 1, 2, 4; then
        // the reduction bit).
        p = p ^ xtime(p);
        q ^= q << 1;
        q ^= q << 2;
        q ^= q << 4;
        if q & 0x80 != 0 {
            q ^= 0x09;
        }
        if let Some(slot) = table.get_mut(usize::from(p)) {
            *slot = q
                ^ q.rotate_left(1)
                ^ q.rotate_left(2)
                ^ q.rotate_left(3)
                ^ q.rotate_left(4)
                ^ 0x63;
        }
        if p == 1 {
            break;
        }
    }
    table
}

/// Multiplication by x in GF(2^8) modulo x^8 + x^4 + x^3 + x + 1.
const fn xtime(b: u8) -> u8 {
    (b << 1) ^ ((b >> 7) * 0x1b)
}

/// An AES-128 key, expanded: 11 round keys, and the S-box its look-ups read (in RAM, next to
/// the key: see the module's documentation). 432 bytes.
#[derive(Clone)]
pub(crate) struct Aes128 {
    round_keys: [[u8; 16]; 11],
    sbox: [u8; 256],
}

impl Aes128 {
    /// Expands `key` (FIPS 197, 5.2).
    pub(crate) fn new(key: &[u8; 16]) -> Aes128 {
        let sbox = sbox();
        let sub = |b: u8| lookup(&sbox, b);
        // The schedule as 44 big-endian words w[i] (FIPS 197's), four to a round key: w[i] is
        // w[i - 4] ^ w[i - 1], transformed every fourth word. Walked with the last four words
        // in hand rather than by index.
        let mut round_keys = [[0u8; 16]; 11];
        let mut last = [0u32; 4];
        for (word, bytes) in last.iter_mut().zip(key.chunks_exact(4)) {
            let mut be = [0u8; 4];
            be.copy_from_slice(bytes);
            *word = u32::from_be_bytes(be);
        }
        let mut rcon = 1u8;
        for (round, round_key) in round_keys.iter_mut().enumerate() {
            if round > 0 {
                let [a, b, c, d] = last[3].rotate_left(8).to_be_bytes();
                let mut t = u32::from_be_bytes([sub(a) ^ rcon, sub(b), sub(c), sub(d)]);
                rcon = xtime(rcon);
                for word in last.iter_mut() {
                    *word ^= t;
                    t = *word;
                }
            }
            for (bytes, word) in round_key.chunks_exact_mut(4).zip(last) {
                bytes.copy_from_slice(&word.to_be_bytes());
            }
        }
        Aes128 { round_keys, sbox }
    }

    /// Encrypts one block in place (FIPS 197, 5.1). The state is column after column, as the
    /// block's bytes are.
    pub(crate) fn encrypt(&self, block: &mut [u8; 16]) {
        let [first, middle @ .., last] = &self.round_keys;
        add(block, first);
        for round_key in middle {
            sub_and_shift(&self.sbox, block);
            mix_columns(block);
            add(block, round_key);
        }
        sub_and_shift(&self.sbox, block);
        add(block, last);
    }
}

fn add(block: &mut [u8; 16], round_key: &[u8; 16]) {
    for (b, k) in block.iter_mut().zip(round_key) {
        *b ^= k;
    }
}

/// SubBytes and ShiftRows together: row r of the state (bytes r, r + 4, r + 8, r + 12) turns
/// left by r columns.
fn sub_and_shift(sbox: &[u8; 256], block: &mut [u8; 16]) {
    let old = *block;
    for (i, b) in block.iter_mut().enumerate() {
        // Column c, row r takes the byte of column c + r.
        let (column, row) = (i / 4, i % 4);
        let from = old.get((column + row) % 4 * 4 + row).copied().unwrap_or(0);
        *b = lookup(sbox, from);
    }
}

/// S(b). `get` rather than indexing (the core has no panicking index); a `u8` is always in
/// range, so the fallback is never taken and LLVM drops it.
fn lookup(sbox: &[u8; 256], b: u8) -> u8 {
    sbox.get(usize::from(b)).copied().unwrap_or(0)
}

fn mix_columns(block: &mut [u8; 16]) {
    for column in block.chunks_exact_mut(4) {
        if let [a0, a1, a2, a3] = column {
            let (b0, b1, b2, b3) = (*a0, *a1, *a2, *a3);
            let all = b0 ^ b1 ^ b2 ^ b3;
            *a0 = b0 ^ all ^ xtime(b0 ^ b1);
            *a1 = b1 ^ all ^ xtime(b1 ^ b2);
            *a2 = b2 ^ all ^ xtime(b2 ^ b3);
            *a3 = b3 ^ all ^ xtime(b3 ^ b0);
        }
    }
}

/// Doubling in GF(2^128) as CMAC defines it (RFC 4493, 2.3): a left shift of the big-endian
/// block, and the constant 0x87 into the last byte if a bit fell out.
fn double(block: &[u8; 16]) -> [u8; 16] {
    let value = u128::from_be_bytes(*block);
    let carry = value >> 127;
    ((value << 1) ^ (carry * 0x87)).to_be_bytes()
}

/// AES-128-CMAC with its subkeys (RFC 4493, 2.3), ready for messages.
#[derive(Clone)]
pub(crate) struct Cmac {
    aes: Aes128,
    /// K1 (a complete last block) and K2 (a padded one).
    k1: [u8; 16],
    k2: [u8; 16],
}

impl Cmac {
    /// Expands `key` and derives the subkeys: one AES block.
    pub(crate) fn new(key: &[u8; 16]) -> Cmac {
        let aes = Aes128::new(key);
        let mut l = [0u8; 16];
        aes.encrypt(&mut l);
        let k1 = double(&l);
        let k2 = double(&k1);
        Cmac { aes, k1, k2 }
    }

    /// The CMAC of the concatenation of `parts` (RFC 4493, 2.4): one AES block per 16 bytes,
    /// at least one. The last block is held back until the end, as it takes a subkey.
    pub(crate) fn mac(&self, parts: &[&[u8]]) -> [u8; 16] {
        let mut x = [0u8; 16];
        let mut pending = [0u8; 16];
        let mut filled = 0usize;
        for &byte in parts.iter().flat_map(|part| part.iter()) {
            if filled == 16 {
                add(&mut x, &pending);
                self.aes.encrypt(&mut x);
                filled = 0;
            }
            if let Some(slot) = pending.get_mut(filled) {
                *slot = byte;
            }
            filled += 1;
        }
        let subkey = if filled == 16 {
            &self.k1
        } else {
            // 10…0 padding after the message's last bytes.
            for (i, slot) in pending.iter_mut().enumerate().skip(filled) {
                *slot = if i == filled { 0x80 } else { 0 };
            }
            &self.k2
        };
        add(&mut pending, subkey);
        add(&mut x, &pending);
        self.aes.encrypt(&mut x);
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex<const N: usize>(text: &str) -> [u8; N] {
        let mut out = [0u8; N];
        for (i, byte) in out.iter_mut().enumerate() {
            *byte = u8::from_str_radix(&text[2 * i..2 * i + 2], 16).unwrap();
        }
        out
    }

    /// x · y in GF(2^8), bit by bit.
    fn gf_mul(mut a: u8, mut b: u8) -> u8 {
        let mut product = 0;
        while b != 0 {
            if b & 1 != 0 {
                product ^= a;
            }
            a = xtime(a);
            b >>= 1;
        }
        product
    }

    #[test]
    fn the_sbox_is_fips_197s() {
        let sbox = sbox();
        // From the definition: the inverse (x^254) through the affine map, for every x.
        for x in 0..=255u8 {
            let inverse = (0..254).fold(1u8, |acc, _| gf_mul(acc, x));
            let b = inverse;
            let expected = b
                ^ b.rotate_left(1)
                ^ b.rotate_left(2)
                ^ b.rotate_left(3)
                ^ b.rotate_left(4)
                ^ 0x63;
            assert_eq!(sbox[usize::from(x)], expected, "S({x:#04x})");
        }
        // FIPS 197, figure 7: a few entries.
        assert_eq!(sbox[0x00], 0x63);
        assert_eq!(sbox[0x01], 0x7c);
        assert_eq!(sbox[0x53], 0xed);
        assert_eq!(sbox[0x9a], 0xb8);
        assert_eq!(sbox[0xff], 0x16);
    }

    #[test]
    fn encrypts_the_fips_197_example() {
        // FIPS 197, appendix C.1.
        let aes = Aes128::new(&hex("000102030405060708090a0b0c0d0e0f"));
        let mut block = hex("00112233445566778899aabbccddeeff");
        aes.encrypt(&mut block);
        assert_eq!(block, hex::<16>("69c4e0d86a7b0430d8cdb78070b4c55a"));
        // Appendix B (the key expansion example of appendix A.1).
        let aes = Aes128::new(&hex("2b7e151628aed2a6abf7158809cf4f3c"));
        assert_eq!(
            aes.round_keys[10],
            hex::<16>("d014f9a8c9ee2589e13f0cc8b6630ca6")
        );
        let mut block = hex("3243f6a8885a308d313198a2e0370734");
        aes.encrypt(&mut block);
        assert_eq!(block, hex::<16>("3925841d02dc09fbdc118597196a0b32"));
    }

    #[test]
    fn cmac_matches_rfc_4493() {
        let cmac = Cmac::new(&hex("2b7e151628aed2a6abf7158809cf4f3c"));
        assert_eq!(cmac.k1, hex::<16>("fbeed618357133667c85e08f7236a8de"));
        assert_eq!(cmac.k2, hex::<16>("f7ddac306ae266ccf90bc11ee46d513b"));
        let m: [u8; 64] = hex(
            "6bc1bee22e409f96e93d7e117393172aae2d8a571e03ac9c9eb76fac45af8e51\
             30c81c46a35ce411e5fbc1191a0a52eff69f2445df4f9b17ad2b417be66c3710",
        );
        assert_eq!(cmac.mac(&[]), hex::<16>("bb1d6929e95937287fa37d129b756746"));
        assert_eq!(
            cmac.mac(&[&m[..16]]),
            hex::<16>("070a16b46b4d4144f79bdd9dd04a287c")
        );
        assert_eq!(
            cmac.mac(&[&m[..40]]),
            hex::<16>("dfa66747de9ae63030ca32611497c827")
        );
        assert_eq!(
            cmac.mac(&[&m[..]]),
            hex::<16>("51f0bebf7e3b9d92fc49741779363cfe")
        );
        // Split anywhere, the same MAC.
        assert_eq!(
            cmac.mac(&[&m[..5], &[], &m[5..33], &m[33..40]]),
            hex::<16>("dfa66747de9ae63030ca32611497c827")
        );
    }

    #[test]
    fn agrees_with_rustcrypto_on_random_keys_and_messages() {
        use cmac::Mac;
        use cmac::digest::KeyInit;
        let mut x = 0x0123_4567_89AB_CDEFu64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..2_000 {
            let mut key = [0u8; 16];
            key.iter_mut().for_each(|b| *b = next() as u8);
            let len = (next() % 100) as usize;
            let mut buffer = [0u8; 100];
            buffer.iter_mut().for_each(|b| *b = next() as u8);
            let message = &buffer[..len];
            let split = (next() as usize) % (len + 1);
            let ours = Cmac::new(&key).mac(&[&message[..split], &message[split..]]);
            let mut theirs = <cmac::Cmac<aes::Aes128> as KeyInit>::new(&key.into());
            theirs.update(message);
            assert_eq!(
                ours,
                <[u8; 16]>::from(theirs.finalize().into_bytes()),
                "{key:?}"
            );
        }
    }
}

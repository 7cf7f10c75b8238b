//! The integer square root, one copy for every module that takes one (competitive dynamics'
//! time constants, the schema server's lengths).

/// ⌊√x⌋, digit by digit (two bits a round, 32 rounds at most, no division): the same value as
/// `u64::isqrt` on every target, whose inlined table-driven form took a board 1 KB of flash (code
/// and a 512-byte table) for a square root taken once per group and table. Out of line so that
/// its callers share it.
#[inline(never)]
pub(crate) const fn isqrt(v: u64) -> u64 {
    let mut rem = v;
    let mut root = 0u64;
    let mut bit = 1u64 << 62;
    while bit > v {
        bit >>= 2;
    }
    while bit != 0 {
        // root < 2^32 and bit ≤ 2^62: the sum cannot overflow.
        if rem >= root + bit {
            rem -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    root
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isqrt_is_the_standard_library_s() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for k in 0..64 {
            for v in [1u64 << k, (1u64 << k) - 1, (1u64 << k) + 1, u64::MAX >> k] {
                assert_eq!(isqrt(v), v.isqrt(), "{v}");
            }
        }
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            assert_eq!(isqrt(x), x.isqrt(), "{x}");
            let small = x >> (x % 64);
            assert_eq!(isqrt(small), small.isqrt(), "{small}");
            let r = x >> 32;
            assert_eq!(isqrt(r * r), r);
            assert_eq!(isqrt(r * r + 2 * r), r);
        }
        assert_eq!(isqrt(0), 0);
        assert_eq!(isqrt(u64::MAX), u64::MAX.isqrt());
    }
}

//! The table body's decoder: postcard's wire format, read by hand.
//!
//! The workstation encodes a [`crate::Table`] with `serde` and postcard; a node decodes it here.
//! Why not serde on the node too: its derived visitors, postcard's deserializer and heapless's
//! `Vec` visitor took some 6 KB of a board's 64 KiB of flash, for a format this small (unsigned
//! varints, bytes, booleans, options, enum indices, lists). This reader is a few hundred bytes.
//!
//! It accepts exactly what postcard accepts and builds the same values (tests/wire.rs checks it
//! against postcard + serde on arbitrary bytes, and the `image_wire` fuzz target too), with
//! postcard's errors. List lengths are read as a workstation's postcard reads them (a 64-bit
//! `usize` varint, up to 10 bytes), on every target: with postcard itself, a 32-bit board refused
//! a length that a workstation accepted (a small length in 6 to 10 bytes), which the fuzzer found.
//!
//! Costs: one pass over the bytes, no allocation; every read is bounds-checked and fails with
//! [`Error::DeserializeUnexpectedEnd`] past the end.

use heapless::Vec;
use postcard::Error;

/// A cursor over a body.
///
/// Errors are sticky: the first one is kept, the bytes left are dropped (so every later read
/// fails at once and every list ends), and reads go on returning zeros, `false`, `None` and
/// empty lists until [`take`] reports that first error. (One exception: a table's own list
/// longer than its capacity keeps the bytes, [`Reader::fill_within`].) So a decoder has no branch per field:
/// one per list element at most. On the NUCLEO-G474RE this took 1 008 bytes less flash than a
/// `Result` (and its `?`) for every field, 1 704 with competitive dynamics. The values a failed decode builds are never seen:
/// [`take`] returns the error instead.
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    error: Option<Error>,
    /// Whether the bytes are dropped: an error other than a list of the table longer than the
    /// receiving table's capacity ([`Reader::fill_within`]), after which reading goes on.
    dropped: bool,
}

/// A value with postcard's encoding of its serde derive: fields in order, newtypes transparent.
/// On an error (kept in the reader) any value of the type may come back.
pub(crate) trait Decode: Sized {
    fn decode(r: &mut Reader<'_>) -> Self;
}

impl<'a> Reader<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Reader {
            bytes,
            error: None,
            dropped: false,
        }
    }

    /// What is left after the values read so far (nothing after an error).
    pub(crate) fn rest(&self) -> &'a [u8] {
        self.bytes
    }

    /// The first error, if a read has failed.
    pub(crate) fn error(&self) -> Option<Error> {
        self.error.clone()
    }

    /// Whether every byte was read as a table's syntax, with no error but lists longer than
    /// their room ([`Reader::fill_within`]): the body is a table, too large for this node.
    pub(crate) fn is_whole(&self) -> bool {
        !self.dropped && self.bytes.is_empty()
    }

    /// Keeps `error` unless one came first, and drops the bytes left.
    #[inline(never)]
    #[cold]
    pub(crate) fn fail(&mut self, error: Error) {
        self.overflow(error);
        self.dropped = true;
        self.bytes = &[];
    }

    /// Keeps `error` unless one came first, and goes on reading ([`Reader::fill_within`]).
    /// Cold, but left to the inliner: out of line it took 64 bytes more of the NUCLEO-G474RE's
    /// flash.
    #[cold]
    fn overflow(&mut self, error: Error) {
        if self.error.is_none() {
            self.error = Some(error);
        }
    }

    #[inline(never)]
    pub(crate) fn u8(&mut self) -> u8 {
        match self.bytes.split_first() {
            Some((&first, rest)) => {
                self.bytes = rest;
                first
            }
            None => {
                self.fail(Error::DeserializeUnexpectedEnd);
                0
            }
        }
    }

    pub(crate) fn bool(&mut self) -> bool {
        match self.u8() {
            0 => false,
            1 => true,
            _ => {
                self.fail(Error::DeserializeBadBool);
                false
            }
        }
    }

    /// An unsigned LEB128 varint of at most `bits` bits (16, 32 or 64), as postcard reads one: at
    /// most ⌈bits/7⌉ bytes, and the last byte of a full-length one no larger than the bits left.
    #[inline(always)]
    fn varint(&mut self, bits: u32) -> u64 {
        // Worked out where `bits` is a constant: no division in the reader.
        self.varint_within(bits.div_ceil(7), (1u8 << (bits % 7)) - 1)
    }

    /// [`Reader::varint`] of at most `max_bytes` bytes, the last of a full-length one at most
    /// `last_max`.
    #[inline(never)]
    fn varint_within(&mut self, max_bytes: u32, last_max: u8) -> u64 {
        let mut out = 0u64;
        for i in 0..max_bytes {
            let Some((&byte, rest)) = self.bytes.split_first() else {
                self.fail(Error::DeserializeUnexpectedEnd);
                return 0;
            };
            self.bytes = rest;
            // i < 10, so the shift is below 64; bits above `bits` are refused below.
            out |= u64::from(byte & 0x7F).wrapping_shl(7 * i);
            if byte & 0x80 == 0 {
                if i == max_bytes - 1 && byte > last_max {
                    break;
                }
                return out;
            }
        }
        self.fail(Error::DeserializeBadVarint);
        0
    }

    /// Out of line, as [`Reader::u32`]: a call is smaller than setting up `varint`'s arguments.
    #[inline(never)]
    pub(crate) fn u16(&mut self) -> u16 {
        // The last-byte check keeps the value within 16 bits.
        self.varint(16) as u16
    }

    /// Out of line, unlike the other readers of a varint: inlined, each of its 19 callers (most
    /// of them the schema server's fields) set up `varint`'s argument; one call is smaller.
    #[inline(never)]
    pub(crate) fn u32(&mut self) -> u32 {
        // The last-byte check keeps the value within 32 bits.
        self.varint(32) as u32
    }

    /// A signed 32-bit integer: postcard's zigzag varint (0, −1, 1, −2 … as 0, 1, 2, 3 …).
    pub(crate) fn i32(&mut self) -> i32 {
        let z = self.u32();
        ((z >> 1) as i32) ^ -((z & 1) as i32)
    }

    /// An enum's variant index (a u32 varint) that must be below `variants`: serde's derive
    /// refuses an unknown index with a custom error (and 0 comes back). Out of line: inlined,
    /// each of its callers (ten with the schema server) had its own comparison and failure.
    #[inline(never)]
    pub(crate) fn variant(&mut self, variants: u32) -> u32 {
        let index = self.u32();
        if index < variants {
            index
        } else {
            self.fail(Error::SerdeDeCustom);
            0
        }
    }

    /// An option that must be `None` (of a kind this build does not decode): a `Some` is the
    /// custom error, as for a list longer than its capacity.
    #[cfg(not(feature = "schema"))]
    pub(crate) fn none(&mut self) {
        if self.u8() != 0 {
            self.fail(Error::SerdeDeCustom);
        }
    }

    pub(crate) fn option<T: Decode>(&mut self) -> Option<T> {
        self.some().then(|| T::decode(self))
    }

    /// An option's tag: whether a value follows. Out of line: one copy for every option type
    /// (the schema server's set-up has them too).
    #[inline(never)]
    fn some(&mut self) -> bool {
        match self.u8() {
            0 => false,
            1 => true,
            _ => {
                self.fail(Error::DeserializeBadOption);
                false
            }
        }
    }

    pub(crate) fn decode<T: Decode>(&mut self) -> T {
        T::decode(self)
    }

    /// A list: its length and loop, one copy for every element type (a copy per list type took
    /// 144 bytes more of the NUCLEO-G474RE's flash): `element` decodes and takes one element.
    /// Returns the length read. The loader runs it once per list of a table, never on the frame
    /// path.
    ///
    /// An element whose decode failed is taken too (and the list ends there, the bytes
    /// dropped): whatever a failed decode builds is never seen ([`take`] reports the error), so
    /// the elements' takers need no test of their own (one per element type: 140 bytes of the
    /// NUCLEO-G474RE's flash with the schema server, 76 without).
    #[inline(never)]
    fn list(&mut self, element: &mut dyn FnMut(&mut Self)) -> usize {
        // A length is a usize varint for postcard: read as on a 64-bit workstation on every
        // target (an overlong encoding of a small length is accepted everywhere), and refused
        // beyond u32 (no body holds that many elements; postcard would run out of bytes).
        let Ok(len) = u32::try_from(self.varint(64)) else {
            self.fail(Error::SerdeDeCustom);
            return 0;
        };
        for _ in 0..len {
            element(self);
            if self.dropped {
                break;
            }
        }
        len as usize
    }

    /// A list into a `Vec` of capacity `N`: more elements than that is heapless's custom error.
    pub(crate) fn vec<T: Decode, const N: usize>(&mut self) -> Vec<T, N> {
        let mut out = Vec::new();
        self.fill(&mut out);
        out
    }

    /// [`Reader::vec`] into an empty `Vec` already in place (a large struct's field), so that the
    /// list is not built elsewhere and moved: the same elements and errors.
    pub(crate) fn fill<T: Decode, const N: usize>(&mut self, out: &mut Vec<T, N>) {
        self.list(&mut |r| {
            let element = T::decode(r);
            if out.push(element).is_err() {
                r.fail(Error::SerdeDeCustom);
            }
        });
    }

    /// One of a table's own lists ([`crate::Table`]'s fields, not a list inside an element)
    /// into `out`: as [`Reader::fill`], but an element beyond `out`'s capacity is heapless's
    /// custom error *without* dropping the bytes. The rest of the body is still read, every
    /// element checked (those that do not fit are dropped), so that at the end
    /// [`Reader::is_whole`] tells a table too large for this node from bytes that are not a
    /// table, in the one pass: the loader needed a second decode for that, each element type's
    /// decoder a second copy (636 bytes of the NUCLEO-G474RE's flash with competitive dynamics).
    /// Returns the length read. A read goes on for at most one element per byte left: every
    /// element of a table's lists reads at least one byte or drops them.
    pub(crate) fn fill_within<T: Decode, const N: usize>(&mut self, out: &mut Vec<T, N>) -> usize {
        self.list(&mut |r| {
            let element = T::decode(r);
            if out.push(element).is_err() {
                r.overflow(Error::SerdeDeCustom);
            }
        })
    }

    /// A list that must be empty (of a kind this build does not decode): the empty `Vec`, or
    /// the custom error, as for a list longer than its capacity.
    #[cfg(any(
        not(feature = "ble"),
        not(feature = "dynamics"),
        not(feature = "filters")
    ))]
    pub(crate) fn empty<T, const N: usize>(&mut self) -> Vec<T, N> {
        if self.varint(64) != 0 {
            self.fail(Error::SerdeDeCustom);
        }
        Vec::new()
    }

    /// A list whose elements are decoded (so checked) and dropped: its length. The loader's
    /// former way to size a body that did not fit, kept for the test that holds
    /// [`Reader::fill_within`] to it.
    #[cfg(test)]
    pub(crate) fn count<T: Decode>(&mut self) -> usize {
        self.list(&mut |r| {
            T::decode(r);
        })
    }
}

impl Decode for u8 {
    fn decode(r: &mut Reader<'_>) -> Self {
        r.u8()
    }
}

impl Decode for bool {
    fn decode(r: &mut Reader<'_>) -> Self {
        r.bool()
    }
}

impl Decode for u16 {
    fn decode(r: &mut Reader<'_>) -> Self {
        r.u16()
    }
}

impl Decode for i32 {
    fn decode(r: &mut Reader<'_>) -> Self {
        r.i32()
    }
}

impl Decode for u32 {
    fn decode(r: &mut Reader<'_>) -> Self {
        r.u32()
    }
}

/// A fixed-size array (postcard's tuple form: the elements, no length), such as a pose.
impl<const N: usize> Decode for [i32; N] {
    fn decode(r: &mut Reader<'_>) -> Self {
        let mut out = [0; N];
        for v in out.iter_mut() {
            *v = r.i32();
        }
        out
    }
}

/// A list as a field (each list type's elements decoded as themselves).
impl<T: Decode, const N: usize> Decode for Vec<T, N> {
    fn decode(r: &mut Reader<'_>) -> Self {
        r.vec()
    }
}

/// Decodes a whole value with trailing bytes allowed: `(value, rest)`, like
/// `postcard::take_from_bytes`, or the first error.
pub(crate) fn take<T: Decode>(bytes: &[u8]) -> Result<(T, &[u8]), Error> {
    let mut r = Reader::new(bytes);
    let value = T::decode(&mut r);
    match r.error {
        Some(error) => Err(error),
        None => Ok((value, r.rest())),
    }
}

/// `impl Decode` for a struct from its fields, in declaration order (postcard's order). Invoked
/// in each type's own module, where its private fields are visible.
macro_rules! decode_struct {
    ($ty:ident { $($field:ident),* $(,)? }) => {
        impl $crate::wire::Decode for $ty {
            fn decode(r: &mut $crate::wire::Reader<'_>) -> Self {
                $ty { $($field: r.decode()),* }
            }
        }
    };
}
pub(crate) use decode_struct;

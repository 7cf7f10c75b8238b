//! Value ports: ports that combine the values their connections carry (Ayllu's Max, Min, Sum and
//! Priority ports), instead of letting one connection through.
//!
//! A value port reads one [`Field`] of each frame (offset, size 1, 2 or 4, signed or not, little
//! or big endian). Each of its connections keeps its last frame. Connection i **contributes** at
//! t while
//!
//! - its own compiled rule lets it through: the decision diagram entered at its own root
//!   (one root per connection, [`crate::Table::push_value_port`]) answers "i delivers" under the
//!   port's activity mask, i being active (any other answer: it does not contribute);
//! - its last frame carried the field (and, on a Priority port, the priority field): a frame too
//!   short for it is no value, is counted as refused, and replaces the connection's value by
//!   nothing until its next frame;
//! - its last frame is within its τ (t − t_frame ≤ τ): a source that stops ages out, which
//!   Ayllu's registers cannot do.
//!
//! The combination of the contributors, [`Combine`]:
//!
//! - Max / Min: the contributor with the largest / smallest value; ties go to the lower
//!   connection index. The consumer gets that connection's last frame.
//! - Priority: the contributor with the largest priority field; a contributor replaces the
//!   incumbent (the last output's connection, while it contributes) only when its priority is
//!   strictly greater, as in the paper; among newcomers, ties go to the lower index. The consumer
//!   gets the winner's last frame.
//! - Sum: the sum of the values, saturated to the field's range. The consumer gets the newest
//!   contributing frame with the field replaced by the sum.
//!
//! The consumer is called when the output changes: its value, and for Max, Min and Priority the
//! winning connection. The output is re-evaluated on every frame the port receives and at the
//! port's next deadline ([`crate::Arbiter::deadline`], [`crate::Arbiter::poll`]): the instant
//! after a contributor's frame passes its τ or a connection's activity ends. No contributor: no
//! output, nothing is delivered.
//!
//! Memory (fixed, whatever the table): [`MAX_VALUE_CONNECTIONS`] connection records of 40 bytes
//! (the last frame, its instant, τ, its value field and key as read, the connection's root) and
//! [`MAX_VALUE_PORTS`] port records of 48 bytes, 832 bytes per arbiter; in the table, [`ValueSpec`] in every port record and a 2-byte
//! root per connection of capacity.

use serde::{Deserialize, Serialize};

use crate::decision::NodeRef;
use crate::frame::{Frame, MAX_DATA_LEN};
use crate::time::Instant;

/// Value ports per node, over all its ports. A table with more is refused
/// ([`crate::TableError::TooManyValuePorts`]).
pub const MAX_VALUE_PORTS: usize = 4;
/// Connections of value ports per node, over all its value ports. A table with more is refused
/// ([`crate::TableError::TooManyValueConnections`]). 16 records of 40 bytes: 640 bytes of RAM
/// per arbiter, on a board too.
pub const MAX_VALUE_CONNECTIONS: usize = 16;

/// How a value port combines its contributors' values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Combine {
    /// The largest value; ties to the lower connection index.
    Max,
    /// The smallest value; ties to the lower connection index.
    Min,
    /// The sum, saturated to the field's range; the newest contributing frame carries it.
    Sum,
    /// The largest priority field; strictly greater replaces the incumbent.
    Priority,
}

/// Byte order of a field.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Endian {
    /// Least significant byte first.
    Little,
    /// Most significant byte first.
    Big,
}

/// An integer field of a frame's payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Field {
    /// Its first byte.
    pub offset: u8,
    /// Its length in bytes: 1, 2 or 4.
    pub size: u8,
    /// Two's complement (true) or unsigned.
    pub signed: bool,
    /// Byte order.
    pub endian: Endian,
}

/// Why a [`Field`] was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FieldError {
    /// Its size is not 1, 2 or 4.
    BadSize {
        /// The size found.
        size: u8,
    },
    /// It does not fit the frames this node takes: offset + size > 8 (64 with the feature `fd`).
    OutOfFrame {
        /// Its offset.
        offset: u8,
        /// Its size.
        size: u8,
    },
}

impl core::fmt::Display for FieldError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FieldError::BadSize { size } => write!(f, "size {size} is not 1, 2 or 4"),
            // The length written out, not formatted: a third argument cost the boards' flash.
            #[cfg(not(feature = "fd"))]
            FieldError::OutOfFrame { offset, size } => write!(
                f,
                "offset {offset} + size {size} is beyond the 8 bytes of a frame"
            ),
            #[cfg(feature = "fd")]
            FieldError::OutOfFrame { offset, size } => write!(
                f,
                "offset {offset} + size {size} is beyond the 64 bytes of a frame"
            ),
        }
    }
}

impl core::error::Error for FieldError {}

impl Field {
    /// Checks the size and that the field fits a frame's [`MAX_DATA_LEN`] bytes. One comparison
    /// or two.
    // Out of line: a value port's two fields are checked with it, and the two inlined copies
    // took 44 bytes more of the NUCLEO-G474RE's flash with competitive dynamics, 16 without.
    #[inline(never)]
    pub const fn validate(&self) -> Result<(), FieldError> {
        if !matches!(self.size, 1 | 2 | 4) {
            return Err(FieldError::BadSize { size: self.size });
        }
        if self.offset as usize + self.size as usize > MAX_DATA_LEN {
            return Err(FieldError::OutOfFrame {
                offset: self.offset,
                size: self.size,
            });
        }
        Ok(())
    }

    /// The field's value in `payload`, or `None` when the payload is too short for it (or the
    /// field is invalid). At most four byte loads, no loop.
    pub fn read(&self, payload: &[u8]) -> Option<i64> {
        self.read_raw(payload).map(|raw| self.decode(raw))
    }

    /// The field's bits in `payload`, sign-extended to 32 bits for a signed field; `None` as for
    /// [`Field::read`]. One load of the field's size and a shift pair; out of line, as it is read
    /// for two fields.
    #[inline(never)]
    fn read_raw(&self, payload: &[u8]) -> Option<u32> {
        let bytes = payload.get(usize::from(self.offset)..)?;
        let (raw, unused) = match (self.size, self.endian) {
            (1, _) => (u32::from(*bytes.first()?), 24),
            (2, Endian::Little) => (u32::from(u16::from_le_bytes(*bytes.first_chunk()?)), 16),
            (2, Endian::Big) => (u32::from(u16::from_be_bytes(*bytes.first_chunk()?)), 16),
            (4, Endian::Little) => (u32::from_le_bytes(*bytes.first_chunk()?), 0),
            (4, Endian::Big) => (u32::from_be_bytes(*bytes.first_chunk()?), 0),
            _ => return None,
        };
        Some(if self.signed {
            (raw.wrapping_shl(unused) as i32).wrapping_shr(unused) as u32
        } else {
            raw
        })
    }

    /// The value of bits read by [`Field::read_raw`].
    #[inline]
    const fn decode(&self, raw: u32) -> i64 {
        if self.signed {
            raw as i32 as i64
        } else {
            raw as i64
        }
    }

    /// Bits read by [`Field::read_raw`] as an unsigned number in the values' order (the sign bit
    /// flipped for a signed field), so that values compare as `u32`.
    #[inline]
    const fn ordered(&self, raw: u32) -> u32 {
        if self.signed { raw ^ 0x8000_0000 } else { raw }
    }

    /// The smallest and largest values the field holds.
    pub const fn range(&self) -> (i64, i64) {
        // From the field's bits as a `u32` mask: 64-bit shifts by a variable amount took a
        // Sum's combination 48 bytes of the NUCLEO-G474RE's flash more.
        let ones: u32 = match self.size {
            1 => 0xFF,
            2 => 0xFFFF,
            _ => u32::MAX,
        };
        if self.signed {
            let high = (ones >> 1) as i64;
            (-high - 1, high)
        } else {
            (0, ones as i64)
        }
    }

    /// `value` clamped to [`Field::range`].
    pub const fn saturate(&self, value: i64) -> i64 {
        let (low, high) = self.range();
        if value < low {
            low
        } else if value > high {
            high
        } else {
            value
        }
    }

    /// Writes `value` (saturated) into the field of `data`; leaves `data` unchanged for a field
    /// that does not fit it.
    pub fn write(&self, data: &mut [u8; MAX_DATA_LEN], value: i64) {
        self.write_raw(data, self.saturate(value) as u32);
    }

    /// Writes the low bits of `raw` that the field holds, as [`Field::write`] does once it has
    /// saturated: a Sum's output is saturated when it is combined, and a second clamp cost the
    /// boards a copy of the 64-bit comparisons and every Sum frame their instructions.
    fn write_raw(&self, data: &mut [u8; MAX_DATA_LEN], raw: u32) {
        let Some(bytes) = data.get_mut(usize::from(self.offset)..) else {
            return;
        };
        match (self.size, self.endian) {
            (1, _) => {
                if let Some(byte) = bytes.first_mut() {
                    *byte = raw as u8;
                }
            }
            (2, endian) => {
                if let Some(chunk) = bytes.first_chunk_mut() {
                    *chunk = match endian {
                        Endian::Little => (raw as u16).to_le_bytes(),
                        Endian::Big => (raw as u16).to_be_bytes(),
                    };
                }
            }
            (4, endian) => {
                if let Some(chunk) = bytes.first_chunk_mut() {
                    *chunk = match endian {
                        Endian::Little => raw.to_le_bytes(),
                        Endian::Big => raw.to_be_bytes(),
                    };
                }
            }
            _ => {}
        }
    }
}

/// What a value port reads and how it combines: part of its port record in the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ValueSpec {
    /// The combination.
    pub combine: Combine,
    /// The field combined.
    pub value: Field,
    /// The priority field: required for, and only for, [`Combine::Priority`].
    pub priority: Option<Field>,
}

/// Why a value port was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ValueError {
    /// The value field is invalid.
    Value(FieldError),
    /// The priority field is invalid.
    Priority(FieldError),
    /// A Priority port without a priority field.
    PriorityMissing,
    /// A priority field on a port that does not combine by priority.
    PriorityNotAllowed,
    /// The port's own decision root is not "nobody": on a value port the connections' roots
    /// decide, and no frame is delivered as it came.
    PortRoot,
    /// Connection `connection`'s root refers to a node the port does not have or to a connection
    /// it does not have.
    BadRoot {
        /// The connection, within the port.
        connection: u8,
    },
}

impl core::fmt::Display for ValueError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ValueError::Value(error) => write!(f, "value field: {error}"),
            ValueError::Priority(error) => write!(f, "priority field: {error}"),
            ValueError::PriorityMissing => f.write_str("a priority port needs a priority field"),
            ValueError::PriorityNotAllowed => {
                f.write_str("a priority field on a port that does not combine by priority")
            }
            ValueError::PortRoot => f.write_str("a value port's own decision root must be nobody"),
            ValueError::BadRoot { connection } => write!(
                f,
                "connection {connection}'s decision root refers to nothing valid"
            ),
        }
    }
}

impl core::error::Error for ValueError {}

impl ValueSpec {
    /// Checks both fields and that the priority field is there exactly for a Priority port.
    pub const fn validate(&self) -> Result<(), ValueError> {
        if let Err(error) = self.value.validate() {
            return Err(ValueError::Value(error));
        }
        match (self.combine, self.priority) {
            (Combine::Priority, None) => Err(ValueError::PriorityMissing),
            (Combine::Priority, Some(priority)) => match priority.validate() {
                Ok(()) => Ok(()),
                Err(error) => Err(ValueError::Priority(error)),
            },
            (_, Some(_)) => Err(ValueError::PriorityNotAllowed),
            (_, None) => Ok(()),
        }
    }

    /// What `payload` gives the combination: the value's bits ([`Field::read_raw`]) and the
    /// key the winner maximises (Max: the value in order, Min: the value in reverse order,
    /// Priority: the priority field in order; Sum does not use it); `None` when the payload lacks
    /// a field the port reads.
    #[inline]
    fn read(&self, payload: &[u8]) -> Option<(u32, u32)> {
        let raw = self.value.read_raw(payload)?;
        let priority = match self.priority {
            Some(field) => Some(field.ordered(field.read_raw(payload)?)),
            None => None,
        };
        let ordered = self.value.ordered(raw);
        let key = match (self.combine, priority) {
            (Combine::Priority, Some(key)) => key,
            (Combine::Min, _) => !ordered,
            _ => ordered,
        };
        Some((raw, key))
    }
}

/// What a value port hands its consumer when its output changes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Combined {
    /// The port, by its index in the table.
    pub port: u8,
    /// The connection whose frame is handed over: the winner (Max, Min, Priority), or the newest
    /// contributor (Sum).
    pub connection: u8,
    /// The combined value.
    pub value: i64,
    /// The frame for the consumer: the winner's last frame, or for Sum the newest contributing
    /// frame with the field replaced by the sum.
    pub frame: Frame,
}

/// One connection of a value port at run time. 40 bytes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ValueSlot {
    /// Its last frame.
    frame: Frame,
    /// When it came.
    time: Instant,
    /// τ in µs: the frame counts until `time + τ`.
    tau: u32,
    /// The last frame's value field, as [`Field::read_raw`] reads it (read once, when the frame
    /// is stored).
    raw: u32,
    /// The last frame's key ([`ValueSpec::read`]): the winner has the largest.
    key: u32,
    /// Its decision root: it may contribute when the diagram entered here answers its index.
    pub(crate) root: NodeRef,
    /// Whether the last frame carried the fields.
    has_value: bool,
}

impl ValueSlot {
    /// A connection with τ `tau` and root `root` that has had no frame.
    pub(crate) const fn new(tau: u32, root: NodeRef) -> Self {
        ValueSlot {
            frame: Frame::empty(),
            time: Instant::from_micros(0),
            tau,
            raw: 0,
            key: 0,
            root,
            has_value: false,
        }
    }
}

/// The earliest of instants offered, all seen from `now` (wrap-safe, an instant passed counting
/// as `now`), in one pass:
/// them, each candidate replacing the kept one only when strictly earlier, and the kept one's
/// distance from `now` computed once.
pub(crate) struct Earliest {
    now: Instant,
    /// The kept instant's distance from `now` (an instant passed: 0); `u64::MAX`, which no
    /// distance reaches (they are below 2^63), while nothing is kept.
    distance: u64,
    kept: Instant,
}

impl Earliest {
    /// Nothing offered yet.
    pub(crate) const fn new(now: Instant) -> Self {
        Earliest {
            now,
            distance: u64::MAX,
            kept: now,
        }
    }

    /// Keeps `candidate` if it is strictly earlier than the one kept (an instant already passed
    /// counts as `now`). Out of line: three callers inlined it (184 bytes of the NUCLEO-G474RE's
    /// flash; on the emulated board a value port's frame costs fewer instructions out of line,
    /// value-min-3 950 -> 921, value-sum-8 1704 -> 1635).
    #[inline(never)]
    pub(crate) fn offer(&mut self, candidate: Instant) {
        let distance = candidate.micros_since(self.now).unwrap_or(0);
        if distance < self.distance {
            self.distance = distance;
            self.kept = candidate;
        }
    }

    /// The earliest instant offered.
    pub(crate) fn get(&self) -> Option<Instant> {
        (self.distance != u64::MAX).then_some(self.kept)
    }
}

/// The last output of a value port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Output {
    connection: u8,
    value: i64,
}

/// A value port at run time: where its connections are among the value slots, what it reads,
/// its last output, its next deadline, and which connections its rules let through under the
/// last activity mask seen.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ValueState {
    /// The port, by its index in the table.
    pub(crate) port: u8,
    /// Its first connection among the value slots.
    first: u8,
    /// Its connections.
    count: u8,
    /// The connection whose frame with the fields came last.
    newest: u8,
    spec: ValueSpec,
    output: Option<Output>,
    /// When the output may change without a frame ([`crate::Arbiter::poll`]).
    pub(crate) due: Option<Instant>,
    /// The activity mask for which `lets_through` was computed.
    pub(crate) decided_for: u32,
    /// The connections whose own rule lets them through under `decided_for`. Under the empty
    /// mask no connection is active, so none (the initial state is consistent).
    pub(crate) lets_through: u32,
}

impl ValueState {
    /// Port `port`, whose `count` connections start at slot `first`.
    pub(crate) const fn new(port: u8, first: u8, count: u8, spec: ValueSpec) -> Self {
        ValueState {
            port,
            first,
            count,
            newest: 0,
            spec,
            output: None,
            due: None,
            decided_for: 0,
            lets_through: 0,
        }
    }

    /// The last output: its connection and value.
    pub(crate) fn output(&self) -> Option<(u8, i64)> {
        self.output.map(|output| (output.connection, output.value))
    }

    /// Forgets every value and the output.
    pub(crate) fn clear(&mut self, slots: &mut [ValueSlot]) {
        for slot in self.slots_mut(slots) {
            slot.has_value = false;
        }
        self.output = None;
        self.due = None;
    }

    /// The port's connections among all the value slots.
    pub(crate) fn slots<'a>(&self, slots: &'a [ValueSlot]) -> &'a [ValueSlot] {
        let first = usize::from(self.first);
        slots
            .get(first..first.saturating_add(usize::from(self.count)))
            .unwrap_or(&[])
    }

    fn slots_mut<'a>(&self, slots: &'a mut [ValueSlot]) -> &'a mut [ValueSlot] {
        let first = usize::from(self.first);
        slots
            .get_mut(first..first.saturating_add(usize::from(self.count)))
            .unwrap_or(&mut [])
    }

    /// Records `frame`, received at `now`, as the last frame of the connections in `fed`, its
    /// fields read once. Returns whether it carried the fields (false: refused, it replaced
    /// their values by none).
    pub(crate) fn store(
        &mut self,
        slots: &mut [ValueSlot],
        fed: u32,
        frame: &Frame,
        now: Instant,
    ) -> bool {
        let read = self.spec.read(frame.payload());
        let (raw, key) = read.unwrap_or((0, 0));
        let own = self.slots_mut(slots);
        let mut newest = None;
        let mut rest = fed;
        while rest != 0 {
            let index = rest.trailing_zeros();
            rest &= rest - 1;
            let Some(slot) = own.get_mut(index as usize) else {
                break;
            };
            slot.frame = *frame;
            slot.time = now;
            slot.raw = raw;
            slot.key = key;
            slot.has_value = read.is_some();
            newest = Some(index as u8);
        }
        if read.is_some()
            && let Some(index) = newest
        {
            self.newest = index;
        }
        read.is_some()
    }

    /// Combines the contributors at `now`: those of `lets_through` (the connections whose rule
    /// lets them through) whose value is fresh. Sets the next deadline to the earliest of `due`
    /// (the instants an activity of the port ends, offered already) and the instants the fresh
    /// values expire. Hands `on_value` the new output if it changed and there is one; returns
    /// whether it changed. Costs a pass over the port's connections and one over the
    /// contributors.
    pub(crate) fn combine(
        &mut self,
        slots: &[ValueSlot],
        lets_through: u32,
        mut due: Earliest,
        now: Instant,
        on_value: &mut dyn FnMut(&Combined),
    ) -> bool {
        let own = self.slots(slots);
        let mut contributors = 0u32;
        for (index, slot) in own.iter().enumerate() {
            // Fresh: it carried the fields and is within τ at `now` (a frame after `now`, out of
            // order, counts as simultaneous); it stops counting one µs after τ.
            if slot.has_value
                && now
                    .micros_since(slot.time)
                    .is_none_or(|since| since <= u64::from(slot.tau))
            {
                due.offer(
                    slot.time
                        .wrapping_add_micros(u64::from(slot.tau).saturating_add(1)),
                );
                contributors |= lets_through & 1u32.checked_shl(index as u32).unwrap_or(0);
            }
        }
        self.due = due.get();
        let output = self.winner(own, contributors);
        let changed = self.differs(output);
        self.output = output;
        // A Sum whose newest contributor changed keeps its value: the frame it would carry is
        // that contributor's from now on.
        if changed
            && let Some(output) = output
            && let Some(slot) = own.get(usize::from(output.connection))
        {
            let frame = match self.spec.combine {
                Combine::Sum => summed(&slot.frame, &self.spec.value, output.value),
                _ => slot.frame,
            };
            on_value(&Combined {
                port: self.port,
                connection: output.connection,
                value: output.value,
                frame,
            });
        }
        changed
    }

    /// Whether `new` differs from the last output as the consumer sees it: the value, and but
    /// for Sum (whose frame is the newest one's anyway) the connection.
    fn differs(&self, new: Option<Output>) -> bool {
        match (self.output, new) {
            (Some(old), Some(new)) if self.spec.combine == Combine::Sum => old.value != new.value,
            (old, new) => old != new,
        }
    }

    /// The output the contributors give (see the module's documentation). One pass over the
    /// contributors, on the values and keys read when their frames were stored: for Sum the
    /// total; else each contributor's key replaces the best so far only when strictly greater,
    /// so ties keep the lower index, or for Priority the incumbent, which is examined first.
    fn winner(&self, own: &[ValueSlot], contributors: u32) -> Option<Output> {
        if contributors == 0 {
            return None;
        }
        let combine = self.spec.combine;
        if combine == Combine::Sum {
            return self.sum(own, contributors);
        }
        let mut best: Option<(u8, u32)> = None;
        if combine == Combine::Priority
            && let Some(output) = self.output
            && contributors & 1u32.checked_shl(u32::from(output.connection)).unwrap_or(0) != 0
            && let Some(slot) = own.get(usize::from(output.connection))
        {
            best = Some((output.connection, slot.key));
        }
        let mut rest = contributors;
        while rest != 0 {
            let index = rest.trailing_zeros() as u8;
            rest &= rest - 1;
            let slot = own.get(usize::from(index))?;
            if best.is_none_or(|(_, kept)| slot.key > kept) {
                best = Some((index, slot.key));
            }
        }
        let (connection, _) = best?;
        let slot = own.get(usize::from(connection))?;
        Some(Output {
            connection,
            value: self.spec.value.decode(slot.raw),
        })
    }

    /// [`ValueState::winner`] for Sum: the total saturated to the field's range, and the newest
    /// contributor (the last one stored if it contributes, else the latest instant, ties to the
    /// lower index).
    // Left to the inliner (its one caller, `ValueState::winner`): out of line it took 108
    // bytes more of both boards' flash, and a value port's frame cost more (value-sum-8 1 635
    // instructions, 1 607 inlined; value-min-3 980, 974 inlined).
    fn sum(&self, own: &[ValueSlot], contributors: u32) -> Option<Output> {
        let field = self.spec.value;
        // At most 32 terms of 32 bits: the total cannot overflow an i64.
        let mut total = 0i64;
        let mut rest = contributors;
        while rest != 0 {
            let index = rest.trailing_zeros();
            rest &= rest - 1;
            total = total.wrapping_add(field.decode(own.get(index as usize)?.raw));
        }
        let connection =
            if contributors & 1u32.checked_shl(u32::from(self.newest)).unwrap_or(0) != 0 {
                self.newest
            } else {
                latest(own, contributors)?
            };
        Some(Output {
            connection,
            value: field.saturate(total),
        })
    }
}

/// The contributor whose frame came last (ties to the lower index), for a Sum whose last stored
/// frame does not contribute: a pass of its own, so that the common case's does not carry it.
fn latest(own: &[ValueSlot], contributors: u32) -> Option<u8> {
    let mut latest: Option<(u8, Instant)> = None;
    let mut rest = contributors;
    while rest != 0 {
        let index = rest.trailing_zeros() as u8;
        rest &= rest - 1;
        let slot = own.get(usize::from(index))?;
        if latest
            .is_none_or(|(_, time)| slot.time.micros_since(time).is_some_and(|since| since > 0))
        {
            latest = Some((index, slot.time));
        }
    }
    Some(latest?.0)
}

/// `frame` with `field` replaced by `value` (Sum's output, within the field's range), as Sum hands it over: a data frame of
/// the same identifier and length, the bytes after the payload zero.
// Left to the inliner (its one caller): out of line it took 68 bytes more of both boards' flash,
// and a value port's frame cost more (value-sum-8 1 607 instructions, 1 585 inlined).
fn summed(frame: &Frame, field: &Field, value: i64) -> Frame {
    let mut summed = frame.republished(frame.id());
    field.write_raw(summed.buffer_mut(), value as u32);
    summed
}

impl crate::wire::Decode for Combine {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        match r.variant(4) {
            0 => Combine::Max,
            1 => Combine::Min,
            2 => Combine::Sum,
            _ => Combine::Priority,
        }
    }
}

impl crate::wire::Decode for Endian {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        match r.variant(2) {
            0 => Endian::Little,
            _ => Endian::Big,
        }
    }
}

crate::wire::decode_struct!(Field {
    offset,
    size,
    signed,
    endian
});

impl crate::wire::Decode for ValueSpec {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        ValueSpec {
            combine: r.decode(),
            value: r.decode(),
            priority: r.option(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(offset: u8, size: u8, signed: bool, endian: Endian) -> Field {
        Field {
            offset,
            size,
            signed,
            endian,
        }
    }

    #[test]
    fn fields_read_and_write_both_orders_and_signs() {
        let data = [0x01, 0x80, 0xFF, 0xFE, 0, 0, 0, 0];
        assert_eq!(field(0, 2, false, Endian::Little).read(&data), Some(0x8001));
        assert_eq!(field(0, 2, false, Endian::Big).read(&data), Some(0x0180));
        assert_eq!(
            field(0, 2, true, Endian::Little).read(&data),
            Some(0x8001 - 0x1_0000)
        );
        assert_eq!(field(2, 1, true, Endian::Little).read(&data), Some(-1));
        assert_eq!(field(2, 2, true, Endian::Big).read(&data), Some(-2));
        assert_eq!(
            field(0, 4, false, Endian::Little).read(&data),
            Some(0xFEFF_8001)
        );
        assert_eq!(field(6, 4, false, Endian::Little).read(&data), None);
        assert_eq!(field(6, 2, false, Endian::Little).read(&data[..7]), None);
        let mut out = [0u8; MAX_DATA_LEN];
        field(1, 2, true, Endian::Big).write(&mut out, -2);
        assert_eq!(out[..8], [0, 0xFF, 0xFE, 0, 0, 0, 0, 0]);
        field(4, 4, false, Endian::Little).write(&mut out, 1 << 40);
        assert_eq!(out[..8], [0, 0xFF, 0xFE, 0, 0xFF, 0xFF, 0xFF, 0xFF]);
    }

    #[test]
    fn ranges_and_saturation() {
        assert_eq!(field(0, 1, true, Endian::Little).range(), (-128, 127));
        assert_eq!(field(0, 2, false, Endian::Little).range(), (0, 65_535));
        assert_eq!(
            field(0, 4, true, Endian::Little).range(),
            (i64::from(i32::MIN), i64::from(i32::MAX))
        );
        assert_eq!(field(0, 1, false, Endian::Little).saturate(-5), 0);
        assert_eq!(field(0, 1, false, Endian::Little).saturate(300), 255);
    }

    #[test]
    fn specs_are_validated() {
        let good = field(0, 2, false, Endian::Little);
        let spec = |combine, priority| ValueSpec {
            combine,
            value: good,
            priority,
        };
        assert_eq!(spec(Combine::Max, None).validate(), Ok(()));
        // The last byte of a frame: 7, or 63 with CAN FD.
        const LAST: u8 = MAX_DATA_LEN as u8 - 1;
        assert_eq!(
            spec(Combine::Priority, Some(field(LAST, 1, false, Endian::Big))).validate(),
            Ok(())
        );
        assert_eq!(
            spec(Combine::Priority, None).validate(),
            Err(ValueError::PriorityMissing)
        );
        assert_eq!(
            spec(Combine::Sum, Some(good)).validate(),
            Err(ValueError::PriorityNotAllowed)
        );
        assert_eq!(
            spec(Combine::Priority, Some(field(LAST, 2, false, Endian::Big))).validate(),
            Err(ValueError::Priority(FieldError::OutOfFrame {
                offset: LAST,
                size: 2
            }))
        );
        let bad = ValueSpec {
            combine: Combine::Min,
            value: field(0, 3, false, Endian::Little),
            priority: None,
        };
        assert_eq!(
            bad.validate(),
            Err(ValueError::Value(FieldError::BadSize { size: 3 }))
        );
    }
}

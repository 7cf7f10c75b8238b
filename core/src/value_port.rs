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
//! Memory (fixed, whatever the table): [`MAX_VALUE_CONNECTIONS`] connection records of 32 bytes
//! (the last frame, its instant, τ, the connection's root) and [`MAX_VALUE_PORTS`] port records of
//! 40 bytes, 672 bytes per arbiter; in the table, [`ValueSpec`] in every port record and a 2-byte
//! root per connection of capacity.

use serde::{Deserialize, Serialize};

use crate::decision::NodeRef;
use crate::frame::{Frame, MAX_DATA_LEN};
use crate::time::Instant;

/// Value ports per node, over all its ports. A table with more is refused
/// ([`crate::TableError::TooManyValuePorts`]).
pub const MAX_VALUE_PORTS: usize = 4;
/// Connections of value ports per node, over all its value ports. A table with more is refused
/// ([`crate::TableError::TooManyValueConnections`]). 16 records of 32 bytes: 512 bytes of RAM
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
pub enum FieldError {
    /// Its size is not 1, 2 or 4.
    BadSize {
        /// The size found.
        size: u8,
    },
    /// It does not fit a classic CAN frame: offset + size > 8.
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
            FieldError::OutOfFrame { offset, size } => write!(
                f,
                "offset {offset} + size {size} is beyond the 8 bytes of a frame"
            ),
        }
    }
}

impl Field {
    /// Checks the size and that the field fits 8 bytes. One comparison or two.
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
    /// field is invalid). At most four byte loads.
    #[inline(never)]
    pub fn read(&self, payload: &[u8]) -> Option<i64> {
        let start = usize::from(self.offset);
        let bytes = payload.get(start..start.checked_add(usize::from(self.size))?)?;
        let mut raw = 0u32;
        match self.endian {
            Endian::Big => {
                for &byte in bytes {
                    raw = (raw << 8) | u32::from(byte);
                }
            }
            Endian::Little => {
                for &byte in bytes.iter().rev() {
                    raw = (raw << 8) | u32::from(byte);
                }
            }
        }
        Some(match (self.signed, self.size) {
            (false, _) => i64::from(raw),
            (true, 1) => i64::from(raw as u8 as i8),
            (true, 2) => i64::from(raw as u16 as i16),
            (true, _) => i64::from(raw as i32),
        })
    }

    /// The smallest and largest values the field holds.
    pub const fn range(&self) -> (i64, i64) {
        let bits = match self.size {
            1 => 8,
            2 => 16,
            _ => 32,
        };
        if self.signed {
            (-(1i64 << (bits - 1)), (1i64 << (bits - 1)) - 1)
        } else {
            (0, (1i64 << bits) - 1)
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
        let raw = self.saturate(value) as u32;
        let size = usize::from(self.size);
        let start = usize::from(self.offset);
        let Some(bytes) = start
            .checked_add(size)
            .and_then(|end| data.get_mut(start..end))
        else {
            return;
        };
        let little = raw.to_le_bytes();
        for (k, byte) in bytes.iter_mut().enumerate() {
            let from = match self.endian {
                Endian::Little => k,
                Endian::Big => size.saturating_sub(1).saturating_sub(k),
            };
            *byte = little.get(from).copied().unwrap_or(0);
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

    /// Whether `payload` carries every field the port reads.
    fn carries(&self, payload: &[u8]) -> bool {
        self.value.read(payload).is_some()
            && self
                .priority
                .is_none_or(|priority| priority.read(payload).is_some())
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

/// One connection of a value port at run time. 32 bytes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ValueSlot {
    /// Its last frame.
    frame: Frame,
    /// When it came.
    time: Instant,
    /// τ in µs: the frame counts until `time + τ`.
    tau: u32,
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
            root,
            has_value: false,
        }
    }

    /// Whether its last frame carried the fields and is within τ at `now` (a frame after `now`,
    /// out of order, counts as simultaneous).
    fn is_fresh(&self, now: Instant) -> bool {
        self.has_value
            && now
                .micros_since(self.time)
                .is_none_or(|since| since <= u64::from(self.tau))
    }

    /// The instant its value stops counting, if it is counting at `now`.
    fn expiry(&self, now: Instant) -> Option<Instant> {
        self.is_fresh(now).then(|| {
            self.time
                .wrapping_add_micros(u64::from(self.tau).saturating_add(1))
        })
    }
}

/// The last output of a value port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Output {
    connection: u8,
    value: i64,
}

/// A value port at run time: where its connections are among the value slots, what it reads,
/// its last output and its next deadline.
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

    /// Records `frame`, received at `now`, as the last frame of the connections in `fed`.
    /// Returns whether it carried the fields (false: refused, it replaced their values by none).
    pub(crate) fn store(
        &mut self,
        slots: &mut [ValueSlot],
        fed: u32,
        frame: &Frame,
        now: Instant,
    ) -> bool {
        let carries = self.spec.carries(frame.payload());
        let mut newest = None;
        for (index, slot) in self.slots_mut(slots).iter_mut().enumerate() {
            if fed & 1u32.checked_shl(index as u32).unwrap_or(0) != 0 {
                slot.frame = *frame;
                slot.time = now;
                slot.has_value = carries;
                newest = Some(index);
            }
        }
        if carries && let Some(index) = newest.and_then(|index| u8::try_from(index).ok()) {
            self.newest = index;
        }
        carries
    }

    /// Combines the contributors at `now`: those of `lets_through` (the connections whose rule
    /// lets them through) whose value is fresh. Sets the next deadline to the earliest of `lapse`
    /// (when an activity of the port ends) and the instants the fresh values expire. Returns
    /// whether the output changed, and the new output if it changed and there is one. Costs a
    /// pass over the port's connections.
    pub(crate) fn combine(
        &mut self,
        slots: &[ValueSlot],
        lets_through: u32,
        lapse: Option<Instant>,
        now: Instant,
    ) -> (bool, Option<Combined>) {
        let before = *self;
        let combined = self.recombine(slots, lets_through, lapse, now);
        (before.differs(self.output), combined)
    }

    /// Whether `new` differs from the last output as the consumer sees it: the value, and but
    /// for Sum (whose frame is the newest one's anyway) the connection.
    fn differs(&self, new: Option<Output>) -> bool {
        match (self.output, new) {
            (Some(old), Some(new)) if self.spec.combine == Combine::Sum => old.value != new.value,
            (old, new) => old != new,
        }
    }

    fn recombine(
        &mut self,
        slots: &[ValueSlot],
        lets_through: u32,
        lapse: Option<Instant>,
        now: Instant,
    ) -> Option<Combined> {
        let own = self.slots(slots);
        let mut due = lapse;
        let mut contributors = 0u32;
        for (index, slot) in own.iter().enumerate() {
            if let Some(expiry) = slot.expiry(now) {
                due = Some(earliest(due, expiry, now));
                if lets_through & 1u32.checked_shl(index as u32).unwrap_or(0) != 0 {
                    contributors |= 1u32.checked_shl(index as u32).unwrap_or(0);
                }
            }
        }
        self.due = due;
        let output = self.winner(own, contributors);
        if !self.differs(output) {
            // A Sum whose newest contributor changed keeps its value: the frame it would carry
            // is that contributor's from now on.
            self.output = output;
            return None;
        }
        self.output = output;
        let output = output?;
        let slot = own.get(usize::from(output.connection))?;
        let frame = match self.spec.combine {
            Combine::Sum => {
                let mut data = [0u8; MAX_DATA_LEN];
                let payload = slot.frame.payload();
                data.get_mut(..payload.len())?.copy_from_slice(payload);
                self.spec.value.write(&mut data, output.value);
                let len = u8::try_from(payload.len()).unwrap_or(0);
                Frame::from_buffer(slot.frame.id(), data, len)
            }
            _ => slot.frame,
        };
        Some(Combined {
            port: self.port,
            connection: output.connection,
            value: output.value,
            frame,
        })
    }

    /// The output the contributors give (see the module's documentation). One pass: each
    /// contributor's key (its value for Max, its negated value for Min, its priority) replaces
    /// the best so far only when strictly greater, so ties keep the lower index, or for
    /// Priority the incumbent, which is examined first.
    fn winner(&self, own: &[ValueSlot], contributors: u32) -> Option<Output> {
        let combine = self.spec.combine;
        let key_field = match (combine, self.spec.priority) {
            (Combine::Priority, Some(priority)) => priority,
            _ => self.spec.value,
        };
        let incumbent = match (combine, self.output) {
            (Combine::Priority, Some(output)) => {
                let bit = 1u32.checked_shl(u32::from(output.connection)).unwrap_or(0);
                (contributors & bit != 0).then_some(output.connection)
            }
            _ => None,
        };
        // (connection, key, value); for Sum, the newest contributor and its instant.
        let mut best: Option<(u8, i64, i64)> = None;
        let mut newest: Option<(u8, Instant)> = None;
        let mut total = 0i64;
        let mut rest = contributors;
        let mut next = incumbent;
        loop {
            let index = match next.take() {
                Some(index) => index,
                None if rest != 0 => {
                    let index = rest.trailing_zeros() as u8;
                    rest &= rest - 1;
                    if Some(index) == incumbent {
                        continue;
                    }
                    index
                }
                None => break,
            };
            let slot = own.get(usize::from(index))?;
            let payload = slot.frame.payload();
            let value = self.spec.value.read(payload)?;
            if combine == Combine::Sum {
                total = total.saturating_add(value);
                // The newest frame: the last one stored, else the latest instant (ties to the
                // lower index).
                let later = newest.is_none_or(|(kept, time)| {
                    kept != self.newest
                        && (index == self.newest
                            || slot.time.micros_since(time).is_some_and(|d| d > 0))
                });
                if later {
                    newest = Some((index, slot.time));
                }
                continue;
            }
            let key = match combine {
                Combine::Min => value.saturating_neg(),
                Combine::Priority => key_field.read(payload)?,
                _ => value,
            };
            if best.is_none_or(|(_, kept, _)| key > kept) {
                best = Some((index, key, value));
            }
        }
        if combine == Combine::Sum {
            let (connection, _) = newest?;
            return Some(Output {
                connection,
                value: self.spec.value.saturate(total),
            });
        }
        best.map(|(connection, _, value)| Output { connection, value })
    }
}

/// The earlier of `current` and `candidate`, both at or after `now` (wrap-safe).
pub(crate) fn earliest(current: Option<Instant>, candidate: Instant, now: Instant) -> Instant {
    match current {
        Some(current) => {
            let to_current = current.micros_since(now).unwrap_or(0);
            let to_candidate = candidate.micros_since(now).unwrap_or(0);
            if to_candidate < to_current {
                candidate
            } else {
                current
            }
        }
        None => candidate,
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
        let mut out = [0u8; 8];
        field(1, 2, true, Endian::Big).write(&mut out, -2);
        assert_eq!(out, [0, 0xFF, 0xFE, 0, 0, 0, 0, 0]);
        field(4, 4, false, Endian::Little).write(&mut out, 1 << 40);
        assert_eq!(out, [0, 0xFF, 0xFE, 0, 0xFF, 0xFF, 0xFF, 0xFF]);
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
        assert_eq!(
            spec(Combine::Priority, None).validate(),
            Err(ValueError::PriorityMissing)
        );
        assert_eq!(
            spec(Combine::Sum, Some(good)).validate(),
            Err(ValueError::PriorityNotAllowed)
        );
        assert_eq!(
            spec(Combine::Priority, Some(field(7, 2, false, Endian::Big))).validate(),
            Err(ValueError::Priority(FieldError::OutOfFrame {
                offset: 7,
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

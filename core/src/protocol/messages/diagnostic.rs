//! The diagnostic stream: one connection's stimulation per frame, and the command that
//! switches it.

/// Flags of a [`DiagnosticSample`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DiagnosticFlags {
    /// The connection is active (its stimulation crossed the threshold and has not decayed).
    pub active: bool,
    /// The connection is resting (ignoring frames during its rest time).
    pub resting: bool,
    /// The port's decision selects this connection: it is the current deliverer.
    pub delivering: bool,
    /// This is the last sample of the round (the round's samples share a sequence number).
    pub end_of_round: bool,
}

impl DiagnosticFlags {
    pub(super) const fn bits(self) -> u8 {
        (self.active as u8)
            | (self.resting as u8) << 1
            | (self.delivering as u8) << 2
            | (self.end_of_round as u8) << 3
    }

    pub(super) const fn from_bits(bits: u8) -> Option<DiagnosticFlags> {
        if bits & !0b1111 != 0 {
            return None;
        }
        Some(DiagnosticFlags {
            active: bits & 1 != 0,
            resting: bits & 2 != 0,
            delivering: bits & 4 != 0,
            end_of_round: bits & 8 != 0,
        })
    }
}

/// One connection's state (service 0x06), when the diagnostic stream is on. A round covers every
/// connection of the selected ports, in port then connection order, at the requested rate.
///
/// ```text
/// byte 0     port index
/// byte 1     connection index within the port
/// byte 2     flags: bit 0 active, bit 1 resting, bit 2 delivering, bit 3 end of round
/// byte 3     round sequence number, wrapping
/// bytes 4-7  stimulation S in Q1.31 (2^31 = 1.0), u32 LE
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DiagnosticSample {
    /// The port.
    pub port: u8,
    /// The connection within the port.
    pub connection: u8,
    /// Activity and selection.
    pub flags: DiagnosticFlags,
    /// The round this sample belongs to.
    pub sequence: u8,
    /// S in Q1.31.
    pub level: u32,
}

impl DiagnosticSample {
    /// S as a number in [0, 1].
    pub fn level_f32(&self) -> f32 {
        self.level as f32 / (1u64 << 31) as f32
    }
}

/// Switches a node's diagnostic stream (service 0x10), tool → node or broadcast.
///
/// ```text
/// bytes 0-1  rounds per second, u16 LE; 0 switches the stream off; at most MAX_RATE_HZ
/// bytes 2-3  ports to sample, bit i = port i, u16 LE
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DiagnosticControl {
    /// Rounds per second, 0 = off.
    pub rate_hz: u16,
    /// Ports to sample.
    pub ports: u16,
}

impl DiagnosticControl {
    /// The highest rate a node accepts (a higher request is refused as malformed).
    pub const MAX_RATE_HZ: u16 = 200;
}

use crate::protocol::Service;
use crate::protocol::layout::{Field, Layout, Scale};

impl DiagnosticSample {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Diagnostic,
        &[
            Field::new("port", 0, 8, "port index in the node's table"),
            Field::new("connection", 8, 8, "connection index within the port"),
            Field::new("active", 16, 1, "1: the connection is active"),
            Field::new("resting", 17, 1, "1: the connection is in its rest time"),
            Field::new(
                "delivering",
                18,
                1,
                "1: the port's decision selects this connection",
            ),
            Field::new("end_of_round", 19, 1, "1: the last sample of the round"),
            Field::new(
                "sequence",
                24,
                8,
                "round sequence number, shared by the round's samples, wrapping",
            ),
            Field::new(
                "level",
                32,
                32,
                "stimulation S in 0..1 (Q1.31 on the wire: raw 2^31 = 1.0)",
            )
            .scale(Scale::Q31)
            .max(1)
            .unit("S"),
        ],
        "one connection's stimulation; while the stream is on, one round (a sample per \
         connection of the selected ports, one sequence number, the last flagged end_of_round) \
         at the requested rate.",
    );
}

impl DiagnosticControl {
    /// The payload's layout (to a node with a key, 4 more bytes: the tag).
    pub const LAYOUT: Layout = Layout::fixed(
        Service::DiagnosticControl,
        &[
            Field::new(
                "rate",
                0,
                16,
                "rounds per second, 0 switches the stream off, at most 200",
            )
            .unit("Hz")
            .max(DiagnosticControl::MAX_RATE_HZ as u32),
            Field::new("ports", 16, 16, "ports to sample: bit i = port i"),
        ],
        "switches the diagnostic stream; the node refuses rates above 200. To a node with a \
         key, the frame is 8 bytes: these 4 and a 4-byte tag over the node's challenge.",
    );
}

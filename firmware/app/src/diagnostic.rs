//! The diagnostic stream: when the tool switches it on, the node sends, at the requested rate, a
//! round of samples (one [`DiagnosticSample`] per connection of the selected ports) read from the
//! arbiter at the moment each sample is sent.
//!
//! A round is produced lazily, one sample at a time as the transmit queue has room, so a node with
//! hundreds of connections needs no buffer for a whole round and never crowds out its heartbeat or
//! faults. A round that is still being sent when the next is due makes the node skip that next
//! round (the stream degrades in rate, not in content).

use pab_core::protocol::{DiagnosticControl, DiagnosticFlags, DiagnosticSample};
use pab_core::{Arbiter, Instant};

/// Where the stream is. 24 bytes.
#[derive(Clone, Debug, Default)]
pub struct DiagnosticStream {
    period_us: Option<u64>,
    ports: u16,
    next_round: Instant,
    cursor: Option<(u8, u8)>,
    sequence: u8,
}

impl DiagnosticStream {
    /// Applies a [`DiagnosticControl`]: rate 0 switches the stream off; otherwise the first round
    /// starts now. The caller has checked the rate against [`DiagnosticControl::MAX_RATE_HZ`].
    pub fn configure(&mut self, control: DiagnosticControl, now: Instant) {
        self.cursor = None;
        if control.rate_hz == 0 || control.ports == 0 {
            self.period_us = None;
            return;
        }
        self.period_us = Some(1_000_000 / u64::from(control.rate_hz));
        self.ports = control.ports;
        self.next_round = now;
    }

    /// The stream's setting (round period in µs, ports) if it is on: for
    /// [`crate::AuthProbe`]. Inline: compiled only where a test or fuzz target calls it.
    #[inline]
    pub(crate) fn setting(&self) -> Option<(u64, u16)> {
        self.period_us.map(|period| (period, self.ports))
    }

    /// Whether the stream is on.
    pub fn is_on(&self) -> bool {
        self.period_us.is_some()
    }

    /// Stops the stream (a new table changes the ports it would sample).
    pub fn restart_round(&mut self) {
        self.cursor = None;
    }

    /// When the stream next needs the node's attention: now while a round is in progress, the next
    /// round's start otherwise.
    pub fn deadline(&self, now: Instant) -> Option<Instant> {
        self.period_us?;
        Some(if self.cursor.is_some() {
            now
        } else {
            self.next_round
        })
    }

    /// The next sample to send at `now`, if one is due.
    pub fn next_sample<const P: usize, const C: usize, const N: usize>(
        &mut self,
        arbiter: &Arbiter<P, C, N>,
        now: Instant,
    ) -> Option<DiagnosticSample> {
        let period = self.period_us?;
        let (port, connection) = match self.cursor {
            Some(cursor) => cursor,
            None => {
                // Not yet time for the next round.
                let late = now.micros_since(self.next_round)?;
                // Schedule from the nominal start, unless we fell more than a period behind
                // (then from now, skipping the missed rounds).
                self.next_round = if late <= period {
                    self.next_round.wrapping_add_micros(period)
                } else {
                    now.wrapping_add_micros(period)
                };
                self.sequence = self.sequence.wrapping_add(1);
                self.first_from(arbiter, 0)?
            }
        };
        let active = arbiter.activity(port, now).contains(connection);
        let sample = DiagnosticSample {
            port,
            connection,
            flags: DiagnosticFlags {
                active,
                resting: arbiter.is_resting(port, connection, now),
                delivering: arbiter.selected(port, now) == Some(connection),
                end_of_round: false,
            },
            sequence: self.sequence,
            level: arbiter
                .level(port, connection, now)
                .map_or(0, |level| level.raw()),
        };
        // Advance: next connection of this port, else the first connection of the next port.
        let next_connection = connection.saturating_add(1);
        self.cursor = if usize::from(next_connection) < arbiter.connection_count(port) {
            Some((port, next_connection))
        } else {
            port.checked_add(1)
                .and_then(|next| self.first_from(arbiter, next))
        };
        Some(DiagnosticSample {
            flags: DiagnosticFlags {
                end_of_round: self.cursor.is_none(),
                ..sample.flags
            },
            ..sample
        })
    }

    /// The first sampled connection at or after port `from`.
    fn first_from<const P: usize, const C: usize, const N: usize>(
        &self,
        arbiter: &Arbiter<P, C, N>,
        from: u8,
    ) -> Option<(u8, u8)> {
        (from..16)
            .filter(|&port| usize::from(port) < arbiter.port_count())
            .find(|&port| self.ports & (1 << port) != 0 && arbiter.connection_count(port) > 0)
            .map(|port| (port, 0))
    }
}

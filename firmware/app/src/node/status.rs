//! What a node says of itself: the heartbeat group, faults (rate-limited) and the diagnostic
//! stream.

use super::outbox::enqueue_cold;
use super::*;

impl<const P: usize, const C: usize, const N: usize, const IMG: usize> Node<P, C, N, IMG> {
    /// The heartbeat group, and the next one's instant.
    // Left to the inliner: out of line it took 40 bytes more of the NUCLEO-G474RE's flash, 36
    // of the emulated board's (a heartbeat group 9 instructions more); the frame path's counts
    // are the same either way.
    pub(super) fn heartbeat_due(&mut self, now: Instant) {
        self.heartbeat(now);
        let next = self
            .next_heartbeat
            .wrapping_add_micros(self.config.heartbeat_period_us);
        // After a long stall, resume from now instead of sending a burst of heartbeats.
        self.next_heartbeat = match next.micros_since(now) {
            Some(_) => next,
            None => now.wrapping_add_micros(self.config.heartbeat_period_us),
        };
    }

    /// The faults due at `now`, as the outbox has room.
    #[inline(never)]
    pub(super) fn send_faults(&mut self, now: Instant) {
        while self.outbox.len() < OUTBOX_LEN {
            let Some(fault) = self.faults.next_due(now) else {
                break;
            };
            self.send(Message::Fault(fault), protocol::BROADCAST);
        }
    }

    /// The diagnostic samples due at `now`, as the outbox has room beyond what it keeps for
    /// everything else.
    #[inline(never)]
    pub(super) fn send_samples(&mut self, now: Instant) {
        if let Some(arbiter) = self.arbiter.as_ref() {
            while self.outbox.len() + DIAGNOSTIC_RESERVE < OUTBOX_LEN {
                let Some(sample) = self.diagnostic.next_sample(arbiter, now) else {
                    break;
                };
                let Some(frame) = Message::Diagnostic(sample)
                    .report_frame(self.config.node_id, protocol::BROADCAST)
                else {
                    break;
                };
                if enqueue_cold(&mut self.outbox, frame).is_err() {
                    break;
                }
            }
        }
    }

    pub(super) fn heartbeat(&mut self, now: Instant) {
        // An unassigned node says only who it is (when asked).
        #[cfg(feature = "identity")]
        if self.me.unassigned {
            return;
        }
        let uptime_s = now.micros_since(self.booted).map_or(0, |micros| {
            u32::try_from(micros / 1_000_000).unwrap_or(u32::MAX)
        });
        let running = self.running;
        let state = self.state();
        let diagnostic = self.diagnostic.is_on();
        self.send(
            Message::Heartbeat(Heartbeat {
                state,
                uptime_s,
                table_version: running.map_or(0, |r| r.header.table_version),
            }),
            protocol::BROADCAST,
        );
        self.send(
            Message::TableStatus(TableStatus {
                crc: running.map_or(0, |r| r.header.crc),
                image_len: running.map_or(0, |r| u16::try_from(r.image_len).unwrap_or(u16::MAX)),
                ports: self
                    .arbiter
                    .as_ref()
                    .map_or(0, |a| u8::try_from(a.port_count()).unwrap_or(u8::MAX)),
                stored: running.is_some_and(|r| r.stored),
                diagnostic,
                keyed: self.guard.is_keyed(),
            }),
            protocol::BROADCAST,
        );
        let counters = self.counters;
        self.send(
            Message::Traffic(Traffic {
                received: counters.received,
                delivered: counters.delivered,
            }),
            protocol::BROADCAST,
        );
        self.send(
            Message::Errors(Errors {
                discarded: counters.discarded,
                errors: counters.errors,
            }),
            protocol::BROADCAST,
        );
        self.send_filter_status();
        if self.arbiter.is_none()
            && let Some(detail) = self.boot_fault
        {
            self.raise(FaultCode::BadStoredTable, detail);
        }
        if let Some(reason) = self.guard.locked() {
            self.raise(FaultCode::KeyPageInvalid, [reason, 0, 0, 0, 0]);
        }
    }

    pub(super) fn raise(&mut self, code: FaultCode, detail: [u8; 5]) {
        self.faults.raise(code, detail);
    }

    /// An error: counted ([`Counters::errors`]), and its fault raised. Out of line: one copy of
    /// the count for its seven callers.
    #[inline(never)]
    pub(super) fn error(&mut self, code: FaultCode, detail: [u8; 5]) {
        self.counters.errors = self.counters.errors.wrapping_add(1);
        self.raise(code, detail);
    }

    #[inline(never)]
    pub(super) fn configure_diagnostic(
        &mut self,
        control: protocol::DiagnosticControl,
        now: Instant,
    ) {
        self.diagnostic.configure(control, now);
        info!(
            "diagnostic stream at {} Hz",
            int(u32::from(control.rate_hz))
        );
    }
}

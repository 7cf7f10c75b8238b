//! What a node says and hears to coordinate with the others: HBBA's exploitation edges and filter
//! answers, the dynamics' steps and Gates, BLE claims.

use super::*;
use pab_core::seal::{Refusal, Verdict};

impl<const P: usize, const C: usize, const N: usize, const IMG: usize> Node<P, C, N, IMG> {
    /// HBBA's exploitation edges: for each port whose delivering connection (the one its
    /// decision selects) changed since the last look, the one that stopped and the one that
    /// started. Only on a table with message filters.
    #[inline(never)]
    pub(super) fn exploitation(&mut self, now: Instant) {
        let Some(arbiter) = self.arbiter.as_ref() else {
            return;
        };
        let mut edges: heapless::Vec<Exploitation, { 2 * pab_core::MAX_PORTS }> =
            heapless::Vec::new();
        for (port, last) in self.exploited.iter_mut().enumerate() {
            let port = port as u8;
            let now_selected = arbiter.selected(port, now);
            if now_selected == *last {
                continue;
            }
            for (connection, delivering) in [(*last, false), (now_selected, true)] {
                if let Some(connection) = connection {
                    let _ = edges.push(Exploitation {
                        port,
                        connection,
                        delivering,
                    });
                }
            }
            *last = now_selected;
        }
        // By reference: the vector's by-value iterator slices, with a bounds check.
        for edge in edges.iter() {
            self.send(Message::Exploitation(*edge), protocol::BROADCAST);
        }
    }

    /// A filter command applied: FilterStatus with its sequence number; refused: FilterRefused
    /// with why, what it named (`what`) and its sequence number, nothing changed.
    pub(super) fn filter_answer(
        &mut self,
        result: Result<(), CommandError>,
        what: [u8; 2],
        sequence: u16,
    ) {
        match result {
            Ok(()) => {
                self.filter_sequence = sequence;
                self.send_filter_status();
            }
            Err(error) => {
                let [s0, s1] = sequence.to_le_bytes();
                self.raise(
                    FaultCode::FilterRefused,
                    [error.code(), what[0], what[1], s0, s1],
                );
            }
        }
    }

    /// FilterStatus: the active profile (or one by one), the last command's sequence number and
    /// the counts; nothing on a table without filters.
    pub(super) fn send_filter_status(&mut self) {
        let Some(arbiter) = self.arbiter.as_ref().filter(|a| a.has_filters()) else {
            return;
        };
        let counts = arbiter.filter_counts();
        let status = FilterStatus {
            profile: arbiter
                .filter_profile()
                .unwrap_or(FilterStatus::SET_ONE_BY_ONE),
            sequence: self.filter_sequence,
            filtered: counts.filtered,
            closed: counts.closed,
            throttled: counts.throttled,
        };
        self.send(Message::FilterStatus(status), protocol::BROADCAST);
    }

    /// The dynamics brought up to `now`: the steps due of the groups the node runs, their
    /// gates queued, and the groups it reads that fell silent reported.
    #[cfg(feature = "dynamics")]
    #[inline(never)]
    pub(super) fn step_dynamics(&mut self, now: Instant) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        if arbiter
            .dynamics_deadline(now)
            .is_some_and(|due| now.micros_since(due).is_none())
        {
            return;
        }
        let skipped = |arbiter: &Arbiter<P, C, N>| {
            arbiter
                .dynamics_runs()
                .iter()
                .map(|run| run.skipped())
                .fold(0u32, u32::saturating_add)
        };
        let before = skipped(arbiter);
        // One Gates frame per group a poll, its last: a poll that catches up several steps may
        // see several changes, and the frames would all leave at this instant, each stale but
        // the last (its `changes` counts them all). The groups are polled one after the other
        // and their numbers differ (the table is validated), so a group's frames come in a row:
        // only the last kept can be the same group's.
        let mut gates: heapless::Vec<protocol::Gates, { dynamics::MAX_DYNAMICS_GROUPS }> =
            heapless::Vec::new();
        // A fault is only recorded, not sent: raised in the poll, no list to keep.
        let faults = &mut self.faults;
        arbiter.dynamics_poll(
            now,
            |_| {},
            |g| match gates.last_mut() {
                Some(kept) if kept.group == g.group => *kept = g,
                _ => {
                    let _ = gates.push(g);
                }
            },
            |l: GatesLost| faults.raise(FaultCode::GatesLost, [l.owner, l.group, 0, 0, 0]),
        );
        let after = skipped(arbiter);
        let late = arbiter
            .dynamics_runs()
            .iter()
            .position(|run| run.skipped() != 0);
        let node_id = self.config.node_id;
        for g in gates.iter() {
            if let Some(frame) = Message::Gates(*g).report_frame(node_id, protocol::BROADCAST) {
                self.queue_sealed(frame, protocol::Service::Gates.code());
            }
        }
        if after != before {
            let [a, b, c, d] = after.to_le_bytes();
            let group = late.and_then(|p| u8::try_from(p).ok()).unwrap_or(0);
            self.raise(FaultCode::DynamicsLate, [a, b, c, d, group]);
        }
    }

    /// Gates from another node: read if the table reads the group, refused with a fault if the
    /// group has another size here.
    #[cfg(feature = "dynamics")]
    #[inline(never)]
    pub(super) fn on_gates(&mut self, source: u8, gates: &protocol::Gates, now: Instant) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        if arbiter.on_gates(source, gates, now).is_err() {
            self.error(
                FaultCode::GatesRefused,
                [source, gates.group, gates.behaviours, 0, 0],
            );
        }
    }

    /// The BLE claims due at `now`, and the holding decisions brought up to it.
    #[inline(never)]
    pub(super) fn send_claims(&mut self, now: Instant) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        // Work due by `now`, seen from the microsecond before: a claim going stale at exactly
        // `now` is a deadline then, where `ble_deadline(now)` counts it as past (and the holding
        // decision would wait for the next claim, a period late). Polling twice in one
        // microsecond changes nothing the second time.
        let before = Instant::from_micros(now.as_micros().wrapping_sub(1));
        if arbiter
            .ble_deadline(before)
            .is_some_and(|due| now.micros_since(due).is_none())
        {
            return;
        }
        // A node is in at most MAX_GROUPS groups: one claim each per poll.
        let mut claims: heapless::Vec<Claim, { ble::MAX_GROUPS }> = heapless::Vec::new();
        arbiter.ble_poll(now, |claim| {
            let _ = claims.push(claim);
        });
        // By reference: the vector's by-value iterator slices, with a bounds check.
        for claim in claims.iter() {
            if let Some(frame) = claim.frame() {
                self.queue_sealed(frame, protocol::Seal::CLAIM);
            }
        }
    }

    /// A peer's BLE claim: held for its seal on a keyed node, else applied.
    pub(super) fn on_claim_frame(&mut self, frame: &Frame, now: Instant) {
        if self.guard.is_keyed() {
            // The source is in the identifier's low 7 bits; a malformed claim is refused when
            // its seal applies it.
            let (raw, _) = frame.raw_id();
            self.hold((raw & 0x7F) as u8, protocol::Seal::CLAIM, frame, now);
        } else {
            self.apply_claim(frame, now);
        }
    }

    /// A peer's BLE claim: kept by the arbiter's group state, or refused with a fault
    /// (ClaimRefused: malformed, this node's own id, no room). Without a table there is no
    /// group to keep it for.
    #[inline(never)]
    pub(super) fn apply_claim(&mut self, frame: &Frame, now: Instant) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        if !arbiter.has_groups() {
            return;
        }
        let (reason, node, group) = match Claim::decode(frame) {
            Err(_) => (1, 0, 0),
            Ok(claim) => match arbiter.on_claim(claim, now) {
                Ok(()) => return,
                Err(BleError::OwnIdClash) => (2, claim.node, claim.group),
                Err(_) => (3, claim.node, claim.group),
            },
        };
        self.error(FaultCode::ClaimRefused, [reason, node, group, 0, 0]);
    }

    /// Queues a coordination frame this node sends (Gates, a claim: `kind`), followed by its
    /// seal on a keyed node ([`pab_core::seal`]).
    #[inline(never)]
    pub(super) fn queue_sealed(&mut self, frame: Frame, kind: u8) {
        self.queue(frame);
        if let Some(seal) = self.guard.seal(self.config.node_id, &frame, kind) {
            self.queue(seal);
        }
    }

    /// Holds a coordination frame from `source` for its seal, refusing the one it pushes out.
    #[inline(never)]
    pub(super) fn hold(&mut self, source: u8, kind: u8, frame: &Frame, now: Instant) {
        let (count, last) = self.guard.hold(source, kind, frame, now);
        if let Some(refusal) = last {
            self.refuse_unsealed(refusal);
            // The fault names the last; the errors count them all (at most `seal::HELD`).
            let more = (count as u32).saturating_sub(1);
            self.counters.errors = self.counters.errors.wrapping_add(more);
        }
    }

    /// A seal from `source`: the frame it seals applied, or refused with a fault; the
    /// freshness request it calls for sent.
    #[inline(never)]
    pub(super) fn on_seal(&mut self, source: u8, seal: &protocol::Seal, now: Instant) {
        let (verdict, request) = self.guard.on_seal(self.config.node_id, source, seal, now);
        if let Some(request) = request {
            self.queue(request);
        }
        match verdict {
            // A sealed frame applies nothing the runner must store.
            Verdict::Accepted(frame) => {
                if seal.kind == protocol::Seal::CLAIM {
                    self.apply_claim(&frame, now);
                } else {
                    let _ = self.on_protocol_frame(&frame, now, true);
                }
            }
            Verdict::Refused(refusal) => self.refuse_unsealed(refusal),
            Verdict::Nothing | Verdict::Synchronised => {}
        }
    }

    /// A coordination frame refused by sealing's rules: counted, and an `Unauthenticated` fault
    /// naming why, what and from whom.
    fn refuse_unsealed(&mut self, refusal: Refusal) {
        self.error(
            FaultCode::Unauthenticated,
            [refusal.reason.code(), refusal.kind, refusal.source, 0, 0],
        );
    }
}

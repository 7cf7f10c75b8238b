//! Worst-case response times of CAN frame streams: Davis, Burns, Bril and Lukkien, "Controller
//! Area Network (CAN) schedulability analysis: refuted, revisited and revised", Real-Time
//! Systems 35(3), 2007 (the revised analysis of its section 5), for classic CAN and CAN FD.
//!
//! A pure function of the streams: no network, no file. Every quantity is a whole number of
//! time units, so the arithmetic is exact: on a classic bus the bit time (τ_bit = 1), on a CAN FD
//! bus a unit in which both the nominal and the data-phase bit are whole
//! ([`TimeBase`](crate::can_frame::TimeBase)), τ_bit the nominal bit's units (arbitration is at
//! the nominal rate). The caller converts its seconds to units, rounding each the safe way
//! (periods and deadlines down, jitter up).
//!
//! For a stream m with transmission time C_m, period (shortest time between two frames) T_m,
//! queuing jitter J_m and deadline D_m:
//!
//! - blocking B_m = the longest frame of a lower-priority stream (a frame on the bus is never
//!   preempted);
//! - the level-m busy period t_m = B_m + Σ_{k ∈ hep(m)} ⌈(t_m + J_k)/T_k⌉·C_k, hep(m) the streams
//!   of higher or equal priority, m included;
//! - the instances in it, q = 0 .. Q_m − 1, Q_m = ⌈(t_m + J_m)/T_m⌉, each with the queuing delay
//!   w_m(q) = B_m + q·C_m + Σ_{k ∈ hp(m)} ⌈(w_m(q) + J_k + τ_bit)/T_k⌉·C_k and the response time
//!   R_m(q) = J_m + w_m(q) − q·T_m + C_m;
//! - R_m = max over q of R_m(q); the stream meets its deadline when R_m ≤ D_m.
//!
//! Streams of equal priority (the same arbitration key: BLE claims, whose identifiers carry an
//! eligibility that changes at run time, rank among themselves only at run time) count each
//! other both as higher priority (interference) and as lower (blocking): the worst of either
//! order. A **background** stream (a table transfer, whose consecutive frames the node's flow
//! control lets come back to back) takes the bus whenever nothing ranks above it: it blocks the
//! streams above it by one frame, and leaves the streams at or below its rank no bound at all.
//!
//! C with worst-case bit stuffing (Davis et al. eq. 2, the DESIGN's): a classic data frame of s
//! bytes takes g + 8s + 13 + ⌊(g + 8s − 1)/4⌋ bits, g = 34 for an 11-bit identifier and 54 for a
//! 29-bit one: 55 + 10s and 80 + 10s bits for s = 0..=8 (135 and 160 for 8 bytes). A CAN FD
//! frame's C is its nominal bits at the nominal rate and its data phase at the data rate
//! ([`crate::can_frame`] derives both from ISO 11898-1:2015's frame format).

pub use crate::can_frame::frame_bits;

/// The longest level-m busy period examined, in time units (2^40: 12.7 days of bit times at 1
/// Mbit/s on a classic bus, at least 18 minutes whatever the rates of a CAN FD bus); a longer one
/// is reported unbounded (a load at or near 100 %).
pub const MAX_BUSY_BITS: u64 = 1 << 40;

/// The most instances of one stream examined in its busy period; more are reported unbounded.
pub const MAX_INSTANCES: u64 = 100_000;

/// The most steps of one fixed-point iteration; more are reported unbounded (a load so near
/// 100 % that the busy period grows by a few bits a step).
pub const MAX_STEPS: u32 = 1_000_000;

/// The order in which the bus arbitrates an identifier: the lower wins. Arbitration compares the
/// bits as sent: an extended identifier's top 11 bits (its base) against a standard one's, then
/// the standard frame's RTR bit (dominant, 0, in a data frame) against the extended frame's SRR
/// (recessive, 1), so a standard frame beats an extended one with the same base; then the
/// extended frame's IDE and its 18 low bits. The key is those bits as one number:
/// `base << 20 | srr << 19 | ide << 18 | low 18 bits`.
pub const fn arbitration_key(id: u32, extended: bool) -> u32 {
    if extended {
        let id = id & 0x1FFF_FFFF;
        ((id >> 18) << 20) | (1 << 19) | (1 << 18) | (id & 0x3FFFF)
    } else {
        (id & 0x7FF) << 20
    }
}

/// A periodic (sporadic) stream of frames, in time units (bit times on a classic bus).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stream {
    /// Its rank on the bus ([`arbitration_key`]): lower wins.
    pub key: u32,
    /// C: one frame's transmission time with worst-case stuffing ([`frame_bits`], or
    /// [`TimeBase::frame`](crate::can_frame::TimeBase::frame)).
    pub bits: u64,
    /// T: the shortest time between two of its frames, at least 1.
    pub period: u64,
    /// J: the queuing jitter.
    pub jitter: u64,
    /// D: the deadline, from the frame's event (its period's start) to its end on the bus.
    pub deadline: u64,
}

/// A stream that takes every bit nothing above it wants (back-to-back frames), in time units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Background {
    /// Its rank on the bus.
    pub key: u32,
    /// One frame's transmission time.
    pub bits: u64,
}

/// A stream's worst-case response time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Response {
    /// R, in time units, and the instance q of the busy period that reached it.
    Bounded {
        /// The worst-case response time.
        r: u64,
        /// B, the blocking.
        blocking: u64,
        /// The busy period's instances examined.
        instances: u64,
    },
    /// No bound: the streams at and above its priority load the bus to 100 % or more, or a
    /// background stream ranks at or above it.
    Unbounded(Unbounded),
}

/// Why a stream has no bound.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unbounded {
    /// The streams at and above its priority load the bus to 100 % or more (their C/T rounded
    /// up to parts per billion), or its busy period grew past [`MAX_BUSY_BITS`], held more than
    /// [`MAX_INSTANCES`] of it, or took more than [`MAX_STEPS`] to find.
    Overload,
    /// Background stream `index` ranks at or above it.
    Background(usize),
}

impl Response {
    /// R in time units, if bounded.
    pub fn bound(&self) -> Option<u64> {
        match *self {
            Response::Bounded { r, .. } => Some(r),
            Response::Unbounded(_) => None,
        }
    }

    /// Whether the deadline `deadline` holds.
    pub fn meets(&self, deadline: u64) -> bool {
        self.bound().is_some_and(|r| r <= deadline)
    }
}

/// The smallest fixed point of `w = base + Σ ⌈(w + extra_k)/T_k⌉·C_k` over `interferers` (each
/// `(C, T, extra)`), from `start`, or `None` past [`MAX_BUSY_BITS`].
fn fixed_point(base: u64, start: u64, interferers: &[(u64, u64, u64)]) -> Option<u64> {
    let mut w = start.max(base);
    for _ in 0..MAX_STEPS {
        let mut next = base;
        for &(c, t, extra) in interferers {
            next = next.checked_add((w + extra).div_ceil(t).checked_mul(c)?)?;
        }
        if next > MAX_BUSY_BITS {
            return None;
        }
        if next == w {
            return Some(w);
        }
        // The right-hand side grows with w: the iteration only ever climbs.
        w = next.max(w);
    }
    None
}

/// The worst-case response time of `streams[m]` among `streams` and `background`, in bit times
/// (τ_bit = 1: a classic bus).
pub fn response(streams: &[Stream], background: &[Background], m: usize) -> Response {
    response_at(streams, background, m, 1)
}

/// The worst-case response time of `streams[m]` among `streams` and `background`, in time units
/// of which a nominal bit is `bit` (τ_bit: a frame queued within one bit after another started
/// its arbitration still takes part in it).
pub fn response_at(streams: &[Stream], background: &[Background], m: usize, bit: u64) -> Response {
    let Some(own) = streams.get(m) else {
        return Response::Unbounded(Unbounded::Overload);
    };
    if let Some(index) = background.iter().position(|b| b.key <= own.key) {
        return Response::Unbounded(Unbounded::Background(index));
    }
    let others = || streams.iter().enumerate().filter(move |&(k, _)| k != m);
    // Lower priority, or equal (the worse of both orders).
    let blocking = others()
        .filter(|(_, s)| s.key >= own.key)
        .map(|(_, s)| s.bits)
        .chain(background.iter().map(|b| b.bits))
        .max()
        .unwrap_or(0);
    let higher: Vec<(u64, u64, u64)> = others()
        .filter(|(_, s)| s.key <= own.key)
        .map(|(_, s)| (s.bits, s.period.max(1), s.jitter + bit))
        .collect();
    // The busy period: hep(m), m included, without the τ_bit.
    let mut hep: Vec<(u64, u64, u64)> = higher.iter().map(|&(c, t, j)| (c, t, j - bit)).collect();
    hep.push((own.bits, own.period.max(1), own.jitter));
    let hep_streams: Vec<Stream> = streams
        .iter()
        .filter(|s| s.key <= own.key)
        .copied()
        .collect();
    if load_ppb(&hep_streams) >= 1_000_000_000 {
        return Response::Unbounded(Unbounded::Overload);
    }
    let Some(busy) = fixed_point(blocking, own.bits, &hep) else {
        return Response::Unbounded(Unbounded::Overload);
    };
    let period = own.period.max(1);
    let instances = (busy + own.jitter).div_ceil(period).max(1);
    if instances > MAX_INSTANCES {
        return Response::Unbounded(Unbounded::Overload);
    }
    let mut worst = 0;
    let mut w = 0;
    for q in 0..instances {
        let base = blocking + q * own.bits;
        // w(q) ≥ w(q − 1) + C: start from there.
        let Some(found) = fixed_point(base, w, &higher) else {
            return Response::Unbounded(Unbounded::Overload);
        };
        w = found;
        let r = (own.jitter + w + own.bits).saturating_sub(q * period);
        worst = worst.max(r);
    }
    Response::Bounded {
        r: worst,
        blocking,
        instances,
    }
}

/// Every stream's response, in order, in bit times.
pub fn responses(streams: &[Stream], background: &[Background]) -> Vec<Response> {
    responses_at(streams, background, 1)
}

/// Every stream's response, in order, in time units of which a nominal bit is `bit`.
pub fn responses_at(streams: &[Stream], background: &[Background], bit: u64) -> Vec<Response> {
    (0..streams.len())
        .map(|m| response_at(streams, background, m, bit))
        .collect()
}

/// The bus load of `streams` (the background left out) in parts per billion, each stream's
/// C/T rounded up: never below the exact load.
pub fn load_ppb(streams: &[Stream]) -> u128 {
    streams
        .iter()
        .map(|s| (u128::from(s.bits) * 1_000_000_000).div_ceil(u128::from(s.period.max(1))))
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn frame_lengths_are_the_worst_case_stuffed_ones() {
        assert_eq!(frame_bits(8, false), 135);
        assert_eq!(frame_bits(8, true), 160);
        assert_eq!(frame_bits(0, false), 55);
        assert_eq!(frame_bits(0, true), 80);
        // A BLE claim: 4 bytes, extended (can-protocol.md: "at most 120").
        assert_eq!(frame_bits(4, true), 120);
        for s in 0..=8u8 {
            assert_eq!(frame_bits(s, false), 55 + 10 * u64::from(s));
            assert_eq!(frame_bits(s, true), 80 + 10 * u64::from(s));
        }
    }

    #[test]
    fn a_standard_frame_wins_over_an_extended_one_with_its_base() {
        // 0x080 standard against the emergency stop 0x0200FF00 (base 0x080): the standard wins
        // (can-protocol.md, "EmergencyStop has the lowest identifiers").
        let stop = arbitration_key(0x0200_FF00, true);
        assert!(arbitration_key(0x080, false) < stop);
        assert!(arbitration_key(0x081, false) > stop);
        assert!(arbitration_key(0x07F, false) < stop);
        // Extended among themselves: their own order.
        assert!(arbitration_key(0x0201_FF03, true) > stop);
        assert!(arbitration_key(0x1202_FF03, true) < arbitration_key(0x1203_FF03, true));
        // Standard among themselves.
        assert!(arbitration_key(0x110, false) < arbitration_key(0x111, false));
    }

    fn stream(key: u32, bits: u64, period: u64) -> Stream {
        Stream {
            key,
            bits,
            period,
            jitter: 0,
            deadline: period,
        }
    }

    /// Davis et al. 2007, section 4: the example that refutes the original analysis, scaled
    /// (frames of 10 bit times, periods 25, 35, 35). Worked by hand for the lowest stream C (no
    /// blocking, A and B above it):
    /// busy period t = ⌈t/25⌉·10 + 2·⌈t/35⌉·10: 10, 30, 40, 60, 70, 70 → t = 70, Q = ⌈70/35⌉ = 2.
    /// q = 0: w = ⌈(w+1)/25⌉·10 + ⌈(w+1)/35⌉·10: 0, 20, 20 → R = 20 + 10 = 30.
    /// q = 1: w = 10 + ...: 10, 30, 40, 50, 60, 60 → R = 60 + 10 − 35 = 35.
    /// R_C = 35: the second instance is the worst (the original analysis stopped at 30).
    /// For A: B = 10 (B's or C's frame), no interference: R = 10 + 10 = 20, one instance.
    /// For B: B = 10, A above: w = 10 + ⌈(w+1)/25⌉·10 = 20, R = 30; busy period
    /// t = 10 + ⌈t/25⌉·10 + ⌈t/35⌉·10: 20, 30, 40, 40 → Q = 2; q = 1: w = 20 + ⌈(w+1)/25⌉·10:
    /// 30, 40, 40 → R = 40 + 10 − 35 = 15; R_B = 30.
    #[test]
    fn the_refuted_example_is_answered_by_its_second_instance() {
        let streams = [stream(1, 10, 25), stream(2, 10, 35), stream(3, 10, 35)];
        let r = responses(&streams, &[]);
        assert_eq!(
            r[2],
            Response::Bounded {
                r: 35,
                blocking: 0,
                instances: 2
            }
        );
        assert_eq!(
            r[0],
            Response::Bounded {
                r: 20,
                blocking: 10,
                instances: 1
            }
        );
        assert_eq!(
            r[1],
            Response::Bounded {
                r: 30,
                blocking: 10,
                instances: 2
            }
        );
        assert!(r[2].meets(35) && !r[2].meets(34));
    }

    #[test]
    fn jitter_adds_to_the_response_and_to_the_interference() {
        let a = |jitter| Stream {
            jitter,
            ..stream(1, 135, 400)
        };
        let b = stream(2, 135, 1000);
        // A, jitter 20: R = J + B + C = 20 + 135 + 135 (B's frame blocks it).
        // B: w = ⌈(w + 21)/400⌉·135: 0, 135, 135 → R = 135 + 135 = 270.
        let r = responses(&[a(20), b], &[]);
        assert_eq!(r[0].bound(), Some(290));
        assert_eq!(r[1].bound(), Some(270));
        // A with jitter 300 queues twice within B's wait: w = ⌈(w + 301)/400⌉·135: 0, 135, 270,
        // 270 → R = 270 + 135 = 405.
        let r = responses(&[a(300), b], &[]);
        assert_eq!(r[1].bound(), Some(405));
        // A alone above 100 %: B has no bound.
        let r = responses(&[stream(1, 135, 100), b], &[]);
        assert_eq!(r[1], Response::Unbounded(Unbounded::Overload));
    }

    #[test]
    fn a_background_stream_blocks_those_above_and_starves_those_below() {
        let streams = [stream(1, 135, 1000), stream(10, 135, 1000)];
        let background = [Background { key: 5, bits: 160 }];
        let r = responses(&streams, &background);
        assert_eq!(r[0].bound(), Some(160 + 135));
        assert_eq!(r[1], Response::Unbounded(Unbounded::Background(0)));
        // The load leaves the background out.
        assert_eq!(load_ppb(&streams), 270_000_000);
    }

    #[test]
    fn equal_keys_interfere_both_ways() {
        let streams = [stream(4, 120, 1000), stream(4, 120, 1000)];
        let r = responses(&streams, &[]);
        // Each: blocked by the other (as lower) and delayed by it (as higher): 120 + 120 + 120.
        assert_eq!(r[0].bound(), Some(360));
        assert_eq!(r[1].bound(), Some(360));
    }

    /// Non-preemptive fixed-priority scheduling of `streams` simulated unit by unit from a
    /// critical instant for stream `m`: the longest lower-priority frame starts at 0, every other
    /// stream queues its first frame at `bit` (one nominal bit later, at its largest jitter: its
    /// event at `bit` − J) and then at its events `bit` − J + n·T; the bus, when free, sends the
    /// queued frame of lowest key (ties: the earlier queued, then the lower index). Returns the
    /// largest response of m (end − event) among its frames queued before `horizon`.
    fn simulate(streams: &[Stream], m: usize, horizon: i64, bit: i64) -> i64 {
        let own = streams[m];
        let blocker = streams
            .iter()
            .enumerate()
            .filter(|&(k, s)| k != m && s.key > own.key)
            .max_by_key(|&(_, s)| s.bits)
            .map(|(k, _)| k);
        // (queued at, event, stream).
        let mut queue: Vec<(i64, i64, usize)> = Vec::new();
        let mut releases: Vec<(i64, i64, usize)> = Vec::new();
        for (k, s) in streams.iter().enumerate() {
            let (t, j) = (s.period as i64, s.jitter as i64);
            let first = if Some(k) == blocker { 0 } else { bit };
            let mut n = 0;
            loop {
                let event = first - j + n * t;
                let queued = if n == 0 { first } else { event.max(first) };
                if queued > horizon {
                    break;
                }
                // The blocker's instance at 0 had no jitter to spend.
                let event = if Some(k) == blocker { n * t } else { event };
                releases.push((queued, event, k));
                n += 1;
            }
        }
        releases.sort();
        let mut next = 0;
        let mut time = 0i64;
        let mut worst = 0;
        loop {
            while next < releases.len() && releases[next].0 <= time {
                queue.push(releases[next]);
                next += 1;
            }
            if queue.is_empty() {
                if next == releases.len() {
                    return worst;
                }
                time = releases[next].0;
                continue;
            }
            let pick = (0..queue.len())
                .min_by_key(|&i| (streams[queue[i].2].key, queue[i].0, queue[i].2))
                .unwrap();
            let (_, event, k) = queue.remove(pick);
            time += streams[k].bits as i64;
            if k == m {
                worst = worst.max(time - event);
            }
        }
    }

    fn arb_stream() -> impl Strategy<Value = Stream> {
        (0u32..6, 0u8..=8, any::<bool>(), 1u64..12, 0u64..100).prop_map(
            |(key, length, extended, periods, jitter)| {
                let bits = frame_bits(length, extended);
                let period = bits * periods + 7 * u64::from(key);
                Stream {
                    key,
                    bits,
                    period,
                    jitter: jitter.min(period / 2),
                    deadline: period,
                }
            },
        )
    }

    /// Streams of classic and CAN FD frames on a 500 kbit/s bus with a 2 Mbit/s data phase, in
    /// its units (a nominal bit 4 units).
    fn arb_fd_stream() -> impl Strategy<Value = Stream> {
        let base = crate::can_frame::TimeBase::new(500_000, Some(2_000_000));
        (
            0u32..6,
            prop::sample::select(vec![0u8, 8, 12, 32, 64]),
            any::<bool>(),
            any::<bool>(),
            1u64..12,
            0u64..400,
        )
            .prop_map(move |(key, length, extended, fd, periods, jitter)| {
                let bits = base.frame(fd || length > 8, length, extended);
                let period = bits * periods + 7 * u64::from(key);
                Stream {
                    key,
                    bits,
                    period,
                    jitter: jitter.min(period / 2),
                    deadline: period,
                }
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// On a CAN FD bus too (units of a data bit, τ_bit 4 units), the analysis is never below
        /// the simulated worst case.
        #[test]
        fn the_fd_bound_is_never_below_the_simulated_worst_case(
            streams in proptest::collection::vec(arb_fd_stream(), 1..6)
        ) {
            let horizon = 8 * streams.iter().map(|s| s.period).max().unwrap_or(1) as i64;
            for m in 0..streams.len() {
                if let Response::Bounded { r, .. } = response_at(&streams, &[], m, 4) {
                    let simulated = simulate(&streams, m, horizon, 4);
                    prop_assert!(
                        r as i64 >= simulated,
                        "stream {m}: analysis {r} < simulated {simulated} in {streams:?}"
                    );
                }
            }
        }

        /// Counting in units of a quarter bit changes nothing but the unit: every quantity times
        /// 4 (τ_bit 4 units) gives every response times 4, exactly.
        #[test]
        fn a_finer_unit_scales_every_response(
            streams in proptest::collection::vec(arb_stream(), 1..6)
        ) {
            let scaled: Vec<Stream> = streams
                .iter()
                .map(|s| Stream {
                    key: s.key,
                    bits: 4 * s.bits,
                    period: 4 * s.period,
                    jitter: 4 * s.jitter,
                    deadline: 4 * s.deadline,
                })
                .collect();
            let background = [Background { key: 3, bits: 160 }];
            let scaled_background = [Background { key: 3, bits: 640 }];
            let bits = responses(&streams, &background);
            let units = responses_at(&scaled, &scaled_background, 4);
            for (b, u) in bits.iter().zip(&units) {
                prop_assert_eq!(b.bound().map(|r| 4 * r), u.bound());
            }
        }

        /// The analysis is never below what a simulation of the bus from a critical instant
        /// shows, for every stream of small random sets.
        #[test]
        fn the_bound_is_never_below_the_simulated_worst_case(
            streams in proptest::collection::vec(arb_stream(), 1..6)
        ) {
            let horizon = 8 * streams.iter().map(|s| s.period).max().unwrap_or(1) as i64;
            for m in 0..streams.len() {
                if let Response::Bounded { r, .. } = response(&streams, &[], m) {
                    let simulated = simulate(&streams, m, horizon, 1);
                    prop_assert!(
                        r as i64 >= simulated,
                        "stream {m}: analysis {r} < simulated {simulated} in {streams:?}"
                    );
                }
            }
        }
    }
}

//! The timed bus (`pabctl sim --timed-bus`, [`super::Options::timed_bus`]): the simulated bus with
//! each frame's transmission time at the network's bit rates, instead of the ideal bus's none.
//!
//! A frame given to the bus (an event's, or one a node sent) waits in its queue; whenever the bus
//! is idle it starts the waiting frame of lowest arbitration rank
//! ([`pab_core::Frame::arbitration_rank`]: the frame that wins arbitration), and carries it for its
//! transmission time, non-preemptively: its actual bits with their actual stuff bits
//! ([`crate::can_frame::transmitted`]), a classic frame's at the nominal rate, a CAN FD frame's
//! data phase at the data rate when it switches (BRS). The bus is busy until the intermission
//! after its EOF has passed; every other node receives the frame when its EOF ends, and what a
//! node sends in answer is queued then. Frames that are waiting when the bus frees compete; a
//! frame queued while another is on the bus waits for it whatever its rank (the bus has no
//! preemption, and here no arbitration with a frame queued after the other's SOF). Frames of
//! the same rank (one identifier) go in the order they were queued.
//!
//! **Time.** The simulator's nodes live in whole microseconds; a frame's bits do not (a bit at 2
//! Mbit/s is 0.5 µs). The bus keeps its own clock in units of 1/lcm(units of the analysis, 10^6)
//! s ([`Clock`]), in which a microsecond, a nominal bit and a data bit are all whole: exact, with
//! the bit times of [`TimeBase`] (the analysis's own). A frame starts at the exact instant the
//! bus is free (or the microsecond it was queued at), ends at its exact bit count, and is handed
//! to the nodes at the microsecond its EOF ends, rounded up: never before it has ended, at most
//! 1 µs after. The latency of a frame ([`Transmission::latency`]) is measured on the bus's clock,
//! exact: the end of its EOF minus the microsecond it was queued at.

use pab_core::Frame;

use crate::can_frame::{TimeBase, Transmitted, transmitted};

/// Who gave a frame to the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sender {
    /// The scenario: an `[[events]]` frame, or a scripted desire to the intention node.
    Scenario,
    /// A node, by its index in the network's nodes.
    Node(usize),
    /// HBBA's intention node.
    Intention,
}

/// The timed bus's clock: units of 1/`per_second` s, in which a microsecond and both kinds of bit
/// are whole numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Clock {
    /// The analysis's time base at the bus's rates: its bits are the bus's.
    pub base: TimeBase,
    /// Units a second: lcm(`base.per_second`, 10^6).
    pub per_second: u128,
}

fn gcd(mut a: u128, mut b: u128) -> u128 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

impl Clock {
    /// The clock of a bus at `bitrate` and, for CAN FD, `data_bitrate` (bit/s).
    pub fn new(bitrate: u32, data_bitrate: Option<u32>) -> Clock {
        let base = TimeBase::new(bitrate, data_bitrate.map(|data| data.max(bitrate)));
        let units = u128::from(base.per_second.max(1));
        Clock {
            base,
            per_second: units / gcd(units, 1_000_000) * 1_000_000,
        }
    }

    /// Units a microsecond.
    pub fn per_us(&self) -> u128 {
        self.per_second / 1_000_000
    }

    /// Units of the clock per unit of the analysis ([`TimeBase`]).
    pub fn per_base_unit(&self) -> u128 {
        self.per_second / u128::from(self.base.per_second.max(1))
    }

    /// Microsecond `t_us` on this clock.
    pub fn at_us(&self, t_us: u64) -> u128 {
        u128::from(t_us) * self.per_us()
    }

    /// `units` of this clock in nanoseconds, rounded up.
    pub fn ns(&self, units: u128) -> u64 {
        u64::try_from((units * 1_000_000_000).div_ceil(self.per_second)).unwrap_or(u64::MAX)
    }

    /// The microsecond in which `units` falls, rounded up: when the nodes see what happened then.
    pub fn ceil_us(&self, units: u128) -> u64 {
        u64::try_from(units.div_ceil(self.per_us())).unwrap_or(u64::MAX)
    }
}

/// One frame the timed bus carried.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Transmission {
    /// The frame.
    pub frame: Frame,
    /// Who gave it to the bus.
    pub sender: Sender,
    /// When it was queued, µs.
    pub queued_us: u64,
    /// When its SOF went out, in [`Clock`] units.
    pub start: u128,
    /// When its EOF ended (the receivers have it), in [`Clock`] units.
    pub end_of_frame: u128,
    /// When the bus was free again, after the intermission, in [`Clock`] units.
    pub end: u128,
    /// The microsecond the nodes received it: `end_of_frame` rounded up.
    pub delivered_us: u64,
    /// Its bits as sent.
    pub bits: Transmitted,
}

impl Transmission {
    /// Its latency, in [`Clock`] units: from when it was queued to the end of its EOF.
    pub fn latency(&self, clock: &Clock) -> u128 {
        self.end_of_frame - clock.at_us(self.queued_us)
    }

    /// How long it waited for the bus, in [`Clock`] units: from when it was queued to its SOF.
    pub fn wait(&self, clock: &Clock) -> u128 {
        self.start - clock.at_us(self.queued_us)
    }
}

/// A frame waiting for the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Waiting {
    /// When it was queued, µs.
    pub queued_us: u64,
    /// Who queued it.
    pub sender: Sender,
    /// The frame.
    pub frame: Frame,
    /// The order it was queued in, for frames of the same rank.
    sequence: u64,
}

/// What the timed bus did in a run ([`super::Outcome::timed`]).
#[derive(Clone, Debug)]
pub struct TimedRun {
    /// Its clock.
    pub clock: Clock,
    /// Every frame it carried, in bus order.
    pub transmissions: Vec<Transmission>,
    /// The frames still waiting for the bus, or on it, when the run ended: no latency.
    pub unsent: Vec<Waiting>,
}

/// The timed bus, running.
pub(super) struct TimedBus {
    clock: Clock,
    transmissions: Vec<Transmission>,
    waiting: Vec<Waiting>,
    on_bus: Option<Transmission>,
    /// When the bus is free, in [`Clock`] units.
    idle_from: u128,
    sequence: u64,
}

impl TimedBus {
    pub fn new(clock: Clock) -> TimedBus {
        TimedBus {
            clock,
            transmissions: Vec::new(),
            waiting: Vec::new(),
            on_bus: None,
            idle_from: 0,
            sequence: 0,
        }
    }

    /// `frame`, from `sender`, waits for the bus from `now_us`.
    pub fn queue(&mut self, now_us: u64, sender: Sender, frame: Frame) {
        self.waiting.push(Waiting {
            queued_us: now_us,
            sender,
            frame,
            sequence: self.sequence,
        });
        self.sequence += 1;
    }

    /// When the next frame starts, if one waits and the bus has none on it: when the bus frees,
    /// or when the first of the waiting frames was queued if later.
    fn next_start(&self) -> Option<u128> {
        if self.on_bus.is_some() {
            return None;
        }
        let first = self.waiting.iter().map(|w| w.queued_us).min()?;
        Some(self.idle_from.max(self.clock.at_us(first)))
    }

    /// The next microsecond at which the bus has something to do: hand the frame on it to the
    /// nodes, or (idle, frames waiting) start the next frame. That one is chosen at the first
    /// microsecond after the one it starts in, when every frame that competes for it (queued by
    /// its start) is known; it still starts at its exact instant.
    pub fn next_us(&self) -> Option<u64> {
        match &self.on_bus {
            Some(on_bus) => Some(on_bus.delivered_us),
            None => self.next_start().map(|start| self.clock.ceil_us(start + 1)),
        }
    }

    /// The frame on the bus, if the nodes receive it by `now_us`: recorded and handed back.
    pub fn deliver(&mut self, now_us: u64) -> Option<Transmission> {
        let done = self.on_bus.take_if(|t| t.delivered_us <= now_us)?;
        self.transmissions.push(done);
        Some(done)
    }

    /// Starts the next frame if it starts before `now_us`: of the frames queued by its start,
    /// the one of lowest arbitration rank (the first queued of equal ones).
    pub fn start(&mut self, now_us: u64) {
        let Some(start) = self.next_start() else {
            return;
        };
        if start >= self.clock.at_us(now_us) {
            return;
        }
        let clock = self.clock;
        let Some(index) = self
            .waiting
            .iter()
            .enumerate()
            .filter(|(_, w)| clock.at_us(w.queued_us) <= start)
            .min_by_key(|(_, w)| (w.frame.arbitration_rank(), w.sequence))
            .map(|(index, _)| index)
        else {
            return;
        };
        let chosen = self.waiting.swap_remove(index);
        let bits = transmitted(&chosen.frame);
        let scale = clock.per_base_unit();
        let end_of_frame = start + u128::from(bits.to_end_of_frame(&clock.base)) * scale;
        let end = start + u128::from(bits.time(&clock.base)) * scale;
        self.idle_from = end;
        self.on_bus = Some(Transmission {
            frame: chosen.frame,
            sender: chosen.sender,
            queued_us: chosen.queued_us,
            start,
            end_of_frame,
            end,
            delivered_us: clock.ceil_us(end_of_frame),
            bits,
        });
    }

    /// A node that stops sends nothing more: its waiting frames are dropped. A frame of its on the
    /// bus is finished (it started before the node stopped).
    pub fn drop_from(&mut self, sender: Sender) {
        self.waiting.retain(|w| w.sender != sender);
    }

    /// What the bus did; the frames still waiting or on the bus are unsent.
    pub fn finish(self) -> TimedRun {
        let mut unsent: Vec<Waiting> = self
            .on_bus
            .map(|t| Waiting {
                queued_us: t.queued_us,
                sender: t.sender,
                frame: t.frame,
                sequence: 0,
            })
            .into_iter()
            .chain(self.waiting)
            .collect();
        unsent.sort_by_key(|w| (w.queued_us, w.frame.arbitration_rank()));
        TimedRun {
            clock: self.clock,
            transmissions: self.transmissions,
            unsent,
        }
    }
}

/// A capture's frames on the timed bus (`pabctl replay --timed-bus`): each frame of `frames`
/// (µs, in time order; a frame's time is when its sender queued it) waits for the bus from its
/// time, and the bus carries them all, as it carries a simulation's. Nothing answers
/// them: the capture already holds what the nodes sent in answer, at the times they sent it.
///
/// The times are taken as queueing times, which is what a capture from a bus that takes no time
/// (Linux's `vcan`) records: there a frame's timestamp is when its sender wrote it. A capture from
/// a real bus stamps each frame when it ended, after its wait for the bus; carried again, it is
/// queued later than it was sent, so its latencies here are those of a bus that released the
/// frames at those instants.
///
/// Cost: each start scans the waiting frames, so a burst of n frames queued at once takes
/// O(n²); a capture's bursts are a node's heartbeat group or a transfer's block.
pub fn carry(clock: Clock, frames: &[(u64, Frame)]) -> TimedRun {
    let mut bus = TimedBus::new(clock);
    let mut pending = frames.iter().peekable();
    loop {
        let next_frame = pending.peek().map(|(t_us, _)| *t_us);
        let Some(now) = [next_frame, bus.next_us()].into_iter().flatten().min() else {
            break;
        };
        bus.deliver(now);
        bus.start(now);
        while let Some((t_us, frame)) = pending.next_if(|(t_us, _)| *t_us <= now) {
            bus.queue(*t_us, Sender::Scenario, *frame);
        }
    }
    bus.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::{Id, StandardId};

    fn frame(id: u16, len: usize) -> Frame {
        Frame::data(Id::Standard(StandardId::new(id).unwrap()), &vec![0x55; len]).unwrap()
    }

    #[test]
    fn the_clock_holds_microseconds_and_bits_whole() {
        // 500 kbit/s: 2 µs bits, units of 1 µs... of lcm(500 000, 10^6) = 10^6 a second.
        let classic = Clock::new(500_000, None);
        assert_eq!((classic.per_second, classic.per_us()), (1_000_000, 1));
        assert_eq!(classic.per_base_unit(), 2);
        // 500 kbit/s and 2 Mbit/s: the analysis's 0.5 µs units, 2 a microsecond.
        let fd = Clock::new(500_000, Some(2_000_000));
        assert_eq!(
            (fd.per_second, fd.per_us(), fd.per_base_unit()),
            (2_000_000, 2, 1)
        );
        // 125 kbit/s: 8 µs bits; 3 bit/s: a third of a second each.
        assert_eq!(Clock::new(125_000, None).per_base_unit(), 8);
        let odd = Clock::new(3, None);
        assert_eq!((odd.per_second, odd.per_us()), (3_000_000, 3));
        assert_eq!(odd.ns(1), 334);
        assert_eq!(fd.ceil_us(5), 3);
        assert_eq!(fd.ceil_us(6), 3);
    }

    /// Three frames queued at once go out lowest identifier first, back to back; one queued
    /// while another is on the bus waits for it, whatever its rank.
    #[test]
    fn the_bus_carries_one_frame_at_a_time_in_arbitration_order() {
        let clock = Clock::new(500_000, None);
        let mut bus = TimedBus::new(clock);
        bus.queue(10, Sender::Scenario, frame(0x300, 8));
        bus.queue(10, Sender::Node(0), frame(0x100, 8));
        bus.queue(10, Sender::Node(1), frame(0x200, 8));
        // Chosen once microsecond 10 is over, started at 10.
        assert_eq!(bus.next_us(), Some(11));
        bus.start(10);
        assert_eq!(bus.next_us(), Some(11));
        bus.start(11);
        let first = bus.on_bus.unwrap();
        assert_eq!(first.frame, frame(0x100, 8));
        assert_eq!(first.start, 10);
        let bits = transmitted(&first.frame);
        assert_eq!(first.end, 10 + 2 * u128::from(bits.nominal));
        assert_eq!(first.end_of_frame, first.end - 6);
        assert_eq!(bus.next_us(), Some(first.delivered_us));
        assert_eq!(bus.deliver(first.delivered_us - 1), None);
        assert_eq!(bus.deliver(first.delivered_us), Some(first));
        // While the first was on the bus, 0x050 was queued: it waits for the first, and then
        // wins over the two that waited longer.
        bus.queue(50, Sender::Node(2), frame(0x050, 0));
        let free = first.end;
        assert_eq!(bus.next_us(), Some(clock.ceil_us(free + 1)));
        bus.start(clock.ceil_us(free + 1));
        let second = bus.on_bus.unwrap();
        assert_eq!((second.frame, second.start), (frame(0x050, 0), free));
        assert_eq!(second.latency(&clock), second.end_of_frame - 50);
        assert_eq!(second.wait(&clock), free - 50);
        bus.deliver(second.delivered_us);
        bus.start(second.delivered_us + 100);
        let third = bus.on_bus.unwrap();
        assert_eq!(third.frame, frame(0x200, 8));
        let run = bus.finish();
        assert_eq!(run.transmissions.len(), 2);
        assert_eq!(run.unsent.len(), 2);
    }

    /// A capture's frames carried again: frames waiting when the bus frees go out in arbitration
    /// order, back to back (0x200, queued while 0x100 was on the bus, before 0x300, which
    /// waited longer), and nothing is left waiting.
    #[test]
    fn a_capture_is_carried_whole() {
        let clock = Clock::new(500_000, None);
        let frames = [
            (0, frame(0x300, 8)),
            (0, frame(0x100, 8)),
            (1, frame(0x200, 2)),
            (5_000, frame(0x400, 0)),
        ];
        let run = carry(clock, &frames);
        assert!(run.unsent.is_empty());
        let order: Vec<Frame> = run.transmissions.iter().map(|t| t.frame).collect();
        assert_eq!(
            order,
            [
                frame(0x100, 8),
                frame(0x200, 2),
                frame(0x300, 8),
                frame(0x400, 0)
            ]
        );
        assert_eq!(run.transmissions[1].start, run.transmissions[0].end);
        assert_eq!(run.transmissions[2].start, run.transmissions[1].end);
        // 0x400 found the bus idle: no wait.
        assert_eq!(run.transmissions[3].wait(&clock), 0);
    }
}

//! Action primitives: what one iteration of the loop does to the attractor, the impedance and the
//! gripper.
//!
//! The paper's three kinds, all called once per tick:
//! - **idle** keeps the command constant (for a time, or until an event);
//! - **atomic** actions act in one iteration (gripper, impedance, relieving forces) and are then
//!   done, so a schema's one-shot event follows them;
//! - **fixed-action patterns** persist: a compliant straight-line move of the attractor at
//!   constant speed (`MoveTo`, `MoveToTouch`), the blind search's spiral under preload, the
//!   grasp's settling time.
//!
//! Everything is integer arithmetic on µm, µrad and µs, exact and the same on every runner.

use serde::{Deserialize, Serialize};

use super::{AXES, Pose, length};
use crate::wire::{Decode, Reader};

/// A gripper command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Gripper {
    /// Open (release).
    Open,
    /// Closed (grasp).
    Closed,
}

/// One action primitive and its parameters. Speeds are µm/s (µrad/s for a purely rotational
/// move), distances µm, times ms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Action {
    /// Keep the command; done after `ms` (never, with 0: idle until an event).
    Idle {
        /// How long, ms; 0 for ever.
        ms: u32,
    },
    /// Open or close the gripper (atomic).
    Gripper(Gripper),
    /// Set the drive's impedance (atomic): stiffness N/m, damping N·s/m.
    SetImpedance {
        /// N/m (= mN/mm).
        stiffness: u32,
        /// N·s/m.
        damping: u32,
    },
    /// Set the attractor to the measured pose (atomic): the impedance controller then relieves
    /// every force between the robot and what it touches.
    Relieve,
    /// Move the attractor in a straight line to `goal` at `speed`; done on the goal.
    MoveTo {
        /// Where the attractor ends, exactly.
        goal: Pose,
        /// Along the translational path (or the rotational one, for a pure rotation).
        speed: u32,
    },
    /// Move the attractor along `direction` at `speed`, at most `distance`: the schema's
    /// reaction to [`super::Measure::Contact`] ends it on touching; done (no contact) at the end
    /// of `distance`.
    MoveToTouch {
        /// Any length; only its direction counts.
        direction: Pose,
        /// Along `direction`.
        speed: u32,
        /// The farthest the attractor goes.
        distance: u32,
    },
    /// The blind search: press `preload` µm into the surface (the attractor that far below
    /// where it was), and slide in a square spiral of `pitch` around the starting point at
    /// `speed`, while rocking about z by ±`wobble` µrad with period `wobble_ms`. It searches
    /// until an event (the part dropping in) and is never done by itself: the watchdog ends a
    /// search that finds nothing, by default 1.5 × the time the spiral takes to cover a square
    /// of half-width `radius`, plus the board's margin.
    BlindSearch {
        /// Attractor depth below the starting point, µm (force = stiffness × preload).
        preload: u32,
        /// Distance between the spiral's turns, µm (at most twice the clearance, to find a hole).
        pitch: u32,
        /// Along the spiral.
        speed: u32,
        /// Half-width of the square the search is expected to cover (its watchdog budget).
        radius: u32,
        /// Rocking amplitude about z, µrad (0: none).
        wobble: u32,
        /// Rocking period, ms.
        wobble_ms: u32,
    },
    /// Close the gripper, done after `settle_ms`.
    Grasp {
        /// Time for the fingers to close, ms.
        settle_ms: u32,
    },
    /// Open the gripper, done after `settle_ms`.
    Release {
        /// Time for the fingers to open, ms.
        settle_ms: u32,
    },
}

/// The command a board sends its drive every tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Setpoint {
    /// The impedance controller's attractor.
    pub attractor: Pose,
    /// N/m.
    pub stiffness: u32,
    /// N·s/m.
    pub damping: u32,
    /// The gripper.
    pub gripper: Gripper,
}

/// An action in progress: what its iterations have done so far.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Progress {
    /// The attractor when the action started.
    start: Pose,
    /// The direction of motion, unnormalised (a move's goal − start).
    dir: [i64; AXES],
    /// |dir| over the axes `progress` counts on (translation, or rotation for a pure rotation).
    norm: u64,
    /// `norm` is over the translational axes (a contact force can oppose the motion).
    translates: bool,
    /// Where the motion ends, in units of `progress`.
    distance: u64,
    /// How far the attractor went, µm (µrad).
    progress: u64,
    /// The sub-µm part of `progress`, in µm·µs/s: speed × period is added here each tick and
    /// whole µm carried over, so no speed is rounded.
    remainder: u64,
    /// The spiral's current leg (0, 1, … : +x, +y, −x, −y, …, lengths pitch × (leg / 2 + 1)).
    leg: u32,
    /// The current leg's start, relative to the spiral's centre.
    corner: [i64; 2],
    /// How far along the current leg, µm.
    along: u64,
    /// Iterations run.
    pub(crate) iterations: u32,
    /// The action is finished.
    pub(crate) done: bool,
}

const MICROS_PER_SECOND: u64 = 1_000_000;

impl Action {
    /// The time the action takes if nothing stops it, µs (`None`: unbounded, an idle for
    /// ever), `p` its [`Action::start`]. The watchdog's default budget is made from it.
    pub(crate) fn nominal_us(&self, p: &Progress) -> Option<u64> {
        // The distance and speed of the travelling actions, then one division for them all.
        let (distance, speed) = match *self {
            Action::Idle { ms: 0 } => return None,
            Action::Idle { ms }
            | Action::Grasp { settle_ms: ms }
            | Action::Release { settle_ms: ms } => return Some(u64::from(ms) * 1000),
            Action::Gripper(_) | Action::SetImpedance { .. } | Action::Relieve => return Some(0),
            // The start measured the line (a move's length, a touch-down's distance) already.
            Action::MoveTo { speed, .. } | Action::MoveToTouch { speed, .. } => (p.distance, speed),
            Action::BlindSearch {
                pitch,
                speed,
                radius,
                ..
            } => {
                // Legs come in pairs of length pitch·n for n = 1, 2, … while pitch·n ≤ 2·radius:
                // pitch·n(n+1) in all. A checked radius is below 2^29: a 32-bit division; and
                // pitch·n ≤ 2·radius whatever the radius, so the product is below 2^64.
                let n = radius.saturating_mul(2) / pitch.max(1);
                (u64::from(pitch * n) * (u64::from(n) + 1), speed)
            }
        };
        Some(distance.saturating_mul(MICROS_PER_SECOND) / u64::from(speed.max(1)))
    }

    /// The direction the action moves the attractor in (translation), for
    /// [`super::Measure::Contact`]: its vector and length, or a zero length (by reference: no
    /// copy of the vector made).
    pub(crate) fn heading<'a>(&self, progress: &'a Progress) -> (&'a [i64], u64) {
        match self {
            Action::MoveTo { .. } | Action::MoveToTouch { .. } => (
                &progress.dir[..3],
                if progress.translates {
                    progress.norm
                } else {
                    0
                },
            ),
            // The preload presses down.
            Action::BlindSearch { .. } => (&[0, 0, -1], 1),
            _ => (&[], 0),
        }
    }

    /// Starts the action from the attractor `from`, into `p` (in place: the server's own field,
    /// not a copy made and moved in).
    pub(crate) fn start(&self, from: &Pose, p: &mut Progress) {
        *p = Progress {
            start: *from,
            ..Progress::default()
        };
        // One computation of the line for both moves: it is large, and a copy each cost more
        // code than choosing its ends.
        let (to, origin, touch) = match self {
            Action::MoveTo { goal, .. } => (goal, from, None),
            Action::MoveToTouch {
                direction,
                distance,
                ..
            } => (direction, &[0; AXES], Some(*distance)),
            _ => return,
        };
        for ((d, t), f) in p.dir.iter_mut().zip(to).zip(origin) {
            *d = i64::from(*t) - i64::from(*f);
        }
        // The length over the translational axes; for a move without translation, over the
        // rotational ones.
        let (translation, rotation) = p.dir.split_at(3);
        p.translates = translation.iter().any(|c| *c != 0);
        p.norm = if p.translates || touch.is_some() {
            length(translation)
        } else {
            length(rotation)
        };
        p.distance = touch.map_or(p.norm, u64::from);
        p.translates |= touch.is_some();
    }

    /// One iteration: updates `out` from the action's state, `elapsed_us` after it started and
    /// `period_us` after the previous iteration; `measured` is the sensor table's pose (`None`
    /// before the first: the attractor stays).
    pub(crate) fn iterate(
        &self,
        p: &mut Progress,
        out: &mut Setpoint,
        elapsed_us: u64,
        period_us: u32,
        measured: Option<&Pose>,
    ) {
        let elapsed_ms = elapsed_us / 1000;
        match *self {
            Action::Idle { ms } => p.done = ms != 0 && elapsed_ms >= u64::from(ms),
            Action::Gripper(g) => {
                out.gripper = g;
                p.done = true;
            }
            Action::SetImpedance { stiffness, damping } => {
                out.stiffness = stiffness;
                out.damping = damping;
                p.done = true;
            }
            Action::Relieve => {
                // Element by element: a whole-array assignment here became a call to memmove,
                // which the boards do not otherwise link (1.5 KB).
                if let Some(measured) = measured {
                    for (o, m) in out.attractor.iter_mut().zip(measured) {
                        *o = *m;
                    }
                }
                p.done = true;
            }
            Action::Grasp { settle_ms } | Action::Release { settle_ms } => {
                out.gripper = if matches!(self, Action::Grasp { .. }) {
                    Gripper::Closed
                } else {
                    Gripper::Open
                };
                p.done = elapsed_ms >= u64::from(settle_ms);
            }
            // One arm for both moves: their steps differ only at the end.
            Action::MoveTo { speed, .. } | Action::MoveToTouch { speed, .. } => {
                if !p.done {
                    p.advance(speed, period_us);
                    p.done = p.progress >= p.distance;
                    match *self {
                        // The goal exactly, not start + dir × 1 rounded.
                        Action::MoveTo { goal, .. } if p.done => out.attractor = goal,
                        _ => {
                            // A touch-down ends on its distance (a move is short of it here).
                            p.progress = p.progress.min(p.distance);
                            p.along_line(&mut out.attractor);
                        }
                    }
                }
            }
            Action::BlindSearch {
                preload,
                pitch,
                speed,
                radius: _,
                wobble,
                wobble_ms,
            } => {
                {
                    let before = p.progress;
                    p.advance(speed, period_us);
                    let step = p.progress - before;
                    p.spiral(step, u64::from(pitch));
                }
                let (x, y) = p.spiral_point(u64::from(pitch));
                let [sx, sy, sz, _, _, srz] = p.start;
                out.attractor[0] = clamp(i64::from(sx).saturating_add(x));
                out.attractor[1] = clamp(i64::from(sy).saturating_add(y));
                out.attractor[2] = clamp(i64::from(sz) - i64::from(preload));
                out.attractor[5] = clamp(i64::from(srz) + triangle(elapsed_ms, wobble, wobble_ms));
            }
        }
        p.iterations = p.iterations.saturating_add(1);
    }
}

impl Progress {
    /// Adds one period at `speed` to `progress`, carrying the sub-µm remainder.
    // Out of line: the three moving actions each inlined a copy.
    #[inline(never)]
    fn advance(&mut self, speed: u32, period_us: u32) {
        // speed ≤ MAX_COORD < 2^29 and period_us < 2^32: the product is below 2^61.
        let total = u64::from(speed) * u64::from(period_us) + self.remainder;
        self.progress = self.progress.saturating_add(total / MICROS_PER_SECOND);
        self.remainder = total % MICROS_PER_SECOND;
    }

    /// The attractor `progress` along `dir` from `start`, into `out` (no copy made and moved).
    fn along_line(&self, out: &mut Pose) {
        // By reference: zipped by value, the arrays were copied first.
        for (o, s) in out.iter_mut().zip(&self.start) {
            *o = *s;
        }
        if self.norm == 0 {
            return;
        }
        // s ≤ 2^31, and |dir| < 2^31 + 2^29 (a goal within MAX_COORD from an attractor anywhere
        // in i32, or a direction within MAX_COORD): the product is below 2^63, so a plain
        // multiply (a saturating 64-bit one is several times its code); norm > 0.
        let s = self.progress.min(1 << 31) as i64;
        for (o, d) in out.iter_mut().zip(&self.dir) {
            *o = clamp(i64::from(*o) + div_toward_zero(d * s, self.norm));
        }
    }

    /// Walks `step` µm along the square spiral.
    fn spiral(&mut self, mut step: u64, pitch: u64) {
        let pitch = pitch.max(1);
        // A tick's step is far below a leg at any sensible speed; the bound only keeps a tick's
        // work finite whatever a schema says (the rest of a step beyond it is dropped).
        for _ in 0..64 {
            let length = pitch * (u64::from(self.leg) / 2 + 1);
            if self.along + step < length {
                self.along += step;
                return;
            }
            step -= length - self.along;
            // Legs grow by one pitch per pair: a search stopped by its watchdog stays far
            // below these bounds; saturating keeps a schema without one finite.
            let length = length.min(1 << 40) as i64;
            let (axis, backwards) = leg_axis(self.leg);
            // `axis` is 0 or 1: the `None` never happens (and the check compiles away).
            if let Some(c) = self.corner.get_mut(axis) {
                *c = if backwards {
                    c.saturating_sub(length)
                } else {
                    c.saturating_add(length)
                };
            }
            self.leg = self.leg.saturating_add(1);
            self.along = 0;
        }
    }

    /// The spiral's point, relative to its centre.
    fn spiral_point(&self, pitch: u64) -> (i64, i64) {
        let (axis, backwards) = leg_axis(self.leg);
        // ≤ a leg's length, which is ≤ pitch × 2^31 < 2^61.
        let along = self.along.min(pitch.max(1) * (u64::from(self.leg) / 2 + 1)) as i64;
        let mut point = self.corner;
        if let Some(c) = point.get_mut(axis) {
            *c = if backwards {
                c.saturating_sub(along)
            } else {
                c.saturating_add(along)
            };
        }
        (point[0], point[1])
    }
}

/// A leg's axis (0: x, 1: y) and whether it runs backwards: +x, +y, −x, −y, … (an axis and a
/// sign rather than a unit vector: no multiply by it).
fn leg_axis(leg: u32) -> (usize, bool) {
    ((leg % 2) as usize, leg % 4 >= 2)
}

/// A triangle wave of amplitude `a` and period `t_ms`, 0 at t = 0, rising first.
fn triangle(t_ms: u64, a: u32, t_ms_period: u32) -> i64 {
    if a == 0 || t_ms_period == 0 {
        return 0;
    }
    let period = u64::from(t_ms_period);
    // u ∈ [0, 4a): a quarter period per amplitude. Unsigned: the boards' one 64-bit division
    // is unsigned (a signed one links compiler_builtins' 0.9 KB).
    let u = ((t_ms % period) * 4 * u64::from(a) / period) as i64;
    let a = i64::from(a);
    if u < a {
        u
    } else if u < 3 * a {
        2 * a - u
    } else {
        u - 4 * a
    }
}

/// `v / d` rounded toward zero, through an unsigned division (see [`triangle`]); `d > 0`. Out
/// of line: its two callers inlined it (32 bytes of the NUCLEO-G474RE's flash).
#[inline(never)]
pub(crate) fn div_toward_zero(v: i64, d: u64) -> i64 {
    let q = (v.unsigned_abs() / d.max(1)).min(i64::MAX as u64) as i64;
    if v < 0 { -q } else { q }
}

/// An `i64` coordinate back into an `i32` (saturating: never reached with coordinates within
/// [`super::MAX_COORD`]).
// Out of line: the search's four and the line's loop each inlined a copy.
#[inline(never)]
fn clamp(v: i64) -> i32 {
    v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

impl Decode for Gripper {
    fn decode(r: &mut Reader<'_>) -> Self {
        if r.variant(2) == 0 {
            Gripper::Open
        } else {
            Gripper::Closed
        }
    }
}

impl Decode for Action {
    fn decode(r: &mut Reader<'_>) -> Self {
        match r.variant(9) {
            0 => Action::Idle { ms: r.u32() },
            1 => Action::Gripper(r.decode()),
            2 => Action::SetImpedance {
                stiffness: r.u32(),
                damping: r.u32(),
            },
            3 => Action::Relieve,
            4 => Action::MoveTo {
                goal: r.decode(),
                speed: r.u32(),
            },
            5 => Action::MoveToTouch {
                direction: r.decode(),
                speed: r.u32(),
                distance: r.u32(),
            },
            6 => Action::BlindSearch {
                preload: r.u32(),
                pitch: r.u32(),
                speed: r.u32(),
                radius: r.u32(),
                wobble: r.u32(),
                wobble_ms: r.u32(),
            },
            7 => Action::Grasp { settle_ms: r.u32() },
            _ => Action::Release { settle_ms: r.u32() },
        }
    }
}

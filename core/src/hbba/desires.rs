//! The intention workspace's desires: who wants what, how much, and for how long.
//!
//! A motivation (any node, or the tool) issues a desire as a frame: a class, an intensity and a
//! lease. The desire lives until its lease runs out without a refresh, or until its sender
//! withdraws it (intensity 0). A sender names its desire with its own number, so `(source, id)`
//! identifies a desire on the bus; a refresh under the same name changes its intensity, class and
//! lease but keeps its age.
//!
//! Per class the workspace keeps the most intense desire (DESIGN.md, "HBBA: decisions"): on equal
//! intensities the older desire (first heard earlier), then the lower `(source, id)`. The solver
//! ([`super::Solver`]) only reads the selected intensity per class; the tie-break decides which
//! desire is reported as the one served.
//!
//! Fixed capacity ([`MAX_DESIRES`]); a desire that does not fit is refused with
//! [`DesireError::Full`], never at the cost of one already held: a flood of new names cannot evict
//! the desires that are being served.

use heapless::Vec;

use super::{Intensities, MAX_CLASSES};
use crate::time::Instant;

/// How many desires the workspace holds at once.
pub const MAX_DESIRES: usize = 32;

/// One desire as the workspace holds it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Desire {
    /// The node that sent it.
    pub source: u8,
    /// Its sender's number for it.
    pub id: u16,
    /// Its class, as numbered by the network (first appearance among the strategies).
    pub class: u8,
    /// How much it is wanted, 1..=65535.
    pub intensity: u16,
    /// When it was first heard (its age, for the tie-break).
    pub since: Instant,
    /// When it lapses unless refreshed.
    pub until: Instant,
}

// Not `#[non_exhaustive]`: the intention board (firmware/intent) logs each variant in its own
// words.
/// Why a desire frame changed nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DesireError {
    /// The workspace already holds [`MAX_DESIRES`] other desires.
    Full,
    /// The class is not one of the network's (`class` ≥ the number of classes).
    UnknownClass {
        /// The class asked for.
        class: u8,
    },
    /// A lease of 0 ms: the desire would lapse as it arrives.
    ZeroLease,
}

impl core::fmt::Display for DesireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DesireError::Full => write!(f, "the workspace holds {MAX_DESIRES} desires already"),
            DesireError::UnknownClass { class } => {
                write!(
                    f,
                    "desire for class {class}, which the network does not have"
                )
            }
            DesireError::ZeroLease => f.write_str("desire with a lease of 0 ms"),
        }
    }
}

impl core::error::Error for DesireError {}

/// The desires held, at most [`MAX_DESIRES`].
#[derive(Clone, Debug, Default)]
pub struct Desires {
    held: Vec<Desire, MAX_DESIRES>,
    classes: u8,
}

impl Desires {
    /// An empty workspace for a network of `classes` classes (at most [`MAX_CLASSES`]: more are
    /// taken as [`MAX_CLASSES`]).
    pub const fn new(classes: u8) -> Desires {
        let classes = if classes as usize > MAX_CLASSES {
            MAX_CLASSES as u8
        } else {
            classes
        };
        Desires {
            held: Vec::new(),
            classes,
        }
    }

    /// Takes a desire frame heard at `now`: `intensity` 0 withdraws `(source, id)`, anything else
    /// adds or refreshes it with a lease of `lease_ms`. Returns whether the held desires changed
    /// in a way the solver must see (a refresh that only extends a lease does not).
    ///
    /// Costs one pass over the held desires. Fails without changing anything on a class the
    /// network does not have, a zero lease, or a new desire when the workspace is full.
    pub fn heard(
        &mut self,
        source: u8,
        id: u16,
        class: u8,
        intensity: u16,
        lease_ms: u16,
        now: Instant,
    ) -> Result<bool, DesireError> {
        let position = self
            .held
            .iter()
            .position(|d| d.source == source && d.id == id);
        if intensity == 0 {
            return Ok(match position {
                Some(index) => {
                    self.held.swap_remove(index);
                    true
                }
                None => false,
            });
        }
        if class >= self.classes {
            return Err(DesireError::UnknownClass { class });
        }
        if lease_ms == 0 {
            return Err(DesireError::ZeroLease);
        }
        let until = now.wrapping_add_micros(u64::from(lease_ms) * 1000);
        match position.and_then(|index| self.held.get_mut(index)) {
            Some(desire) => {
                let changed = desire.class != class || desire.intensity != intensity;
                desire.class = class;
                desire.intensity = intensity;
                desire.until = until;
                Ok(changed)
            }
            None => {
                let desire = Desire {
                    source,
                    id,
                    class,
                    intensity,
                    since: now,
                    until,
                };
                self.held.push(desire).map_err(|_| DesireError::Full)?;
                Ok(true)
            }
        }
    }

    /// Drops every desire whose lease ran out at or before `now`; returns whether any was.
    pub fn expire(&mut self, now: Instant) -> bool {
        let before = self.held.len();
        self.held.retain(|d| now.micros_since(d.until).is_none());
        self.held.len() != before
    }

    /// The next instant at which a lease runs out, if any desire is held.
    pub fn deadline(&self, now: Instant) -> Option<Instant> {
        self.held
            .iter()
            .map(|d| d.until.micros_since(now).unwrap_or(0))
            .min()
            .map(|left| now.wrapping_add_micros(left))
    }

    /// The desires held, in no particular order.
    pub fn held(&self) -> &[Desire] {
        &self.held
    }

    /// The desire served for `class`: the most intense; on a tie the older, then the lower
    /// `(source, id)`. `None` when nobody desires the class.
    pub fn selected(&self, class: u8) -> Option<&Desire> {
        self.held
            .iter()
            .filter(|d| d.class == class)
            .reduce(|best, d| if ranks_above(d, best) { d } else { best })
    }

    /// The intensity the solver sees for each class (0: no desire). Costs one pass over the held
    /// desires per class.
    pub fn intensities(&self) -> Intensities {
        let mut out: Intensities = [0; MAX_CLASSES];
        for (class, slot) in out.iter_mut().enumerate() {
            *slot = u8::try_from(class)
                .ok()
                .and_then(|class| self.selected(class))
                .map_or(0, |d| d.intensity);
        }
        out
    }
}

/// Whether `a` is served before `b` in the same class.
fn ranks_above(a: &Desire, b: &Desire) -> bool {
    if a.intensity != b.intensity {
        return a.intensity > b.intensity;
    }
    // Older first: `a` heard strictly before `b`.
    match b.since.micros_since(a.since) {
        Some(0) => (a.source, a.id) < (b.source, b.id),
        Some(_) => true,
        None => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Instant {
        Instant::from_micros(ms * 1000)
    }

    #[test]
    fn the_most_intense_then_the_older_then_the_lower_name_is_served() {
        let mut desires = Desires::new(3);
        assert_eq!(desires.heard(5, 1, 0, 10, 1000, at(0)), Ok(true));
        assert_eq!(desires.heard(4, 9, 0, 10, 1000, at(5)), Ok(true));
        // Equal intensities: the older (5, 1).
        assert_eq!(desires.selected(0).map(|d| (d.source, d.id)), Some((5, 1)));
        // Same age: the lower name.
        assert_eq!(desires.heard(4, 2, 1, 7, 1000, at(7)), Ok(true));
        assert_eq!(desires.heard(3, 8, 1, 7, 1000, at(7)), Ok(true));
        assert_eq!(desires.selected(1).map(|d| (d.source, d.id)), Some((3, 8)));
        // More intense wins whatever its age.
        assert_eq!(desires.heard(9, 9, 0, 11, 1000, at(9)), Ok(true));
        assert_eq!(desires.selected(0).map(|d| (d.source, d.id)), Some((9, 9)));
        assert_eq!(desires.intensities()[..3], [11, 7, 0]);
    }

    #[test]
    fn a_lease_runs_out_unless_refreshed_and_a_refresh_keeps_the_age() {
        let mut desires = Desires::new(1);
        desires.heard(1, 1, 0, 10, 100, at(0)).unwrap();
        assert_eq!(desires.deadline(at(0)), Some(at(100)));
        // A refresh with the same intensity changes nothing the solver sees.
        assert_eq!(desires.heard(1, 1, 0, 10, 100, at(90)), Ok(false));
        assert!(!desires.expire(at(189)));
        assert_eq!(desires.held()[0].since, at(0));
        assert!(desires.expire(at(190)));
        assert!(desires.held().is_empty());
        assert_eq!(desires.deadline(at(190)), None);
    }

    #[test]
    fn withdrawal_refusals_and_capacity() {
        let mut desires = Desires::new(2);
        assert_eq!(desires.heard(1, 1, 0, 0, 100, at(0)), Ok(false));
        assert_eq!(
            desires.heard(1, 1, 2, 5, 100, at(0)),
            Err(DesireError::UnknownClass { class: 2 })
        );
        assert_eq!(
            desires.heard(1, 1, 0, 5, 0, at(0)),
            Err(DesireError::ZeroLease)
        );
        for id in 0..MAX_DESIRES as u16 {
            assert_eq!(desires.heard(2, id, 1, 5, 100, at(0)), Ok(true));
        }
        assert_eq!(
            desires.heard(3, 0, 1, 9, 100, at(0)),
            Err(DesireError::Full)
        );
        // A held desire can still be refreshed and withdrawn.
        assert_eq!(desires.heard(2, 0, 1, 6, 100, at(1)), Ok(true));
        assert_eq!(desires.heard(2, 0, 1, 0, 100, at(1)), Ok(true));
        assert_eq!(desires.held().len(), MAX_DESIRES - 1);
    }
}

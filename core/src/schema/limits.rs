//! The safety bounds of a board: the workspace, the force, torque and contact limits, the
//! Cartesian speed and rate limits and each joint's range and speed ([`Limits`]).
//!
//! The table carries the loosest bounds the board may ever run with ([`super::Config::limits`]).
//! At run time a client may set other bounds ([`super::Server::set_limits`], the SchemaTransfer's
//! limits channel, authenticated on a keyed node), each within the table's: tighter, or back up to
//! the table's, never beyond (DESIGN.md, "A stop that stays stopped: decisions").
//!
//! Why speeds are measured over a window ([`SPEED_WINDOW_US`]) and not frame to frame: at 1 kHz a
//! pose sensor's noise (1 mm by default) is a metre a second between two frames; over 20 ms it is
//! 50 mm/s, below any speed limit worth setting, and the event comes at most a window late.

use heapless::Vec;
use serde::{Deserialize, Serialize};

use super::{AXES, MAX_SENSORS, Pose, SchemaError};
use crate::wire::decode_struct;

/// Joints a board's limits bound: one per extra sensor at most.
pub const MAX_JOINTS: usize = MAX_SENSORS;

/// Measured speeds are the displacement over at least this long, µs: at 1 kHz a pose noise of
/// 1 mm is a metre a second between two frames, over 20 ms it is 50 mm/s.
pub const SPEED_WINDOW_US: u64 = 20_000;

/// One joint's bounds, in the counts of the extra sensor that measures it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Joint {
    /// The extra sensor ([`super::Measure::Sensor`]) that reads the joint's position.
    pub sensor: u8,
    /// The lowest position, counts.
    pub min: i32,
    /// The highest position, counts.
    pub max: i32,
    /// The top speed, counts per second (0: none). A reading farther than this allows from the
    /// one a window before (and one count) is a speed event.
    pub rate: u32,
}

/// A board's safety bounds. A speed, rate or limit of 0 is none, except the force limit, which
/// a board always has.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Limits {
    /// The workspace's lower corner (µm, µrad).
    pub workspace_min: Pose,
    /// The workspace's upper corner.
    pub workspace_max: Pose,
    /// The safety limit on the force's magnitude, mN (the contact thresholds of schemas are
    /// lower).
    pub force_limit: u32,
    /// The safety limit on the torque's magnitude, mN·m (0: none).
    pub torque_limit: u32,
    /// The highest contact force a schema may wait for, mN (0: none): a reaction to
    /// [`super::Measure::Contact`] above a higher threshold holds from this one.
    pub contact_limit: u32,
    /// The top speed of the measured pose's translation (its magnitude), µm/s (0: none).
    pub speed_limit: u32,
    /// The top rate of the measured pose's rotation (its magnitude), µrad/s (0: none).
    pub rate_limit: u32,
    /// The joints' ranges and speeds.
    pub joints: Vec<Joint, MAX_JOINTS>,
}

/// Why limits were refused: as a table's ([`super::ConfigError::Limits`]) or at run time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum LimitsError {
    /// A workspace whose lower corner is above its upper one on some axis.
    Workspace,
    /// A force limit of 0.
    ForceLimit,
    /// A joint (its index) whose lowest position is above its highest.
    Joint(u8),
    /// Run-time limits looser than the table's on some bound, or with other joints than the
    /// table's (the same sensors, in the same order).
    Looser,
}

impl Limits {
    /// ±1 m (rad) of workspace, 50 N, and no other bound.
    pub fn new() -> Limits {
        Limits {
            workspace_min: [-1_000_000; AXES],
            workspace_max: [1_000_000; AXES],
            force_limit: 50_000,
            torque_limit: 0,
            contact_limit: 0,
            speed_limit: 0,
            rate_limit: 0,
            joints: Vec::new(),
        }
    }

    /// Checks that the bounds are consistent: each lower corner at most its upper one, a force
    /// limit.
    pub fn check(&self) -> Result<(), LimitsError> {
        if self
            .workspace_min
            .iter()
            .zip(&self.workspace_max)
            .any(|(lo, hi)| lo > hi)
        {
            return Err(LimitsError::Workspace);
        }
        if self.force_limit == 0 {
            return Err(LimitsError::ForceLimit);
        }
        match self.joints.iter().position(|j| j.min > j.max) {
            Some(i) => Err(LimitsError::Joint(i as u8)),
            None => Ok(()),
        }
    }

    /// Checks that these bounds are consistent and nowhere looser than `table`'s: each corner
    /// and range within the table's, each limit at most the table's (and not none where the
    /// table has one), the same joints.
    pub fn check_within(&self, table: &Limits) -> Result<(), LimitsError> {
        self.check()?;
        // Every lower bound at least the table's, every upper one at most: the workspace's
        // corners, then each joint's (the same sensors), then the limits, where 0 is none.
        let joints = self.joints.len() == table.joints.len()
            && self.joints.iter().zip(&table.joints).all(|(new, old)| {
                new.sensor == old.sensor
                    && new.min >= old.min
                    && old.max >= new.max
                    && within(new.rate, old.rate)
            });
        let inside = at_least(&self.workspace_min, &table.workspace_min)
            && at_least(&table.workspace_max, &self.workspace_max)
            && joints
            && within(self.force_limit, table.force_limit)
            && within(self.torque_limit, table.torque_limit)
            && within(self.contact_limit, table.contact_limit)
            && within(self.speed_limit, table.speed_limit)
            && within(self.rate_limit, table.rate_limit);
        if inside {
            Ok(())
        } else {
            Err(LimitsError::Looser)
        }
    }

    /// Decodes limits as the SchemaTransfer's limits channel carries them (postcard); the bytes
    /// must hold exactly one. Not checked: [`super::Server::set_limits`] checks them against the
    /// table's.
    pub fn decode(bytes: &[u8]) -> Result<Limits, SchemaError> {
        let (limits, rest) = crate::wire::take::<Limits>(bytes).map_err(SchemaError::Malformed)?;
        if rest.is_empty() {
            Ok(limits)
        } else {
            Err(SchemaError::TrailingBytes)
        }
    }

    /// The contact threshold a reaction waiting for `threshold` holds from: the lower of the
    /// two, with a contact limit.
    pub fn contact(&self, threshold: i32) -> i32 {
        match i32::try_from(self.contact_limit) {
            Ok(0) => threshold,
            Ok(limit) => threshold.min(limit),
            // Beyond i32: above every threshold.
            Err(_) => threshold,
        }
    }
}

impl Default for Limits {
    fn default() -> Limits {
        Limits::new()
    }
}

/// Whether every coordinate of `a` is at least `b`'s.
fn at_least(a: &Pose, b: &Pose) -> bool {
    a.iter().zip(b).all(|(a, b)| a >= b)
}

/// Whether a limit `new` is at most `old`, where 0 is none: `new` in 1..=old, or `old` none.
fn within(new: u32, old: u32) -> bool {
    // Without branches: 0 wraps to u32::MAX, above every limit.
    old == 0 || new.wrapping_sub(1) < old
}

/// How far an axis may move in `dt_us` at `speed` (per second), plus `noise`: saturating.
// Out of line: the pose's plausibility and its speed each inlined a copy (its 64-bit division).
#[inline(never)]
pub(crate) fn allowance(speed: u32, dt_us: u64, noise: u32) -> u64 {
    u64::from(speed)
        .saturating_mul(dt_us)
        .div_ceil(1_000_000)
        .saturating_add(u64::from(noise))
}

/// Whether the translation or the rotation from `last` to `next` in `dt_us` was faster than
/// `limits` allow, beyond twice the pose's `noise` (the noise of two readings, on the magnitude
/// of three axes: more than its √3). An allowance of 2^32 µm (µrad) or more in one window
/// (4 km) lets any motion pass. In integers: each axis's difference fits a `u32` and its square
/// a `u64`; their sum saturates, above any allowance's square (below 2^64).
pub(crate) fn too_fast(limits: &Limits, last: &Pose, next: &Pose, dt_us: u64, noise: u32) -> bool {
    let noise = noise.saturating_mul(2);
    [(0, limits.speed_limit), (3, limits.rate_limit)]
        .iter()
        .any(|(axis, limit)| {
            let Ok(allowed) = u32::try_from(allowance(*limit, dt_us, noise)) else {
                return false;
            };
            let moved = (*axis..axis + 3).fold(0u64, |sum, a| {
                let d = match (last.get(a), next.get(a)) {
                    (Some(x), Some(y)) => u64::from(x.abs_diff(*y)),
                    _ => 0,
                };
                sum.saturating_add(d * d)
            });
            *limit != 0 && moved > u64::from(allowed) * u64::from(allowed)
        })
}

/// How far `v` is outside `lo..=hi`. In 32 bits: with lo ≤ hi at most one side is exceeded,
/// and the distance between two `i32` fits a `u32`.
pub(crate) fn axis_excess(v: i32, lo: i32, hi: i32) -> u32 {
    if v < lo {
        lo.abs_diff(v)
    } else if v > hi {
        v.abs_diff(hi)
    } else {
        0
    }
}

decode_struct!(Joint {
    sensor,
    min,
    max,
    rate
});
decode_struct!(Limits {
    workspace_min,
    workspace_max,
    force_limit,
    torque_limit,
    contact_limit,
    speed_limit,
    rate_limit,
    joints
});

impl core::fmt::Display for LimitsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LimitsError::Workspace => {
                f.write_str("a workspace whose lower corner is above its upper one")
            }
            LimitsError::ForceLimit => f.write_str("a force limit of 0"),
            LimitsError::Joint(i) => write!(f, "joint {i}'s lowest position is above its highest"),
            LimitsError::Looser => f.write_str("looser than the table's limits"),
        }
    }
}

impl core::error::Error for LimitsError {}

#[cfg(test)]
mod tests {
    use super::*;

    fn joint(sensor: u8, min: i32, max: i32, rate: u32) -> Joint {
        Joint {
            sensor,
            min,
            max,
            rate,
        }
    }

    #[test]
    fn run_time_limits_may_tighten_and_come_back_but_never_loosen() {
        let mut table = Limits::new();
        table.speed_limit = 250_000;
        table.joints.push(joint(2, -1000, 1000, 500)).unwrap();
        assert_eq!(table.check_within(&table), Ok(()));

        let mut tight = table.clone();
        tight.force_limit = 10_000;
        tight.torque_limit = 2_000;
        tight.contact_limit = 5_000;
        tight.speed_limit = 100_000;
        tight.rate_limit = 500_000;
        tight.workspace_min[0] = -200_000;
        tight.workspace_max[2] = 300_000;
        tight.joints[0] = joint(2, -500, 800, 100);
        assert_eq!(tight.check_within(&table), Ok(()));

        let looser: [fn(&mut Limits); 9] = [
            |l| l.force_limit = 50_001,
            |l| l.speed_limit = 0,
            |l| l.speed_limit = 250_001,
            |l| l.workspace_min[5] = -1_000_001,
            |l| l.workspace_max[1] = 1_000_001,
            |l| l.joints[0].min = -1001,
            |l| l.joints[0].rate = 0,
            |l| l.joints[0].sensor = 3,
            |l| l.joints.clear(),
        ];
        for (i, loosen) in looser.iter().enumerate() {
            let mut l = table.clone();
            loosen(&mut l);
            assert_eq!(l.check_within(&table), Err(LimitsError::Looser), "case {i}");
        }
        // Inconsistent bounds are refused as such, tighter or not.
        let mut crossed = table.clone();
        crossed.joints[0] = joint(2, 10, -10, 1);
        assert_eq!(crossed.check_within(&table), Err(LimitsError::Joint(0)));
        let mut none = table.clone();
        none.force_limit = 0;
        assert_eq!(none.check_within(&table), Err(LimitsError::ForceLimit));
    }

    #[test]
    fn limits_decode_as_postcard_encodes_them_and_nothing_else() {
        let mut l = Limits::new();
        l.speed_limit = 250_000;
        l.joints.push(joint(1, -7, 9, 3)).unwrap();
        let mut buffer = [0u8; 300];
        let len = postcard::to_slice(&l, &mut buffer).unwrap().len();
        let bytes = &buffer[..len];
        assert_eq!(Limits::decode(bytes), Ok(l));
        assert_eq!(
            Limits::decode(&buffer[..len + 1]),
            Err(SchemaError::TrailingBytes)
        );
        assert!(matches!(
            Limits::decode(&bytes[..bytes.len() - 1]),
            Err(SchemaError::Malformed(_))
        ));
    }

    #[test]
    fn the_contact_limit_lowers_higher_thresholds_only() {
        let mut l = Limits::new();
        assert_eq!(l.contact(8_000), 8_000);
        l.contact_limit = 5_000;
        assert_eq!((l.contact(8_000), l.contact(3_000)), (5_000, 3_000));
        l.contact_limit = u32::MAX;
        assert_eq!(l.contact(8_000), 8_000);
    }

    #[test]
    fn speed_is_the_magnitude_beyond_twice_the_noise() {
        let mut l = Limits::new();
        l.speed_limit = 100_000; // 100 mm/s: 2 mm in a 20 ms window.
        let rest = [0; AXES];
        // 2 mm + 2 × 0.1 mm along a diagonal of x and y: allowed, a hair more is not.
        let edge = [1555, 1555, 0, 0, 0, 0]; // |d| = 2199.1 µm
        assert!(!too_fast(&l, &rest, &edge, 20_000, 100));
        assert!(too_fast(&l, &rest, &[1556, 1556, 0, 0, 0, 0], 20_000, 100));
        // Rotation is free without a rate limit, bounded with one.
        let turn = [0, 0, 0, 0, 0, 900_000];
        assert!(!too_fast(&l, &rest, &turn, 20_000, 100));
        l.rate_limit = 1_000_000;
        assert!(too_fast(&l, &rest, &turn, 20_000, 100));
        // Extremes: the sum saturates, an allowance of 2^32 or more lets anything pass.
        let far = [i32::MIN, i32::MAX, i32::MIN, i32::MAX, i32::MIN, i32::MAX];
        assert!(too_fast(&l, &[i32::MAX; AXES], &far, 1, 0));
        assert!(!too_fast(&l, &[i32::MAX; AXES], &far, u64::MAX, 0));
        // |d| is 7.4e9 µm from corner to corner: too fast for an allowance of 2^32 − 1, not
        // for 2^32 (the noise doubled, plus 1 µm of 100 mm/s for 1 µs).
        let corner = [i32::MAX; AXES];
        assert!(too_fast(&l, &corner, &far, 1, (1 << 31) - 1));
        assert!(!too_fast(&l, &corner, &far, 1, 1 << 31));
    }
}

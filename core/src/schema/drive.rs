//! The drive's frames (docs/can-protocol.md, "The drive's frames"): three signed 21-bit values
//! and a flag in 8 bytes, little endian.
//!
//! Why 21 bits: three of them and a flag fill a classic frame, so a pose travels in two frames
//! (translation, rotation) instead of three or four, and ±2^20 µm is ±1.048 m, µrad ±1.048 rad:
//! an arm's reach and a wrist's turn. A value beyond is sent saturated (a limit event stops the
//! robot long before).

use super::{Gripper, Pose, Setpoint};

/// The largest value a field holds: 2^20 − 1.
pub const FIELD_MAX: i32 = (1 << 20) - 1;
/// The smallest: −2^20.
pub const FIELD_MIN: i32 = -(1 << 20);

/// Packs three values (saturated to 21 bits) and a flag.
// Left to the inliner: out of line (one copy for the attractor's two frames) it took 28 bytes
// more of the NUCLEO-G474RE's flash than its two inlined copies.
pub fn pack(values: [i32; 3], flag: bool) -> [u8; 8] {
    let field = |v: i32| u64::from(v.clamp(FIELD_MIN, FIELD_MAX) as u32 & 0x1F_FFFF);
    let [x, y, z] = values;
    let (x, y, z) = (field(x), field(y), field(z));
    // Constant shifts: a 64-bit shift by a variable is a dozen instructions on a Cortex-M4.
    (x | y << 21 | z << 42 | u64::from(flag) << 63).to_le_bytes()
}

/// Unpacks a frame's payload: three values and the flag, or `None` unless it has 8 bytes.
pub fn unpack(data: &[u8]) -> Option<([i32; 3], bool)> {
    let bytes: [u8; 8] = data.try_into().ok()?;
    let word = u64::from_le_bytes(bytes);
    // The field's 21 bits at the top of a u32 (the shift drops the bits above them), then
    // sign-extended from bit 20; constant shifts, as in `pack`.
    let field = |shift: u32| ((((word >> shift) as u32) << 11) as i32) >> 11;
    Some(([field(0), field(21), field(42)], word >> 63 != 0))
}

/// The two attractor frames of a set-point: translation (flag: gripper closed) and rotation.
pub fn attractor_frames(s: &Setpoint) -> [[u8; 8]; 2] {
    let [x, y, z, rx, ry, rz] = s.attractor;
    [
        pack([x, y, z], s.gripper == Gripper::Closed),
        pack([rx, ry, rz], false),
    ]
}

/// The impedance frame: stiffness then damping, u32 LE each.
pub fn impedance_frame(s: &Setpoint) -> [u8; 8] {
    let mut out = [0u8; 8];
    let (k, d) = out.split_at_mut(4);
    k.copy_from_slice(&s.stiffness.to_le_bytes());
    d.copy_from_slice(&s.damping.to_le_bytes());
    out
}

/// Puts three values from a frame into `pose` at `axis` (0: translation, 3: rotation).
pub fn place(pose: &mut Pose, axis: usize, values: [i32; 3]) {
    // By index, those that fit: a zip with the array by value copied it first.
    for (i, v) in values.iter().enumerate() {
        if let Some(slot) = pose.get_mut(axis.saturating_add(i)) {
            *slot = *v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_round_trip_and_saturate() {
        for v in [
            0, 1, -1, 1000, -1000, FIELD_MAX, FIELD_MIN, 123_456, -654_321,
        ] {
            let frame = pack([v, -v.saturating_add(0).max(FIELD_MIN + 1), 7], true);
            let (values, flag) = unpack(&frame).unwrap();
            assert_eq!(values[0], v);
            assert_eq!(values[2], 7);
            assert!(flag);
        }
        let (values, flag) = unpack(&pack([i32::MAX, i32::MIN, 2_000_000], false)).unwrap();
        assert_eq!(values, [FIELD_MAX, FIELD_MIN, FIELD_MAX]);
        assert!(!flag);
        assert_eq!(unpack(&[0; 7]), None);
        // The layout: x in bits 0-20, y in 21-41, z in 42-62, the flag in 63.
        let frame = pack([1, 1, 1], true);
        assert_eq!(
            u64::from_le_bytes(frame),
            1 | (1 << 21) | (1 << 42) | (1 << 63)
        );
        assert_eq!(pack([-1, 0, 0], false), [0xFF, 0xFF, 0x1F, 0, 0, 0, 0, 0]);
    }
}

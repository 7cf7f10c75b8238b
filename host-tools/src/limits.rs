//! `pabctl limits`: a schema server's safety bounds set at run time, from its table's and the
//! command line's, in the network file's units (N, N·m, mm, mm/s, rad/s, a sensor's unit).
//!
//! The board takes limits only within its table's ([`pab_core::schema::Limits::check_within`]):
//! tighter, or back up to the table's. The tool checks that first and names every bound that would
//! be looser, in the network file's words, so that a refusal never needs the bus to be explained.

use pab_core::schema::{Limits, MAX_COORD};
use pab_lang::network::SchemaBoard;

/// What the command line changes (`pabctl limits`' options); every other bound stays the
/// table's.
#[derive(Clone, Debug, Default, PartialEq, clap::Args)]
pub struct Overrides {
    /// The safety limit on |F|, N.
    #[arg(long, value_name = "N")]
    pub force_limit_n: Option<f64>,
    /// The safety limit on |T|, N·m.
    #[arg(long, value_name = "NM")]
    pub torque_limit_nm: Option<f64>,
    /// The highest contact force a schema may wait for, N.
    #[arg(long, value_name = "N")]
    pub contact_limit_n: Option<f64>,
    /// The top speed of the measured translation, mm/s.
    #[arg(long, value_name = "MM_S")]
    pub speed_limit_mm_s: Option<f64>,
    /// The top rate of the measured rotation, rad/s.
    #[arg(long, value_name = "RAD_S")]
    pub rate_limit_rad_s: Option<f64>,
    /// The workspace's lower corner, mm.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = point)]
    pub workspace_min_mm: Option<[f64; 3]>,
    /// The workspace's upper corner, mm.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = point)]
    pub workspace_max_mm: Option<[f64; 3]>,
    /// A joint's range (and speed per second), in its sensor's unit; repeat for several.
    #[arg(long = "joint", value_name = "SENSOR=MIN:MAX[:SPEED]", value_parser = joint)]
    pub joints: Vec<JointOverride>,
}

/// One `--joint SENSOR=MIN:MAX[:SPEED]`.
#[derive(Clone, Debug, PartialEq)]
pub struct JointOverride {
    /// The sensor's name in the network file.
    pub sensor: String,
    /// The lowest position, in the sensor's unit.
    pub min: f64,
    /// The highest.
    pub max: f64,
    /// The top speed per second (`None`: the table's).
    pub speed: Option<f64>,
}

/// Reads `X,Y,Z` (mm).
pub fn point(text: &str) -> Result<[f64; 3], String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("`{text}` is not three numbers X,Y,Z (mm)"))?;
    match <[f64; 3]>::try_from(values) {
        Ok(p) if p.iter().all(|v| v.is_finite()) => Ok(p),
        _ => Err(format!("`{text}` is not three finite numbers X,Y,Z (mm)")),
    }
}

/// Reads `SENSOR=MIN:MAX` or `SENSOR=MIN:MAX:SPEED`.
pub fn joint(text: &str) -> Result<JointOverride, String> {
    let usage = || format!("`{text}` is not SENSOR=MIN:MAX or SENSOR=MIN:MAX:SPEED");
    let (sensor, range) = text.split_once('=').ok_or_else(usage)?;
    let numbers: Vec<f64> = range
        .split(':')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| usage())?;
    if numbers.iter().any(|v| !v.is_finite()) {
        return Err(usage());
    }
    let (min, max, speed) = match numbers.as_slice() {
        [min, max] => (*min, *max, None),
        [min, max, speed] => (*min, *max, Some(*speed)),
        _ => return Err(usage()),
    };
    Ok(JointOverride {
        sensor: sensor.trim().to_string(),
        min,
        max,
        speed,
    })
}

/// The board's table limits with `o` applied, checked against them: the limits, or every reason
/// they are not acceptable (a value out of range, an unknown sensor, a bound looser than the
/// table's), in the network file's words.
pub fn apply(board: &SchemaBoard, o: &Overrides) -> Result<Limits, Vec<String>> {
    let table = &board.config.limits;
    let mut l = table.clone();
    let mut errors = Vec::new();
    let max = f64::from(MAX_COORD);
    let mut amount = |value: Option<f64>, scale: f64, key: &str, slot: &mut u32| {
        if let Some(v) = value {
            let scaled = (v * scale).round();
            if !(0.0..=max).contains(&scaled) {
                errors.push(format!("{key} {v} is not within 0..={}", max / scale));
            } else {
                *slot = scaled as u32;
            }
        }
    };
    amount(o.force_limit_n, 1000.0, "force_limit_n", &mut l.force_limit);
    amount(
        o.torque_limit_nm,
        1000.0,
        "torque_limit_nm",
        &mut l.torque_limit,
    );
    amount(
        o.contact_limit_n,
        1000.0,
        "contact_limit_n",
        &mut l.contact_limit,
    );
    amount(
        o.speed_limit_mm_s,
        1000.0,
        "speed_limit_mm_s",
        &mut l.speed_limit,
    );
    amount(
        o.rate_limit_rad_s,
        1e6,
        "rate_limit_rad_s",
        &mut l.rate_limit,
    );
    for (corner, slot, key) in [
        (o.workspace_min_mm, &mut l.workspace_min, "workspace_min_mm"),
        (o.workspace_max_mm, &mut l.workspace_max, "workspace_max_mm"),
    ] {
        if let Some(p) = corner {
            for (axis, v) in p.iter().enumerate() {
                let scaled = (v * 1000.0).round();
                if scaled.abs() > max {
                    errors.push(format!("{key}: {v} mm is beyond ±{} mm", max / 1000.0));
                } else {
                    slot[axis] = scaled as i32;
                }
            }
        }
    }
    for j in &o.joints {
        let Some(index) = board.sensors.iter().position(|s| s.name == j.sensor) else {
            let known: Vec<&str> = board.sensors.iter().map(|s| s.name.as_str()).collect();
            errors.push(format!(
                "--joint {}: no such sensor (sensors: {})",
                j.sensor,
                if known.is_empty() {
                    "none".to_string()
                } else {
                    known.join(", ")
                }
            ));
            continue;
        };
        let Some(slot) = l.joints.iter_mut().find(|t| usize::from(t.sensor) == index) else {
            errors.push(format!(
                "--joint {}: the sensor is no joint in the table (give it `joint = {{ min, max }}` in the network file)",
                j.sensor
            ));
            continue;
        };
        let scale = board.sensors[index].scale;
        // Inwards to whole counts, as the compiler rounds a joint's range.
        let counts = |v: f64| v / scale;
        let (min, max) = (counts(j.min).ceil(), counts(j.max).floor());
        if !(f64::from(i32::MIN)..=f64::from(i32::MAX)).contains(&min)
            || !(f64::from(i32::MIN)..=f64::from(i32::MAX)).contains(&max)
        {
            errors.push(format!(
                "--joint {}: a bound beyond the sensor's counts",
                j.sensor
            ));
            continue;
        }
        slot.min = min as i32;
        slot.max = max as i32;
        if let Some(speed) = j.speed {
            let rate = (speed / scale).floor();
            if !(1.0..=f64::from(u32::MAX)).contains(&rate) {
                errors.push(format!(
                    "--joint {}: a speed of at least one count ({scale}) a second",
                    j.sensor
                ));
                continue;
            }
            slot.rate = rate as u32;
        }
    }
    // Every reason at once: the bounds given, then what they would loosen.
    errors.extend(looser(board, &l));
    if errors.is_empty() {
        Ok(l)
    } else {
        Err(errors)
    }
}

/// A limit in its unit (`value` / `scale`), or `none` for 0.
fn limit(value: u32, scale: f64, unit: &str) -> String {
    if value == 0 {
        "none".to_string()
    } else {
        format!("{} {unit}", f64::from(value) / scale)
    }
}

/// Every bound of `l` looser than the table's or inconsistent, in the network file's words.
pub fn looser(board: &SchemaBoard, l: &Limits) -> Vec<String> {
    let t = &board.config.limits;
    let mut out = Vec::new();
    for (key, new, old, scale, unit) in [
        ("force_limit_n", l.force_limit, t.force_limit, 1000.0, "N"),
        (
            "torque_limit_nm",
            l.torque_limit,
            t.torque_limit,
            1000.0,
            "N·m",
        ),
        (
            "contact_limit_n",
            l.contact_limit,
            t.contact_limit,
            1000.0,
            "N",
        ),
        (
            "speed_limit_mm_s",
            l.speed_limit,
            t.speed_limit,
            1000.0,
            "mm/s",
        ),
        ("rate_limit_rad_s", l.rate_limit, t.rate_limit, 1e6, "rad/s"),
    ] {
        if old != 0 && (new == 0 || new > old) {
            out.push(format!(
                "{key}: {} is looser than the table's {} (limits may only tighten)",
                limit(new, scale, unit),
                limit(old, scale, unit)
            ));
        }
    }
    const AXIS: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];
    for (a, axis) in AXIS.iter().enumerate() {
        let unit = if a < 3 { "mm" } else { "mrad" };
        let shown = |v: i32| f64::from(v) / 1000.0;
        if l.workspace_min[a] < t.workspace_min[a] {
            out.push(format!(
                "workspace {}: a lowest {} {unit} is below the table's {} {unit}",
                axis,
                shown(l.workspace_min[a]),
                shown(t.workspace_min[a])
            ));
        }
        if l.workspace_max[a] > t.workspace_max[a] {
            out.push(format!(
                "workspace {}: a highest {} {unit} is above the table's {} {unit}",
                axis,
                shown(l.workspace_max[a]),
                shown(t.workspace_max[a])
            ));
        }
        if l.workspace_min[a] > l.workspace_max[a] {
            out.push(format!(
                "workspace {}: the lowest {} {unit} is above the highest {} {unit}",
                axis,
                shown(l.workspace_min[a]),
                shown(l.workspace_max[a])
            ));
        }
    }
    for (new, old) in l.joints.iter().zip(&t.joints) {
        let Some(sensor) = board.sensors.get(usize::from(new.sensor)) else {
            continue;
        };
        let unit = |v: f64| format!("{} {}", shown(v * sensor.scale), sensor.unit);
        let name = &sensor.name;
        if new.min < old.min {
            out.push(format!(
                "joint {name}: a lowest {} is below the table's {}",
                unit(f64::from(new.min)),
                unit(f64::from(old.min))
            ));
        }
        if new.max > old.max {
            out.push(format!(
                "joint {name}: a highest {} is above the table's {}",
                unit(f64::from(new.max)),
                unit(f64::from(old.max))
            ));
        }
        if new.min > new.max {
            out.push(format!(
                "joint {name}: the lowest position is above the highest"
            ));
        }
        if old.rate != 0 && (new.rate == 0 || new.rate > old.rate) {
            out.push(format!(
                "joint {name}: a speed of {}/s is looser than the table's {}/s",
                unit(f64::from(new.rate)),
                unit(f64::from(old.rate))
            ));
        }
    }
    // What the board checks, the same way: nothing the list above missed.
    if out.is_empty()
        && let Err(e) = l.check_within(t)
    {
        out.push(format!("refused as the board would: {e}"));
    }
    out
}

/// The limits in one line each, in the network file's units.
pub fn describe(board: &SchemaBoard, l: &Limits) -> Vec<String> {
    let mm = |p: &[i32; 6]| {
        p[..3]
            .iter()
            .map(|v| format!("{}", f64::from(*v) / 1000.0))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut out = vec![
        format!("force limit {}", limit(l.force_limit, 1000.0, "N")),
        format!("torque limit {}", limit(l.torque_limit, 1000.0, "N·m")),
        format!("contact limit {}", limit(l.contact_limit, 1000.0, "N")),
        format!("speed limit {}", limit(l.speed_limit, 1000.0, "mm/s")),
        format!("rate limit {}", limit(l.rate_limit, 1e6, "rad/s")),
        format!(
            "workspace [{}] to [{}] mm",
            mm(&l.workspace_min),
            mm(&l.workspace_max)
        ),
    ];
    for j in &l.joints {
        if let Some(s) = board.sensors.get(usize::from(j.sensor)) {
            let v = |c: i64| format!("{}", shown(c as f64 * s.scale));
            out.push(format!(
                "joint {}: {} to {} {}, speed {}",
                s.name,
                v(j.min.into()),
                v(j.max.into()),
                s.unit,
                if j.rate == 0 {
                    "none".to_string()
                } else {
                    format!("{} {}/s", v(j.rate.into()), s.unit)
                }
            ));
        }
    }
    out
}

/// A value in a unit, without the last bits of a binary fraction (0.1 × 3 is 0.3, not
/// 0.30000000000000004).
fn shown(v: f64) -> f64 {
    (v * 1e9).round() / 1e9
}

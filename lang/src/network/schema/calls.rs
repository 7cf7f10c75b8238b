//! One call of a program or an innate schema, `name(argument, key=value, …); EVENT -> SOURCE`:
//! split, its arguments checked in the client's units, its reactions and thresholds read, and the
//! schema made by [`pab_core::schema::build`].

use super::*;

/// A call parsed: its name, positional arguments and keyword arguments, with the byte offset of
/// each within the call's text.
pub(super) struct Parsed<'a> {
    name: &'a str,
    positional: Vec<(&'a str, usize)>,
    keywords: Vec<(&'a str, &'a str, usize)>,
}

/// Splits `name(a, k=v, …)`; the error names the offending column's cause.
pub(super) fn split_call(text: &str) -> Result<Parsed<'_>, (usize, String)> {
    let open = text.find('(').ok_or((
        0,
        "a call is written `name(arguments)`, for example `grasp()`".to_string(),
    ))?;
    let name = text[..open].trim();
    if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err((0, format!("`{}` is not a call's name", name)));
    }
    let inner = text[open + 1..].trim_end();
    let Some(inner) = inner.strip_suffix(')') else {
        return Err((text.len(), "the call's `)` is missing".to_string()));
    };
    let mut positional = Vec::new();
    let mut keywords = Vec::new();
    let mut offset = open + 1;
    if !inner.trim().is_empty() {
        for part in inner.split(',') {
            let at = offset + (part.len() - part.trim_start().len());
            offset += part.len() + 1;
            let part = part.trim();
            if part.is_empty() {
                return Err((at, "an empty argument".to_string()));
            }
            match part.split_once('=') {
                Some((k, v)) => keywords.push((k.trim(), v.trim(), at)),
                None if keywords.is_empty() => positional.push((part, at)),
                None => {
                    return Err((
                        at,
                        format!("`{part}`: positional arguments come before keywords"),
                    ));
                }
            }
        }
    }
    Ok(Parsed {
        name,
        positional,
        keywords,
    })
}

impl Builder<'_> {
    /// One call's schema (with id `id`), or, among commands, an abort or emergency stop.
    ///
    /// `CALL; EVENT -> SOURCE; …`: the reactions written after the call come before the call's
    /// own (the first that holds wins, so `done -> high_priority` there replaces a call's
    /// `done -> queue`).
    pub(super) fn call(
        &mut self,
        text: &Spanned<String>,
        id: u16,
        places: &[(String, Pose)],
        d: &Defaults,
        command: bool,
        names: Names<'_>,
    ) -> Option<Made> {
        // The string's content starts after its opening quote.
        let base = text.span().start + 1;
        let at = |offset: usize| base + offset..base + offset + 1;
        let full = text.get_ref().as_str();
        let (call_text, reactions_at) = match full.find(';') {
            Some(i) => (&full[..i], Some(i + 1)),
            None => (full, None),
        };
        let parsed = match split_call(call_text) {
            Ok(p) => p,
            Err((offset, message)) => {
                self.error(at(offset), message);
                return None;
            }
        };
        let mut written = Vec::new();
        if let Some(start) = reactions_at {
            let mut offset = start;
            for part in full[start..].split(';') {
                let lead = part.len() - part.trim_start().len();
                match reaction(part.trim(), names) {
                    Ok(r) => written.push(r),
                    Err((o, message)) => {
                        self.error(at(offset + lead + o), message);
                        return None;
                    }
                }
                offset += part.len() + 1;
            }
            if command && matches!(parsed.name, "estop" | "abort") {
                self.error(
                    at(start),
                    format!(
                        "`{}()` is a command, not a schema: it takes no reactions",
                        parsed.name
                    ),
                );
                return None;
            }
        }
        let mut args: HashMap<&str, (f64, usize)> = HashMap::new();
        for (k, v, offset) in &parsed.keywords {
            match v.parse::<f64>() {
                Ok(x) if x.is_finite() && x >= 0.0 => {
                    args.insert(k, (x, *offset));
                }
                _ => {
                    self.error(
                        at(*offset),
                        format!("`{k}={v}`: a keyword's value is a number, 0 or more"),
                    );
                    return None;
                }
            }
        }
        let allowed: &[&str] = match parsed.name {
            "move_to" => &["speed"],
            "move_to_touch" => &["speed", "contact", "distance"],
            "grasp" | "release" => &["settle"],
            "blind_search" => &[
                "preload", "pitch", "speed", "radius", "wobble", "period", "depth",
            ],
            "set_impedance" => &["stiffness", "damping"],
            _ => &[],
        };
        for (k, _, offset) in &parsed.keywords {
            if *k != "watchdog" && !allowed.contains(k) {
                self.error(
                    at(*offset),
                    format!(
                        "`{}` takes no `{k}` (it takes: {})",
                        parsed.name,
                        list_or_none(allowed)
                    ),
                );
                return None;
            }
        }
        let positional = |n: usize| parsed.positional.get(n).copied();
        let expect_args = |b: &mut Self, n: usize| -> bool {
            if let Some((extra, offset)) = positional(n) {
                b.error(
                    at(offset),
                    format!(
                        "`{}` takes {n} positional argument{}; `{extra}` is one too many",
                        parsed.name,
                        if n == 1 { "" } else { "s" }
                    ),
                );
                false
            } else {
                true
            }
        };
        // mm (or mm/s, N) → µm (µm/s, mN); ms stay ms; mrad → µrad.
        let scaled = |b: &mut Self, key: &str, scale: f64, default: u32| -> Option<u32> {
            let Some((v, offset)) = args.get(key).copied() else {
                return Some(default);
            };
            let x = (v * scale).round();
            if x > f64::from(MAX_COORD) {
                b.error(at(offset), format!("`{key}` is too large"));
                return None;
            }
            Some(x as u32)
        };
        let place = |b: &mut Self, what: &str| -> Option<Pose> {
            let Some((name, offset)) = positional(0) else {
                b.error(
                    at(0),
                    format!(
                        "`{}` needs a {what}: `{}({what})`",
                        parsed.name, parsed.name
                    ),
                );
                return None;
            };
            match places.iter().find(|(n, _)| n == name) {
                Some((_, p)) => Some(*p),
                None => {
                    let known: Vec<&str> = places.iter().map(|(n, _)| n.as_str()).collect();
                    b.error(
                        at(offset),
                        format!(
                            "place `{name}` is not in [client.places] ({})",
                            list_or_none(&known)
                        ),
                    );
                    None
                }
            }
        };
        let mut schema = match parsed.name {
            "estop" | "abort" if command => {
                if !expect_args(self, 0) {
                    return None;
                }
                return Some(if parsed.name == "estop" {
                    Made::EmergencyStop
                } else {
                    Made::Abort
                });
            }
            "move_to" => {
                let goal = place(self, "PLACE")?;
                if !expect_args(self, 1) {
                    return None;
                }
                let speed = scaled(self, "speed", 1000.0, d.speed)?;
                build::move_to(id, goal, speed)
            }
            "move_to_touch" => {
                let direction = place(self, "DIRECTION")?;
                if !expect_args(self, 1) {
                    return None;
                }
                let speed = scaled(self, "speed", 1000.0, d.touch_speed)?;
                let contact = scaled(self, "contact", 1000.0, d.contact as u32)?;
                let distance = scaled(self, "distance", 1000.0, d.touch_distance)?;
                build::move_to_touch(id, direction, speed, contact as i32, distance)
            }
            "grasp" | "release" => {
                if !expect_args(self, 0) {
                    return None;
                }
                let settle = scaled(self, "settle", 1.0, d.settle_ms)?;
                if parsed.name == "grasp" {
                    build::grasp(id, settle)
                } else {
                    build::release(id, settle)
                }
            }
            "blind_search" => {
                if !expect_args(self, 0) {
                    return None;
                }
                let search = Action::BlindSearch {
                    preload: scaled(self, "preload", 1000.0, d.preload)?,
                    pitch: scaled(self, "pitch", 1000.0, d.pitch)?,
                    speed: scaled(self, "speed", 1000.0, d.search_speed)?,
                    radius: scaled(self, "radius", 1000.0, d.search_radius)?,
                    wobble: scaled(self, "wobble", 1000.0, d.wobble)?,
                    wobble_ms: scaled(self, "period", 1.0, d.wobble_ms)?,
                };
                let depth = scaled(self, "depth", 1000.0, d.insert_depth)?;
                build::blind_search(id, search, depth)
            }
            "idle" => {
                let ms = match positional(0) {
                    None => 0,
                    Some((v, offset)) => match v.parse::<f64>() {
                        Ok(x) if x.is_finite() && (0.0..=f64::from(MAX_COORD)).contains(&x) => {
                            x.round() as u32
                        }
                        _ => {
                            self.error(
                                at(offset),
                                format!("`idle({v})`: the time is a number of ms"),
                            );
                            return None;
                        }
                    },
                };
                if !expect_args(self, 1) {
                    return None;
                }
                build::idle(id, ms)
            }
            "open" | "close" => {
                if !expect_args(self, 0) {
                    return None;
                }
                build::gripper(
                    id,
                    if parsed.name == "close" {
                        Gripper::Closed
                    } else {
                        Gripper::Open
                    },
                )
            }
            "relieve" => {
                if !expect_args(self, 0) {
                    return None;
                }
                build::atomic(id, Action::Relieve)
            }
            "set_impedance" => {
                if !expect_args(self, 0) {
                    return None;
                }
                let stiffness = scaled(self, "stiffness", 1.0, 2000)?;
                let damping = scaled(self, "damping", 1.0, 100)?;
                build::atomic(id, Action::SetImpedance { stiffness, damping })
            }
            other => {
                let extra = if command {
                    "; a command may also be estop() or abort()"
                } else {
                    ""
                };
                self.error(
                    at(0),
                    format!("unknown call `{other}`: the calls are {CALLS}{extra}"),
                );
                return None;
            }
        };
        if let Some((w, _)) = args.get("watchdog") {
            schema.watchdog_ms = w.round().min(f64::from(MAX_COORD)) as u32;
        }
        if !written.is_empty() {
            let own = std::mem::take(&mut schema.reactions);
            for r in written.iter().chain(&own) {
                if schema.reactions.push(*r).is_err() {
                    self.error(
                        at(reactions_at.unwrap_or(0)),
                        format!(
                            "{} reactions with the call's own {}: a schema holds at most {MAX_REACTIONS}",
                            written.len() + own.len(),
                            own.len()
                        ),
                    );
                    return None;
                }
            }
        }
        if let Err(e) = schema.check() {
            self.error(
                text.span(),
                format!(
                    "`{}` makes a schema the board refuses: {e:?}",
                    text.get_ref()
                ),
            );
            return None;
        }
        Some(Made::Schema(Box::new(schema)))
    }
}

/// A call's name in traces: its text up to its reactions.
pub(super) fn call_name(text: &str) -> String {
    text.split(';').next().unwrap_or(text).trim().to_string()
}

/// Letters, digits and `_`, not starting with a digit.
pub(super) fn is_identifier(name: &str) -> bool {
    name.chars().next().is_some_and(|c| !c.is_ascii_digit())
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// The words a measure starts with: no sensor may be called so.
pub(super) fn is_measure_word(name: &str) -> bool {
    matches!(name, "contact" | "position" | "displacement" | "force")
}

pub(super) const REACTION_HELP: &str = "a reaction is written `EVENT -> SOURCE`: EVENT one of done, one_shot, \
     queue_ready, elapsed(ms), above(MEASURE, VALUE), below(MEASURE, VALUE); SOURCE queue, \
     high_priority or an innate schema's name";
pub(super) const MEASURE_HELP: &str = "contact (N), position.AXIS or displacement.AXIS (mm; mrad about rx, \
     ry, rz), force.AXIS (N; N·m about rx, ry, rz), with AXIS x, y, z, rx, ry or rz, or a sensor \
     of [schema.NODE.sensors] (in its unit)";

/// One reaction, `EVENT -> SOURCE`; an error's byte offset within `text` and its cause.
pub(super) fn reaction(text: &str, names: Names<'_>) -> Result<Reaction, (usize, String)> {
    let list = |v: Vec<&str>| list_or_none(&v);
    let Some(arrow) = text.find("->") else {
        return Err((0, REACTION_HELP.to_string()));
    };
    let (event_text, source_text) = (&text[..arrow], &text[arrow + 2..]);
    let source_at = arrow + 2 + (source_text.len() - source_text.trim_start().len());
    let next = match source_text.trim() {
        "queue" => Source::Queue,
        "high_priority" => Source::HighPriority,
        name => match names.innate.iter().position(|n| n == name) {
            Some(i) => Source::Innate(i as u8),
            None => {
                return Err((
                    source_at,
                    format!(
                        "`{name}` is not a source: queue, high_priority or an innate schema of the board (innate: {})",
                        list(names.innate.iter().map(String::as_str).collect())
                    ),
                ));
            }
        },
    };
    let event_text = event_text.trim_end();
    let event = match event_text {
        "done" => Event::Done,
        "one_shot" => Event::OneShot,
        "queue_ready" => Event::QueueReady,
        _ => {
            let parsed = split_call(event_text).map_err(|_| (0, REACTION_HELP.to_string()))?;
            if let Some((k, _, o)) = parsed.keywords.first() {
                return Err((*o, format!("`{k}=`: an event takes no keywords")));
            }
            let args = &parsed.positional;
            let arity = if parsed.name == "elapsed" { 1 } else { 2 };
            if !matches!(parsed.name, "elapsed" | "above" | "below") {
                return Err((
                    0,
                    format!("unknown event `{}`: {REACTION_HELP}", parsed.name),
                ));
            }
            if args.len() != arity {
                return Err((
                    0,
                    format!(
                        "`{}` takes {arity} argument{}",
                        parsed.name,
                        if arity == 1 {
                            ": a time in ms"
                        } else {
                            "s: a measure and a value"
                        }
                    ),
                ));
            }
            let number = |(v, o): (&str, usize)| match v.parse::<f64>() {
                Ok(x) if x.is_finite() => Ok(x),
                _ => Err((o, format!("`{v}` is not a number"))),
            };
            if parsed.name == "elapsed" {
                let ms = number(args[0])?;
                if !(0.0..=f64::from(MAX_COORD)).contains(&ms) {
                    return Err((
                        args[0].1,
                        format!("elapsed: {ms} ms is not 0 to {MAX_COORD}"),
                    ));
                }
                Event::Elapsed(ms.round() as u32)
            } else {
                let above = parsed.name == "above";
                let value = number(args[1])?;
                let (measure, threshold) = threshold(args[0], value, above, names)?;
                let threshold = threshold.ok_or((
                    args[1].1,
                    format!(
                        "`{}` is beyond what a threshold holds (±2^31 of the board's units)",
                        args[1].0
                    ),
                ))?;
                if above {
                    Event::Above(measure, threshold)
                } else {
                    Event::Below(measure, threshold)
                }
            }
        }
    };
    Ok(Reaction { event, next })
}

/// The measure `m` names and `value` (in the file's units) in the board's: ×1000 for mm, mrad,
/// N and N·m; counts for a sensor, rounded so that the board's integer comparison holds exactly
/// when the value in units would (up for `above`, down for `below`). `None`: beyond `i32`.
pub(super) fn threshold(
    (m, offset): (&str, usize),
    value: f64,
    above: bool,
    names: Names<'_>,
) -> Result<(Measure, Option<i32>), (usize, String)> {
    const AXES_NAMES: [&str; AXES] = ["x", "y", "z", "rx", "ry", "rz"];
    let fits = |x: f64| {
        (f64::from(i32::MIN)..=f64::from(i32::MAX))
            .contains(&x)
            .then_some(x as i32)
    };
    let physical = |measure| Ok((measure, fits((value * 1000.0).round())));
    let axis = |a: &str| {
        AXES_NAMES
            .iter()
            .position(|n| *n == a)
            .map(|i| i as u8)
            .ok_or((
                offset,
                format!("`{m}`: the axes are x, y, z, rx, ry and rz"),
            ))
    };
    match m.split_once('.') {
        Some(("position", a)) => physical(Measure::Position(axis(a)?)),
        Some(("displacement", a)) => physical(Measure::Displacement(axis(a)?)),
        Some(("force", a)) => physical(Measure::Force(axis(a)?)),
        None if m == "contact" => physical(Measure::Contact),
        _ => {
            let Some(i) = names.sensors.iter().position(|s| s.name == m) else {
                let known: Vec<&str> = names.sensors.iter().map(|s| s.name.as_str()).collect();
                return Err((
                    offset,
                    format!(
                        "`{m}` is not a measure: {MEASURE_HELP} (sensors: {})",
                        list_or_none(&known)
                    ),
                ));
            };
            let topic = &names.sensors[i];
            let counts = value / topic.scale;
            let nearest = counts.round();
            // Within rounding of a whole count it is that count (0.3 mm / 0.1 mm is 2.999…).
            let counts = if (counts - nearest).abs() <= 1e-9 * nearest.abs().max(1.0) {
                nearest
            } else if above {
                counts.ceil()
            } else {
                counts.floor()
            };
            let (low, high) = topic.sensor.field.range();
            let never = if above {
                counts > high as f64
            } else {
                counts < low as f64
            };
            if never {
                return Err((
                    offset,
                    format!(
                        "`{}({m}, {value})` can never hold: sensor `{m}` reads {} to {} {}",
                        if above { "above" } else { "below" },
                        low as f64 * topic.scale,
                        high as f64 * topic.scale,
                        topic.unit
                    ),
                ));
            }
            Ok((Measure::Sensor(i as u8), fits(counts)))
        }
    }
}

/// What a call makes.
pub(super) enum Made {
    Schema(Box<Schema>),
    Abort,
    EmergencyStop,
}

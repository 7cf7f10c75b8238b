//! `[schema.NODE]`: a schema server's board (period, drive, safety limits, workspace, sensors,
//! joints, places, innate schemas), read into [`SchemaBoard`].

use super::*;

impl Builder<'_> {
    pub(in crate::network) fn schema_boards(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawSchema>>,
        nodes: &[Node],
    ) -> Vec<SchemaBoard> {
        let mut boards = Vec::new();
        for (name, section) in raw {
            let Some(node) = nodes.iter().position(|n| &n.name == name.get_ref()) else {
                let known: Vec<&str> = nodes.iter().map(|n| n.name.as_str()).collect();
                self.error(
                    name.span(),
                    format!(
                        "[schema.{}]: node `{}` is not defined (nodes: {})",
                        name.get_ref(),
                        name.get_ref(),
                        list_or_none(&known)
                    ),
                );
                continue;
            };
            if !boards.is_empty() {
                self.error(
                    name.span(),
                    "one schema server per network file: the simulator drives one plant with one client",
                );
                continue;
            }
            let raw = section.get_ref();
            let errors = self.errors.len();
            let drive = self.drive(&raw.drive);
            let sensors = self.sensors(&raw.sensors, drive.as_ref());
            let places = self.places(&raw.places);
            let innate = self.innate(raw, name.get_ref(), &sensors, &places);
            if let (Some(mut config), Some(drive)) = (self.schema_config(raw), drive)
                && self.errors.len() == errors
            {
                // The joints' limits, from their sensors (at most MAX_SENSORS = MAX_JOINTS).
                for joint in sensors.iter().filter_map(|s| s.joint) {
                    let _ = config.limits.joints.push(joint);
                }
                let mut names = Vec::new();
                for (name, schema) in innate {
                    // `innate` took at most MAX_INNATE.
                    let _ = config.innate.push(schema);
                    names.push(name);
                }
                boards.push(SchemaBoard {
                    node,
                    config,
                    drive,
                    sensors,
                    innate: names,
                    span: section.span(),
                });
            }
        }
        boards
    }

    /// `[schema.NODE.sensors.NAME]`: each a topic on its own identifier or sharing one (each
    /// its own field), off the drive's frames.
    pub(super) fn sensors(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawSensor>>,
        drive: Option<&Drive>,
    ) -> Vec<SensorTopic> {
        let mut out = Vec::new();
        if raw.len() > MAX_SENSORS {
            if let Some((name, _)) = raw.get_index(MAX_SENSORS) {
                self.error(
                    name.span(),
                    format!(
                        "sensors: {} of them; a board reads at most {MAX_SENSORS}",
                        raw.len()
                    ),
                );
            }
            return out;
        }
        for (name, section) in raw {
            let s = section.get_ref();
            let what = format!("sensor `{}`", name.get_ref());
            if !self.printable(name, "sensor name") {
                continue;
            }
            if !is_identifier(name.get_ref()) || is_measure_word(name.get_ref()) {
                self.error(
                    name.span(),
                    format!(
                        "{what}: a sensor's name is letters, digits and _ (not starting with a digit), \
                         and not `contact`, `position`, `displacement` or `force`"
                    ),
                );
                continue;
            }
            let id = u32::try_from(*s.can_id.get_ref())
                .ok()
                .and_then(|v| OutputId::new(v, s.extended).ok());
            let Some(id) = id else {
                let max = if s.extended { "0x1FFFFFFF" } else { "0x7FF" };
                self.error(
                    s.can_id.span(),
                    format!("{what}: can_id is 0..={max} (extended = {})", s.extended),
                );
                continue;
            };
            let on_drive = drive.is_some_and(|d| {
                [(d.setpoint, 3), (d.pose, 2), (d.wrench, 2)]
                    .iter()
                    .any(|(base, n)| {
                        base.is_extended() == id.is_extended()
                            && id.raw().wrapping_sub(base.raw()) < *n
                    })
            });
            if on_drive {
                self.error(
                    s.can_id.span(),
                    format!("{what}: can_id is one of the drive's frames"),
                );
                continue;
            }
            if pab_core::protocol::classify_id(&id.id()).is_ours() {
                self.error(
                    s.can_id.span(),
                    format!(
                        "{what}: can_id is in the project's own protocol space (29-bit ids with 0b10 in bits 25..24)"
                    ),
                );
                continue;
            }
            let Some(field) = self.field(&s.value, &format!("{what}: value")) else {
                continue;
            };
            let scale = match &s.scale {
                None => 1.0,
                Some(v) if v.get_ref().is_finite() && *v.get_ref() > 0.0 => *v.get_ref(),
                Some(v) => {
                    self.error(
                        v.span(),
                        format!("{what}: scale is a positive number (units per count)"),
                    );
                    continue;
                }
            };
            let unit = match &s.unit {
                None => String::new(),
                Some(u) if self.printable(u, "unit") => u.get_ref().clone(),
                Some(_) => continue,
            };
            let joint = match &s.joint {
                Some(j) => match self.joint(j, out.len(), field.range(), scale, &what, &unit) {
                    Some(joint) => Some(joint),
                    None => continue,
                },
                None => None,
            };
            out.push(SensorTopic {
                name: name.get_ref().clone(),
                sensor: Sensor { id, field },
                scale,
                unit,
                joint,
            });
        }
        out
    }

    /// `joint = { min, max, speed }` of sensor `index` (its field's `range` of counts, `scale`
    /// units a count): the range in whole counts within the file's (the bounds rounded inwards),
    /// the speed in counts per second (rounded down, at least 1).
    pub(super) fn joint(
        &mut self,
        raw: &Spanned<RawJoint>,
        index: usize,
        range: (i64, i64),
        scale: f64,
        what: &str,
        unit: &str,
    ) -> Option<Joint> {
        let j = raw.get_ref();
        let errors = self.errors.len();
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        let (low, high) = (range.0 as f64, range.1 as f64);
        // Within rounding of a whole count it is that count (0.3 / 0.1 is 2.999…).
        let counts = |v: f64, inwards: fn(f64) -> f64| {
            let c = v / scale;
            if (c - c.round()).abs() <= 1e-9 * c.abs().max(1.0) {
                c.round()
            } else {
                inwards(c)
            }
        };
        let bound = |this: &mut Self, v: &Spanned<f64>, name: &str, inwards: fn(f64) -> f64| {
            let c = counts(*v.get_ref(), inwards);
            if !c.is_finite() || c < low || c > high {
                this.error(
                    v.span(),
                    format!(
                        "{what}: joint.{name} is outside what the sensor reads ({} to {}{unit})",
                        low * scale,
                        high * scale
                    ),
                );
                0
            } else {
                c as i32
            }
        };
        let min = bound(self, &j.min, "min", f64::ceil);
        let max = bound(self, &j.max, "max", f64::floor);
        if self.errors.len() == errors && min > max {
            self.error(
                raw.span(),
                format!("{what}: joint.min is above joint.max (in whole counts of the sensor)"),
            );
        }
        let rate = match &j.speed {
            None => 0,
            Some(v) => {
                let c = (*v.get_ref() / scale).floor();
                if !c.is_finite() || c < 1.0 || c > f64::from(u32::MAX) {
                    self.error(
                        v.span(),
                        format!(
                            "{what}: joint.speed is at least one count a second ({scale}{unit} a second)"
                        ),
                    );
                }
                c.clamp(0.0, f64::from(u32::MAX)) as u32
            }
        };
        (self.errors.len() == errors).then_some(Joint {
            sensor: index as u8,
            min,
            max,
            rate,
        })
    }

    /// Named places and directions (`[client.places]`, `[schema.NODE.places]`), µm and µrad.
    pub(super) fn places(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<Vec<f64>>>,
    ) -> Vec<(String, Pose)> {
        let mut places = Vec::new();
        let mut seen = HashMap::new();
        for (name, value) in raw {
            if !self.printable(name, "place name") {
                continue;
            }
            if seen.insert(name.get_ref().clone(), ()).is_some() {
                continue;
            }
            if let Some(p) = self.point(value, &format!("place `{}`", name.get_ref()), 3) {
                places.push((name.get_ref().clone(), p));
            }
        }
        places
    }

    /// `[schema.NODE.innate]`: `NAME = "CALL; EVENT -> SOURCE; …"`, by index in file order, with
    /// the built-in defaults (a board has no client's).
    pub(super) fn innate(
        &mut self,
        raw: &RawSchema,
        node: &str,
        sensors: &[SensorTopic],
        places: &[(String, Pose)],
    ) -> Vec<(String, Schema)> {
        if raw.innate.len() > MAX_INNATE {
            if let Some((name, _)) = raw.innate.get_index(MAX_INNATE) {
                self.error(
                    name.span(),
                    format!(
                        "[schema.{node}.innate]: {} schemas; a board stores at most {MAX_INNATE}",
                        raw.innate.len()
                    ),
                );
            }
            return Vec::new();
        }
        let names: Vec<String> = raw.innate.keys().map(|k| k.get_ref().clone()).collect();
        let mut out = Vec::new();
        for (i, (name, text)) in raw.innate.iter().enumerate() {
            if !self.printable(name, "innate schema name") {
                continue;
            }
            if !is_identifier(name.get_ref())
                || matches!(name.get_ref().as_str(), "queue" | "high_priority")
            {
                self.error(
                    name.span(),
                    format!(
                        "innate schema `{}`: a name is letters, digits and _ (not starting with a digit), and not `queue` or `high_priority`",
                        name.get_ref()
                    ),
                );
                continue;
            }
            let vocabulary = Names {
                sensors,
                innate: &names,
            };
            let id = INNATE_IDS + i as u16;
            if let Some(Made::Schema(schema)) =
                self.call(text, id, places, &Defaults::default(), false, vocabulary)
            {
                out.push((name.get_ref().clone(), *schema));
            }
        }
        out
    }

    /// The drive's identifiers: each a base with the frames after it (setpoint 3, pose and
    /// wrench 2), within the format, apart, and outside our protocol's identifiers.
    pub(super) fn drive(&mut self, raw: &Spanned<RawDrive>) -> Option<Drive> {
        let d = raw.get_ref();
        let mut ids = Vec::new();
        for (value, what) in [
            (&d.setpoint, "setpoint"),
            (&d.pose, "pose"),
            (&d.wrench, "wrench"),
        ] {
            let id = u32::try_from(*value.get_ref())
                .ok()
                .and_then(|v| OutputId::new(v, d.extended).ok());
            match id {
                Some(id) => ids.push(id),
                None => {
                    let max = if d.extended { "0x1FFFFFFF" } else { "0x7FF" };
                    self.error(
                        value.span(),
                        format!(
                            "drive.{what}: an identifier is 0..={max} (extended = {})",
                            d.extended
                        ),
                    );
                    return None;
                }
            }
        }
        let [setpoint, pose, wrench] = [ids[0], ids[1], ids[2]];
        let drive = Drive {
            setpoint,
            pose,
            wrench,
        };
        if let Err(e) = drive.check() {
            self.error(
                raw.span(),
                format!(
                    "drive: {e} (the set-point takes 3 identifiers from its own, the pose and the wrench 2 each)"
                ),
            );
            return None;
        }
        if [setpoint, pose, wrench]
            .iter()
            .any(|id| pab_core::protocol::classify_id(&id.id()).is_ours())
        {
            self.error(
                raw.span(),
                "drive: an identifier in the project's own protocol space (29-bit ids with 0b10 in bits 25..24)",
            );
            return None;
        }
        Some(drive)
    }

    /// A positive amount in `[min, max]` of a unit, scaled to an integer (rounded).
    pub(super) fn scaled(
        &mut self,
        value: Option<&Spanned<f64>>,
        scale: f64,
        default: u32,
        what: &str,
        unit: &str,
        allow_zero: bool,
    ) -> u32 {
        let Some(value) = value else {
            return default;
        };
        let v = *value.get_ref() * scale;
        let max = f64::from(MAX_COORD);
        if !v.is_finite() || v < 0.0 || v > max || (!allow_zero && v.round() < 1.0) {
            let lowest = if allow_zero { "0" } else { "above 0" };
            self.error(
                value.span(),
                format!("{what} must be {lowest} and at most {} {unit}", max / scale),
            );
            return default;
        }
        v.round() as u32
    }

    pub(super) fn schema_config(&mut self, raw: &RawSchema) -> Option<Config> {
        let errors = self.errors.len();
        let period = self.scaled(
            raw.period_ms.as_ref(),
            1000.0,
            1000,
            "period_ms",
            "ms",
            false,
        );
        let mut config = Config::new(period);
        config.overrun_us = self.scaled(
            raw.overrun_ms.as_ref(),
            1000.0,
            config.overrun_us,
            "overrun_ms",
            "ms",
            false,
        );
        if let Some(o) = &raw.overrun_ms
            && config.overrun_us < config.period_us
        {
            self.error(o.span(), "overrun_ms must be at least period_ms");
        }
        let rotation = self.scaled(
            raw.rotation_limit_mrad.as_ref(),
            1000.0,
            1_000_000,
            "rotation_limit_mrad",
            "mrad",
            false,
        ) as i32;
        let limits = &mut config.limits;
        limits.workspace_min = [
            -1_000_000, -1_000_000, -1_000_000, -rotation, -rotation, -rotation,
        ];
        limits.workspace_max = [
            1_000_000, 1_000_000, 1_000_000, rotation, rotation, rotation,
        ];
        if let Some(w) = &raw.workspace_mm {
            let min = self.point(&w.get_ref().min, "workspace_mm.min", 3);
            let max = self.point(&w.get_ref().max, "workspace_mm.max", 3);
            if let (Some(min), Some(max)) = (min, max) {
                if min.iter().zip(&max).take(3).any(|(lo, hi)| lo > hi) {
                    self.error(w.span(), "workspace_mm: min is above max on some axis");
                }
                config.limits.workspace_min[..3].copy_from_slice(&min[..3]);
                config.limits.workspace_max[..3].copy_from_slice(&max[..3]);
            }
        }
        config.limits.force_limit = self.scaled(
            raw.force_limit_n.as_ref(),
            1000.0,
            config.limits.force_limit,
            "force_limit_n",
            "N",
            false,
        );
        config.limits.torque_limit = self.scaled(
            raw.torque_limit_nm.as_ref(),
            1000.0,
            0,
            "torque_limit_nm",
            "N·m",
            true,
        );
        // The bounds 0 leaves off: a contact threshold, the pose's speed and rate.
        config.limits.contact_limit = self.scaled(
            raw.contact_limit_n.as_ref(),
            1000.0,
            0,
            "contact_limit_n",
            "N",
            true,
        );
        config.limits.speed_limit = self.scaled(
            raw.speed_limit_mm_s.as_ref(),
            1000.0,
            0,
            "speed_limit_mm_s",
            "mm/s",
            true,
        );
        config.limits.rate_limit = self.scaled(
            raw.rate_limit_rad_s.as_ref(),
            1_000_000.0,
            0,
            "rate_limit_rad_s",
            "rad/s",
            true,
        );
        config.stale_us = self.scaled(
            raw.stale_ms.as_ref(),
            1000.0,
            config.stale_us,
            "stale_ms",
            "ms",
            false,
        );
        config.sensor_stale_us = self.scaled(
            raw.sensor_stale_ms.as_ref(),
            1000.0,
            config.sensor_stale_us,
            "sensor_stale_ms",
            "ms",
            false,
        );
        config.watchdog_margin_ms = self.scaled(
            raw.watchdog_margin_ms.as_ref(),
            1.0,
            config.watchdog_margin_ms,
            "watchdog_margin_ms",
            "ms",
            true,
        );
        // The drive's own limits: a pose frame that jumps farther is implausible.
        config.drive_speed = self.scaled(
            raw.drive_speed_mm_s.as_ref(),
            1000.0,
            config.drive_speed,
            "drive_speed_mm_s",
            "mm/s",
            false,
        );
        config.drive_rate = self.scaled(
            raw.drive_rate_rad_s.as_ref(),
            1_000_000.0,
            config.drive_rate,
            "drive_rate_rad_s",
            "rad/s",
            false,
        );
        config.pose_noise = self.scaled(
            raw.pose_noise_mm.as_ref(),
            1000.0,
            config.pose_noise,
            "pose_noise_mm",
            "mm",
            true,
        );
        config.stiffness = self.scaled(
            raw.stiffness_n_per_m.as_ref(),
            1.0,
            config.stiffness,
            "stiffness_n_per_m",
            "N/m",
            false,
        );
        config.damping = self.scaled(
            raw.damping_ns_per_m.as_ref(),
            1.0,
            config.damping,
            "damping_ns_per_m",
            "N·s/m",
            true,
        );
        (self.errors.len() == errors).then_some(config)
    }

    /// A point in mm (three values; six with rotations in mrad) as a pose in µm and µrad.
    pub(in crate::network) fn point(
        &mut self,
        value: &Spanned<Vec<f64>>,
        what: &str,
        least: usize,
    ) -> Option<Pose> {
        let v = value.get_ref();
        if v.len() != least && v.len() != AXES {
            self.error(
                value.span(),
                format!(
                    "{what}: {} values; write [x, y, z] in mm{}",
                    v.len(),
                    if least == 3 {
                        ", or six with rotations about x, y, z in mrad"
                    } else {
                        ""
                    }
                ),
            );
            return None;
        }
        let mut p = [0; AXES];
        for (o, c) in p.iter_mut().zip(v) {
            let um = c * 1000.0;
            if !um.is_finite() || um.abs() > f64::from(MAX_COORD) {
                self.error(
                    value.span(),
                    format!("{what}: {c} is beyond ±{} mm", MAX_COORD / 1000),
                );
                return None;
            }
            *o = um.round() as i32;
        }
        Some(p)
    }
}

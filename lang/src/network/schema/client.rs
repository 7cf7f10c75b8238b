//! `[client]`: the workstation client's program, its places, defaults and timed commands, read
//! into [`Client`].

use super::*;

impl Builder<'_> {
    pub(in crate::network) fn client(
        &mut self,
        raw: Option<&Spanned<RawClient>>,
        nodes: &[Node],
        boards: &[SchemaBoard],
        declared: &[&str],
    ) -> Option<Client> {
        let raw_span = raw?.span();
        let raw = raw?.get_ref();
        let errors = self.errors.len();
        let node = nodes.iter().position(|n| &n.name == raw.node.get_ref());
        match node {
            None => {
                let known: Vec<&str> = boards
                    .iter()
                    .filter_map(|b| nodes.get(b.node).map(|n| n.name.as_str()))
                    .collect();
                self.error(
                    raw.node.span(),
                    format!(
                        "[client] node `{}` is not defined (schema servers: {})",
                        raw.node.get_ref(),
                        list_or_none(&known)
                    ),
                );
            }
            // A board whose section has mistakes is reported there, not here again.
            Some(_) if declared.iter().any(|d| d == raw.node.get_ref()) => {}
            Some(n) if !boards.iter().any(|b| b.node == n) => self.error(
                raw.node.span(),
                format!(
                    "[client] node `{}` runs no schema server: add a [schema.{}] section",
                    raw.node.get_ref(),
                    raw.node.get_ref()
                ),
            ),
            Some(_) => {}
        }
        let mut d = Defaults::default();
        d.speed = self.scaled(
            raw.speed_mm_s.as_ref(),
            1000.0,
            d.speed,
            "speed_mm_s",
            "mm/s",
            false,
        );
        d.touch_speed = self.scaled(
            raw.touch_speed_mm_s.as_ref(),
            1000.0,
            d.touch_speed,
            "touch_speed_mm_s",
            "mm/s",
            false,
        );
        d.contact = self.scaled(
            raw.contact_n.as_ref(),
            1000.0,
            d.contact as u32,
            "contact_n",
            "N",
            false,
        ) as i32;
        d.touch_distance = self.scaled(
            raw.touch_distance_mm.as_ref(),
            1000.0,
            d.touch_distance,
            "touch_distance_mm",
            "mm",
            false,
        );
        d.settle_ms = self.scaled(
            raw.settle_ms.as_ref(),
            1.0,
            d.settle_ms,
            "settle_ms",
            "ms",
            true,
        );
        d.preload = self.scaled(
            raw.preload_mm.as_ref(),
            1000.0,
            d.preload,
            "preload_mm",
            "mm",
            true,
        );
        d.pitch = self.scaled(
            raw.pitch_mm.as_ref(),
            1000.0,
            d.pitch,
            "pitch_mm",
            "mm",
            false,
        );
        d.search_speed = self.scaled(
            raw.search_speed_mm_s.as_ref(),
            1000.0,
            d.search_speed,
            "search_speed_mm_s",
            "mm/s",
            false,
        );
        d.search_radius = self.scaled(
            raw.search_radius_mm.as_ref(),
            1000.0,
            d.search_radius,
            "search_radius_mm",
            "mm",
            false,
        );
        d.wobble = self.scaled(
            raw.wobble_mrad.as_ref(),
            1000.0,
            d.wobble,
            "wobble_mrad",
            "mrad",
            true,
        );
        d.wobble_ms = self.scaled(
            raw.wobble_period_ms.as_ref(),
            1.0,
            d.wobble_ms,
            "wobble_period_ms",
            "ms",
            false,
        );
        d.insert_depth = self.scaled(
            raw.insert_depth_mm.as_ref(),
            1000.0,
            d.insert_depth,
            "insert_depth_mm",
            "mm",
            false,
        );

        let places = self.places(&raw.places);
        let board = node.and_then(|n| boards.iter().find(|b| b.node == n));
        let vocabulary = board.map_or_else(Names::default, |b| Names {
            sensors: &b.sensors,
            innate: &b.innate,
        });
        if raw.program.len() > MAX_CALLS {
            self.error(
                raw_span.clone(),
                format!(
                    "{} calls: a program holds at most {MAX_CALLS}",
                    raw.program.len()
                ),
            );
        }
        let mut program = Vec::new();
        for text in raw.program.iter().take(MAX_CALLS) {
            let id = program.len() as u16 + 1;
            if let Some(Made::Schema(schema)) = self.call(text, id, &places, &d, false, vocabulary)
            {
                program.push(Call {
                    name: call_name(text.get_ref()),
                    schema: *schema,
                });
            }
        }
        if raw.commands.len() > MAX_CALLS {
            self.error(
                raw_span.clone(),
                format!(
                    "{} commands: a client holds at most {MAX_CALLS}",
                    raw.commands.len()
                ),
            );
        }
        let mut commands: Vec<Timed> = Vec::new();
        for (k, c) in raw.commands.iter().take(MAX_CALLS).enumerate() {
            let c = c.get_ref();
            let Some(at) = self.time(&c.at, "a command's `at`") else {
                continue;
            };
            // High-priority schemas are numbered after the program's.
            let id = (raw.program.len().min(MAX_CALLS) + k + 1) as u16;
            let command = match self.call(&c.call, id, &places, &d, true, vocabulary) {
                Some(Made::Schema(schema)) => Command::HighPriority(Box::new(Call {
                    name: call_name(c.call.get_ref()),
                    schema: *schema,
                })),
                Some(Made::Abort) => Command::Abort,
                Some(Made::EmergencyStop) => Command::EmergencyStop,
                None => continue,
            };
            commands.push(Timed {
                t_us: crate::time::micros(at),
                command,
            });
        }
        commands.sort_by_key(|t| t.t_us);
        if self.errors.len() != errors {
            return None;
        }
        Some(Client {
            node: node?,
            program,
            commands,
            places,
            defaults: d,
        })
    }
}

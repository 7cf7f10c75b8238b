//! A schema server's board, its client and its plant in virtual time.
//!
//! The board is `pab_core::schema::Server`, the code the boards run, ticked every period. The
//! client sends its program's calls (schemas made by `pab_core::schema::build`) to the queue as
//! a real client does: the next call as soon as the queue takes it, again at the next tick when
//! it is full. Timed commands (a high-priority schema, an abort, an emergency stop) reach the
//! server between two ticks, as a frame would. The plant ([`super::plant`]) integrates the
//! drive's set-point between ticks and feeds its pose and wrench back before each tick, as the
//! topics would; its range finder, when `[plant]` names a board sensor for it, goes out as that
//! sensor's frame and is read by the board's own code (`pab_core::schema::feed_sensors`).
//!
//! Each installed schema is a row of the trace ([`Installed`]): its time, name, source and the
//! event that triggered it.

use pab_core::schema::{
    Event, Measure, Origin, Refusal, Safety, Schema, Server, Setpoint, Trigger, feed_sensors,
};
use pab_core::{Frame, Instant};

use super::SimError;
use super::plant::{Plant, PlantConfig};
pub use crate::network::{Call, Command, Timed};
use crate::network::{Network, SchemaBoard, SensorTopic};

/// One installed schema.
#[derive(Clone, Debug, PartialEq)]
pub struct Installed {
    /// When (the tick), µs.
    pub t_us: u64,
    /// The schema's id.
    pub id: u16,
    /// Its name: the call's, or the server's own (`wait-queue`, `wait-high-priority`,
    /// `safety:<name>`).
    pub name: String,
    /// Where it came from.
    pub source: Origin,
    /// The triggering event: the reaction's ([`event_name`]), `high-priority`, `abort` or
    /// `safety:<name>`.
    pub event: String,
}

/// One tick's state, for plots.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// µs.
    pub t_us: u64,
    /// The measured pose before the tick, µm.
    pub pose: [i32; 3],
    /// The attractor after it, µm.
    pub attractor: [i32; 3],
    /// The contact force's magnitude, N.
    pub force_n: f64,
    /// The installed schema.
    pub schema: u16,
}

/// What a run produced.
#[derive(Clone, Debug)]
pub struct Run {
    /// Every installed schema, in order.
    pub installed: Vec<Installed>,
    /// One sample per tick.
    pub samples: Vec<Sample>,
    /// The plant at the end.
    pub plant: Plant,
    /// The program's calls sent (all of them, unless the run ended first).
    pub sent: usize,
    /// When the run ended, µs.
    pub end_us: u64,
    /// The first safety event, if any.
    pub fault: Option<Safety>,
}

/// How long a run may go on.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Stop at this time, µs.
    pub until_us: u64,
    /// Stop once every call has been sent and the board waits (on the queue, or on the
    /// high-priority channel with nothing timed left), or once a safety event has stopped it
    /// with nothing timed left, this long after.
    pub settle_us: u64,
}

/// The name of a reaction's event in traces: `one-shot`, `done`, `elapsed`, `queue-ready`,
/// `above:<measure>` or `below:<measure>` with `position.z`, `displacement.z`, `force.x`,
/// `contact`, `sensor.3`, ….
pub fn event_name(event: &Event) -> String {
    let measure = |m: &Measure| {
        const AXES: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];
        let axis = |a: &u8| AXES.get(usize::from(*a)).copied().unwrap_or("?");
        match m {
            Measure::Position(a) => format!("position.{}", axis(a)),
            Measure::Displacement(a) => format!("displacement.{}", axis(a)),
            Measure::Force(a) => format!("force.{}", axis(a)),
            Measure::Contact => "contact".to_string(),
            Measure::Sensor(s) => format!("sensor.{s}"),
        }
    };
    match event {
        Event::OneShot => "one-shot".into(),
        Event::Done => "done".into(),
        Event::Elapsed(_) => "elapsed".into(),
        Event::QueueReady => "queue-ready".into(),
        Event::Above(m, _) => format!("above:{}", measure(m)),
        Event::Below(m, _) => format!("below:{}", measure(m)),
    }
}

/// `name` with a sensor's index replaced by its name in the file (`below:gap`, not
/// `below:sensor.0`).
fn sensor_named(name: String, event: &Event, board: &SchemaBoard) -> String {
    match event {
        Event::Above(Measure::Sensor(i), _) | Event::Below(Measure::Sensor(i), _) => {
            match board.sensors.get(usize::from(*i)) {
                Some(topic) => format!("{}:{}", name.split(':').next().unwrap_or(""), topic.name),
                None => name,
            }
        }
        _ => name,
    }
}

/// The server's own schemas' names.
pub fn builtin_name(id: u16) -> Option<String> {
    match id {
        Schema::WAIT_QUEUE => Some("wait-queue".into()),
        Schema::WAIT_HIGH_PRIORITY => Some("wait-high-priority".into()),
        _ => {
            let cause = id.checked_sub(Schema::SAFETY)?;
            let cause = Safety::from_u8(u8::try_from(cause).ok()?)?;
            Some(format!("safety:{}", cause.name()))
        }
    }
}

/// The frame the range finder's reading (µm) makes on `topic`: the reading in mm over the
/// topic's scale, rounded and saturated to its field (`value_port::Field::write`). The one
/// encoding of the plant's range finder: the simulator here and `pabctl plant`
/// (`pabctl::plant::BusPlant`) both publish it with this, so a board sees the same counts in
/// virtual time and on a live bus. `None` only for an identifier no frame can carry (the
/// network file refuses those).
pub fn range_frame(topic: &SensorTopic, range_um: f64) -> Option<Frame> {
    let counts = (range_um / 1000.0 / topic.scale).round();
    let mut data = [0u8; 8];
    topic.sensor.field.write(
        &mut data,
        counts.clamp(i64::MIN as f64, i64::MAX as f64) as i64,
    );
    Frame::with_raw_id(topic.sensor.id.raw(), topic.sensor.id.is_extended(), &data)
}

/// Runs `program` (and `commands`) on `board` driving a plant with `plant`.
///
/// Fails when the configuration or a call is refused by the board for any reason but a full
/// queue (a malformed call is the file's error, not something to simulate).
pub fn run(
    board: &SchemaBoard,
    plant: PlantConfig,
    program: &[Call],
    commands: &[Timed],
    limits: Limits,
) -> Result<Run, SimError> {
    let config = board.config.clone();
    let period = config.period_us;
    let innate: Vec<(u16, String, Schema)> = config
        .innate
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let name = board.innate.get(i).cloned();
            (
                s.id,
                name.unwrap_or_else(|| format!("innate.{i}")),
                s.clone(),
            )
        })
        .collect();
    let sensors: Vec<_> = board.sensors.iter().map(|s| s.sensor).collect();
    let range_finder = plant.range_finder.and_then(|i| board.sensors.get(i));
    let mut server = Server::new(config)
        .map_err(|e| SimError(format!("the board's set-up is refused: {e:?}")))?;
    let mut plant = Plant::new(plant);
    let known = |id: u16| -> Option<(&str, &Schema)> {
        program
            .iter()
            .map(|c| (c.name.as_str(), &c.schema))
            .chain(commands.iter().filter_map(|t| match &t.command {
                Command::HighPriority(c) => Some((c.name.as_str(), &c.schema)),
                _ => None,
            }))
            .chain(innate.iter().map(|(_, n, s)| (n.as_str(), s)))
            .find(|(_, s)| s.id == id)
    };
    let mut installed = Vec::new();
    let mut samples = Vec::new();
    let mut sent = 0usize;
    let mut pending = commands.iter().peekable();
    let mut fault = None;
    let mut idle_since: Option<u64> = None;
    let mut t_us = 0u64;
    let mut setpoint: Option<Setpoint> = None;
    while t_us <= limits.until_us {
        let now = Instant::from_micros(t_us);
        // The client tops the queue up.
        while let Some(call) = program.get(sent) {
            match server.enqueue(call.schema.clone()) {
                Ok(_) => sent += 1,
                Err(Refusal::QueueFull) => break,
                Err(other) => {
                    return Err(SimError(format!(
                        "the board refused call {} ({}): {other:?}",
                        sent + 1,
                        call.name
                    )));
                }
            }
        }
        while let Some(timed) = pending.next_if(|c| c.t_us <= t_us) {
            match &timed.command {
                Command::EmergencyStop => server.emergency_stop(),
                Command::Abort => server.abort(),
                // The simulated client has seen every report up to now: its call acknowledges
                // the latest stop the server counted (a stop asked at the same instant counts
                // from the tick that handles it, and discards the call).
                Command::HighPriority(call) => server
                    .high_priority(call.schema.clone(), server.stop_number())
                    .map_err(|e| SimError(format!("the board refused {}: {e:?}", call.name)))?,
            }
        }
        server.set_pose(plant.pose(), now);
        server.set_wrench(plant.wrench(), now);
        if let Some(frame) = range_finder.and_then(|topic| range_frame(topic, plant.range())) {
            feed_sensors(&sensors, &frame, &mut server, now);
        }
        let tick = server.tick(now);
        for t in &tick.transitions {
            let event = match t.by {
                Trigger::HighPriority => "high-priority".to_string(),
                Trigger::Abort => "abort".to_string(),
                Trigger::Safety(cause) => {
                    fault.get_or_insert(cause);
                    format!("safety:{}", cause.name())
                }
                Trigger::Reaction(_, event) => sensor_named(event_name(&event), &event, board),
            };
            let name = builtin_name(t.installed)
                .or_else(|| known(t.installed).map(|(n, _)| n.to_string()))
                .unwrap_or_else(|| format!("schema {}", t.installed));
            installed.push(Installed {
                t_us,
                id: t.installed,
                name,
                source: t.source,
                event,
            });
        }
        if let Some(s) = tick.setpoint {
            setpoint = Some(s);
        }
        let pose = plant.pose();
        let attractor = setpoint.map_or(pose, |s| s.attractor);
        samples.push(Sample {
            t_us,
            pose: [pose[0], pose[1], pose[2]],
            attractor: [attractor[0], attractor[1], attractor[2]],
            force_n: plant.force_n(),
            schema: server.current(),
        });
        if let Some(s) = &setpoint {
            plant.step(s, period);
        }
        let waiting = server.current() == Schema::WAIT_QUEUE
            || (server.current() == Schema::WAIT_HIGH_PRIORITY && pending.peek().is_none());
        // Stopped on a safety event with nothing timed left: the queue will not run again, and
        // the client cannot send what it still has (the queue does not drain).
        let stopped = server.fault().is_some() && waiting;
        if stopped || (sent == program.len() && waiting && server.queued() == 0) {
            let since = *idle_since.get_or_insert(t_us);
            if t_us - since >= limits.settle_us {
                break;
            }
        } else {
            idle_since = None;
        }
        t_us += u64::from(period);
    }
    Ok(Run {
        installed,
        samples,
        plant,
        sent,
        end_us: t_us,
        fault,
    })
}

/// Runs the file's schema server: its board's set-up, its plant (the default one without
/// `[plant]`), its client's program and commands.
///
/// Fails when the file has no `[client]` (nothing would happen) or the board refuses a call.
pub fn simulate(network: &Network, limits: Limits) -> Result<Run, SimError> {
    let client = network.client.as_ref().ok_or_else(|| {
        SimError("the file has no [client]: a schema server with nothing to do".into())
    })?;
    let board = network
        .schema_boards
        .iter()
        .find(|b| b.node == client.node)
        .ok_or_else(|| SimError("the client's node runs no schema server".into()))?;
    run(
        board,
        network.plant.clone().unwrap_or_default(),
        &client.program,
        &client.commands,
        limits,
    )
}

/// Writes `run`'s installed schemas as CSV: `t,node,schema,source,event`, one row per installed
/// schema (t in seconds with six decimals, `node` the board's name in `network`).
pub fn write_trace(
    run: &Run,
    network: &Network,
    out: &mut impl std::io::Write,
) -> std::io::Result<()> {
    let node = network
        .client
        .as_ref()
        .and_then(|c| network.nodes.get(c.node))
        .map_or("", |n| n.name.as_str());
    writeln!(out, "t,node,schema,source,event")?;
    for i in &run.installed {
        writeln!(
            out,
            "{},{},{},{},{}",
            super::seconds_text(i.t_us),
            csv_field(node),
            csv_field(&i.name),
            i.source.name(),
            csv_field(&i.event)
        )?;
    }
    Ok(())
}

/// A CSV field, quoted when it holds a comma or a quote (a call's keyword arguments do).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// A report of `run` for a terminal: the board, what was installed, the parts, the fault.
pub fn report(run: &Run, network: &Network) -> String {
    let node = network
        .client
        .as_ref()
        .and_then(|c| network.nodes.get(c.node))
        .map_or("?", |n| n.name.as_str());
    let program = network.client.as_ref().map_or(0, |c| c.program.len());
    let mut text = format!(
        "schema server on `{node}`: {} schemas installed, {} of {program} calls sent, until t = {} s\n",
        run.installed.len(),
        run.sent,
        super::seconds_text(run.end_us)
    );
    let parts = run.plant.parts().len();
    if parts > 0 {
        text.push_str(&format!(
            "  parts inserted: {} of {parts}\n",
            run.plant.inserted()
        ));
    }
    match run.fault {
        Some(cause) => {
            let at = run
                .installed
                .iter()
                .find(|i| i.event == format!("safety:{}", cause.name()))
                .map_or(0, |i| i.t_us);
            text.push_str(&format!(
                "  safety event: {} at t = {} s; the board waits on the high-priority channel\n",
                cause.name(),
                super::seconds_text(at)
            ));
        }
        None => text.push_str("  no safety event\n"),
    }
    text
}

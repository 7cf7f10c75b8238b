//! A schema server's frames: its drive's (`Drive_*`: attractor, pose, wrench), its extra
//! sensors' (`Sensor_*`, one signal per sensor at its field), and the stops the tool sends it.

use pab_core::protocol::{BROADCAST, FrameId, Service, TOOL};
use pab_core::value_port::{Endian, Field};

use super::services::{service_comment, service_signals};
use super::{
    DbcMessage, DbcSignal, EXTENDED_FLAG, Names, TOOL_NODE, UNKNOWN_NODE, extended, field_signal,
    serves, signal,
};
use crate::network::{Network, SchemaBoard, SensorTopic};

/// Three signed 21-bit values and a flag (bit 63) in 8 bytes.
fn triple(names: [&str; 3], unit: &str, what: &str, flag: Option<(&str, &str)>) -> Vec<DbcSignal> {
    let mut signals: Vec<DbcSignal> = names
        .iter()
        .enumerate()
        .map(|(i, name)| DbcSignal {
            unit: unit.to_string(),
            min: (-(1i64 << 20)).to_string(),
            max: ((1u64 << 20) - 1).to_string(),
            signed: true,
            ..signal(
                name,
                21 * i as u32,
                21,
                &format!("{what}, {name}; saturated at ±2^20"),
            )
        })
        .collect();
    if let Some((name, comment)) = flag {
        signals.push(signal(name, 63, 1, comment));
    }
    signals
}

/// The Drive_* messages of one schema server's board.
fn drive_messages(
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
    board: &SchemaBoard,
    node_name: &str,
    dbc_node: &str,
) {
    let id = |base: pab_core::OutputId, offset: u32| {
        let raw = base.raw().saturating_add(offset);
        if base.is_extended() {
            raw | EXTENDED_FLAG
        } else {
            raw
        }
    };
    let period_ms = (board.config.period_us / 1000).max(1);
    let d = board.drive;
    let out = |name: &str, base, offset, signals, comment: &str, cycle| DbcMessage {
        id: id(base, offset),
        name: name.to_string(),
        dlc: 8,
        transmitter: dbc_node.to_string(),
        receivers: vec![UNKNOWN_NODE.to_string()],
        signals,
        comment: format!("{comment} Sent by node `{node_name}`'s schema server to its drive."),
        fd: false,
        cycle_ms: Some(cycle),
    };
    let inward = |name: &str, base, offset, signals, comment: &str| DbcMessage {
        id: id(base, offset),
        name: name.to_string(),
        dlc: 8,
        transmitter: UNKNOWN_NODE.to_string(),
        receivers: vec![dbc_node.to_string()],
        signals,
        comment: format!("{comment} Read by node `{node_name}`'s schema server."),
        fd: false,
        cycle_ms: None,
    };
    let attractor = triple(
        ["x", "y", "z"],
        "um",
        "the attractor",
        Some(("gripper_closed", "1: the gripper is commanded closed")),
    );
    let rotation = triple(["rx", "ry", "rz"], "urad", "the attractor's rotation", None);
    let impedance = vec![
        DbcSignal {
            unit: "N/m".to_string(),
            ..signal("stiffness", 0, 32, "the drive's stiffness")
        },
        DbcSignal {
            unit: "N.s/m".to_string(),
            ..signal("damping", 32, 32, "the drive's damping")
        },
    ];
    let made = [
        out(
            &names.unique(format!("Drive_Attractor_{dbc_node}")),
            d.setpoint,
            0,
            attractor,
            "The impedance controller's attractor, every loop period.",
            period_ms,
        ),
        out(
            &names.unique(format!("Drive_AttractorRotation_{dbc_node}")),
            d.setpoint,
            1,
            rotation,
            "The attractor's rotation, every loop period.",
            period_ms,
        ),
        out(
            &names.unique(format!("Drive_Impedance_{dbc_node}")),
            d.setpoint,
            2,
            impedance,
            "The drive's impedance, on change and every 100 ms.",
            100,
        ),
        inward(
            &names.unique(format!("Drive_Pose_{dbc_node}")),
            d.pose,
            0,
            triple(["x", "y", "z"], "um", "the measured position", None),
            "The drive's measured position.",
        ),
        inward(
            &names.unique(format!("Drive_PoseRotation_{dbc_node}")),
            d.pose,
            1,
            triple(["rx", "ry", "rz"], "urad", "the measured rotation", None),
            "The drive's measured rotation.",
        ),
        inward(
            &names.unique(format!("Drive_Wrench_{dbc_node}")),
            d.wrench,
            0,
            triple(
                ["fx", "fy", "fz"],
                "mN",
                "the contact force on the robot",
                None,
            ),
            "The wrist sensor's force (pressing down on a surface reads +z).",
        ),
        inward(
            &names.unique(format!("Drive_Torque_{dbc_node}")),
            d.wrench,
            1,
            triple(["tx", "ty", "tz"], "mN.m", "the torque", None),
            "The wrist sensor's torque.",
        ),
    ];
    messages.extend(made);
}

/// The signal of one extra sensor: its field where the board's `value_port::Field` reads it
/// (byte offset, size, sign, byte order), scaled to the sensor's unit. DBC's physical value is
/// raw × factor and the sensor's scale is units per count, so the factor is the scale; the board
/// itself compares the raw counts.
fn sensor_signal(topic: &SensorTopic, index: usize, range_finder: bool) -> DbcSignal {
    let field: Field = topic.sensor.field;
    let len = 8 * u32::from(field.size);
    let (low, high) = field.range();
    let physical = |raw: i64| (raw as f64 * topic.scale).to_string();
    let per_count = if topic.unit.is_empty() {
        format!("{} per count", topic.scale)
    } else {
        format!("{} {} per count", topic.scale, topic.unit)
    };
    let order = match field.endian {
        Endian::Big if field.size > 1 => " big endian",
        Endian::Little if field.size > 1 => " little endian",
        _ => "",
    };
    let mut comment = format!(
        "Sensor `{}` (index {index}): {}{len}{order} at byte {}, {per_count} (the factor). The \
         board compares the raw counts",
        topic.name,
        if field.signed { "i" } else { "u" },
        field.offset,
    );
    if !field.signed && field.size == 4 {
        // Sensor::read: the server's sensor table holds i32.
        comment.push_str(" (a raw value above 2^31 - 1 reads as 2^31 - 1)");
    }
    comment.push('.');
    if range_finder {
        comment.push_str(
            " The plant's range finder ([plant] range_finder): pabctl sim and pabctl plant publish \
             the height under the tip on it, every loop period.",
        );
    }
    DbcSignal {
        factor: topic.scale.to_string(),
        min: physical(low),
        max: physical(high),
        unit: topic.unit.clone(),
        ..field_signal(&topic.name, field, &comment)
    }
}

/// The Sensor_* messages of one schema server's board: one per identifier its extra sensors
/// (`[schema.NODE.sensors.NAME]`) read, with one signal per sensor on it (several may share an
/// identifier, each its own field: DBC allows one message per identifier). Their frames are the
/// user's (a device's, or the plant's range finder): the board only reads them. `range_finder`
/// is the index of the sensor `[plant] range_finder` names, if it is this board's.
fn sensor_messages(
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
    board: &SchemaBoard,
    range_finder: Option<usize>,
    node_name: &str,
    dbc_node: &str,
) {
    let mut topics: Vec<(pab_core::OutputId, Vec<usize>)> = Vec::new();
    for (i, topic) in board.sensors.iter().enumerate() {
        match topics.iter_mut().find(|(id, _)| *id == topic.sensor.id) {
            Some((_, sensors)) => sensors.push(i),
            None => topics.push((topic.sensor.id, vec![i])),
        }
    }
    for (id, sensors) in topics {
        let on_it: Vec<&SensorTopic> = sensors.iter().map(|&i| &board.sensors[i]).collect();
        let joined: Vec<&str> = on_it.iter().map(|t| t.name.as_str()).collect();
        let sections: Vec<String> = joined
            .iter()
            .map(|name| format!("[schema.{node_name}.sensors.{name}]"))
            .collect();
        // The shortest frame the board reads all of them from: longer ones decode the same.
        let dlc = on_it
            .iter()
            .map(|t| t.sensor.field.offset + t.sensor.field.size)
            .max()
            .unwrap_or(8);
        messages.push(DbcMessage {
            id: if id.is_extended() {
                id.raw() | EXTENDED_FLAG
            } else {
                id.raw()
            },
            name: names.unique(format!("Sensor_{}_{dbc_node}", joined.join("_"))),
            dlc,
            transmitter: UNKNOWN_NODE.to_string(),
            receivers: vec![dbc_node.to_string()],
            signals: sensors
                .iter()
                .map(|&i| sensor_signal(&board.sensors[i], i, range_finder == Some(i)))
                .collect(),
            comment: format!(
                "A sensor topic of node `{node_name}`'s schema server ({}): the user's frames on \
                 {} id 0x{:X}, from an unnamed sender, read by the board (value_port::Field) \
                 into its sensor table for the reactions that name it. DLC is the shortest frame \
                 it reads.",
                sections.join(", "),
                if id.is_extended() {
                    "extended"
                } else {
                    "standard"
                },
                id.raw()
            ),
            fd: false,
            cycle_ms: None,
        });
    }
}

/// The schema servers' drives: the set-point the board sends every period, the pose and the
/// wrench it reads (docs/can-protocol.md, "The drive's frames"), on the ids of the board's
/// `drive`; then its extra sensors' topics. A network topic on a sensor's identifier joins
/// the sensor's message (`topics::topic_messages`): its signals say more than raw bytes.
pub(super) fn drives_and_sensors(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) -> Vec<(u32, usize)> {
    let mut sensor_ids: Vec<(u32, usize)> = Vec::new();
    for (index, board) in network.schema_boards.iter().enumerate() {
        let Some(dbc_node) = nodes.get(board.node + 1) else {
            continue;
        };
        let Some(node) = network.nodes.get(board.node) else {
            continue;
        };
        drive_messages(messages, names, board, &node.name, dbc_node);
        // `[plant] range_finder` is a sensor of the first board (the network file's reading).
        let range_finder = network
            .plant
            .as_ref()
            .and_then(|p| p.range_finder)
            .filter(|_| index == 0);
        let first = messages.len();
        sensor_messages(messages, names, board, range_finder, &node.name, dbc_node);
        sensor_ids.extend(
            messages[first..]
                .iter()
                .enumerate()
                .map(|(i, m)| (m.id, first + i)),
        );
    }
    sensor_ids
}

/// The schema servers' stops: the emergency stop and the abort, from the tool (anyone may
/// send them) to each board and to all.
pub(super) fn stops(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
    let boards: Vec<(u8, String, String)> = network
        .nodes
        .iter()
        .zip(nodes.iter().skip(1))
        .enumerate()
        .filter(|(index, _)| serves(network, *index))
        .map(|(_, (node, dbc_node))| (node.id, dbc_node.clone(), format!("node `{}`", node.name)))
        .collect();
    if !boards.is_empty() {
        let every: Vec<String> = boards.iter().map(|(_, name, _)| name.clone()).collect();
        let all = (BROADCAST, "all".to_string(), "all nodes (0xFF)".to_string());
        for service in [Service::EmergencyStop, Service::SchemaAbort] {
            for (destination, suffix, whom) in boards.iter().chain([&all]) {
                messages.push(DbcMessage {
                    id: extended(FrameId::new(service, TOOL, *destination)),
                    name: names.unique(format!("PAB_{service:?}_{suffix}")),
                    dlc: service.payload_len() as u8,
                    transmitter: TOOL_NODE.to_string(),
                    receivers: if *destination == BROADCAST {
                        every.clone()
                    } else {
                        vec![suffix.clone()]
                    },
                    signals: service_signals(service).unwrap_or_default(),
                    comment: format!(
                        "{} From the tool to {whom}; any node sends the same from its own \
                         address.",
                        service_comment(service)
                    ),
                    fd: false,
                    cycle_ms: None,
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dbc::build;
    use crate::dbc::tests::{NET, dbc_raw, fits_without_overlap, network};

    #[test]
    fn a_schema_servers_board_has_its_reports_and_the_stops_to_it_and_to_all() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/assembly.toml");
        let text = std::fs::read_to_string(path).unwrap();
        let dbc = build(&network(&text), &[]).unwrap();
        let find = |name: &str| {
            dbc.messages
                .iter()
                .find(|m| m.name == name)
                .unwrap_or_else(|| panic!("no {name}"))
        };
        // Node `arm`, id 10, runs the server.
        let ack = find("PAB_SchemaAck_arm");
        assert_eq!(
            (ack.id, ack.dlc),
            (
                FrameId::new(Service::SchemaAck, 10, TOOL).raw() | EXTENDED_FLAG,
                8
            )
        );
        let change = find("PAB_SchemaTransition_arm");
        assert_eq!(
            change.id,
            FrameId::new(Service::SchemaTransition, 10, BROADCAST).raw() | EXTENDED_FLAG
        );
        let state = find("PAB_SchemaState_arm");
        assert_eq!((state.dlc, state.cycle_ms), (8, Some(100)));
        let fault = state.signals.iter().find(|s| s.name == "fault").unwrap();
        assert_eq!(fault.values.last(), Some(&(255, "none")));
        let stop_number = state.signals.iter().find(|s| s.name == "stop").unwrap();
        assert_eq!((stop_number.start, stop_number.len), (42, 6));
        assert_eq!(fault.max, "255");
        let stop = find("PAB_EmergencyStop_all");
        assert_eq!(
            (stop.id, stop.dlc, stop.signals.len()),
            (0x0200_FF00 | EXTENDED_FLAG, 0, 0)
        );
        assert_eq!(stop.receivers, ["arm"]);
        assert_eq!(
            find("PAB_EmergencyStop_arm").id,
            FrameId::new(Service::EmergencyStop, TOOL, 10).raw() | EXTENDED_FLAG
        );
        let abort = find("PAB_SchemaAbort_arm");
        assert_eq!(
            (abort.id, abort.dlc),
            (
                FrameId::new(Service::SchemaAbort, TOOL, 10).raw() | EXTENDED_FLAG,
                0
            )
        );
        assert!(find("PAB_SchemaAbort_all").comment.contains("0x19"));
        // ISO-TP: the tool's frames and the board's flow control, 8 bytes each (padded).
        let transfer = FrameId::new(Service::SchemaTransfer, TOOL, 10).raw();
        assert!(dbc.node_comments[1].contains(&format!("0x{transfer:08X}")));
        let data = find("PAB_SchemaTransfer_arm");
        assert_eq!((data.id, data.dlc), (transfer | EXTENDED_FLAG, 8));
        let flow = find("PAB_SchemaTransferFlow_arm");
        assert_eq!(
            (flow.id, flow.dlc),
            (
                FrameId::new(Service::SchemaTransfer, 10, TOOL).raw() | EXTENDED_FLAG,
                8
            )
        );
        fits_without_overlap(&dbc);
        // Without a schema server: none of them.
        let plain = build(&network(NET), &[]).unwrap();
        assert!(plain.messages.iter().all(|m| {
            ["PAB_Schema", "PAB_EmergencyStop"]
                .iter()
                .all(|prefix| !m.name.starts_with(prefix))
        }));
    }

    /// host-tools/tests/fixtures/sensors.toml: a board with one sensor of each kind of field
    /// (the file cantools checks in ./test.sh).
    fn sensors_network() -> Network {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../host-tools/tests/fixtures/sensors.toml"
        );
        network(&std::fs::read_to_string(path).unwrap())
    }

    #[test]
    fn a_schema_servers_sensor_topics_are_messages_with_one_signal_per_field() {
        let dbc = build(&sensors_network(), &[]).unwrap();
        let sensors: Vec<(&str, u32, u8)> = dbc
            .messages
            .iter()
            .filter(|m| m.name.starts_with("Sensor_"))
            .map(|m| (m.name.as_str(), m.id, m.dlc))
            .collect();
        // One message per identifier (pressure and temperature share 0x331), the DLC the
        // shortest frame the board reads.
        assert_eq!(
            sensors,
            [
                ("Sensor_gap_arm", 0x330, 2),
                ("Sensor_pressure_temperature_arm", 0x331, 8),
                ("Sensor_ticks_arm", 0x123_4567 | EXTENDED_FLAG, 8),
                ("Sensor_torque_arm", 0x332, 5),
            ]
        );
        let signal = |message: &str, name: &str| {
            let message = dbc.messages.iter().find(|m| m.name == message).unwrap();
            assert_eq!(message.transmitter, UNKNOWN_NODE);
            message
                .signals
                .iter()
                .find(|s| s.name == name)
                .unwrap()
                .clone()
        };
        let gap = signal("Sensor_gap_arm", "gap");
        assert_eq!(
            (gap.start, gap.len, gap.endian, gap.signed),
            (0, 16, Endian::Little, false)
        );
        // physical = raw × factor: the factor is the scale, the bounds the field's in mm.
        assert_eq!(
            (gap.factor.as_str(), gap.min.as_str(), gap.max.as_str()),
            ("0.01", "0", "655.35")
        );
        assert_eq!(gap.unit, "mm");
        assert!(gap.comment.contains("range finder"), "{}", gap.comment);
        let pressure = signal("Sensor_pressure_temperature_arm", "pressure");
        // Motorola: the most significant bit, bit 7 of byte 2.
        assert_eq!(
            (
                pressure.start,
                pressure.len,
                pressure.endian,
                pressure.signed
            ),
            (23, 16, Endian::Big, true)
        );
        assert_eq!(
            (pressure.min.as_str(), pressure.max.as_str()),
            ("-16384", "16383.5")
        );
        let temperature = signal("Sensor_pressure_temperature_arm", "temperature");
        assert_eq!((temperature.start, temperature.len), (56, 8));
        let ticks = signal("Sensor_ticks_arm", "ticks");
        assert_eq!(
            (ticks.start, ticks.endian, ticks.unit.as_str()),
            (39, Endian::Big, "")
        );
        assert!(ticks.comment.contains("2^31 - 1"), "{}", ticks.comment);
        // The network's topic on the range finder's id joins its message: no second one.
        let joined = dbc.messages.iter().find(|m| m.id == 0x330).unwrap();
        assert_eq!(joined.receivers, ["arm", "eye"]);
        assert!(
            joined.comment.contains("Also topic `range`"),
            "{}",
            joined.comment
        );
        assert_eq!(dbc.messages.iter().filter(|m| m.id == 0x330).count(), 1);
        fits_without_overlap(&dbc);

        let text = dbc.render();
        assert!(text.contains(" SG_ gap : 0|16@1+ (0.01,0) [0|655.35] \"mm\" arm,eye\n"));
        assert!(
            text.contains(" SG_ pressure : 23|16@0- (0.5,0) [-16384|16383.5] \"kPa\" arm\n"),
            "{text}"
        );
        assert!(text.contains(&format!(
            "BO_ {} Sensor_ticks_arm: 8 Vector__XXX\n",
            0x123_4567 | EXTENDED_FLAG
        )));
    }

    #[test]
    fn a_dbc_reader_takes_from_a_sensor_frame_the_count_the_board_reads() {
        let network = sensors_network();
        let dbc = build(&network, &[]).unwrap();
        for topic in &network.schema_boards[0].sensors {
            let signal = dbc
                .messages
                .iter()
                .flat_map(|m| &m.signals)
                .find(|s| s.name == topic.name)
                .unwrap();
            let field = topic.sensor.field;
            let (low, high) = field.range();
            // The bounds, and a value whose bytes all differ (a byte-order mistake shows).
            for value in [low, high, 0x0102_0304 % (high + 1)] {
                let mut payload = [0u8; pab_core::frame::MAX_DATA_LEN];
                field.write(&mut payload, value);
                assert_eq!(field.read(&payload), Some(value));
                assert_eq!(
                    dbc_raw(signal, payload.first_chunk().unwrap()),
                    value,
                    "{}",
                    topic.name
                );
            }
        }
    }
}

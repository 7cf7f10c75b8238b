//! pabctl's `--json` outputs: one JSON object on standard output per run, for scripts and CI,
//! beside the human text on standard error. Each shape is documented in docs/pabctl.md ("JSON
//! output") and held to it by the command-line tests; a field is added, never renamed.

use pab_lang::check::Report;
use pab_lang::compile::CompiledNode;
use pab_lang::diagnostic::Diagnostic;
use pab_lang::network::Network;
use serde_json::{Value, json};
use std::path::Path;

/// A diagnostic: `file`, `line` and `column` (1-based; null for a whole-file one), `message`.
pub fn diagnostic(d: &Diagnostic) -> Value {
    json!({
        "file": d.path.display().to_string(),
        "line": d.position.map(|(line, _)| line),
        "column": d.position.map(|(_, column)| column),
        "message": d.message,
    })
}

/// `pabctl check --json` on a file that could not be read or is invalid: `valid` false and its
/// `errors`.
pub fn invalid(path: &Path, errors: &[Diagnostic]) -> Value {
    json!({
        "file": path.display().to_string(),
        "valid": false,
        "consistent": null,
        "errors": errors.iter().map(diagnostic).collect::<Vec<_>>(),
        "warnings": [],
        "ports": [],
        "bus": null,
    })
}

/// `pabctl check --json`: `valid` true, `consistent`, per port its name, node, connections,
/// masks, the masks in which nothing delivers, every overlap (two connections and a smallest
/// set of active connections under which both deliver) and every connection that can never
/// deliver; the `errors` (the same as the text's) and the `warnings`.
pub fn check(
    path: &Path,
    network: &Network,
    report: &Report,
    errors: &[Diagnostic],
    warnings: &[&Diagnostic],
) -> Value {
    let ports: Vec<Value> = report
        .ports
        .iter()
        .map(|port| {
            let names = network.port_connection_names(port.port);
            let name = |index: usize| names.get(index).cloned().unwrap_or_default();
            let active = |mask: u32| {
                (0..names.len())
                    .filter(|bit| mask & (1 << bit) != 0)
                    .map(name)
                    .collect::<Vec<_>>()
            };
            let (port_name, node) = network.ports.get(port.port).map_or(("?", "?"), |p| {
                (
                    p.name.as_str(),
                    network.nodes.get(p.node).map_or("?", |n| n.name.as_str()),
                )
            });
            json!({
                "port": port_name,
                "node": node,
                "consistent": port.is_consistent(),
                "connections": names,
                "masks": port.masks(),
                "idle_masks": port.idle_masks,
                "overlaps": port.overlaps.iter().map(|o| json!({
                    "first": name(o.first),
                    "second": name(o.second),
                    "active": active(o.mask),
                })).collect::<Vec<_>>(),
                "never_deliver": port.dead.iter().map(|&d| name(d)).collect::<Vec<_>>(),
            })
        })
        .collect();
    json!({
        "file": path.display().to_string(),
        "valid": true,
        "consistent": report.is_consistent(),
        "errors": errors.iter().map(diagnostic).collect::<Vec<_>>(),
        "warnings": warnings.iter().map(|d| diagnostic(d)).collect::<Vec<_>>(),
        "ports": ports,
    })
}

/// `pabctl check --json`'s `bus`: `null` without a bit rate; else `bitrate` (bit/s, the nominal
/// rate), `data_bitrate` (a CAN FD bus's data rate, bit/s, or null on a classic bus),
/// `load_percent`, `holds` (every deadline met, load at most 100 %), `lowest_bitrate` (the lowest
/// standard bit rate at which everything holds, or null; on a CAN FD bus the nominal one, with
/// the data phase at `data_bitrate`), `streams` in order of rank (each `name`, `kind` ("topic",
/// "gateway", "protocol"), `id`, `extended`, `bytes`, `fd` (CAN FD frames; a gateway's when a
/// topic feeding it sends them), `period_s`, `jitter_s`, `deadline_s`, `c_s`, `r_s` (null when
/// unbounded), `slack_s` (D − R, negative when missed; null when unbounded), `meets`),
/// `background` (`name`, `id`, `bytes`, `fd`), `not_analysed` (`name`, `reason`) and `errors`
/// (the missed deadlines and the overload, as diagnostics).
pub fn bus(timing: &pab_lang::check::bus::Timing, errors: &[Diagnostic]) -> Value {
    use pab_lang::check::bus::Kind;
    let Some(analysis) = &timing.analysis else {
        return Value::Null;
    };
    let seconds = |ns: u64| ns as f64 / 1e9;
    let streams: Vec<Value> = timing
        .streams
        .streams
        .iter()
        .zip(&analysis.rows)
        .map(|(stream, row)| {
            json!({
                "name": stream.name,
                "kind": match stream.kind {
                    Kind::Topic(_) => "topic",
                    Kind::Gateway(_) => "gateway",
                    Kind::Protocol => "protocol",
                },
                "id": stream.id,
                "extended": stream.extended,
                "bytes": stream.length,
                "fd": stream.fd,
                "period_s": seconds(stream.period_ns),
                "jitter_s": seconds(row.jitter_ns),
                "deadline_s": seconds(row.deadline_ns),
                "c_s": seconds(row.c_ns),
                "r_s": row.r_ns.map(seconds),
                "slack_s": row.r_ns.map(|r| (row.deadline_ns as f64 - r as f64) / 1e9),
                "meets": row.meets,
            })
        })
        .collect();
    json!({
        "bitrate": analysis.bitrate,
        "data_bitrate": analysis.data_bitrate,
        "load_percent": analysis.load_ppb as f64 / 1e7,
        "holds": analysis.holds(),
        "lowest_bitrate": timing.lowest,
        "streams": streams,
        "background": timing.streams.background.iter().map(|b| json!({
            "name": b.name,
            "id": b.id,
            "bytes": b.length,
            "fd": b.fd,
        })).collect::<Vec<_>>(),
        "not_analysed": timing.streams.unanalysed.iter().map(|u| json!({
            "name": u.name,
            "reason": u.reason,
        })).collect::<Vec<_>>(),
        "errors": errors.iter().map(diagnostic).collect::<Vec<_>>(),
    })
}

/// `pabctl compile --json`: per image written, its node, node id, file, size, table version,
/// ports, connections, decision nodes, the mechanisms it needs (`needs`, feature names) and its
/// push's frames on the bus (`push`: `classic` and `fd`, each `frames`, `flow_controls`,
/// `seconds`; `bitrate`, `data_bitrate`).
pub fn compiled(
    output: &Path,
    nodes: &[CompiledNode],
    table_version: u32,
    rates: &pab_lang::push_frames::PushRates,
    pushes: &[pab_lang::push_frames::Push],
) -> Value {
    let (classic_base, fd_base) = (rates.classic_base(), rates.fd_base());
    let frames = |p: &pab_lang::push_frames::PushFrames, base: &pab_lang::can_frame::TimeBase| {
        json!({
            "frames": p.frames,
            "flow_controls": p.flow_controls,
            "seconds": p.seconds(base),
        })
    };
    Value::Array(
        nodes
            .iter()
            .zip(pushes)
            .map(|(node, push)| {
                json!({
                    "node": node.name,
                    "id": node.id,
                    "file": output.join(format!("{}.pab", node.name)).display().to_string(),
                    "bytes": node.image.len(),
                    "table_version": table_version,
                    "ports": node.ports,
                    "connections": node.connections,
                    "decision_nodes": node.decision_nodes,
                    "needs": crate::identity::mechanisms(&node.image).unwrap_or_default(),
                    "push": {
                        "bitrate": rates.bitrate,
                        "data_bitrate": rates.data_bitrate,
                        "classic": frames(&push.classic, &classic_base),
                        "fd": frames(&push.fd, &fd_base),
                    },
                })
            })
            .collect(),
    )
}

/// `pabctl nodes --json`: per node heard, by address: `id` (the address: a node id, or an
/// unassigned node's provisional address 128-254), `node_id` (`null` when unassigned), from its
/// identity `uid` (hex), `firmware` (`name`, `version`, `build`), `protocol`, `table_formats`
/// (lowest, highest), `capacity` (`ports`, `connections`, `decision_nodes`, `image_bytes`),
/// `features` (names), `bitrate_kbps` (`null` when its host sets it), `bitrate_trial` (all
/// `null` until its identity arrived), `name` (from the network file, `null`
/// without one), `state`, `uptime_s` and `table_version` (from its heartbeat; `null` before
/// one), `crc` (the running table's, 8 hex digits; `null` without a table or a status),
/// `stored`, `keyed`, `received`, `delivered`, `discarded`, `errors` (`null` until its frames
/// said), and `last_fault` (`code`, `description`, `count`, `seconds_ago`; `null` without one).
pub fn nodes(
    observer: &crate::observe::Observer,
    names: &std::collections::BTreeMap<u8, String>,
    now: std::time::Instant,
) -> Value {
    Value::Array(
        observer
            .nodes()
            .iter()
            .map(|(id, view)| {
                let heartbeat = view.heartbeat.map(|(heartbeat, _)| heartbeat);
                let table = view.table.filter(|table| table.crc != 0);
                let identity = view.identity.map(|(identity, _)| identity);
                let unassigned = pab_core::identity::is_provisional(*id);
                json!({
                    "id": id,
                    "node_id": (!unassigned).then_some(*id),
                    "uid": identity.map(|i| crate::identity::uid_text(&i.uid)),
                    "firmware": identity.map(|i| json!({
                        "name": i.firmware.name_str(),
                        "version": crate::observe::version_text(&i),
                        "build": i.firmware.build.iter().map(|b| format!("{b:02x}")).collect::<String>(),
                    })),
                    "protocol": identity.map(|i| i.protocol),
                    "table_formats": identity.map(|i| i.formats),
                    "capacity": identity.map(|i| json!({
                        "ports": i.capacity.ports,
                        "connections": i.capacity.connections,
                        "decision_nodes": i.capacity.decision_nodes,
                        "image_bytes": i.capacity.image_len,
                    })),
                    "features": identity.map(|i| i.feature_names().collect::<Vec<_>>()),
                    "bitrate_kbps": identity.map(|i| i.bitrate_kbps).filter(|rate| *rate != 0),
                    "bitrate_trial": identity.map(|i| i.flags & pab_core::identity::Identity::FLAG_BITRATE_TRIAL != 0),
                    "name": names.get(id),
                    "state": heartbeat.map(|h| h.state.description()),
                    "uptime_s": heartbeat.map(|h| h.uptime_s),
                    "table_version": heartbeat.map(|h| h.table_version),
                    "crc": table.map(|t| format!("{:08x}", t.crc)),
                    "stored": table.map(|t| t.stored),
                    "keyed": identity.map(|i| i.keyed()).or(view.table.map(|t| t.keyed)),
                    "received": view.traffic.map(|t| t.received),
                    "delivered": view.traffic.map(|t| t.delivered),
                    "discarded": view.errors.map(|e| e.discarded),
                    "errors": view.errors.map(|e| e.errors),
                    "last_fault": view.last_fault.map(|(fault, at)| json!({
                        "code": fault.code.code(),
                        "description": crate::observe::describe_fault(&fault),
                        "count": fault.count,
                        "seconds_ago": now.saturating_duration_since(at).as_secs_f64(),
                    })),
                })
            })
            .collect(),
    )
}

/// `pabctl sim --json`: `file`, `frames` (frames on the simulated bus), `nodes`, `until_s`, and
/// per port, in file order: `port`, `node`, `changes` (each time the connection that gets
/// through changes: `t_s`, `delivers`, the connection or `null` for nobody, and its `topic`),
/// and `connections` (`name`, `kind`, `frames`, `delivered`, `discarded`).
pub fn sim(path: &Path, network: &Network, outcome: &pab_lang::sim::Outcome) -> Value {
    let ports: Vec<Value> = network
        .ports
        .iter()
        .enumerate()
        .map(|(index, port)| {
            let changes: Vec<Value> = outcome
                .timelines
                .get(index)
                .into_iter()
                .flatten()
                .map(|change| {
                    let connection = change.selected.and_then(|c| network.connections.get(c));
                    json!({
                        "t_s": change.t_us as f64 / 1e6,
                        "delivers": connection.map(|c| c.name.as_str()),
                        "topic": connection
                            .and_then(|c| network.topics.get(c.topic))
                            .map(|t| t.name.as_str()),
                    })
                })
                .collect();
            let connections: Vec<Value> = port
                .connections
                .iter()
                .filter_map(|&c| Some((c, network.connections.get(c)?)))
                .map(|(c, connection)| {
                    let frames = outcome.rows_of(c, 0, u64::MAX).count();
                    let delivered = outcome
                        .rows_of(c, 0, u64::MAX)
                        .filter(|row| row.delivered)
                        .count();
                    json!({
                        "name": connection.name,
                        "kind": connection.kind.name(),
                        "frames": frames,
                        "delivered": delivered,
                        "discarded": frames - delivered,
                    })
                })
                .collect();
            json!({
                "port": port.name,
                "node": network.nodes.get(port.node).map(|n| n.name.as_str()),
                "changes": changes,
                "connections": connections,
            })
        })
        .collect();
    json!({
        "file": path.display().to_string(),
        "frames": outcome.frames,
        "nodes": network.nodes.len(),
        "until_s": outcome.until_us as f64 / 1e6,
        "ports": ports,
    })
}

/// `pabctl sim --timed-bus --json`'s `timed_bus` (absent without the option, so that the ideal
/// bus's JSON stays as it was): `bitrate`, `data_bitrate` (or null), `carried` (frames the bus
/// carried), `unsent` (still waiting at the end), `holds` (no compared latency above its bound),
/// `streams` in order of rank (each `name`, `id`, `extended`, `frames`, `compared`,
/// `worst_latency_s` and `worst_wait_s` (of the compared frames, null without one),
/// `worst_queued_s` (when the frame of the worst latency was queued), `bound_s` (R, null when
/// unbounded), `verdict` ("within", "above", "no frames", "unbounded" or "not compared"), `why`
/// (why not compared, else null), `beyond_period` (null, or its frames closer to the earlier
/// ones than its period and jitter allow, not compared: `frames`, `first_queued_s`, `detail`),
/// `behind` (null, or the frames not compared for what they waited behind: `frames`,
/// `first_queued_s`, `worst_latency_s`, `ahead`, the names)) and `unmatched` (the frames of
/// no analysed stream: `name`, `id`, `extended`, `frames`, `first_queued_s`, `worst_latency_s`).
/// Times in seconds, from the bus's exact clock.
pub fn timed_bus(
    comparison: &pab_lang::sim::latency::Comparison,
    timing: &pab_lang::check::bus::Timing,
) -> Value {
    use pab_lang::sim::latency::Verdict;
    let clock = &comparison.clock;
    let seconds = |units: u128| clock.ns(units) as f64 / 1e9;
    let streams: Vec<Value> = comparison
        .streams
        .iter()
        .filter_map(|row| {
            let stream = timing.streams.streams.get(row.stream)?;
            let compared = row.compared > 0;
            Some(json!({
                "name": stream.name,
                "id": stream.id,
                "extended": stream.extended,
                "frames": row.frames,
                "compared": row.compared,
                "worst_latency_s": compared.then(|| seconds(row.worst_latency)),
                "worst_wait_s": compared.then(|| seconds(row.worst_wait)),
                "worst_queued_s": row.worst.map(|t| t.queued_us as f64 / 1e6),
                "bound_s": row.bound.map(seconds),
                "verdict": match &row.verdict {
                    Verdict::Within => "within",
                    Verdict::Above => "above",
                    Verdict::NoFrames => "no frames",
                    Verdict::Unbounded => "unbounded",
                    Verdict::Outside(_) => "not compared",
                },
                "why": match &row.verdict {
                    Verdict::Outside(why) => Some(why.as_str()),
                    _ => None,
                },
                "beyond_period": row.faster.as_ref().map(|f| json!({
                    "frames": f.frames,
                    "first_queued_s": f.first_us as f64 / 1e6,
                    "detail": f.detail,
                })),
                "behind": row.behind.as_ref().map(|b| json!({
                    "frames": b.frames,
                    "first_queued_s": b.first_us as f64 / 1e6,
                    "worst_latency_s": seconds(b.worst_latency),
                    "ahead": b.ahead,
                })),
            }))
        })
        .collect();
    let unmatched: Vec<Value> = comparison
        .unmatched
        .iter()
        .map(|u| {
            json!({
                "name": u.name,
                "id": u.id,
                "extended": u.extended,
                "frames": u.frames,
                "first_queued_s": u.first_us as f64 / 1e6,
                "worst_latency_s": seconds(u.worst_latency),
            })
        })
        .collect();
    let analysis = timing.analysis.as_ref();
    json!({
        "bitrate": analysis.map(|a| a.bitrate),
        "data_bitrate": analysis.and_then(|a| a.data_bitrate),
        "carried": comparison.carried,
        "unsent": comparison.unsent,
        "holds": comparison.holds(),
        "streams": streams,
        "unmatched": unmatched,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observe::Observer;
    use pab_core::protocol::{BROADCAST, Heartbeat, Message, NodeState};
    use std::collections::BTreeMap;
    use std::time::Instant;

    #[test]
    fn a_node_heard_only_by_its_heartbeat_has_nulls_for_what_it_did_not_say() {
        let mut observer = Observer::new();
        let at = Instant::now();
        let heartbeat = Message::Heartbeat(Heartbeat {
            state: NodeState::Operational,
            uptime_s: 42,
            table_version: 3,
        });
        observer.observe(&heartbeat.to_frame(2, BROADCAST), at);
        let names = BTreeMap::from([(2, "hand".to_string())]);
        let found = nodes(&observer, &names, at);
        assert_eq!(
            found,
            json!([{
                "id": 2, "name": "hand", "state": "operational", "uptime_s": 42,
                "table_version": 3, "crc": null, "stored": null, "keyed": null,
                "received": null, "delivered": null, "discarded": null, "errors": null,
                "last_fault": null, "node_id": 2, "uid": null, "firmware": null,
                "protocol": null, "table_formats": null, "capacity": null, "features": null,
                "bitrate_kbps": null, "bitrate_trial": null,
            }])
        );
    }

    #[test]
    fn an_unassigned_node_is_listed_by_its_identity_with_a_null_node_id() {
        use pab_core::identity::{Capacity, Firmware, Identity, IdentityPart};
        let identity = Identity {
            uid: [0xAB, 1, 2, 3, 4, 5, 6, 0xCD, 0, 0, 0, 0],
            firmware: Firmware::new("pab-node", "0.1.0", "0123abcd"),
            protocol: 1,
            formats: [10, 10],
            capacity: Capacity {
                ports: 16,
                connections: 512,
                decision_nodes: 2048,
                image_len: 32768,
            },
            features: Identity::FEATURE_BLE | Identity::FEATURE_SCHEMA,
            flags: Identity::FLAG_UNASSIGNED,
            bitrate_kbps: 0,
        };
        let address = pab_core::identity::provisional_address(&identity.uid);
        let mut observer = Observer::new();
        let at = Instant::now();
        for part in IdentityPart::ALL {
            let message = Message::Identity {
                part,
                payload: identity.payload(part),
            };
            observer.observe(&message.to_frame(address, BROADCAST), at);
        }
        let found = nodes(&observer, &BTreeMap::new(), at);
        let node = &found[0];
        assert_eq!(node["id"], json!(address));
        assert_eq!(node["node_id"], Value::Null);
        assert_eq!(node["uid"], json!("ab010203040506cd"));
        assert_eq!(
            node["firmware"],
            json!({"name": "pab-node", "version": "0.1.0", "build": "0123abcd00000000"})
        );
        assert_eq!(node["protocol"], json!(1));
        assert_eq!(node["features"], json!(["ble", "schema"]));
        assert_eq!(node["keyed"], json!(false));
        assert_eq!(node["bitrate_kbps"], Value::Null);
    }
}

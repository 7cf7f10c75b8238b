//! Identity and configuration over the bus: a node says who it is when asked (and once at
//! start), an unassigned node takes only its identity request and its assignment, a node id
//! and a bit rate are stored before they count, and a bit rate that hears nothing goes back.

use crate::common;

use common::*;
use pab_app::{Config, Firmware, Settings};
use pab_core::auth::{Authenticator, Key};
use pab_core::identity::{self, Identity, IdentityParts};
use pab_core::protocol::{
    self, Assign, AuthFailure, ConfigStatus, ConfigStatusCode, Configure, DiagnosticControl,
    FaultCode, Message, Service,
};
use pab_core::{Frame, Instant};

const UID: [u8; 12] = [
    0xA1, 0xB2, 0xC3, 0xD4, 0xE5, 0xF6, 0x07, 0x18, 0x29, 0x3A, 0x4B, 0x5C,
];
const FIRMWARE: Firmware = Firmware::new("fw-test", "1.2.3", "00c0ffee00c0ffee");

/// The identities the node sent to `destination` since `from` µs (each of six frames in a row).
fn identities(h: &Harness, from: u64, destination: u8) -> Vec<(u8, Identity)> {
    let mut parts = std::collections::BTreeMap::<u8, IdentityParts>::new();
    let mut out = Vec::new();
    for (_, id, message) in h.messages_since(from) {
        if let Message::Identity { part, payload } = message
            && id.destination == destination
        {
            let entry = parts.entry(id.source).or_default();
            entry.add(part, payload);
            if let Some(identity) = entry.complete() {
                out.push((id.source, identity));
                parts.remove(&id.source);
            }
        }
    }
    out
}

fn statuses(h: &Harness, from: u64) -> Vec<(u8, ConfigStatus)> {
    h.messages_since(from)
        .into_iter()
        .filter_map(|(_, id, message)| match message {
            Message::ConfigStatus(status) => Some((id.source, status)),
            _ => None,
        })
        .collect()
}

fn unassigned(setup: impl FnOnce(&mut TestNode)) -> Harness {
    Harness::boot_config(Config::unassigned(), None, |node| {
        node.set_identity(FIRMWARE, UID);
        node.set_settings(Ok(None), 500, Instant::from_micros(0));
        setup(node);
    })
}

fn request(h: &mut Harness, destination: u8) {
    h.feed(&Message::IdentityRequest.to_frame(protocol::TOOL, destination));
}

fn assign(destination: u8, uid: &[u8; 12], node_id: u8) -> Frame {
    Message::Assign(Assign {
        uid_check: identity::uid_check(uid),
        node_id,
        tag: None,
    })
    .to_frame(protocol::TOOL, destination)
}

#[test]
fn a_node_answers_who_it_is_and_announces_it_at_start() {
    let mut h = Harness::boot_with(None, |node| {
        node.set_identity(FIRMWARE, UID);
        node.set_settings(Ok(None), 500, Instant::from_micros(0));
    });
    // Announced once at start, to all.
    let announced = identities(&h, 0, protocol::BROADCAST);
    assert_eq!(announced.len(), 1);
    h.advance_to(100_000);
    request(&mut h, Harness::NODE_ID);
    let answers = identities(&h, 100_000, protocol::TOOL);
    assert_eq!(answers.len(), 1, "one answer of six frames");
    let (source, identity) = answers[0];
    assert_eq!(source, Harness::NODE_ID);
    assert_eq!(identity, announced[0].1);
    assert_eq!(identity.uid, UID);
    assert_eq!(identity.firmware.name_str(), Some("fw-test"));
    assert_eq!(identity.firmware.version, [1, 2, 3]);
    assert_eq!(
        identity.firmware.build,
        [0, 0xC0, 0xFF, 0xEE, 0, 0xC0, 0xFF, 0xEE]
    );
    assert_eq!(identity.protocol, identity::PROTOCOL_VERSION);
    let format = pab_core::image::FORMAT_VERSION as u8;
    assert_eq!(identity.formats, [format, format]);
    // TestNode's capacities.
    assert_eq!(
        (
            identity.capacity.ports,
            identity.capacity.connections,
            identity.capacity.decision_nodes,
            identity.capacity.image_len
        ),
        (4, 64, 256, 8192)
    );
    let features: Vec<&str> = identity.feature_names().collect();
    assert!(features.contains(&"ble") && features.contains(&"filters"));
    assert_eq!(
        features.contains(&"dynamics"),
        cfg!(feature = "dynamics"),
        "{features:?}"
    );
    // CAN FD is said as it is built: the boards' classic builds without, pab-node with.
    assert_eq!(
        features.contains(&"fd"),
        cfg!(feature = "fd"),
        "{features:?}"
    );
    assert_eq!(identity.flags, 0, "unkeyed, assigned, no trial");
    assert_eq!(identity.bitrate_kbps, 500);
    // A broadcast request is answered too; a second one within 20 ms is not (six frames per
    // 20 ms at most, whatever floods the bus).
    h.advance_to(200_000);
    request(&mut h, protocol::BROADCAST);
    request(&mut h, protocol::BROADCAST);
    h.advance_to(219_000);
    request(&mut h, protocol::BROADCAST);
    assert_eq!(identities(&h, 200_000, protocol::TOOL).len(), 1);
    h.advance_to(221_000);
    request(&mut h, protocol::BROADCAST);
    assert_eq!(identities(&h, 200_000, protocol::TOOL).len(), 2);
}

#[test]
fn an_unassigned_node_answers_only_identity_and_assignment() {
    let mut h = unassigned(|_| {});
    let address = identity::provisional_address(&UID);
    assert!((0x80..=0xFE).contains(&address));
    // Its announcement comes from the provisional address and says it is unassigned.
    let announced = identities(&h, 0, protocol::BROADCAST);
    assert_eq!(announced.len(), 1);
    assert_eq!(announced[0].0, address);
    assert_ne!(announced[0].1.flags & Identity::FLAG_UNASSIGNED, 0);
    // No heartbeat, ever; a diagnostic command or a table transfer does nothing.
    h.feed(
        &Message::DiagnosticControl(DiagnosticControl {
            rate_hz: 10,
            ports: 1,
        })
        .to_frame(protocol::TOOL, address),
    );
    h.advance_to(3_000_000);
    assert!(h.messages_since(0).iter().all(|(_, id, message)| {
        matches!(message, Message::Identity { .. }) && id.source == address
    }));
    // A request to its address is answered from it.
    request(&mut h, address);
    assert_eq!(identities(&h, 3_000_000, protocol::TOOL).len(), 1);
    // An assignment for another uid behind the same address is not its business.
    let mut other = UID;
    other[11] ^= 1;
    h.feed(&assign(address, &other, 9));
    assert!(h.settings_saved.is_empty());
    // Broadcast assignments are not taken: each names one node.
    h.feed(&assign(protocol::BROADCAST, &UID, 9));
    assert!(h.settings_saved.is_empty());
    // Its own: stored, then in force, answered from the new id.
    h.advance_to(3_100_000);
    h.feed(&assign(address, &UID, 9));
    assert_eq!(h.settings_saved.len(), 1);
    let settings = Settings::from_record(h.settings_saved[0]).unwrap();
    assert_eq!(settings.node_id, Some(9));
    assert_eq!(
        statuses(&h, 3_100_000),
        [(
            9,
            ConfigStatus {
                command: Service::Assign.code(),
                status: ConfigStatusCode::Stored,
                node_id: 9,
                bitrate_kbps: 500
            }
        )]
    );
    let renamed = identities(&h, 3_100_000, protocol::BROADCAST);
    assert_eq!(renamed.len(), 1);
    assert_eq!(renamed[0].0, 9);
    assert_eq!(renamed[0].1.flags & Identity::FLAG_UNASSIGNED, 0);
    // Now a node: heartbeats from 9.
    h.advance_to(4_200_000);
    assert!(
        h.messages_since(3_100_000)
            .iter()
            .any(|(_, id, message)| { matches!(message, Message::Heartbeat(_)) && id.source == 9 })
    );
}

#[test]
fn an_assignment_that_cannot_be_stored_changes_nothing() {
    let mut h = unassigned(|_| {});
    h.settings_result = Err(pab_app::StoreError::VerifyFailed);
    let address = identity::provisional_address(&UID);
    h.feed(&assign(address, &UID, 9));
    assert_eq!(
        statuses(&h, 0),
        [(
            address,
            ConfigStatus {
                command: Service::Assign.code(),
                status: ConfigStatusCode::StoreFailed,
                node_id: 0,
                bitrate_kbps: 500
            }
        )]
    );
    h.advance_to(2_000_000);
    assert!(
        !h.messages_since(0)
            .iter()
            .any(|(_, _, m)| matches!(m, Message::Heartbeat(_)))
    );
    // Without a configuration page (a Linux node without --store): in force, not stored.
    h.settings_result = Ok(false);
    h.feed(&assign(address, &UID, 9));
    assert_eq!(
        statuses(&h, 2_000_000)[0].1.status,
        ConfigStatusCode::NotStored
    );
    assert_eq!(h.node.config().node_id, 9);
}

#[test]
fn a_keyed_node_takes_an_assignment_only_with_the_key() {
    let key = Key::from_bytes([7; 16]);
    let mut h = unassigned(|node| node.set_key(&key, 1));
    let address = identity::provisional_address(&UID);
    assert_ne!(
        identities(&h, 0, protocol::BROADCAST)[0].1.flags & Identity::FLAG_KEYED,
        0
    );
    // Without a tag: refused, said in a fault from the provisional address.
    h.feed(&assign(address, &UID, 9));
    assert!(h.settings_saved.is_empty());
    assert_eq!(h.auth_failures_since(0), [AuthFailure::Missing]);
    // With a tag over the node's challenge (to its provisional address): taken.
    let since = h.now;
    h.feed(&Message::ChallengeRequest { tool_nonce: 0x1234 }.to_frame(protocol::TOOL, address));
    let node_nonce = h
        .messages_since(since)
        .into_iter()
        .find_map(|(_, id, message)| match message {
            Message::Challenge { node_nonce, .. } if id.source == address => Some(node_nonce),
            _ => None,
        })
        .expect("a challenge from the provisional address");
    let nonce = Authenticator::new(&key)
        .exchange(address, 0x1234, node_nonce)
        .nonce;
    let command = Assign {
        uid_check: identity::uid_check(&UID),
        node_id: 9,
        tag: None,
    };
    let tag = Authenticator::new(&key).command_tag(
        address,
        Service::Assign.code(),
        nonce,
        &command.payload(),
    );
    h.feed(
        &Message::Assign(Assign {
            tag: Some(tag),
            ..command
        })
        .to_frame(protocol::TOOL, address),
    );
    assert_eq!(h.settings_saved.len(), 1);
    assert_eq!(h.node.config().node_id, 9);
}

#[test]
fn a_bit_rate_is_stored_for_the_next_start_and_kept_only_if_the_bus_is_heard() {
    let mut h = Harness::boot_with(None, |node| {
        node.set_identity(FIRMWARE, UID);
        node.set_settings(Ok(None), 500, Instant::from_micros(0));
    });
    let configure = |kbps| {
        Message::Configure(Configure {
            bitrate_kbps: kbps,
            tag: None,
        })
        .to_frame(protocol::TOOL, Harness::NODE_ID)
    };
    h.feed(&configure(800));
    assert!(h.settings_saved.is_empty());
    assert_eq!(statuses(&h, 0)[0].1.status, ConfigStatusCode::BadValue);
    h.advance_to(10_000);
    h.feed(&configure(250));
    let settings = Settings::from_record(*h.settings_saved.last().unwrap()).unwrap();
    assert_eq!(
        (
            settings.bitrate_kbps,
            settings.previous_kbps,
            settings.trial
        ),
        (Some(250), Some(500), true)
    );
    let answer = statuses(&h, 10_000)[0].1;
    assert_eq!(
        (answer.status, answer.bitrate_kbps),
        (ConfigStatusCode::Stored, 250)
    );
    // Still 500 now; 250 from the next start.
    assert_eq!(h.node.identity().bitrate_kbps, 500);

    // The next start, on 250 with the trial: a frame heard within 5 s keeps it.
    let record = *h.settings_saved.last().unwrap();
    let mut heard = Harness::boot_with(None, |node| {
        node.set_identity(FIRMWARE, UID);
        node.set_settings(Ok(Some(record)), 250, Instant::from_micros(0));
    });
    assert_ne!(
        heard.node.identity().flags & Identity::FLAG_BITRATE_TRIAL,
        0
    );
    heard.advance_to(1_000_000);
    heard.feed(&frame(TOPIC_A, &[1]));
    heard.advance_to(5_000_001);
    let kept = Settings::from_record(*heard.settings_saved.last().unwrap()).unwrap();
    assert_eq!(
        (kept.bitrate_kbps, kept.trial, kept.fell_back),
        (Some(250), false, false)
    );
    assert_eq!(heard.restarts, 0);
    assert_eq!(
        heard.node.identity().flags & Identity::FLAG_BITRATE_TRIAL,
        0
    );

    // ... and nothing heard within 5 s: the previous rate stored again, and a restart.
    let mut deaf = Harness::boot_with(None, |node| {
        node.set_identity(FIRMWARE, UID);
        node.set_settings(Ok(Some(record)), 250, Instant::from_micros(0));
    });
    deaf.advance_to(4_999_000);
    assert!(deaf.settings_saved.is_empty());
    deaf.advance_to(5_000_001);
    let back = Settings::from_record(*deaf.settings_saved.last().unwrap()).unwrap();
    assert_eq!(
        (
            back.bitrate_kbps,
            back.previous_kbps,
            back.trial,
            back.fell_back
        ),
        (Some(500), Some(250), false, true)
    );
    assert_eq!(deaf.restarts, 1);
    // The start after the restart says what happened.
    let back_record = *deaf.settings_saved.last().unwrap();
    let restarted = Harness::boot_with(None, |node| {
        node.set_identity(FIRMWARE, UID);
        node.set_settings(Ok(Some(back_record)), 500, Instant::from_micros(0));
    });
    let mut h = restarted;
    h.advance_to(1_000_000);
    assert!(h.messages_since(0).iter().any(|(_, _, m)| matches!(
        m,
        Message::Fault(fault) if fault.code == FaultCode::BitrateFallback
            && fault.detail[..4] == [250, 0, 0xF4, 1]
    )));
    assert_ne!(
        h.node.identity().flags & Identity::FLAG_BITRATE_FELL_BACK,
        0
    );
}

#[test]
fn a_host_node_does_not_set_its_bit_rate_and_a_bad_page_is_said() {
    let mut h = Harness::boot_with(None, |node| {
        node.set_identity(FIRMWARE, UID);
        node.set_settings(
            Err(pab_app::StoreError::Corrupt),
            0,
            Instant::from_micros(0),
        );
    });
    h.feed(
        &Message::Configure(Configure {
            bitrate_kbps: 250,
            tag: None,
        })
        .to_frame(protocol::TOOL, Harness::NODE_ID),
    );
    assert_eq!(statuses(&h, 0)[0].1.status, ConfigStatusCode::Unsupported);
    h.advance_to(1_000_000);
    assert!(h.messages_since(0).iter().any(|(_, _, m)| matches!(
        m,
        Message::Fault(fault) if fault.code == FaultCode::SettingsUnreadable
    )));
}

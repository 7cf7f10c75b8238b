//! BLE claims: the claim messages of each group member (one per eligibility, since a claim's
//! identifier carries it), and the claims a capture holds, checked against the network.

use pab_core::ble::Claim;

use super::{DbcMessage, EXTENDED_FLAG, Names, UNKNOWN_NODE, signal};
use crate::diagnostic::Diagnostics;
use crate::network::Network;

/// The BLE claims of a capture, for [`build`](super::build): every frame with a claim's
/// identifier must decode as one (`Claim::decode`, the nodes' own check) from a node that is in a
/// BLE group of `network`; each that does not is reported at its line. Claims are listed once per
/// (node, eligibility).
pub fn claims_in(
    network: &Network,
    capture: &crate::candump::Capture,
    path: &std::path::Path,
) -> Result<Vec<Claim>, Diagnostics> {
    let mut claims: Vec<Claim> = Vec::new();
    let mut errors = Vec::new();
    let members: Vec<u8> = network
        .nodes
        .iter()
        .enumerate()
        .filter(|(index, _)| network.groups.iter().any(|g| g.member(*index).is_some()))
        .map(|(_, node)| node.id)
        .collect();
    for captured in &capture.frames {
        if pab_core::protocol::classify(&captured.frame) != pab_core::protocol::FrameKind::Claim {
            continue;
        }
        let at =
            |message: String| crate::diagnostic::Diagnostic::at(path, captured.line, 1, message);
        match Claim::decode(&captured.frame) {
            Ok(claim) if !members.contains(&claim.node) => errors.push(at(format!(
                "a BLE claim from node id {}, which is in no BLE group of {}",
                claim.node,
                network.source.path().display()
            ))),
            Ok(claim) => {
                if !claims
                    .iter()
                    .any(|c| c.node == claim.node && c.eligibility == claim.eligibility)
                {
                    claims.push(claim);
                }
            }
            Err(error) => errors.push(at(format!(
                "a frame with a BLE claim's identifier that is not a claim: {error}"
            ))),
        }
    }
    if errors.is_empty() {
        return Ok(claims);
    }
    // A capture of another network has thousands: the first twenty say what is wrong.
    const SHOWN: usize = 20;
    if errors.len() > SHOWN {
        let more = errors.len() - SHOWN;
        errors.truncate(SHOWN);
        errors.push(crate::diagnostic::Diagnostic::file(
            path,
            format!("{more} more frames like these"),
        ));
    }
    Err(Diagnostics(errors))
}

/// BLE claims: messages per node of a group. A DBC names whole identifiers, and a claim's
/// identifier carries its eligibility (higher eligibility, lower identifier), so each node gets
/// its claim at eligibility 0 ("not a candidate") and one per eligibility of `claims`; the
/// payload reads the same at every eligibility.
pub(super) fn claim_messages(
    network: &Network,
    claims: &[Claim],
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
    for (index, (node, dbc_node)) in network.nodes.iter().zip(nodes.iter().skip(1)).enumerate() {
        let groups: Vec<&crate::network::BleGroup> = network
            .groups
            .iter()
            .filter(|g| g.member(index).is_some())
            .collect();
        let Some(period) = groups.iter().map(|g| g.period_us).min() else {
            continue;
        };
        let mut eligibilities: Vec<u16> = claims
            .iter()
            .filter(|c| c.node == node.id)
            .map(|c| c.eligibility)
            .chain([0])
            .collect();
        eligibilities.sort_unstable();
        eligibilities.dedup();
        let peers: Vec<String> = network
            .nodes
            .iter()
            .zip(nodes.iter().skip(1))
            .enumerate()
            .filter(|(other, _)| {
                *other != index && groups.iter().any(|g| g.member(*other).is_some())
            })
            .map(|(_, (_, name))| name.clone())
            .collect();
        let names_of: Vec<String> = groups
            .iter()
            .map(|g| format!("{} = {}", g.number, g.name))
            .collect();
        for eligibility in eligibilities {
            let Some(frame) = (Claim {
                group: 0,
                node: node.id,
                eligibility,
            })
            .frame() else {
                continue;
            };
            messages.push(DbcMessage {
            id: frame.raw_id().0 | EXTENDED_FLAG,
            name: names.unique(if eligibility == 0 {
                format!("PAB_Claim_{dbc_node}")
            } else {
                format!("PAB_Claim_{dbc_node}_e{eligibility}")
            }),
            dlc: 4,
            transmitter: dbc_node.clone(),
            receivers: if peers.is_empty() {
                vec![UNKNOWN_NODE.to_string()]
            } else {
                peers.clone()
            },
            signals: vec![
                signal(
                    "Group",
                    0,
                    8,
                    &format!("the BLE group, numbered in file order ({})", names_of.join(", ")),
                ),
                signal(
                    "Eligibility",
                    8,
                    16,
                    "the node's eligibility for the group's task (0: not a candidate); the identifier carries 0xFFFF minus it in bits 22..7",
                ),
                signal("Reserved", 24, 8, "0"),
            ],
            comment: format!(
                "BLE claim of node `{}` (id {}), once per period per group. The identifier ranks the claim (bits 22..7: 0xFFFF - eligibility; bits 6..0: the node id), so it changes with the eligibility: this message is the claim at eligibility {eligibility}; every claim of the node has this payload layout (pabctl dbc --claims-from CAPTURE lists the eligibilities of a capture). See docs/can-protocol.md, Broadcast of Local Eligibility.",
                node.name, node.id
            ),
            fd: false,
            cycle_ms: Some(period.div_ceil(1000)),
        });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dbc::build;
    use crate::dbc::tests::network;

    #[test]
    fn a_captures_claims_are_listed_and_frames_that_are_not_claims_of_members_refused() {
        let net = network(include_str!(
            "../../../examples/multi-target-observation.toml"
        ));
        let claim = |node: u8, eligibility: u16| Claim {
            group: 1,
            node,
            eligibility,
        };
        let good = claim(2, 500).frame().unwrap();
        let stranger = claim(99, 7).frame().unwrap();
        // The identifier says 500, the payload 501: a claim no node would keep.
        let mut bytes = [1, 0xF4, 0x01, 0];
        bytes[1] = 0xF5;
        let forged = pab_core::Frame::data(good.id(), &bytes).unwrap();
        let path = std::path::Path::new("bus.log");
        let capture = |frames: &[pab_core::Frame]| {
            let timed: Vec<(u64, pab_core::Frame)> = frames.iter().map(|f| (0, *f)).collect();
            crate::candump::Capture::from_frames("vcan0", &timed)
        };
        let claims = claims_in(&net, &capture(&[good, good]), path).unwrap();
        assert_eq!(claims, [claim(2, 500)]);
        let dbc = build(&net, &claims).unwrap();
        let listed: Vec<u32> = dbc
            .messages
            .iter()
            .filter(|m| m.name.starts_with("PAB_Claim_r2"))
            .map(|m| m.id & !EXTENDED_FLAG)
            .collect();
        assert_eq!(
            listed,
            [claim(2, 0).frame().unwrap().raw_id().0, good.raw_id().0]
        );
        let errors = claims_in(&net, &capture(&[good, stranger, forged]), path).unwrap_err();
        let text: Vec<String> = errors.0.iter().map(|e| e.render(false)).collect();
        assert_eq!(text.len(), 2, "{text:#?}");
        assert!(
            text[0].starts_with(
                "bus.log:2:1: error: a BLE claim from node id 99, which is in no BLE group"
            ),
            "{text:#?}"
        );
        assert!(
            text[1].starts_with(
                "bus.log:3:1: error: a frame with a BLE claim's identifier that is not a claim"
            ),
            "{text:#?}"
        );
    }
}

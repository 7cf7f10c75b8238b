//! The DBC text of a [`Dbc`](super::Dbc): nodes, messages and signals, comments, cycle times and
//! value tables, in the order DBC readers expect.

use std::fmt::Write as _;

use pab_core::value_port::Endian;

use super::Dbc;

/// `VFrameFormat`'s values, in Vector's order (the attribute's value is an index into them).
const VFRAME_FORMATS: [&str; 16] = [
    "StandardCAN",
    "ExtendedCAN",
    "reserved",
    "J1939PG",
    "reserved",
    "reserved",
    "reserved",
    "reserved",
    "reserved",
    "reserved",
    "reserved",
    "reserved",
    "reserved",
    "reserved",
    "StandardCAN_FD",
    "ExtendedCAN_FD",
];

/// Strips what a DBC string cannot hold.
fn text(s: &str) -> String {
    s.replace('"', "'").replace(['\n', '\r'], " ")
}

impl Dbc {
    /// The DBC text.
    pub fn render(&self) -> String {
        let mut out = String::new();
        // Writing to a String cannot fail.
        let _ = self.write(&mut out);
        out
    }

    fn write(&self, out: &mut String) -> std::fmt::Result {
        writeln!(out, "VERSION \"\"")?;
        writeln!(out)?;
        writeln!(out)?;
        writeln!(out, "NS_ :")?;
        for keyword in [
            "NS_DESC_",
            "CM_",
            "BA_DEF_",
            "BA_",
            "VAL_",
            "BA_DEF_DEF_",
            "VAL_TABLE_",
            "SIG_VALTYPE_",
            "BO_TX_BU_",
        ] {
            writeln!(out, "\t{keyword}")?;
        }
        writeln!(out)?;
        writeln!(out, "BS_:")?;
        writeln!(out)?;
        writeln!(out, "BU_: {}", self.nodes.join(" "))?;
        writeln!(out)?;
        for message in &self.messages {
            writeln!(out)?;
            writeln!(
                out,
                "BO_ {} {}: {} {}",
                message.id, message.name, message.dlc, message.transmitter
            )?;
            for signal in &message.signals {
                let sign = if signal.signed { '-' } else { '+' };
                let order = match signal.endian {
                    Endian::Little => 1,
                    Endian::Big => 0,
                };
                writeln!(
                    out,
                    " SG_ {} : {}|{}@{order}{sign} ({},0) [{}|{}] \"{}\" {}",
                    signal.name,
                    signal.start,
                    signal.len,
                    signal.factor,
                    signal.min,
                    signal.max,
                    text(&signal.unit),
                    message.receivers.join(",")
                )?;
            }
        }
        writeln!(out)?;
        writeln!(out)?;
        writeln!(out, "CM_ \"{}\";", text(&self.comment))?;
        for (node, comment) in self.nodes.iter().zip(&self.node_comments) {
            writeln!(out, "CM_ BU_ {node} \"{}\";", text(comment))?;
        }
        for message in &self.messages {
            writeln!(
                out,
                "CM_ BO_ {} \"{}\";",
                message.id,
                text(&message.comment)
            )?;
            for signal in &message.signals {
                writeln!(
                    out,
                    "CM_ SG_ {} {} \"{}\";",
                    message.id,
                    signal.name,
                    text(&signal.comment)
                )?;
            }
        }
        writeln!(out, "BA_DEF_ BO_ \"GenMsgCycleTime\" INT 0 65535;")?;
        if let Some(brs) = self.fd_brs {
            // Vector's CAN FD attributes, as cantools and CANdb++ read them: the bus type, each
            // message's frame format (an index into the enum: 0 standard, 1 extended, 14 and 15
            // their CAN FD forms) and its bit-rate switch.
            writeln!(out, "BA_DEF_ \"BusType\" STRING ;")?;
            write!(out, "BA_DEF_ BO_ \"VFrameFormat\" ENUM ")?;
            let formats: Vec<String> = VFRAME_FORMATS.iter().map(|f| format!("\"{f}\"")).collect();
            writeln!(out, "{};", formats.join(","))?;
            writeln!(out, "BA_DEF_ BO_ \"CANFD_BRS\" ENUM \"0\",\"1\";")?;
            writeln!(out, "BA_DEF_DEF_ \"BusType\" \"CAN\";")?;
            writeln!(out, "BA_DEF_DEF_ \"VFrameFormat\" \"StandardCAN\";")?;
            writeln!(out, "BA_DEF_DEF_ \"CANFD_BRS\" \"{}\";", u8::from(brs))?;
            writeln!(out, "BA_DEF_DEF_ \"GenMsgCycleTime\" 0;")?;
            writeln!(out, "BA_ \"BusType\" \"CAN FD\";")?;
        } else {
            writeln!(out, "BA_DEF_DEF_ \"GenMsgCycleTime\" 0;")?;
        }
        for message in &self.messages {
            if let Some(cycle) = message.cycle_ms {
                writeln!(out, "BA_ \"GenMsgCycleTime\" BO_ {} {cycle};", message.id)?;
            }
        }
        if self.fd_brs.is_some() {
            for message in &self.messages {
                let extended = message.id & super::EXTENDED_FLAG != 0;
                let format = match (message.fd, extended) {
                    (false, false) => continue,
                    (false, true) => 1,
                    (true, false) => 14,
                    (true, true) => 15,
                };
                writeln!(out, "BA_ \"VFrameFormat\" BO_ {} {format};", message.id)?;
            }
        }
        for message in &self.messages {
            for signal in message.signals.iter().filter(|s| !s.values.is_empty()) {
                write!(out, "VAL_ {} {}", message.id, signal.name)?;
                for (code, description) in &signal.values {
                    write!(out, " {code} \"{}\"", text(description))?;
                }
                writeln!(out, " ;")?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::dbc::tests::{NET, network};
    use crate::dbc::{Q31_FACTOR, build};

    #[test]
    fn the_text_has_the_dbc_sections() {
        let text = build(&network(NET), &[]).unwrap().render();
        assert!(text.contains("BU_: PABCTL arm node_2nd_hand\n"), "{text}");
        assert!(
            text.contains("BO_ 2449669889 PAB_Heartbeat_arm: 8 arm\n"),
            "{text}"
        );
        assert!(text.contains(" SG_ uptime : 8|24@1+ (1,0) [0|16777215] \"s\" PABCTL\n"));
        assert!(text.contains(&format!(
            " SG_ level : 32|32@1+ ({Q31_FACTOR},0) [0|1] \"S\""
        )));
        assert!(
            text.contains("VAL_ 2449669889 state 0 \"no table\" 1 \"operational\" 2 \"fault\" ;\n")
        );
        assert!(text.contains("BA_ \"GenMsgCycleTime\" BO_ 2449669889 1000;\n"));
        assert!(text.contains("BO_ 272 object_pos: 8 Vector__XXX\n"));
        // A classic bus declares no CAN FD attribute.
        assert!(!text.contains("VFrameFormat") && !text.contains("BusType"));
    }

    #[test]
    fn a_can_fd_bus_declares_its_frame_formats() {
        let fd = NET.replace(
            "[topics.object_pos]",
            "[bus]\nbitrate = 500000\ndata_bitrate = 2000000\n\n[topics.skin]\ncan_id = 0x141\n\
             fd = true\nlength = 48\n\n[topics.object_pos]",
        );
        let text = build(&network(&fd), &[]).unwrap().render();
        assert!(text.contains("BO_ 321 skin: 48 Vector__XXX\n"), "{text}");
        assert!(text.contains("BA_ \"BusType\" \"CAN FD\";\n"));
        assert!(text.contains("BA_DEF_DEF_ \"CANFD_BRS\" \"1\";\n"));
        // The FD topic, standard id: StandardCAN_FD; a classic topic keeps the default; the
        // protocol's extended frames say ExtendedCAN.
        assert!(text.contains("BA_ \"VFrameFormat\" BO_ 321 14;\n"));
        assert!(!text.contains("BA_ \"VFrameFormat\" BO_ 272 "));
        assert!(text.contains("BA_ \"VFrameFormat\" BO_ 2449669889 1;\n"));
    }
}

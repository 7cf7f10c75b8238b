//! The DBC text of a [`Dbc`](super::Dbc): nodes, messages and signals, comments, cycle times and
//! value tables, in the order DBC readers expect.

use std::fmt::Write as _;

use pab_core::value_port::Endian;

use super::Dbc;

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
        writeln!(out, "BA_DEF_DEF_ \"GenMsgCycleTime\" 0;")?;
        for message in &self.messages {
            if let Some(cycle) = message.cycle_ms {
                writeln!(out, "BA_ \"GenMsgCycleTime\" BO_ {} {cycle};", message.id)?;
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
    }
}

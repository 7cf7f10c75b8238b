//! Numbers on the command line: every duration, time, rate and table version `pabctl` takes, read
//! and checked before anything runs. Each parser accepts a leading `-` (so that `-1` reaches it
//! instead of clap's "unexpected argument") and answers with what the value must be; clap prints
//! that as `error: invalid value '-1' for '--duration <SECONDS>': must be positive` and exits 2.

use pab_lang::network::MAX_TIME_S;

/// The longest `nodes --listen`, in seconds.
pub const MAX_LISTEN_S: f64 = 3600.0;

/// Seconds in (0, `max`]: not NaN, not negative, not zero, finite and at most `max`.
pub fn seconds_up_to(text: &str, max: f64) -> Result<f64, String> {
    let value: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a number of seconds"))?;
    if value.is_nan() {
        return Err("NaN is not a number of seconds".into());
    }
    if value <= 0.0 {
        return Err(format!("must be positive (seconds, at most {max})"));
    }
    if value > max {
        return Err(format!("must be at most {max} seconds"));
    }
    Ok(value)
}

/// A time or duration of the simulation or the monitor: (0, 10^6] seconds.
pub fn seconds(text: &str) -> Result<f64, String> {
    seconds_up_to(text, MAX_TIME_S)
}

/// How long `nodes` listens: (0, 3600] seconds.
pub fn listen_seconds(text: &str) -> Result<f64, String> {
    seconds_up_to(text, MAX_LISTEN_S)
}

/// A whole number in `min..=max`; `what` says what it is and its range, in messages.
fn whole(text: &str, min: u64, max: u64, what: &str) -> Result<u64, String> {
    let trimmed = text.trim();
    let digits = trimmed.strip_prefix('+').unwrap_or(trimmed);
    if digits.starts_with('-') {
        return Err(format!("must be positive ({what})"));
    }
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!("`{trimmed}` is not a whole number ({what})"));
    }
    // All digits: either it fits u64 and is compared, or it is larger than any maximum here.
    match digits.parse::<u64>() {
        Ok(value) if value < min => Err(format!("must be positive ({what})")),
        Ok(value) if value <= max => Ok(value),
        _ => Err(format!("must be at most {max} ({what})")),
    }
}

/// A table version: 1..=4294967295. Version 0 is what heartbeats report without a table, so an
/// image with it could never be told from no table at all.
pub fn table_version(text: &str) -> Result<u32, String> {
    match whole(text, 0, u64::from(u32::MAX), "a table version, 1 to 4294967295")? {
        0 => Err(
            "table version 0 is reserved (heartbeats report version 0 for \"no table\"); use 1 or more"
                .into(),
        ),
        value => u32::try_from(value).map_err(|_| format!("must be at most {}", u32::MAX)),
    }
}

/// Diagnostic rounds per second asked of a node: 1..=200 (what nodes accept).
pub fn rate_hz(text: &str) -> Result<u16, String> {
    let max = pab_core::protocol::DiagnosticControl::MAX_RATE_HZ;
    let value = whole(
        text,
        1,
        u64::from(max),
        &format!("rounds per second, 1 to {max}"),
    )?;
    u16::try_from(value).map_err(|_| format!("must be at most {max}"))
}

/// A node id: 1..=127.
pub fn node_id(text: &str) -> Result<u8, String> {
    let value = whole(text, 1, 127, "a node id, 1 to 127")?;
    u8::try_from(value).map_err(|_| "must be at most 127".into())
}

/// A bit rate a node can be set to, kbit/s: 125, 250, 500 or 1000.
pub fn bitrate_kbps(text: &str) -> Result<u16, String> {
    let rates = pab_core::protocol::Configure::BITRATES_KBPS;
    let value = whole(text, 1, 1_000_000, "kbit/s: 125, 250, 500 or 1000")?;
    match u16::try_from(value) {
        Ok(rate) if rates.contains(&rate) => Ok(rate),
        _ if rates.iter().any(|&r| u64::from(r) * 1000 == value) => Err(format!(
            "the bit rate is in kbit/s: did you mean {}?",
            value / 1000
        )),
        _ => Err(format!(
            "{value} kbit/s is not a bit rate nodes take: 125, 250, 500 or 1000"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_ids_and_bit_rates_say_what_is_wrong() {
        assert_eq!(node_id("127"), Ok(127));
        assert!(node_id("0").unwrap_err().contains("positive"));
        assert!(node_id("128").unwrap_err().contains("at most 127"));
        assert_eq!(bitrate_kbps("250"), Ok(250));
        assert!(
            bitrate_kbps("500000")
                .unwrap_err()
                .contains("did you mean 500")
        );
        assert!(bitrate_kbps("800").unwrap_err().contains("not a bit rate"));
    }

    #[test]
    fn seconds_must_be_finite_positive_and_bounded() {
        assert_eq!(seconds("2.5"), Ok(2.5));
        assert_eq!(seconds("1e6"), Ok(1e6));
        for (text, message) in [
            ("-1", "must be positive"),
            ("-0", "must be positive"),
            ("0", "must be positive"),
            ("-inf", "must be positive"),
            ("NaN", "NaN is not a number"),
            ("inf", "must be at most 1000000 seconds"),
            ("1e30", "must be at most 1000000 seconds"),
            ("1000000.5", "must be at most"),
            ("", "is not a number"),
            ("5s", "`5s` is not a number of seconds"),
        ] {
            let error = seconds(text).unwrap_err();
            assert!(error.contains(message), "{text}: {error}");
        }
        assert!(listen_seconds("3601").unwrap_err().contains("at most 3600"));
    }

    #[test]
    fn versions_and_rates_are_whole_numbers_in_range() {
        assert_eq!(table_version("1"), Ok(1));
        assert_eq!(table_version("4294967295"), Ok(u32::MAX));
        for (text, message) in [
            ("0", "version 0 is reserved"),
            ("000", "version 0 is reserved"),
            ("-1", "must be positive"),
            ("-0", "must be positive"),
            ("4294967296", "must be at most 4294967295"),
            ("99999999999999999999999", "must be at most 4294967295"),
            ("1.5", "is not a whole number"),
            ("1e3", "is not a whole number"),
            ("", "is not a whole number"),
        ] {
            let error = table_version(text).unwrap_err();
            assert!(error.contains(message), "{text:?}: {error}");
        }
        assert_eq!(rate_hz("200"), Ok(200));
        assert!(rate_hz("0").unwrap_err().contains("must be positive"));
        assert!(rate_hz("-5").unwrap_err().contains("must be positive"));
        assert!(rate_hz("201").unwrap_err().contains("must be at most 200"));
        assert!(
            rate_hz("70000")
                .unwrap_err()
                .contains("must be at most 200")
        );
    }
}

//! `pabctl solve`: HBBA's intention solver on a network's `[hbba]` section and a set of desires,
//! and its answer as text or JSON.

use std::fmt::Write as _;

use pab_core::hbba::Intensities;
use pab_lang::network::{Hbba, Solved};

/// The answer for people: the desires, then per class (in order of first appearance) the chosen
/// strategy and what it adds, the objective, and each resource's use against its capacity.
///
/// ```text
/// desires: face=2, qr=1, nav=2, voice=3
/// objective 17
///   face   face_throttled  utility 2 × intensity 2 = 4
///   qr     none            (desire 1 not fulfilled)
///   voice  voice_localise  utility 3 × intensity 3 = 9
///   nav    nav_follow      utility 2 × intensity 2 = 4
///   avoid  avoid_laser     required (no desire)
/// use
///   cpu  95 of 100
///   bus  12 of 30 (% of 125000 bit/s)
/// ```
pub fn report(hbba: &Hbba, intensities: &Intensities, solved: &Solved) -> String {
    let mut out = String::new();
    let desires: Vec<String> = hbba
        .classes
        .iter()
        .zip(intensities.iter())
        .filter(|&(_, &intensity)| intensity != 0)
        .map(|(class, intensity)| format!("{class}={intensity}"))
        .collect();
    let _ = writeln!(
        out,
        "desires: {}",
        if desires.is_empty() {
            "none".to_string()
        } else {
            desires.join(", ")
        }
    );
    let _ = writeln!(out, "objective {}", solved.objective);
    let class_width = hbba
        .classes
        .iter()
        .map(|c| c.chars().count())
        .max()
        .unwrap_or(0);
    let strategy_width = solved
        .strategies
        .iter()
        .filter_map(|&s| hbba.strategies.get(s))
        .map(|s| s.name.chars().count())
        .max()
        .unwrap_or(0)
        .max(4);
    for (index, class) in hbba.classes.iter().enumerate() {
        let intensity = intensities.get(index).copied().unwrap_or(0);
        let chosen = solved
            .strategies
            .iter()
            .filter_map(|&s| hbba.strategies.get(s))
            .find(|s| s.class == index);
        let (name, note) = match (chosen, intensity) {
            (Some(s), 0) => (s.name.as_str(), "required (no desire)".to_string()),
            (Some(s), _) => (
                s.name.as_str(),
                format!(
                    "utility {} × intensity {intensity} = {}",
                    s.utility,
                    u64::from(s.utility) * u64::from(intensity)
                ),
            ),
            (None, 0) => ("none", String::new()),
            (None, _) => ("none", format!("(desire {intensity} not fulfilled)")),
        };
        let line = format!("  {class:<class_width$}  {name:<strategy_width$}  {note}");
        let _ = writeln!(out, "{}", line.trim_end());
    }
    if !hbba.resources.is_empty() {
        let _ = writeln!(out, "use");
        let width = hbba
            .resources
            .iter()
            .map(|r| r.name.chars().count())
            .max()
            .unwrap_or(0);
        for (resource, used) in hbba.resources.iter().zip(&solved.usage) {
            let unit = match (hbba.bus(), hbba.bitrate) {
                (Some(bus), Some(bitrate)) if hbba.resources.get(bus) == Some(resource) => {
                    format!(" (% of {bitrate} bit/s)")
                }
                _ => String::new(),
            };
            let _ = writeln!(
                out,
                "  {:<width$}  {used} of {}{unit}",
                resource.name, resource.capacity
            );
        }
    }
    out
}

/// The answer as one JSON object: `strategies` (the chosen strategies' names, sorted),
/// `objective` (an integer) and `use` (resource name → its use, resources in file order).
pub fn json(hbba: &Hbba, solved: &Solved) -> String {
    let mut names: Vec<&str> = solved
        .strategies
        .iter()
        .filter_map(|&s| hbba.strategies.get(s))
        .map(|s| s.name.as_str())
        .collect();
    names.sort_unstable();
    let strategies: Vec<String> = names.iter().map(|name| string(name)).collect();
    let usage: Vec<String> = hbba
        .resources
        .iter()
        .zip(&solved.usage)
        .map(|(resource, used)| format!("{}:{used}", string(&resource.name)))
        .collect();
    format!(
        "{{\"strategies\":[{}],\"objective\":{},\"use\":{{{}}}}}",
        strategies.join(","),
        solved.objective,
        usage.join(",")
    )
}

/// A JSON string. Names are letters, digits, `_` and `-` (the parser's rule), but quote and
/// escape anyway.
fn string(text: &str) -> String {
    let mut out = String::from("\"");
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if u32::from(c) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", u32::from(c));
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_strings_are_escaped() {
        assert_eq!(string("a\"b\\c\u{1}"), "\"a\\\"b\\\\c\\u0001\"");
    }
}

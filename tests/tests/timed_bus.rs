//! The simulator's timed bus against `pabctl check`'s bounds: every example with a `[bus]` (and
//! variants that load its bus more) runs on the bus that takes time, and every analysed stream's
//! worst measured latency is at most its worst-case response time R. The comparison is checked
//! not to be empty: streams with frames, latencies above zero, frames that waited for others.
//! That it can fail at all is lang's unit test (a bound made smaller than a measured latency,
//! `sim::latency`'s tests).

use pab_lang::check::bus::{Timing, timing};
use pab_lang::network::Network;
use pab_lang::sim::latency::{Comparison, Verdict, compare};
use pab_lang::sim::{self, Outcome};
use pab_lang::{check, compile};
use pab_tests::{example_text, examples_dir, network};

/// `text` simulated on the timed bus and compared with its analysis.
fn timed(name: &str, text: &str) -> (Network, Timing, Outcome, Comparison) {
    let network = network(name, text);
    assert!(check::check(&network).is_consistent(), "{name}");
    let nodes = compile::compile(&network).unwrap_or_else(|errors| panic!("{errors:?}"));
    let options = sim::Options {
        timed_bus: true,
        ..sim::Options::default()
    };
    let outcome =
        sim::simulate(&network, &nodes, &options).unwrap_or_else(|error| panic!("{error}"));
    let timing = timing(&network);
    let run = outcome.timed.as_ref().expect("a timed run");
    let comparison = compare(&network, &timing, run).unwrap_or_else(|error| panic!("{error}"));
    (network, timing, outcome, comparison)
}

/// What every run must show: every compared latency within its bound, and a comparison that
/// says something (streams with frames, latencies above zero, some frame that waited for the
/// bus). No stream is left out for its own frames (the examples keep their periods); a stream
/// left out for what it waited behind names frames of no analysed stream, which the comparison
/// lists. Frames still waiting at the end were queued in its last 10 ms.
fn assert_within(name: &str, timing: &Timing, outcome: &Outcome, comparison: &Comparison) {
    let table = comparison.table(timing);
    assert!(comparison.holds(), "{name}\n{table}");
    let compared: Vec<_> = comparison.compared().collect();
    assert!(!compared.is_empty(), "{name}: nothing compared\n{table}");
    for row in &comparison.streams {
        let stream = &timing.streams.streams[row.stream];
        match &row.verdict {
            Verdict::Within | Verdict::NoFrames => {}
            Verdict::Outside(why) if why.starts_with("every frame of it was beyond") => {}
            other => panic!("{name}: {}: {other:?}\n{table}", stream.name),
        }
        if row.behind.is_some() {
            assert!(!comparison.unmatched.is_empty(), "{name}\n{table}");
        }
        if row.compared == 0 {
            continue;
        }
        let bound = row.bound.expect("a bound");
        let worst = row.worst.expect("a worst frame");
        assert!(
            row.worst_latency <= bound,
            "{name}: {}: {} > {bound}",
            stream.name,
            row.worst_latency
        );
        // A latency is at least its own frame's time on the bus (SOF to EOF).
        assert!(row.worst_latency >= worst.end_of_frame - worst.start);
        assert!(row.worst_latency > 0);
    }
    // Some frame waited for another: its latency exceeds its own transmission.
    assert!(
        compared.iter().any(|row| row.worst_wait > 0),
        "{name}: no frame ever waited\n{table}"
    );
    let run = outcome.timed.as_ref().unwrap();
    assert!(
        run.unsent
            .iter()
            .all(|w| w.queued_us + 10_000 >= outcome.until_us),
        "{name}: {:?}",
        run.unsent
    );
}

/// Take and Return's networks: every stream with frames compared, and the only frames of no
/// analysed stream are the nodes' identity announcements at start-up (the Traffic and Errors
/// frames of 0 s wait behind them, and are left out).
fn assert_all_compared(name: &str, timing: &Timing, comparison: &Comparison) {
    let table = comparison.table(timing);
    for row in &comparison.streams {
        assert!(
            matches!(row.verdict, Verdict::Within | Verdict::NoFrames),
            "{name}: {:?}\n{table}",
            row.verdict
        );
        if let Some(behind) = &row.behind {
            assert_eq!((behind.frames, behind.first_us), (1, 0), "{name}\n{table}");
        }
    }
    assert!(!comparison.unmatched.is_empty());
    for unmatched in &comparison.unmatched {
        assert!(
            unmatched.name.contains(": Identity") && unmatched.first_us == 0,
            "{name}: {unmatched:?}"
        );
    }
}

/// Every example whose network has a `[bus]` (found, not listed, so that a new one is covered).
fn examples_with_a_bus() -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(examples_dir())
        .unwrap()
        .filter_map(|entry| {
            let path = entry.ok()?.path();
            (path.extension()? == "toml").then(|| path.file_stem()?.to_str().map(String::from))?
        })
        .filter(|name| network(name, &example_text(name)).bus.is_some())
        .collect();
    names.sort();
    names
}

#[test]
fn every_example_with_a_bus_keeps_its_bounds_on_the_timed_bus() {
    let names = examples_with_a_bus();
    assert!(
        names.contains(&"take-and-return".to_string())
            && names.contains(&"take-and-return-fd".to_string()),
        "{names:?}"
    );
    for name in &names {
        let (_, timing, outcome, comparison) = timed(name, &example_text(name));
        assert_within(name, &timing, &outcome, &comparison);
        if name.starts_with("take-and-return") {
            assert_all_compared(name, &timing, &comparison);
        }
    }
}

/// Take and Return on a CAN FD bus with its two CAN FD sensor streams published (the example
/// declares them, but no event sends them): the arm's 32-byte joint state at 100 Hz and the
/// hand's 48-byte tactile array at 50 Hz, with bit-rate switching, among the classic frames.
#[test]
fn can_fd_frames_keep_their_bounds_on_the_timed_bus() {
    let text = format!(
        "{}\n[[events]]\ntopic = \"arm_state\"\nrate_hz = 100.0\nfrom = 0.0\nto = 78.0\n\n\
         [[events]]\ntopic = \"hand_skin\"\nrate_hz = 50.0\nfrom = 0.0\nto = 78.0\n",
        example_text("take-and-return-fd")
    );
    let (_, timing, outcome, comparison) = timed("take-and-return-fd-sensors", &text);
    assert_within("take-and-return-fd-sensors", &timing, &outcome, &comparison);
    assert_all_compared("take-and-return-fd-sensors", &timing, &comparison);
    let run = outcome.timed.as_ref().unwrap();
    let fd: Vec<_> = run
        .transmissions
        .iter()
        .filter(|t| t.frame.is_fd())
        .collect();
    assert_eq!(fd.len(), 7800 + 3900);
    assert!(fd.iter().all(|t| t.frame.is_brs() && t.bits.data > 0));
    let skin = comparison
        .streams
        .iter()
        .find(|row| timing.streams.streams[row.stream].name == "hand_skin")
        .unwrap();
    assert_eq!(skin.compared, 3900);
    // The tactile array waits behind the classic topics at their instants; its 5 ms deadline
    // is R 3.180 ms, and its worst latency on the bus below that.
    assert!(skin.worst_wait > 0);
    assert_eq!(run.clock.ns(skin.bound.unwrap()), 3_180_000);
}

/// Take and Return at 20 kbit/s, the lowest standard bit rate at which `pabctl check` proves
/// every deadline (the bus loaded 71 %): frames queue behind each other for tens of milliseconds,
/// and still none exceeds its bound.
#[test]
fn a_heavily_loaded_bus_keeps_its_bounds_on_the_timed_bus() {
    let text = example_text("take-and-return").replace("bitrate = 500000", "bitrate = 20000");
    let (_, timing, outcome, comparison) = timed("take-and-return-20k", &text);
    assert_eq!(timing.lowest, Some(20_000));
    assert_within("take-and-return-20k", &timing, &outcome, &comparison);
    let waited = comparison
        .compared()
        .map(|row| comparison.clock.ns(row.worst_wait))
        .max()
        .unwrap();
    assert!(waited > 50_000_000, "{}", comparison.table(&timing));
}

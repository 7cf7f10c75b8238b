//! Figure 1 of the paper: Face Detector (C1, rule "C1 & !C2") and Object Detector (C2) at Gaze
//! Control. The timeline and the trace are fully determined by the reference semantics; the
//! example's comment derives them.

use pab_lang::{compile, sim};
use pab_tests::{Scenario, example_text, network};

#[test]
fn the_gaze_follows_the_face_unless_the_object_is_active() {
    let scenario = Scenario::run("figure-1");
    let c1 = Some(scenario.connection("C1"));
    let c2 = Some(scenario.connection("C2"));
    let timeline: Vec<(u64, Option<usize>)> = scenario.outcome.timelines[0]
        .iter()
        .map(|change| (change.t_us, change.selected))
        .collect();
    assert_eq!(
        timeline,
        vec![
            (0, None),
            // C1's sixth frame (S = 0.2, 0.3998, ...): active at 0.5 s.
            (500_000, c1),
            // C2's sixth frame, 0.5 s apart: active at 6.5 s.
            (6_500_000, c2),
            // C2's last frame was at 6.5 s: it lapses 3 s later.
            (9_500_001, c1),
            // C1's last frame was at 11.9 s.
            (14_900_001, None),
        ]
    );
    // The face's frames during the object's activity are discarded.
    assert_eq!(scenario.delivered("C1", 6.55, 9.5), 0);
    assert_eq!(scenario.delivered("C1", 0.0, 15.0), 120 - 5 - 30);
}

#[test]
fn the_trace_has_the_documented_format_and_is_deterministic() {
    let text = example_text("figure-1");
    let csv = |_: ()| {
        let network = network("figure-1", &text);
        let nodes = compile::compile(&network).unwrap();
        let outcome = sim::simulate(&network, &nodes, &sim::Options::default()).unwrap();
        let mut bytes = Vec::new();
        outcome.write_csv(&network, &mut bytes).unwrap();
        String::from_utf8(bytes).unwrap()
    };
    let first = csv(());
    assert_eq!(first, csv(()), "two runs give the same trace");
    let lines: Vec<&str> = first.lines().collect();
    assert_eq!(lines.len(), 1 + 120 + 6);
    assert_eq!(lines[0], "t,port,connection,stimulation,active,delivered");
    assert_eq!(lines[1], "0.000000,gaze.target,C1,0.2000,0,0");
    assert_eq!(lines[2], "0.100000,gaze.target,C1,0.3998,0,0");
    assert_eq!(lines[6], "0.500000,gaze.target,C1,1.0000,1,1");
    // At 6.5 s both topics have a frame: rows in the connections' file order. The face's frame
    // (0x110) wins bus arbitration and goes first, before C2 is active: it is delivered; C2's
    // frame then activates C2 and is delivered too.
    let at_6_5: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|l| l.starts_with("6.500000,"))
        .collect();
    assert_eq!(
        at_6_5,
        [
            "6.500000,gaze.target,C1,1.0000,1,1",
            "6.500000,gaze.target,C2,1.0000,1,1"
        ]
    );
    assert!(lines.contains(&"6.600000,gaze.target,C1,1.0000,1,0"));
    let times: Vec<&str> = lines[1..]
        .iter()
        .map(|l| l.split(',').next().unwrap())
        .collect();
    let mut sorted = times.clone();
    sorted.sort_by(|a, b| {
        a.parse::<f64>()
            .unwrap()
            .total_cmp(&b.parse::<f64>().unwrap())
    });
    assert_eq!(times, sorted, "rows are in time order");
}

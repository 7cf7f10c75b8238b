//! DESIGN.md's competitive-dynamics scenarios ("Competitive dynamics: decisions", scenarios for
//! tests) as example networks, `examples/dynamics/*.toml`: each file is checked (consistent, no
//! warning), compiled, and simulated with the boards' code (`pab_lang::sim`, the nodes' arbiters
//! stepping `pab_core::dynamics`), and its dynamics rows must show DESIGN's orderings and bounds.
//! `core/tests/dynamics.rs` checks the same scenarios on the integrator alone against an f64
//! reference; the door sequence itself is `examples/door-dynamics.toml` (tests/door_dynamics.rs).
//!
//! Time: every file keeps DESIGN's defaults, a step of 1 ms and a unit of 10 ms, so τ = τ_ρ1 =
//! τ_n = 1 unit = 10 steps, τ_ρ2 = 20 units = 200 steps, a memory τ_i = 50 units = 500 steps,
//! and q = 0.001 per √unit. A row at t_k holds the state after k steps and the context that the
//! step from t_k uses; a gate "opens at t" when the row at t is the first with it open.
//!
//! The bounds used throughout, derived below from the equations:
//! - [`refractory_steps`]: a first activation waits at least 139 steps (τ_ρ2·ln 2 = 138.6 ms)
//!   after its context appears;
//! - [`FIRST_WITHIN_US`]: and comes within 0.45 s of it;
//! - [`closing_steps`]: a saturated gate closes 3 steps after its context's first 0;
//! - [`RESUME_WITHIN_US`]: a behaviour whose ρ is already 1, held down only by another's
//!   activity, opens within 0.139 s of being let go (faster than any first activation).

use pab_lang::check;
use pab_lang::compile;
use pab_lang::network::Network;
use pab_lang::sim::{self, DynamicsRow, Options, Outcome};
use pab_tests::{dynamics_example_text, network};

/// One step, µs.
const STEP_US: u64 = 1_000;

/// When a context whose frames start at 0 s is first read: the simulated nodes boot at 0 and
/// sample their contexts then (t_0), before the frames of that instant, as a board that starts
/// with its behaviours does; those frames count from the first step on.
///
/// The same holds for any frame that shares its microsecond with a step and follows another
/// frame of that microsecond on the bus: the node takes the step after the first frame it
/// handles at that instant (as a board does that reads a burst with one timestamp), so the
/// later frames count from the next step. Only the simulator's ideal bus puts two frames in
/// one microsecond.
const FIRST_READ_US: u64 = STEP_US;

/// Steps per τ_ρ2 (20 units of 10 steps).
const TAU_RHO_SLOW_STEPS: u32 = 200;

/// The least number of steps of context 1 after which ρ, from 0, exceeds ½ (so that
/// α = 2ρI − 1 > 0): the explicit step of (3) at I = 1 is ρ += (1 − ρ) / 200, so
/// ρ_k = 1 − 0.995^k, above ½ from k = 139 (0.995^139 = 0.4983; τ_ρ2·ln 2 = 138.6 steps in
/// continuous time). Before that α < 0 and n only shrinks: no gate can open earlier.
fn refractory_steps() -> u64 {
    let (mut rho, mut k) = (0.0f64, 0);
    while rho <= 0.5 {
        rho += (1.0 - rho) / f64::from(TAU_RHO_SLOW_STEPS);
        k += 1;
    }
    k
}

/// A first activation comes within this long of its context appearing. From the crossing
/// t0 = τ_ρ2·ln 2, α = 1 − 2e^(−t/τ_ρ2) and n grows as exp(∫α dt/τ); x units after t0,
/// ∫α = x − 20 (1 − e^(−x/20)). 0.45 s is 45 units after the context, 31 after t0, where
/// ∫α = 15.2: n reaches 0.707 from any start above 0.707·e^(−15.2) = 1.8e-7, while the noise
/// spreads n at the crossing over about q·(π/0.05)^(1/4) = 2.8e-3 (the noise of the steps
/// around t0, weighted by exp(−0.025 u²) with u units from t0). The cubic term adds about half
/// a unit. Measured in these files: 0.30 to 0.38 s (0.36 s for the door's search).
const FIRST_WITHIN_US: u64 = 450_000;

/// The steps from a saturated behaviour's first step with context 0 to its gate's closing. With
/// I = 0, α = −1 at once and n += (dt/τ)(−n − n³), dt/τ = 0.1: from 1, n goes 0.8, 0.672,
/// 0.582, and n² (0.64, 0.45, 0.34) falls below the closing threshold 0.4 at the third step
/// (0.45 is above it: the hysteresis keeps the gate open after the second). The noise, 3e-4 a
/// step, is far from these margins.
fn closing_steps() -> u64 {
    let (mut n, mut k) = (1.0f64, 0);
    while n * n >= 0.4 {
        n += 0.1 * (-n - n * n * n);
        k += 1;
    }
    k
}

/// A behaviour whose context has held (ρ ≈ 1) but which another's activity held down opens
/// within this long of that other's context ending: α = 2ρ − 1 ≈ 1 as soon as the other's n² is
/// below 1/3 (3 steps), and n grows from where the push held it: while held at growth rate
/// α − γ n² = 1 − 3 = −2 its noise has a spread of q / √(2·2) = 5e-4, and from 5e-4 to 0.707
/// takes ln(1414) = 7.3 units. 139 ms (τ_ρ2·ln 2, the least delay of any first activation)
/// leaves room for a start 500 times smaller. Measured from the other's context end: 0.079 s
/// (one-way.toml) and 0.102 s (incumbent.toml).
const RESUME_WITHIN_US: u64 = 139_000;

/// A simulated example of `examples/dynamics/`.
struct Run {
    network: Network,
    outcome: Outcome,
}

impl Run {
    /// Checks `examples/dynamics/<name>.toml` (consistent, no dynamics warning), compiles it and
    /// simulates it to its default end with the dynamics rows recorded.
    fn example(name: &str) -> Run {
        Run::text(name, &dynamics_example_text(name))
    }

    fn text(name: &str, text: &str) -> Run {
        let network = network(name, text);
        let report = check::check(&network);
        assert!(
            report.is_consistent(),
            "{name}: {:?}",
            report.errors(&network)
        );
        let warnings = check::dynamics::warnings(&network);
        assert!(warnings.is_empty(), "{name}: {warnings:?}");
        let nodes = compile::compile(&network).unwrap_or_else(|errors| panic!("{errors:?}"));
        let options = Options {
            dynamics: true,
            ..Options::default()
        };
        let outcome =
            sim::simulate(&network, &nodes, &options).unwrap_or_else(|error| panic!("{error}"));
        Run { network, outcome }
    }

    /// The rows of behaviour `name` ("group.behaviour"), one per step from t = 0, in time order.
    fn lane(&self, name: &str) -> Vec<DynamicsRow> {
        let (group, behaviour) = name.split_once('.').expect("group.behaviour");
        let g = self
            .network
            .dynamics
            .iter()
            .position(|d| d.name == group)
            .unwrap_or_else(|| panic!("no group {group}"));
        let b = self.network.dynamics[g]
            .behaviours
            .iter()
            .position(|d| d.name == behaviour)
            .unwrap_or_else(|| panic!("no behaviour {name}"));
        let lane: Vec<DynamicsRow> = self
            .outcome
            .dynamics
            .iter()
            .filter(|r| r.group == g && r.behaviour == b)
            .copied()
            .collect();
        // Every step from 0 to the end of the run, the end included.
        assert_eq!(lane.len() as u64, self.outcome.until_us / STEP_US + 1);
        for (k, row) in lane.iter().enumerate() {
            assert_eq!(row.t_us, k as u64 * STEP_US);
        }
        lane
    }
}

/// The times (µs) at which a lane's gate opens and closes.
fn edges(lane: &[DynamicsRow]) -> (Vec<u64>, Vec<u64>) {
    let (mut opens, mut closes) = (Vec::new(), Vec::new());
    let mut open = false;
    for row in lane {
        if row.gate != open {
            if row.gate {
                opens.push(row.t_us);
            } else {
                closes.push(row.t_us);
            }
            open = row.gate;
        }
    }
    (opens, closes)
}

/// The times (µs) at which a lane's context turns on (to 1) and off (to 0), the first row
/// counting as a turn on if its context is 1. Every context of these files is 0 or 1.
fn context_edges(lane: &[DynamicsRow]) -> (Vec<u64>, Vec<u64>) {
    let (mut on, mut off) = (Vec::new(), Vec::new());
    let mut was = 0.0;
    for row in lane {
        assert!(
            row.context == 0.0 || row.context == 1.0,
            "context {} at {}",
            row.context,
            row.t_us
        );
        if row.context != was {
            if row.context == 1.0 {
                on.push(row.t_us);
            } else {
                off.push(row.t_us);
            }
            was = row.context;
        }
    }
    (on, off)
}

/// The row of `lane` at `t_us`.
fn at(lane: &[DynamicsRow], t_us: u64) -> DynamicsRow {
    lane[(t_us / STEP_US) as usize]
}

/// `opened` (µs) is a first activation of a context that appeared at `appeared`: not before
/// [`refractory_steps`], within [`FIRST_WITHIN_US`].
fn assert_first_activation(what: &str, appeared: u64, opened: u64) {
    let earliest = appeared + refractory_steps() * STEP_US;
    assert!(
        (earliest..=appeared + FIRST_WITHIN_US).contains(&opened),
        "{what}: opened at {opened} µs, context from {appeared} µs (expected {earliest} to {})",
        appeared + FIRST_WITHIN_US
    );
}

#[test]
fn the_derived_bounds_are_designs() {
    // τ_ρ2·ln 2 = 138.6 steps, rounded up by the explicit step.
    assert_eq!(refractory_steps(), 139);
    assert!((138.0..139.0).contains(&(200.0 * 2f64.ln())));
    assert_eq!(closing_steps(), 3);
    // FIRST_WITHIN_US: 31 units after the crossing, ∫α = 15.2.
    let x = (FIRST_WITHIN_US / 10_000) as f64 - 200.0 * 2f64.ln() / 10.0;
    let integral = x - 20.0 * (1.0 - (-x / 20.0).exp());
    assert!(integral > 15.0, "{integral}");
    // RESUME_WITHIN_US is the least delay of a first activation.
    assert_eq!(RESUME_WITHIN_US, refractory_steps() * STEP_US);
}

/// single.toml: one behaviour, its context the activity of LINE (frames 0 to 1.90 s, tc 0.1 s).
#[test]
fn one_behaviour_opens_after_the_refractory_delay_and_closes_with_its_context() {
    let run = Run::example("single");
    assert_eq!(run.outcome.until_us, 3_000_000);
    let follow = run.lane("line.follow");
    // LINE is active from its first frame (0 s) through its last frame + tc (1.90 + 0.1 s, that
    // instant included): the context's first 0 is at 2.001 s.
    assert_eq!(
        context_edges(&follow),
        (vec![FIRST_READ_US], vec![2_001_000])
    );
    let (opens, closes) = edges(&follow);
    assert_eq!((opens.len(), closes.len()), (1, 1), "{opens:?} {closes:?}");
    assert_first_activation("follow", FIRST_READ_US, opens[0]);
    assert_eq!(closes[0], 2_001_000 + closing_steps() * STEP_US);
    // Saturated just before the context ends: n² near 1, ρ = 1 − e^(−10) after 2 s (10 τ_ρ2),
    // m near 1 (it rises on τ_n = 10 ms while n² ≈ 1).
    let last = at(&follow, 2_000_000);
    assert!(
        last.n * last.n > 0.99 && last.rho > 0.99 && last.m > 0.99,
        "{last:?}"
    );
    // 1 s (100 units) after the context's end: ρ falls on τ_ρ1 (e^(−100)), m decays on its
    // memory τ_i = 50 units while n ≈ 0: 1 + m = 2 e^(−100/50), m = −0.729.
    let end = at(&follow, 3_000_000);
    assert!(end.n.abs() < 0.01 && end.rho < 1e-6, "{end:?}");
    let m = 2.0 * (-2.0f64).exp() - 1.0;
    assert!((end.m - m).abs() < 0.02, "m {} vs {m}", end.m);
}

/// exclusive-pair.toml with its seed (1), or `seed` in its place.
fn exclusive_pair(seed: u32) -> Run {
    let text = dynamics_example_text("exclusive-pair");
    assert_eq!(text.matches("\nseed = 1\n").count(), 1);
    let text = text.replace("\nseed = 1\n", &format!("\nseed = {seed}\n"));
    Run::text(&format!("exclusive-pair, seed {seed}"), &text)
}

#[test]
fn two_exclusive_behaviours_one_wins_and_either_can() {
    let mut winners = Vec::new();
    for seed in 1..=8 {
        let run = exclusive_pair(seed);
        let lanes = [run.lane("fork.left"), run.lane("fork.right")];
        let [left, right] = [edges(&lanes[0]), edges(&lanes[1])];
        let all = format!("seed {seed}: left {left:?}, right {right:?}");
        // One gate opens, once, and stays open; the other never opens.
        let winner = match (left.0.len(), right.0.len()) {
            (1, 0) => 0,
            (0, 1) => 1,
            _ => panic!("{all}"),
        };
        let (won, lost) = (&lanes[winner], &lanes[1 - winner]);
        let opened = edges(won).0[0];
        assert!(edges(won).1.is_empty(), "{all}");
        // While both are small the pushes γ n_j² are negligible: the winner opens as a lone
        // behaviour would (measured 0.30 to 0.38 s over seeds 1 to 24).
        assert_first_activation(&all, FIRST_READ_US, opened);
        // The loser's growth rate is α − γ n_winner² = 1 − 3 = −2 once the winner is up: from
        // below 0.71 (it never reached the opening threshold n² = ½) it is down to about
        // e^(−20) of that 10 units later, and its noise spreads it over q / √(2·2) = 5e-4 only.
        for row in lost.iter().filter(|r| r.t_us >= opened + 100_000) {
            assert!(row.n.abs() < 0.01, "{all}: {row:?}");
        }
        assert!(
            lanes[0]
                .iter()
                .zip(&lanes[1])
                .all(|(a, b)| !(a.gate && b.gate))
        );
        // The wheels deliver the winner's commands only, every one of them after its gate
        // opened (a command frame every 50 ms to 1.85 s).
        let name = ["LEFT", "RIGHT"];
        let connection = |n: &str| {
            run.network
                .connections
                .iter()
                .position(|c| c.name == n)
                .unwrap()
        };
        let (w, l) = (connection(name[winner]), connection(name[1 - winner]));
        let end = run.outcome.until_us;
        assert_eq!(
            run.outcome
                .rows_of(l, 0, end)
                .filter(|r| r.delivered)
                .count(),
            0
        );
        for row in run.outcome.rows_of(w, 0, end) {
            if row.t_us < opened {
                assert!(!row.delivered, "{all}: {row:?}");
            } else if row.t_us > opened {
                assert!(row.delivered, "{all}: {row:?}");
            }
        }
        winners.push(name[winner]);
    }
    // Either can win: with these seeds right wins 7 times and left once (seed 8; over seeds 1
    // to 24, left 9 times). The first outputs of xorshift32 from a small seed are poorly mixed.
    assert!(
        winners.contains(&"LEFT") && winners.contains(&"RIGHT"),
        "{winners:?}"
    );
}

/// incumbent.toml: wall (context WALL, 0 to 3.000 s) and phototaxis (LIGHT, from 0.6 s) exclude
/// each other with γ = 3.
#[test]
fn the_incumbent_keeps_its_place_while_its_context_holds() {
    let run = Run::example("incumbent");
    let wall = run.lane("go.wall");
    let photo = run.lane("go.phototaxis");
    assert_eq!(context_edges(&wall), (vec![FIRST_READ_US], vec![3_001_000]));
    // LIGHT's first frame (0x121) follows WALL's (0x120) at 0.6 s: it counts from the step after.
    assert_eq!(context_edges(&photo), (vec![601_000], vec![4_401_000]));
    let (wall_on, wall_off) = edges(&wall);
    let (photo_on, _) = edges(&photo);
    let all = format!("wall {wall_on:?} {wall_off:?}, phototaxis {photo_on:?}");
    // The wall first, alone, before the light appears.
    assert_eq!((wall_on.len(), wall_off.len()), (1, 1), "{all}");
    assert_first_activation("wall", FIRST_READ_US, wall_on[0]);
    assert!(wall_on[0] < 600_000, "{all}");
    // It keeps its place while its context holds, and goes 3 steps after.
    assert_eq!(wall_off[0], 3_001_000 + closing_steps() * STEP_US, "{all}");
    // The challenger was ready (2.4 s = 12 τ_ρ2 of context: ρ = 1 − e^(−12)), but held down.
    let ready = at(&photo, 3_000_000);
    assert!(ready.rho > 0.99, "{ready:?}");
    assert!(photo.iter().take(3_001).all(|r| r.n * r.n < 0.4), "{all}");
    // It takes over once, after the wall, sooner than any first activation could.
    assert_eq!(photo_on.len(), 1, "{all}");
    assert!(photo_on[0] > wall_off[0], "{all}");
    assert!(photo_on[0] <= 3_001_000 + RESUME_WITHIN_US, "{all}");
    assert!(wall.iter().zip(&photo).all(|(a, b)| !(a.gate && b.gate)));
}

/// one-way.toml: wander (constant context) excludes avoid (OBSTACLE, 0.6 to 2.000 s); avoid
/// ignores wander.
#[test]
fn a_one_way_exclusion_lets_the_suppressor_displace() {
    let run = Run::example("one-way");
    let wander = run.lane("roam.wander");
    let avoid = run.lane("roam.avoid");
    // A constant context is 1 from t_0.
    assert_eq!(context_edges(&wander), (vec![0], vec![]));
    assert_eq!(context_edges(&avoid), (vec![600_000], vec![2_001_000]));
    let (wander_on, wander_off) = edges(&wander);
    let (avoid_on, avoid_off) = edges(&avoid);
    let all = format!("wander {wander_on:?} {wander_off:?}, avoid {avoid_on:?} {avoid_off:?}");
    assert_eq!((wander_on.len(), wander_off.len()), (2, 1), "{all}");
    assert_eq!((avoid_on.len(), avoid_off.len()), (1, 1), "{all}");
    // Wander first, before the obstacle.
    assert_first_activation("wander", FIRST_READ_US, wander_on[0]);
    assert!(wander_on[0] < 600_000, "{all}");
    // Avoid as if alone: wander does not push it.
    assert_first_activation("avoid", 600_000, avoid_on[0]);
    // Wander goes as avoid comes, within a unit (10 steps): wander's growth rate
    // 1 − γ n_avoid² turns negative once n_avoid² > 1/3, and avoid's gate opens at ½, about a
    // unit later at avoid's growth rate (measured: wander 4 steps before).
    assert!(wander_off[0].abs_diff(avoid_on[0]) <= 10 * STEP_US, "{all}");
    // Avoid holds to its context's end, and goes 3 steps after.
    assert_eq!(avoid_off[0], 2_001_000 + closing_steps() * STEP_US, "{all}");
    // Wander is back, its ρ still 1 (its context never left): no refractory delay.
    assert!(at(&wander, 2_000_000).rho > 0.99);
    assert!(wander_on[1] > avoid_off[0], "{all}");
    assert!(wander_on[1] <= 2_001_000 + RESUME_WITHIN_US, "{all}");
}

/// co-activation.toml: wander and look, constant contexts, no exclusion.
#[test]
fn without_exclusion_both_are_active() {
    let run = Run::example("co-activation");
    let lanes = [run.lane("explore.wander"), run.lane("explore.look")];
    let mut opened = Vec::new();
    for lane in &lanes {
        let (opens, closes) = edges(lane);
        assert_eq!((opens.len(), closes.len()), (1, 0), "{opens:?} {closes:?}");
        assert_first_activation("co-activation", FIRST_READ_US, opens[0]);
        opened.push(opens[0]);
    }
    // Both open together from the later opening to the end (1.5 s), and 0.1 s (10 units) after
    // it both are at a lone behaviour's fixed point, n = ±1 (α = 1; spread q / √(2·2) = 5e-4).
    let both = *opened.iter().max().unwrap();
    for (a, b) in lanes[0].iter().zip(&lanes[1]) {
        if a.t_us >= both {
            assert!(a.gate && b.gate, "{a:?} {b:?}");
        }
        if a.t_us >= both + 100_000 {
            assert!(a.n * a.n > 0.98 && b.n * b.n > 0.98, "{a:?} {b:?}");
        }
    }
    assert!(run.outcome.until_us >= both + 1_000_000);
}

/// door-without-recognise.toml: DESIGN's door (search, recognise, approach, avoid); the door is
/// seen for 100 steps only.
#[test]
fn the_door_glimpsed_too_briefly_is_neither_recognised_nor_approached() {
    let run = Run::example("door-without-recognise");
    let [search, recognise, approach, avoid] = [
        "door.search",
        "door.recognise",
        "door.approach",
        "door.avoid",
    ]
    .map(|b| run.lane(b));
    // The context is 1 for the steps from 0.800 to 0.899 s: the frame of 0 at 0.9 s counts from
    // its instant.
    assert_eq!(context_edges(&recognise), (vec![800_000], vec![900_000]));
    // ρ from 0 after 100 explicit steps of ρ += (1 − ρ)/200: 1 − 0.995^100 = 0.3942 < ½, so
    // α = 2ρ − 1 < 0 throughout and recognise's n only shrinks.
    let rho_max = recognise.iter().map(|r| r.rho).fold(0.0, f64::max);
    let expected = 1.0 - (1.0 - 1.0 / f64::from(TAU_RHO_SLOW_STEPS)).powi(100);
    assert!(
        (rho_max - expected).abs() < 1e-5,
        "ρ {rho_max} vs {expected}"
    );
    assert!(expected < 0.5);
    assert!(edges(&recognise).0.is_empty());
    assert!(recognise.iter().all(|r| r.n.abs() < 0.01));
    // Recognise never active: its memory stays near −1, and approach's input
    // C · (1 + ½ (tanh(10 m) − 1)) is about 1 − tanh(10) = 2e-9: approach's ρ stays at its fixed
    // point I / (I + 20 (1 − I)) ≈ 1e-10, and its gate shut, though its context holds.
    assert!(recognise.iter().all(|r| r.m < -0.99));
    assert!(approach.iter().all(|r| r.context == 1.0 && r.rho < 1e-6));
    assert!(edges(&approach).0.is_empty());
    // Search and avoid open once, before the glimpse, and run to the end (2.5 s).
    for (name, lane) in [("search", &search), ("avoid", &avoid)] {
        let (opens, closes) = edges(lane);
        assert_eq!(
            (opens.len(), closes.len()),
            (1, 0),
            "{name}: {opens:?} {closes:?}"
        );
        assert_first_activation(name, FIRST_READ_US, opens[0]);
    }
    assert_eq!(run.outcome.until_us, 2_500_000);
}

/// context-dip.toml: three independent behaviours whose contexts dip at 1.0 s for 2, 5 and 100
/// steps.
#[test]
fn a_short_context_dip_barely_delays_a_long_one_costs_the_refractory_delay() {
    let run = Run::example("context-dip");
    let [blink, short, long] = ["dips.blink", "dips.short", "dips.long"].map(|b| run.lane(b));
    // The three frames of 0 share 1.0 s: blink's (0x120) is first on the bus, short's and
    // long's count from the step after (dips of 2, 4 and 99 steps).
    assert_eq!(
        context_edges(&blink),
        (vec![FIRST_READ_US, 1_002_000], vec![1_000_000])
    );
    assert_eq!(
        context_edges(&short),
        (vec![FIRST_READ_US, 1_005_000], vec![1_001_000])
    );
    assert_eq!(
        context_edges(&long),
        (vec![FIRST_READ_US, 1_100_000], vec![1_001_000])
    );
    let [b, s, l] = [&blink, &short, &long].map(|lane| edges(lane));
    let all = format!("blink {b:?}, short {s:?}, long {l:?}");
    for opens in [&b.0, &s.0, &l.0] {
        assert_first_activation(&all, FIRST_READ_US, opens[0]);
        assert!(opens[0] < 1_000_000, "{all}");
    }
    // 2 steps (< τ_ρ1 = 10 steps): n 1 → 0.8 → 0.67, n² still above 0.4; the gate stays open.
    assert_eq!((b.0.len(), b.1.len()), (1, 0), "{all}");
    assert!(2 < closing_steps());
    // 4 steps (< τ_ρ1): the gate closes at the third, and opens again within 5 units of the
    // context's return: ρ only fell to 0.993 · 0.9^4 = 0.65 > ½, so α ≈ 0.3 at once, and n
    // grows back to 0.707 (ln(n / √(1 − n²)) to 0 at rate α) in 3.9 units at most, less as ρ
    // climbs back (measured 1.7).
    assert_eq!((s.0.len(), s.1.len()), (2, 1), "{all}");
    assert_eq!(s.1[0], 1_001_000 + closing_steps() * STEP_US, "{all}");
    // Four steps of 0 (its frame of 0 follows blink's at 1.0 s): ρ fell to 0.993 · 0.9^4 = 0.65.
    let back = at(&short, 1_005_000);
    assert!(back.rho > 0.6 && back.rho < 0.7, "{back:?}");
    let short_delay = s.0[1] - 1_005_000;
    assert!(short_delay <= 50_000, "{all}");
    // 99 steps (10 τ_ρ1): ρ falls to 0.9^99 ≈ 3e-5, and must pass ½ again: a first activation
    // from the context's return (at least 139 steps, within 0.45 s).
    assert_eq!((l.0.len(), l.1.len()), (2, 1), "{all}");
    assert_eq!(l.1[0], 1_001_000 + closing_steps() * STEP_US, "{all}");
    assert!(at(&long, 1_100_000).rho < 1e-4);
    assert_first_activation(&all, 1_100_000, l.0[1]);
    // The short dip costs less than a third of what the long one costs at the least.
    assert!(3 * short_delay < refractory_steps() * STEP_US, "{all}");
}

/// flicker.toml: a context on for 0.6 s, then 0.15 s off / 0.15 s on eight times, followed by
/// the same behaviour in two groups, with and without the refractory filter.
#[test]
fn a_flickering_context_activates_once_with_the_refractory_filter_and_each_time_without() {
    let run = Run::example("flicker");
    let filtered = run.lane("filtered.follow");
    let unfiltered = run.lane("unfiltered.follow");
    // On from 0, off at 0.6 s, then every 0.15 s: on at 0.75, 1.05, ..., 2.85 s, off at 0.9,
    // 1.2, ..., 2.7 s, to the end (3.0 s).
    let ons: Vec<u64> = (0..9)
        .map(|i| {
            if i == 0 {
                FIRST_READ_US
            } else {
                450_000 + 300_000 * i
            }
        })
        .collect();
    let offs: Vec<u64> = (0..8).map(|i| 600_000 + 300_000 * i).collect();
    assert_eq!(context_edges(&filtered), (ons.clone(), offs.clone()));
    assert_eq!(context_edges(&unfiltered), (ons.clone(), offs.clone()));
    assert_eq!(run.outcome.until_us, 3_000_000);
    // With the filter: once, in the first on period, closed 3 steps into the first off period.
    let (opens, closes) = edges(&filtered);
    assert_eq!((opens.len(), closes.len()), (1, 1), "{opens:?} {closes:?}");
    assert_first_activation("filtered", FIRST_READ_US, opens[0]);
    assert!(opens[0] < offs[0]);
    assert_eq!(closes[0], offs[0] + closing_steps() * STEP_US);
    // Each off period (15 units at τ_ρ1 = 1 unit) takes ρ to 0.9^150 ≈ 1e-7 (from 0.95 after
    // the first on period: 1 − e^(−3)), and each later on period
    // (150 steps) brings it back to 1 − 0.995^150 = 0.5285 at most: α = 2ρ − 1 ≤ 0.06, positive
    // for a dozen steps only.
    let ceiling = 1.0 - (1.0 - 1.0 / f64::from(TAU_RHO_SLOW_STEPS)).powi(150);
    let rho_max = filtered
        .iter()
        .filter(|r| r.t_us >= ons[1])
        .map(|r| r.rho)
        .fold(0.0, f64::max);
    assert!(rho_max <= ceiling + 1e-6, "ρ {rho_max} vs {ceiling}");
    assert!(ceiling < 0.53);
    // Without it (τ_ρ2 = τ_ρ1, ρ = 1 − e^(−t/τ_ρ1) after each return): an opening in every on
    // period. α crosses 0 at ln 2 units and n grows from the noise (spread 7e-4 after 15 units
    // at α = −1) to 0.707 once ∫α = t − 2 (1 − e^(−t)) reaches ln(1000) = 6.9: at about 9 units
    // of the period's 15 (measured 8.1 to 11.5; an opening would be missed only from a start
    // below 0.707·e^(−13) = 1.6e-6). Each gate closes 3 steps into the next off period.
    let (opens, closes) = edges(&unfiltered);
    assert_eq!((opens.len(), closes.len()), (9, 8), "{opens:?} {closes:?}");
    for (i, &opened) in opens.iter().enumerate() {
        let period_end = offs.get(i).copied().unwrap_or(run.outcome.until_us);
        assert!((ons[i]..period_end).contains(&opened), "{opens:?}");
    }
    for (&closed, &off) in closes.iter().zip(&offs) {
        assert_eq!(closed, off + closing_steps() * STEP_US, "{closes:?}");
    }
}

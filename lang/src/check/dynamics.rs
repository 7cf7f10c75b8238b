//! Warnings about `[dynamics.*]` groups: what parses, runs and passes `Params::validate`, but
//! cannot behave as the file means (DESIGN.md, "Competitive dynamics: decisions").
//!
//! - **Weak exclusion**: a declared exclusion with γ < 1.5. With γ = 1 (the paper's value) two
//!   behaviours whose contexts hold settle at n² = 1/(1 + γ) = 0.5, on the gates' opening
//!   threshold (open at n² ≥ 0.5, closed below 0.4): both stay half-active and the gates chatter.
//!   Below 1 both gates stay open; between 1 and 1.5 one wins, slowly, out of the noise. Only
//!   γ ≥ 2.5 both ways keeps two gates from being open together.
//! - **Presupposition cycle**: `requires` edges that come back to where they start. Each
//!   behaviour of the cycle needs the memory m_j of the next (equation (4): I_i has the factor
//!   1 + ½(tanh(c m_j) − 1), about 0 while m_j = −1), and m_j rises only while j is active: none
//!   of them ever starts, nor does anything that requires one of them.
//! - **Unsaturable context**: a context whose largest possible value is below
//!   `activation_threshold`: α stays negative, the behaviour never starts.
//!
//! Warnings fail nothing: `pabctl check` prints them and still exits 0 on consistent rules.

use std::ops::Range;

use pab_core::dynamics::C_ONE;

use crate::diagnostic::Warning;
use crate::network::{Context, DynamicsGroup, Network};

/// Below this γ a declared exclusion gets a warning.
pub const WEAK_GAMMA: f64 = 1.5;

/// The least constant input I with which a behaviour can ever start, for the group's τ_ρ1
/// (`tau_rho_fast`) and τ_ρ2 (`tau_rho_slow`), in any common unit.
///
/// Derivation. With a constant I, equation (3),
/// dρ/dt = (1 − ρ) I / τ_ρ2 + ρ (I − 1) / τ_ρ1, has the fixed point
///
/// ```text
/// ρ* = (I / τ_ρ2) / (I / τ_ρ2 + (1 − I) / τ_ρ1) = I / (I + r (1 − I)),   r = τ_ρ2 / τ_ρ1,
/// ```
///
/// which ρ approaches from its initial 0 (ρ* grows with I, so under any context bounded by I, ρ
/// stays below ρ*(I)). A behaviour starts only if α = 2 ρ I − 1 (equation (2)) gets above 0: n = 0
/// is then unstable and n grows to ±1; with α < 0, n decays to 0 whatever the noise. So it needs
///
/// ```text
/// 2 ρ* I > 1  ⇔  2 I² > I + r (1 − I)  ⇔  2 I² + (r − 1) I − r > 0
///             ⇔  I > ((1 − r) + √((r − 1)² + 8 r)) / 4
/// ```
///
/// (the positive root). At the defaults (r = 20): (√521 − 19) / 4 = 0.9564, DESIGN's "I > 0.957";
/// at r = 1: 1/√2.
pub fn activation_threshold(tau_rho_fast: f64, tau_rho_slow: f64) -> f64 {
    let r = tau_rho_slow / tau_rho_fast;
    ((1.0 - r) + ((r - 1.0) * (r - 1.0) + 8.0 * r).sqrt()) / 4.0
}

/// Every warning about the network's dynamics groups, in file order.
pub fn warnings(network: &Network) -> Vec<Warning> {
    let mut warnings = Vec::new();
    for group in &network.dynamics {
        weak_exclusions(network, group, &mut warnings);
        presupposition_cycles(network, group, &mut warnings);
        unsaturable_contexts(network, group, &mut warnings);
    }
    warnings.sort_by_key(|warning| warning.0.position);
    warnings
}

fn warn(network: &Network, span: Range<usize>, message: String) -> Warning {
    Warning(network.error(span, message))
}

fn name(group: &DynamicsGroup, i: usize) -> &str {
    group.behaviours.get(i).map_or("?", |b| b.name.as_str())
}

fn weak_exclusions(network: &Network, group: &DynamicsGroup, out: &mut Vec<Warning>) {
    for behaviour in &group.behaviours {
        for exclusion in &behaviour.written.exclusions {
            if exclusion.gamma >= WEAK_GAMMA {
                continue;
            }
            let whose = if exclusion.from_group {
                " (the group's `gamma`)"
            } else {
                ""
            };
            out.push(warn(
                network,
                exclusion.span.clone(),
                format!(
                    "dynamics group `{}`: `{}` excludes `{}` with γ = {}{whose}, below {WEAK_GAMMA}: too weak to choose between them (at γ = 1 both stay half-active, n² = 0.5, and their gates chatter); use γ ≥ 2.5 both ways to keep both gates from opening together (default 3)",
                    group.name,
                    behaviour.name,
                    name(group, exclusion.by),
                    exclusion.gamma,
                ),
            ));
        }
    }
}

/// Per behaviour, the set (bit j) of behaviours it requires, directly.
fn requirements(group: &DynamicsGroup) -> Vec<u64> {
    group
        .behaviours
        .iter()
        .map(|b| {
            b.written
                .requires
                .iter()
                .filter(|(j, _)| *j < 64)
                .fold(0u64, |set, (j, _)| set | 1 << j)
        })
        .collect()
}

/// Per behaviour, the set of behaviours it requires directly or through others.
fn closure(direct: &[u64]) -> Vec<u64> {
    let mut reach = direct.to_vec();
    loop {
        let mut changed = false;
        for i in 0..reach.len() {
            let through = (0..reach.len())
                .filter(|&j| reach[i] & (1 << j) != 0)
                .fold(reach[i], |set, j| set | reach[j]);
            if through != reach[i] {
                reach[i] = through;
                changed = true;
            }
        }
        if !changed {
            return reach;
        }
    }
}

/// The shortest path of `requires` edges from `start` back to itself, within `within`: the
/// behaviours in order, `start` first (not repeated at the end).
fn shortest_cycle(direct: &[u64], start: usize, within: u64) -> Vec<usize> {
    let mut previous: Vec<Option<usize>> = vec![None; direct.len()];
    let mut queue = std::collections::VecDeque::from([start]);
    let mut seen = 1u64 << start;
    while let Some(i) = queue.pop_front() {
        for j in (0..direct.len()).filter(|&j| direct[i] & within & (1 << j) != 0) {
            if j == start {
                let mut cycle = vec![i];
                while let Some(p) = previous[*cycle.last().unwrap_or(&start)] {
                    cycle.push(p);
                }
                cycle.reverse();
                return cycle;
            }
            if seen & (1 << j) == 0 {
                seen |= 1 << j;
                previous[j] = Some(i);
                queue.push_back(j);
            }
        }
    }
    vec![start]
}

fn presupposition_cycles(network: &Network, group: &DynamicsGroup, out: &mut Vec<Warning>) {
    let direct = requirements(group);
    let reach = closure(&direct);
    let on_cycle = |i: usize| reach[i] & (1 << i) != 0;
    let mut reported = 0u64;
    for start in 0..direct.len() {
        if !on_cycle(start) || reported & (1 << start) != 0 {
            continue;
        }
        // The strongly connected component of `start`: one warning for it, at its first
        // behaviour in file order, naming a shortest cycle through it.
        let component = (0..direct.len())
            .filter(|&j| reach[start] & (1 << j) != 0 && reach[j] & (1 << start) != 0)
            .fold(0u64, |set, j| set | 1 << j);
        reported |= component;
        let cycle = shortest_cycle(&direct, start, component);
        let next = cycle.get(1).copied().unwrap_or(start);
        let Some(span) = group.behaviours[start]
            .written
            .requires
            .iter()
            .find(|(j, _)| *j == next)
            .map(|(_, span)| span.clone())
        else {
            continue;
        };
        let path: Vec<&str> = cycle
            .iter()
            .chain([&start])
            .map(|&i| name(group, i))
            .collect();
        let others: Vec<String> = (0..direct.len())
            .filter(|&k| component & (1 << k) == 0 && reach[k] & component != 0)
            .map(|k| format!("`{}`", name(group, k)))
            .collect();
        let also = if others.is_empty() {
            String::new()
        } else {
            format!(
                "; nor can {}, which require{} one of them",
                others.join(", "),
                if others.len() == 1 { "s" } else { "" }
            )
        };
        let more = component.count_ones() as usize - cycle.len();
        let rest = if more > 0 {
            format!(
                " (and {more} more behaviour{} in cycles with them)",
                plural(more)
            )
        } else {
            String::new()
        };
        out.push(warn(
            network,
            span,
            format!(
                "dynamics group `{}`: presupposition cycle {} (each requires the next){rest}: none of them can ever start, each needs another's memory first{also}",
                group.name,
                path.join(" → "),
            ),
        ));
    }
}

fn plural(n: usize) -> &'static str {
    if n == 1 { "" } else { "s" }
}

fn unsaturable_contexts(network: &Network, group: &DynamicsGroup, out: &mut Vec<Warning>) {
    let params = &group.params;
    let threshold = activation_threshold(
        f64::from(params.tau_rho_fast_us),
        f64::from(params.tau_rho_slow_us),
    );
    let ratio = f64::from(params.tau_rho_slow_us) / f64::from(params.tau_rho_fast_us);
    let why = format!(
        "a behaviour starts only with I > {threshold:.4} (with tau_rho_slow / tau_rho_fast = {ratio}: ρ's fixed point must make α = 2ρI − 1 positive)"
    );
    // Where m_j = 1 the factor of each required j is ½ (1 + tanh c): below 1 for a small c.
    let c = f64::from(params.c) / f64::from(C_ONE);
    let per_requirement = (1.0 + c.tanh()) / 2.0;
    for behaviour in &group.behaviours {
        let (largest, what) = match &behaviour.context {
            Context::Connection { .. } => (1.0, String::new()),
            Context::Constant(value) => (*value, format!("its constant context {value}")),
            Context::Topic {
                topic,
                field,
                scale,
                ..
            } => {
                let bits = 8 * u32::from(field.size) - u32::from(field.signed);
                let max = 2f64.powi(bits as i32) - 1.0;
                let topic = network.topics.get(*topic).map_or("?", |t| t.name.as_str());
                (
                    (max / scale).min(1.0),
                    format!(
                        "its context from topic `{topic}` ({} field of {} byte{}, at most {max}, / scale {scale} = at most {:.4})",
                        if field.signed { "signed" } else { "unsigned" },
                        field.size,
                        plural(usize::from(field.size)),
                        max / scale
                    ),
                )
            }
        };
        let span = behaviour.written.context.clone();
        if largest < threshold {
            out.push(warn(
                network,
                span,
                format!(
                    "dynamics group `{}`: behaviour `{}` can never start: {what} stays below {threshold:.4}; {why}",
                    group.name, behaviour.name
                ),
            ));
            continue;
        }
        let requires = behaviour.written.requires.len();
        let reach = largest * per_requirement.powi(requires as i32);
        if requires > 0 && reach < threshold {
            out.push(warn(
                network,
                span,
                format!(
                    "dynamics group `{}`: behaviour `{}` can never start: with c = {c} each requirement keeps at most (1 + tanh c) / 2 = {per_requirement:.4} of the context, and it has {requires}: I ≤ {reach:.4}, below {threshold:.4}; {why}",
                    group.name, behaviour.name,
                ),
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;

    const HEAD: &str = r#"[nodes.base]
id = 1
[topics.cue]
can_id = 0x100
[ports."base.p"]
[connections.C3]
topic = "cue"
port = "base.p"
st = 1.0
tc = 0.1
[dynamics.g]
node = "base"
"#;

    /// The warnings of HEAD + `extra`, as printed.
    fn warnings_of(extra: &str) -> Vec<String> {
        let network = Network::parse(Source::new("d.toml", format!("{HEAD}{extra}")))
            .unwrap_or_else(|errors| panic!("{errors}"));
        warnings(&network).iter().map(Warning::to_string).collect()
    }

    /// `extra`'s line `line` (1-based) as the file's.
    fn at(line: usize, column: usize) -> String {
        format!("d.toml:{}:{column}: warning: ", HEAD.lines().count() + line)
    }

    #[test]
    fn the_threshold_is_the_designs() {
        assert!((activation_threshold(1.0, 20.0) - 0.956_36).abs() < 1e-5);
        assert!((activation_threshold(0.01, 0.2) - 0.956_36).abs() < 1e-5);
        assert!((activation_threshold(1.0, 1.0) - 0.5f64.sqrt()).abs() < 1e-12);
        // At the threshold ρ*'s α is 0.
        for r in [0.5, 1.0, 20.0, 100.0] {
            let i = activation_threshold(1.0, r);
            let rho = (i / r) / (i / r + (1.0 - i));
            assert!((2.0 * rho * i - 1.0).abs() < 1e-12, "r = {r}");
        }
    }

    #[test]
    fn the_door_example_has_no_warning() {
        let text = include_str!("../../../examples/door-dynamics.toml");
        let network = Network::parse(Source::new("door-dynamics.toml", text)).unwrap();
        assert_eq!(warnings(&network), []);
    }

    #[test]
    fn a_weak_exclusion_is_named_with_both_behaviours_and_its_value() {
        let found = warnings_of(
            "gamma = 1.0\n\
             [dynamics.g.behaviours.a]\ncontext = \"C3\"\nexcludes = [\"b\"]\n\
             [dynamics.g.behaviours.b]\ncontext = \"C3\"\ngamma = { a = 1.25 }\n\
             [dynamics.g.behaviours.c]\ncontext = \"C3\"\nexcludes = [\"a\"]\ngamma = { a = 1.5, b = 4.0 }\n",
        );
        assert_eq!(found.len(), 2, "{found:#?}");
        assert_eq!(
            found[0],
            format!(
                "{}dynamics group `g`: `a` excludes `b` with γ = 1 (the group's `gamma`), below 1.5: too weak to choose between them (at γ = 1 both stay half-active, n² = 0.5, and their gates chatter); use γ ≥ 2.5 both ways to keep both gates from opening together (default 3)",
                at(4, 13)
            )
        );
        assert!(
            found[1].starts_with(&format!(
                "{}dynamics group `g`: `b` excludes `a` with γ = 1.25, below 1.5",
                at(7, 15)
            )),
            "{}",
            found[1]
        );
    }

    #[test]
    fn presupposition_cycles_are_named_in_order() {
        let found = warnings_of(
            "[dynamics.g.behaviours.a]\ncontext = \"C3\"\nrequires = [\"b\"]\n\
             [dynamics.g.behaviours.b]\ncontext = \"C3\"\nrequires = [\"a\"]\n\
             [dynamics.g.behaviours.c]\ncontext = \"C3\"\nrequires = [\"d\"]\n\
             [dynamics.g.behaviours.d]\ncontext = \"C3\"\nrequires = [\"e\", \"a\"]\n\
             [dynamics.g.behaviours.e]\ncontext = \"C3\"\nrequires = [\"c\"]\n\
             [dynamics.g.behaviours.f]\ncontext = \"C3\"\nrequires = [\"d\"]\n",
        );
        assert_eq!(
            found,
            [
                format!(
                    "{}dynamics group `g`: presupposition cycle a → b → a (each requires the next): none of them can ever start, each needs another's memory first; nor can `c`, `d`, `e`, `f`, which require one of them",
                    at(3, 13)
                ),
                format!(
                    "{}dynamics group `g`: presupposition cycle c → d → e → c (each requires the next): none of them can ever start, each needs another's memory first; nor can `f`, which requires one of them",
                    at(9, 13)
                ),
            ]
        );
    }

    #[test]
    fn requirements_without_a_cycle_are_fine() {
        let found = warnings_of(
            "[dynamics.g.behaviours.a]\ncontext = \"C3\"\nrequires = [\"b\", \"c\"]\n\
             [dynamics.g.behaviours.b]\ncontext = \"C3\"\nrequires = [\"c\"]\n\
             [dynamics.g.behaviours.c]\ncontext = \"C3\"\n",
        );
        assert_eq!(found, Vec::<String>::new());
    }

    #[test]
    fn contexts_that_cannot_saturate() {
        let found = warnings_of(
            "[dynamics.g.behaviours.a]\ncontext = 0.95\n\
             [dynamics.g.behaviours.b]\ncontext = 0.96\n\
             [dynamics.g.behaviours.c]\n\
             context = { topic = \"cue\", value = { offset = 0, size = 1 }, scale = 300.0, timeout = 0.2 }\n\
             [dynamics.g.behaviours.d]\n\
             context = { topic = \"cue\", value = { offset = 0, size = 1 }, scale = 255.0, timeout = 0.2 }\n\
             [dynamics.g.behaviours.e]\n\
             context = { topic = \"cue\", value = { offset = 0, size = 2, signed = true }, scale = 40000.0, timeout = 0.2 }\n",
        );
        assert_eq!(found.len(), 3, "{found:#?}");
        assert_eq!(
            found[0],
            format!(
                "{}dynamics group `g`: behaviour `a` can never start: its constant context 0.95 stays below 0.9564; a behaviour starts only with I > 0.9564 (with tau_rho_slow / tau_rho_fast = 20: ρ's fixed point must make α = 2ρI − 1 positive)",
                at(2, 11)
            )
        );
        assert!(
            found[1].starts_with(&format!(
                "{}dynamics group `g`: behaviour `c` can never start: its context from topic `cue` (unsigned field of 1 byte, at most 255, / scale 300 = at most 0.8500) stays below 0.9564",
                at(6, 11)
            )),
            "{}",
            found[1]
        );
        assert!(
            found[2].contains("behaviour `e` can never start: its context from topic `cue` (signed field of 2 bytes, at most 32767, / scale 40000 = at most 0.8192)"),
            "{}",
            found[2]
        );
    }

    #[test]
    fn the_threshold_follows_the_groups_time_constants() {
        // r = 1: I > 0.7071, so 0.8 can start.
        let found = warnings_of(
            "tau_rho_slow = 1.0\n[dynamics.g.behaviours.a]\ncontext = 0.8\n\
             [dynamics.g.behaviours.b]\ncontext = 0.7\n",
        );
        assert_eq!(found.len(), 1, "{found:#?}");
        assert!(
            found[0].contains("`b` can never start: its constant context 0.7 stays below 0.7071")
                && found[0].contains("tau_rho_fast = 1:"),
            "{}",
            found[0]
        );
    }

    #[test]
    fn a_small_c_keeps_a_requiring_behaviour_below_the_threshold() {
        let found = warnings_of(
            "c = 1.0\n[dynamics.g.behaviours.a]\ncontext = \"C3\"\nrequires = [\"b\"]\n\
             [dynamics.g.behaviours.b]\ncontext = \"C3\"\n",
        );
        assert_eq!(found.len(), 1, "{found:#?}");
        assert!(
            found[0].starts_with(&at(3, 11))
                && found[0].contains("with c = 1 each requirement keeps at most (1 + tanh c) / 2 = 0.8808 of the context, and it has 1: I ≤ 0.8808, below 0.9564"),
            "{}",
            found[0]
        );
    }
}

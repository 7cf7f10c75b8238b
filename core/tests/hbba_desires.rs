//! The intention workspace's desires (`pab_core::hbba::Desires`) against a model written here
//! from DESIGN.md ("HBBA: decisions"): random scripts of desire frames (new names, refreshes,
//! withdrawals, other classes, zero leases, unknown classes) and time steps, and after each step
//! the same desires held, the same one served per class and the same next deadline.

use std::collections::BTreeMap;

use pab_core::Instant;
use pab_core::hbba::{DesireError, Desires, MAX_CLASSES, MAX_DESIRES};
use proptest::prelude::*;

#[derive(Clone, Debug)]
enum Step {
    Heard {
        source: u8,
        id: u16,
        class: u8,
        intensity: u16,
        lease_ms: u16,
    },
    Wait(u64),
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        4 => (0u8..4, 0u16..12, 0u8..5, prop_oneof![Just(0u16), 1u16..4, any::<u16>()],
              prop_oneof![Just(0u16), 1u16..300])
            .prop_map(|(source, id, class, intensity, lease_ms)| Step::Heard {
                source, id, class, intensity, lease_ms
            }),
        1 => (0u64..400_000).prop_map(Step::Wait),
    ]
}

/// The model: each held desire by name, with (class, intensity, first heard, lapses at), in µs.
type Model = BTreeMap<(u8, u16), (u8, u16, u64, u64)>;

/// The model's served desire for `class`: the most intense, then the older, then the lower name.
fn served(model: &Model, class: u8) -> Option<(u8, u16)> {
    model
        .iter()
        .filter(|(_, d)| d.0 == class)
        .min_by_key(|(name, d)| (u16::MAX - d.1, d.2, **name))
        .map(|(name, _)| *name)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn desires_follow_the_model(
        classes in 1u8..5,
        start in prop_oneof![Just(0u64), Just(u64::MAX - 1_000_000), any::<u64>()],
        script in prop::collection::vec(step(), 1..120),
    ) {
        let mut desires = Desires::new(classes);
        let mut model = Model::new();
        let mut now = 0u64; // µs since `start`
        let at = |t: u64| Instant::from_micros(start.wrapping_add(t));
        for step in script {
            match step {
                Step::Wait(us) => {
                    now += us;
                    let lapsed = model.values().any(|d| d.3 <= now);
                    model.retain(|_, d| d.3 > now);
                    prop_assert_eq!(desires.expire(at(now)), lapsed);
                }
                Step::Heard { source, id, class, intensity, lease_ms } => {
                    let name = (source, id);
                    let got = desires.heard(source, id, class, intensity, lease_ms, at(now));
                    let expected = if intensity == 0 {
                        Ok(model.remove(&name).is_some())
                    } else if class >= classes {
                        Err(DesireError::UnknownClass { class })
                    } else if lease_ms == 0 {
                        Err(DesireError::ZeroLease)
                    } else {
                        let until = now + u64::from(lease_ms) * 1000;
                        let full = model.len() == MAX_DESIRES;
                        match model.get_mut(&name) {
                            Some(d) => {
                                let changed = d.0 != class || d.1 != intensity;
                                *d = (class, intensity, d.2, until);
                                Ok(changed)
                            }
                            None if full => Err(DesireError::Full),
                            None => {
                                model.insert(name, (class, intensity, now, until));
                                Ok(true)
                            }
                        }
                    };
                    prop_assert_eq!(got, expected);
                }
            }
            let mut held: Vec<_> = desires
                .held()
                .iter()
                .map(|d| ((d.source, d.id), d.class, d.intensity))
                .collect();
            held.sort();
            let modelled: Vec<_> = model.iter().map(|(n, d)| (*n, d.0, d.1)).collect();
            prop_assert_eq!(held, modelled);
            let intensities = desires.intensities();
            for class in 0..MAX_CLASSES as u8 {
                let expected = served(&model, class);
                prop_assert_eq!(desires.selected(class).map(|d| (d.source, d.id)), expected);
                let intensity = expected.map_or(0, |name| model[&name].1);
                prop_assert_eq!(intensities[usize::from(class)], intensity);
            }
            let deadline = model.values().map(|d| d.3).min().map(at);
            prop_assert_eq!(desires.deadline(at(now)), deadline);
        }
    }
}

//! `pabctl init`: the network files a new one starts from, built into the binary so that
//! `pabctl init` works anywhere, not only in a clone of the repository.
//!
//! The tutorial's network is the default; the project's examples (examples/*.toml) are the
//! others, by their file's name. `lang/tests` and `test.sh` check every one of them, so a file
//! written here starts out as one that `pabctl check` accepts as the example itself.

/// The starter written without `--example`: the tutorial's network (a grasp and a release
/// competing for a gripper), commented for a first reading.
pub const DEFAULT: &str = "first-network";

/// Every starter, by name: the examples' file names without `.toml`.
pub const STARTERS: &[(&str, &str)] = &[
    (
        "first-network",
        include_str!("../../examples/first-network.toml"),
    ),
    ("assembly", include_str!("../../examples/assembly.toml")),
    (
        "door-dynamics",
        include_str!("../../examples/door-dynamics.toml"),
    ),
    ("figure-1", include_str!("../../examples/figure-1.toml")),
    (
        "multi-target-observation",
        include_str!("../../examples/multi-target-observation.toml"),
    ),
    ("reflex", include_str!("../../examples/reflex.toml")),
    (
        "return-an-object",
        include_str!("../../examples/return-an-object.toml"),
    ),
    (
        "subsumption",
        include_str!("../../examples/subsumption.toml"),
    ),
    (
        "take-an-object",
        include_str!("../../examples/take-an-object.toml"),
    ),
    (
        "take-and-return-dynamics",
        include_str!("../../examples/take-and-return-dynamics.toml"),
    ),
    (
        "take-and-return-fd",
        include_str!("../../examples/take-and-return-fd.toml"),
    ),
    (
        "take-and-return",
        include_str!("../../examples/take-and-return.toml"),
    ),
    ("tour-guide", include_str!("../../examples/tour-guide.toml")),
    (
        "value-ports",
        include_str!("../../examples/value-ports.toml"),
    ),
];

/// The starter called `name`, or why not: the names there are, and the nearest.
pub fn find(name: &str) -> Result<&'static str, String> {
    if let Some((_, text)) = STARTERS.iter().find(|(n, _)| *n == name) {
        return Ok(text);
    }
    let names = STARTERS.iter().map(|(n, _)| *n);
    let hint = pab_lang::diagnostic::did_you_mean(name, names.clone())
        .map(|near| format!("; did you mean `{near}`?"))
        .unwrap_or_default();
    Err(format!(
        "no example `{name}`{hint} (the examples: {})",
        names.collect::<Vec<_>>().join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_example_of_the_repository_is_a_starter_and_no_other() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
        let mut on_disk: Vec<String> = std::fs::read_dir(&dir)
            .expect("examples/")
            .filter_map(|entry| {
                let path = entry.ok()?.path();
                (path.extension()? == "toml")
                    .then(|| path.file_stem()?.to_str().map(str::to_string))?
            })
            .collect();
        on_disk.sort();
        let mut built: Vec<String> = STARTERS.iter().map(|(n, _)| n.to_string()).collect();
        built.sort();
        assert_eq!(
            built, on_disk,
            "host-tools/src/starter.rs lists examples/*.toml"
        );
        assert!(find(DEFAULT).is_ok());
    }

    #[test]
    fn a_slip_of_a_name_gets_the_nearest() {
        let error = find("take-and-retrun").unwrap_err();
        assert!(error.contains("did you mean `take-and-return`?"), "{error}");
        assert!(error.contains("tour-guide"), "{error}");
    }
}

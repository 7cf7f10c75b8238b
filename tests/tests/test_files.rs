//! Every test file is built. A crate whose Cargo.toml says `autotests = false` builds the files of
//! its tests/ directory only as modules of tests/integration.rs or as the `[[test]]` targets its
//! Cargo.toml names: a file that is neither would never run, and nothing else would say so.

use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The workspace's members, from the root Cargo.toml's `members = [...]`.
fn members() -> Vec<String> {
    let manifest = std::fs::read_to_string(repo().join("Cargo.toml")).unwrap();
    let start = manifest
        .find("\nmembers = [")
        .expect("members = [ in Cargo.toml");
    let list = &manifest[start..];
    let list = &list[..list.find(']').expect("the members' closing bracket")];
    list.split('"')
        .skip(1)
        .step_by(2)
        .map(str::to_string)
        .collect()
}

/// The names of the `[[test]]` targets a Cargo.toml declares.
fn test_targets(manifest: &str) -> Vec<String> {
    manifest
        .split("[[test]]")
        .skip(1)
        .filter_map(|section| {
            let line = section
                .lines()
                .find(|l| l.trim_start().starts_with("name"))?;
            Some(line.split('"').nth(1)?.to_string())
        })
        .collect()
}

#[test]
fn every_file_of_a_tests_directory_is_a_test_or_a_module_of_one() {
    let mut checked = Vec::new();
    for member in members() {
        let dir = repo().join(&member);
        let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap();
        if !manifest.lines().any(|l| l.trim() == "autotests = false") {
            continue;
        }
        let targets = test_targets(&manifest);
        assert!(
            targets.iter().any(|t| t == "integration"),
            "{member}/Cargo.toml: autotests = false without the [[test]] integration"
        );
        let root = std::fs::read_to_string(dir.join("tests/integration.rs")).unwrap();
        let mut files: Vec<String> = std::fs::read_dir(dir.join("tests"))
            .unwrap()
            .map(|entry| entry.unwrap().path())
            .filter(|path| path.extension().is_some_and(|e| e == "rs"))
            .map(|path| path.file_stem().unwrap().to_string_lossy().into_owned())
            .collect();
        files.sort();
        for file in files {
            let declared = root.lines().any(|l| l.trim() == format!("mod {file};"));
            assert!(
                targets.contains(&file) || declared,
                "{member}/tests/{file}.rs is never built: declare it in \
                 {member}/tests/integration.rs (`mod {file};`) or as a [[test]] in \
                 {member}/Cargo.toml"
            );
            assert!(
                !(targets.contains(&file) && declared),
                "{member}/tests/{file}.rs is built twice: its own [[test]] and a module of \
                 tests/integration.rs"
            );
        }
        checked.push(member);
    }
    // The crates whose test files were one binary each before they were merged.
    for member in [
        "core",
        "firmware/app",
        "firmware/storage",
        "lang",
        "host-tools",
        "tests",
    ] {
        assert!(
            checked.iter().any(|c| c == member),
            "{member}: not checked ({checked:?})"
        );
    }
}

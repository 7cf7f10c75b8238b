//! The book's `pabctl` reference (docs/pabctl.md, its synopsis) against `pabctl --help`: the
//! same commands, and for each the same long options, so that neither can drift from the other.
//! The help is the binary's own (clap's), read as a user reads it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

fn help(args: &[&str]) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_pabctl"))
        .args(args)
        .arg("-h")
        .output()
        .expect("pabctl runs");
    assert!(output.status.success(), "pabctl {args:?} -h failed");
    String::from_utf8(output.stdout).expect("UTF-8 help")
}

/// The lines of a help section (`Commands:`, `Options:`), up to the next blank line.
fn section<'a>(text: &'a str, title: &str) -> Vec<&'a str> {
    text.lines()
        .skip_while(|line| line.trim() != title)
        .skip(1)
        .take_while(|line| !line.trim().is_empty())
        .collect()
}

/// Every option named in `text`, as written: the long ones (`--plot`), but `--help` and
/// `--version`, and the short ones a synopsis may use (`-o DIR`).
fn options_named(text: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for word in text.split_whitespace() {
        let word = word.trim_start_matches('[');
        if word.len() == 2 && word.starts_with('-') && word.as_bytes()[1].is_ascii_alphabetic() {
            found.insert(word.to_string());
        }
    }
    let mut rest = text;
    while let Some(at) = rest.find("--") {
        let name: String = rest[at + 2..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
            .collect();
        if !name.is_empty() && name != "help" && name != "version" {
            found.insert(format!("--{name}"));
        }
        rest = &rest[at + 2 + name.len()..];
    }
    found
}

/// The synopsis of docs/pabctl.md: each command's long options, from its `pabctl NAME ...` line
/// and the lines that continue it (indented further).
fn synopsis() -> BTreeMap<String, BTreeSet<String>> {
    let page = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/pabctl.md");
    let text = std::fs::read_to_string(page).expect("docs/pabctl.md");
    let mut commands = BTreeMap::new();
    let mut current: Option<String> = None;
    for line in text.lines() {
        if let Some(rest) = line.strip_prefix("    pabctl ") {
            let name = rest.split_whitespace().next().unwrap_or("").to_string();
            let options = commands.entry(name.clone()).or_insert_with(BTreeSet::new);
            options.extend(options_named(rest));
            current = Some(name);
        } else if line.starts_with("        ") && line.trim_start().starts_with('[') {
            if let Some(name) = &current {
                commands
                    .get_mut(name)
                    .expect("entered above")
                    .extend(options_named(line));
            }
        } else if !line.is_empty() {
            // The synopsis is the page's first block: it ends at the first line of prose.
            if current.is_some() {
                break;
            }
        }
    }
    commands
}

#[test]
fn the_books_synopsis_has_every_command_and_option_that_pabctl_help_shows() {
    let documented = synopsis();
    let top = help(&[]);
    let commands: BTreeSet<String> = section(&top, "Commands:")
        .iter()
        // A command's line starts two spaces in; its description's wrapped lines, further.
        .filter(|line| line.starts_with("  ") && !line.starts_with("   "))
        .filter_map(|line| line.split_whitespace().next())
        .filter(|name| *name != "help")
        .map(str::to_string)
        .collect();
    assert!(commands.len() >= 10, "commands in the help: {commands:?}");
    let in_book: BTreeSet<String> = documented.keys().cloned().collect();
    assert_eq!(
        in_book, commands,
        "docs/pabctl.md's synopsis (left) and `pabctl --help`'s commands (right) differ"
    );
    let mut wrong = Vec::new();
    for command in &commands {
        // An option's own line starts with its flags; a description's wrapped lines may name
        // another option, which does not count.
        // `-o, --output <DIR>`: the book may show either form.
        let mut options = BTreeSet::new();
        let mut shorts = BTreeMap::new();
        for line in section(&help(&[command]), "Options:") {
            let flags = line.trim_start();
            if !flags.starts_with('-') {
                continue;
            }
            let flags = flags.split("  ").next().unwrap_or(flags);
            if let Some(long) = options_named(flags).pop_first() {
                if let Some(short) = flags.strip_prefix('-').filter(|f| !f.starts_with('-')) {
                    shorts.insert(format!("-{}", &short[..1]), long.clone());
                }
                options.insert(long);
            }
        }
        let shown: BTreeSet<String> = documented[command]
            .iter()
            .map(|flag| shorts.get(flag).unwrap_or(flag).clone())
            .collect();
        let missing: Vec<_> = options.difference(&shown).collect();
        let extra: Vec<_> = shown.difference(&options).collect();
        if !missing.is_empty() {
            wrong.push(format!(
                "pabctl {command}: in --help, not in the book: {missing:?}"
            ));
        }
        if !extra.is_empty() {
            wrong.push(format!(
                "pabctl {command}: in the book, not in --help: {extra:?}"
            ));
        }
    }
    assert!(
        wrong.is_empty(),
        "docs/pabctl.md's synopsis and pabctl's help disagree:\n{}",
        wrong.join("\n")
    );
}

//! The README's first network and the book's tutorial are a tested example: the network they
//! show is `examples/first-network.toml` as it is, and what they show `pabctl check` and
//! `pabctl sim` print is what they print.

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn read(relative: &str) -> String {
    let path = repo().join(relative);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The example without its opening comment: the part the documents show.
fn example_body() -> String {
    let text = read("examples/first-network.toml");
    let start = text
        .lines()
        .position(|line| !line.starts_with('#') && !line.trim().is_empty())
        .expect("the example has a body");
    text.lines()
        .skip(start)
        .map(|line| format!("{line}\n"))
        .collect()
}

/// The first fenced block of `language` in `text`.
fn fenced(text: &str, language: &str) -> Option<String> {
    let open = format!("```{language}\n");
    let start = text.find(&open)? + open.len();
    let end = start + text[start..].find("```")?;
    Some(text[start..end].to_string())
}

/// The indented lines shown right after the line `$ {command}` (the printed output), unindented.
fn shown_output(text: &str, command: &str) -> Vec<String> {
    let prompt = format!("    $ {command}");
    let mut lines = text.lines().skip_while(|line| *line != prompt);
    assert!(lines.next().is_some(), "no `$ {command}` shown");
    lines
        .take_while(|line| line.starts_with("    ") && !line.starts_with("    $ "))
        .map(|line| line[4..].to_string())
        .collect()
}

fn pabctl(args: &[&str]) -> (i32, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_pabctl"))
        .args(args)
        .current_dir(repo())
        .output()
        .expect("pabctl runs");
    let mut text = String::from_utf8_lossy(&output.stdout).into_owned();
    text.push_str(&String::from_utf8_lossy(&output.stderr));
    (output.status.code().unwrap_or(-1), text)
}

#[test]
fn the_readme_and_the_tutorial_show_the_example_as_it_is() {
    let body = example_body();
    for document in ["README.md", "docs/tutorial.md"] {
        let shown =
            fenced(&read(document), "toml").unwrap_or_else(|| panic!("{document}: no TOML block"));
        assert_eq!(
            shown, body,
            "{document}'s network differs from examples/first-network.toml"
        );
    }
}

#[test]
fn what_the_readme_shows_check_and_sim_print_is_what_they_print() {
    let readme = read("README.md");
    for (command, args, status) in [
        ("check", vec!["check", "examples/first-network.toml"], 0),
        ("sim", vec!["sim", "examples/first-network.toml"], 0),
    ] {
        let (code, printed) = pabctl(&args);
        assert_eq!(code, status, "pabctl {command}: {printed}");
        let shown_command = match command {
            "check" => "cargo run --release -p pabctl -- check examples/first-network.toml",
            _ => {
                "cargo run --release -p pabctl -- sim examples/first-network.toml --plot first-network.png"
            }
        };
        let shown = shown_output(&readme, shown_command);
        assert!(
            shown.len() >= 4,
            "README shows too little of `pabctl {command}`: {shown:?}"
        );
        for line in &shown {
            assert!(
                printed
                    .lines()
                    .any(|printed| printed.trim_end() == line.trim_end()),
                "README shows {line:?} for `pabctl {command}`, which printed:\n{printed}"
            );
        }
    }
}

#[test]
fn the_rule_the_readme_says_is_refused_is_refused_at_its_line() {
    let network = read("examples/first-network.toml")
        .replace("rule = \"GRASP & !RELEASE\"", "rule = \"GRASP\"");
    assert!(network.contains("rule = \"GRASP\""));
    let dir = std::env::temp_dir().join(format!("pab-tutorial-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("first-network.toml");
    std::fs::write(&path, network).unwrap();
    let (code, printed) = pabctl(&["check", path.to_str().unwrap()]);
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(code, 1, "{printed}");
    assert!(
        printed.contains("GRASP (rule \"GRASP\") and RELEASE (rule \"RELEASE\") can both deliver"),
        "{printed}"
    );
    assert!(
        printed.contains("first-network.toml:"),
        "the error names the file: {printed}"
    );
}

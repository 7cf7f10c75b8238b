//! The build id every node states in its identity (`pab_app::BUILD_ID`): the git commit the
//! firmware was built from, as hex, or `PAB_BUILD_ID` when set (a build outside a git checkout,
//! a release pipeline). Empty when neither is known: the identity then reads build 0.
use std::path::Path;
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let output = Command::new("git")
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .ok()?;
    let text = String::from_utf8(output.stdout).ok()?;
    (output.status.success() && !text.trim().is_empty()).then(|| text.trim().to_string())
}

fn main() {
    println!("cargo:rerun-if-env-changed=PAB_BUILD_ID");
    let id = match std::env::var("PAB_BUILD_ID") {
        Ok(id) => id,
        Err(_) => {
            // Built again when HEAD moves: HEAD itself, the branch it names, or packed refs.
            if let Some(dir) = git(&["rev-parse", "--absolute-git-dir"]) {
                let dir = Path::new(&dir);
                println!("cargo:rerun-if-changed={}", dir.join("HEAD").display());
                let branch = git(&["symbolic-ref", "-q", "HEAD"]).map(|name| dir.join(name));
                match branch {
                    Some(file) if file.exists() => {
                        println!("cargo:rerun-if-changed={}", file.display())
                    }
                    _ if dir.join("packed-refs").exists() => println!(
                        "cargo:rerun-if-changed={}",
                        dir.join("packed-refs").display()
                    ),
                    _ => {}
                }
            }
            git(&["rev-parse", "HEAD"]).unwrap_or_default()
        }
    };
    println!("cargo:rustc-env=PAB_BUILD_ID={id}");
}

//! Records the git commit the library is built from (`SPINEDRR_GIT_COMMIT`: the hash, with `-dirty`
//! appended when tracked files differ from it; "unknown" outside a git checkout or without git), which
//! the study report names in its provenance line.

use std::path::PathBuf;
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let o = Command::new("git").args(args).output().ok()?;
    o.status
        .success()
        .then(|| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .filter(|s| !s.is_empty())
}

fn main() {
    let commit = git(&["rev-parse", "HEAD"]).map_or_else(
        || "unknown".to_string(),
        |c| match git(&["status", "--porcelain", "--untracked-files=no"]) {
            Some(_) => format!("{c}-dirty"),
            None => c,
        },
    );
    // Rerun when what is built changes (a dirty tree), not only when HEAD moves.
    for p in ["src", "Cargo.toml", "reference", "build.rs"] {
        println!("cargo:rerun-if-changed={p}");
    }
    println!("cargo:rustc-env=SPINEDRR_GIT_COMMIT={commit}");
    // Rerun when HEAD moves: HEAD itself (a checkout), the branch it names (a commit), packed refs.
    if let Some(dir) = git(&["rev-parse", "--git-dir"]).map(PathBuf::from) {
        println!("cargo:rerun-if-changed={}", dir.join("HEAD").display());
        println!(
            "cargo:rerun-if-changed={}",
            dir.join("packed-refs").display()
        );
        if let Some(branch) = git(&["symbolic-ref", "-q", "HEAD"]) {
            let common = git(&["rev-parse", "--git-common-dir"]).map_or(dir, PathBuf::from);
            println!("cargo:rerun-if-changed={}", common.join(branch).display());
        }
    }
}

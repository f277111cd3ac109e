//! Records the git commit the library is built from (`SPINEDRR_GIT_COMMIT`: the hash, with `-dirty`
//! appended when a tracked file among the build's inputs ([`INPUTS`]) differs from it; "unknown" outside
//! a git checkout or without git), which the study report names in its provenance line. The mark covers
//! exactly the files whose change reruns this script: a tree-wide `git status` let an edit to a file the
//! binary is not built from (a test, the README) mark it `-dirty`, and the mark then outlived the
//! edit's revert, since nothing the script watches had changed (a clean checkout's report called its
//! binary dirty). Also records the build's code digest (`SPINEDRR_BUILD_DIGEST`, of every input above,
//! the compiler and the profile; `core/code_digest.rs`), which keys a study's unit files; the digest that
//! keys the phantom mesh cache is `spinedrr-core`'s (`core/build.rs`).

include!("core/code_digest.rs");

/// What the library is built from; a change to any of it reruns this script.
const INPUTS: [&str; 12] = [
    "src",
    "core/src",
    "core/code_digest.rs",
    "sys",
    "cv",
    "assets",
    "reference",
    "Cargo.toml",
    "core/Cargo.toml",
    "core/build.rs",
    "Cargo.lock",
    "build.rs",
];

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
        |c| match git(&["status", "--porcelain", "--untracked-files=no", "--"]
            .into_iter()
            .chain(INPUTS)
            .collect::<Vec<_>>())
        {
            Some(_) => format!("{c}-dirty"),
            None => c,
        },
    );
    // Rerun when what is built changes (a dirty tree), not only when HEAD moves.
    for p in INPUTS {
        println!("cargo:rerun-if-changed={p}");
    }
    println!("cargo:rustc-env=SPINEDRR_GIT_COMMIT={commit}");
    // What a study's unit files are keyed by besides their config and inputs: results of another build
    // (another source, compiler or profile) are computed again, never reused.
    println!(
        "cargo:rustc-env=SPINEDRR_BUILD_DIGEST={}",
        code_digest(&INPUTS)
    );
    // Rerun when HEAD moves: HEAD itself (a checkout), a commit on any branch (the loose refs, a directory
    // cargo scans for changed files) and packed refs. Only paths that exist: cargo takes a missing file as
    // changed, so a checkout without packed refs (a fresh `git init`) or a branch whose ref was packed
    // reran this script, and recompiled the library, on every build.
    if let Some(dir) = git(&["rev-parse", "--git-dir"]).map(PathBuf::from) {
        let common =
            git(&["rev-parse", "--git-common-dir"]).map_or_else(|| dir.clone(), PathBuf::from);
        for p in [
            dir.join("HEAD"),
            common.join("refs/heads"),
            common.join("packed-refs"),
        ] {
            if p.exists() {
                println!("cargo:rerun-if-changed={}", p.display());
            }
        }
    }
}

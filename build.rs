//! Records the git commit the library is built from (`SPINEDRR_GIT_COMMIT`: the hash, with `-dirty`
//! appended when tracked files differ from it; "unknown" outside a git checkout or without git), which
//! the study report names in its provenance line, and a digest of the code itself
//! (`SPINEDRR_CODE_DIGEST`), which keys the phantom mesh cache (`src/anatomy/phantom_cache.rs`).

use std::hash::{DefaultHasher, Hasher};
use std::path::{Path, PathBuf};
use std::process::Command;

/// What the library is built from; a change to any of it reruns this script.
const INPUTS: [&str; 6] = [
    "src",
    "assets",
    "reference",
    "Cargo.toml",
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

fn files_under(p: &Path, out: &mut Vec<PathBuf>) {
    if p.is_dir() {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(p)
            .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default();
        entries.sort();
        for e in entries {
            files_under(&e, out);
        }
    } else if p.is_file() {
        out.push(p.to_path_buf());
    }
}

/// A 128-bit digest (two SipHash-1-3 streams, hex) of every input file's path and bytes, the compiler's
/// version, the target and the profile's settings: equal digests mean the same code compiled the same
/// way, so a result it built once may be reused. Not cryptographic; it guards against staleness, not
/// against an adversary (the cache's entries also carry a BLAKE3 checksum).
fn code_digest() -> String {
    let mut files = Vec::new();
    for p in INPUTS {
        files_under(Path::new(p), &mut files);
    }
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let version = Command::new(rustc)
        .arg("-vV")
        .output()
        .map(|o| o.stdout)
        .unwrap_or_default();
    let (mut a, mut b) = (DefaultHasher::new(), DefaultHasher::new());
    b.write(b"second stream");
    let mut feed = |bytes: &[u8]| {
        for h in [&mut a, &mut b] {
            h.write_usize(bytes.len());
            h.write(bytes);
        }
    };
    for f in &files {
        feed(f.to_string_lossy().as_bytes());
        feed(&std::fs::read(f).unwrap_or_default());
    }
    feed(&version);
    for var in [
        "TARGET",
        "PROFILE",
        "OPT_LEVEL",
        "DEBUG",
        "CARGO_ENCODED_RUSTFLAGS",
    ] {
        feed(std::env::var(var).unwrap_or_default().as_bytes());
    }
    format!("{:016x}{:016x}", a.finish(), b.finish())
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
    for p in INPUTS {
        println!("cargo:rerun-if-changed={p}");
    }
    println!("cargo:rustc-env=SPINEDRR_GIT_COMMIT={commit}");
    println!("cargo:rustc-env=SPINEDRR_CODE_DIGEST={}", code_digest());
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

// The code digest both build scripts compute (`include!`d by `core/build.rs` and the workspace's
// `build.rs`): a change to this file reruns both.

use std::hash::{DefaultHasher, Hasher};
use std::path::{Path, PathBuf};
use std::process::Command;

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
fn code_digest(inputs: &[&str]) -> String {
    let mut files = Vec::new();
    for p in inputs {
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

//! Records a digest of the code itself (`SPINEDRR_CODE_DIGEST`), which keys the phantom mesh cache
//! (`core/src/anatomy/phantom_cache.rs`). The git commit the report names is the `spinedrr` crate's (its
//! `build.rs`).

/// What the code is built from (paths relative to this crate; the assets and the lock file are the
/// workspace's); a change to any of it reruns this script.
const INPUTS: [&str; 6] = [
    "src",
    "code_digest.rs",
    "../assets",
    "Cargo.toml",
    "../Cargo.lock",
    "build.rs",
];

include!("code_digest.rs");

fn main() {
    for p in INPUTS {
        println!("cargo:rerun-if-changed={p}");
    }
    println!(
        "cargo:rustc-env=SPINEDRR_CODE_DIGEST={}",
        code_digest(&INPUTS)
    );
}

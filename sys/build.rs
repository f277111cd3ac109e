//! Finds the system Embree (4 preferred, else 3), generates raw bindings with bindgen and compiles the
//! C shim. Without Embree it stops with one sentence naming the package to install.

use std::env;
use std::path::{Path, PathBuf};

struct Embree {
    major: u32,
    include_dirs: Vec<PathBuf>,
}

/// pkg-config first (embree4, then embree3), then `EMBREE_DIR`, then the standard include directories.
fn find_embree() -> Option<Embree> {
    for (major, name) in [(4, "embree4"), (3, "embree3")] {
        if let Ok(lib) = pkg_config::Config::new().cargo_metadata(true).probe(name) {
            return Some(Embree {
                major,
                include_dirs: lib.include_paths,
            });
        }
    }
    let mut prefixes: Vec<PathBuf> = Vec::new();
    if let Ok(dir) = env::var("EMBREE_DIR") {
        prefixes.push(PathBuf::from(dir));
    }
    prefixes.extend(["/usr", "/usr/local", "/opt/homebrew"].map(PathBuf::from));
    for prefix in &prefixes {
        for major in [4u32, 3] {
            let include = prefix.join("include");
            if include.join(format!("embree{major}/rtcore.h")).is_file() {
                for lib in [
                    "lib",
                    "lib64",
                    "lib/x86_64-linux-gnu",
                    "lib/aarch64-linux-gnu",
                ] {
                    let dir = prefix.join(lib);
                    if has_library(&dir, major) {
                        println!("cargo:rustc-link-search=native={}", dir.display());
                    }
                }
                println!("cargo:rustc-link-lib=embree{major}");
                return Some(Embree {
                    major,
                    include_dirs: vec![include],
                });
            }
        }
    }
    None
}

fn has_library(dir: &Path, major: u32) -> bool {
    ["so", "dylib", "a"]
        .iter()
        .any(|ext| dir.join(format!("libembree{major}.{ext}")).exists())
}

fn main() {
    println!("cargo:rerun-if-changed=wrapper.h");
    println!("cargo:rerun-if-changed=shim/spd_shim.h");
    println!("cargo:rerun-if-changed=shim/spd_shim.c");
    println!("cargo:rerun-if-env-changed=EMBREE_DIR");
    println!("cargo::rustc-check-cfg=cfg(embree_major, values(\"3\", \"4\"))");

    let Some(embree) = find_embree() else {
        panic!(
            "\n\nEmbree was not found: install the Debian package libembree-dev \
             (`sudo apt-get install libembree-dev`, or run scripts/install-deps.sh), \
             or set EMBREE_DIR to an Embree install prefix.\n\n"
        );
    };
    let major = embree.major;
    println!("cargo:rustc-cfg=embree_major=\"{major}\"");
    // Exposed to dependants as DEP_EMBREE_MAJOR.
    println!("cargo:major={major}");

    let mut cc = cc::Build::new();
    cc.file("shim/spd_shim.c")
        .define("SPD_EMBREE_MAJOR", major.to_string().as_str())
        .opt_level(3)
        .warnings(true);
    for dir in &embree.include_dirs {
        cc.include(dir);
    }
    cc.compile("spd_shim");

    let mut builder = bindgen::Builder::default()
        .header("wrapper.h")
        .clang_arg(format!("-DSPD_EMBREE_MAJOR={major}"))
        .allowlist_function("rtc.*")
        .allowlist_function("spd_.*")
        .allowlist_type("RTC.*")
        .allowlist_type("spd_.*")
        .allowlist_var("RTC_.*")
        .default_enum_style(bindgen::EnumVariation::Consts)
        .prepend_enum_name(false)
        .derive_default(true)
        .layout_tests(false)
        .parse_callbacks(Box::new(bindgen::CargoCallbacks::new()));
    for dir in &embree.include_dirs {
        builder = builder.clang_arg(format!("-I{}", dir.display()));
    }
    let bindings = builder
        .generate()
        .unwrap_or_else(|e| panic!("bindgen could not process the Embree {major} header: {e}"));
    let out = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    bindings
        .write_to_file(out.join("bindings.rs"))
        .expect("writing bindings.rs to OUT_DIR");
}

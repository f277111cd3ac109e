//! Compiles the C++ shim against the system OpenCV (pkg-config `opencv4`, else `opencv`) and links the
//! three modules it calls. Without OpenCV it stops with one sentence naming the package to install.

fn main() {
    println!("cargo:rerun-if-changed=shim/cv_shim.cpp");
    let lib = ["opencv4", "opencv"].iter().find_map(|name| {
        pkg_config::Config::new()
            // The include paths and the library directory only: the shim needs three of OpenCV's
            // forty-odd libraries, linked below.
            .cargo_metadata(false)
            .probe(name)
            .ok()
    });
    let Some(lib) = lib else {
        panic!(
            "\n\nOpenCV was not found by pkg-config: install the Debian package libopencv-dev \
             (`sudo apt-get install libopencv-dev`, or run scripts/install-deps.sh).\n\n"
        );
    };
    let mut cc = cc::Build::new();
    cc.cpp(true)
        .file("shim/cv_shim.cpp")
        .flag_if_supported("-std=c++17")
        .warnings(true)
        .extra_warnings(true);
    for dir in &lib.include_paths {
        cc.include(dir);
    }
    cc.compile("spinedrr_cv_shim");
    for dir in &lib.link_paths {
        println!("cargo:rustc-link-search=native={}", dir.display());
    }
    for module in ["opencv_calib3d", "opencv_imgproc", "opencv_core"] {
        println!("cargo:rustc-link-lib={module}");
    }
}

//! The one runner of the `spinedrr` binary shared by the integration tests (`crate::common`).
//!
//! `spinedrr(&args)` runs the binary and returns its `Output`; `run(&args)` returns whether it
//! succeeded and its stderr. `Spinedrr` builds a command line of mixed arguments (strings and paths) or
//! one that needs a working directory.

// Each test binary compiles this module and uses a part of it.
#![allow(dead_code)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Output};

/// The phantom mesh cache of every `spinedrr` the tests run (`SPINEDRR_CACHE_DIR`), inside the build's
/// target directory: the runs share meshes with each other, never with the user's own cache, and a
/// fresh clone starts with none.
pub const MESH_CACHE: &str = concat!(env!("CARGO_TARGET_TMPDIR"), "/phantom-mesh-cache");

/// A study config's `experiments` line: every experiment but the intensity registration, which studies
/// the phantom's L3 whatever the anatomy (its default target) and dominated the time of the studies that
/// test other targets (`study_intensity` and `registration_intensity*` test it). Derived from
/// `Experiment::ALL`, so an experiment added later runs here too.
pub fn all_but_intensity() -> String {
    use spinedrr::study::config::Experiment;
    let names: Vec<String> = Experiment::ALL
        .iter()
        .filter(|&&e| e != Experiment::IntensityRegistration)
        .map(|e| format!("{:?}", e.name()))
        .collect();
    format!("experiments = [{}]", names.join(", "))
}

/// A `spinedrr` command line under construction.
pub struct Spinedrr(Command);

impl Spinedrr {
    /// The binary cargo built for these tests, with no arguments yet, caching phantom meshes at
    /// [`MESH_CACHE`].
    pub fn new() -> Self {
        let mut c = Command::new(env!("CARGO_BIN_EXE_spinedrr"));
        c.env("SPINEDRR_CACHE_DIR", MESH_CACHE);
        Spinedrr(c)
    }

    /// Appends one argument.
    pub fn arg(mut self, a: impl AsRef<OsStr>) -> Self {
        self.0.arg(a);
        self
    }

    /// Appends arguments.
    pub fn args<S: AsRef<OsStr>>(mut self, args: impl IntoIterator<Item = S>) -> Self {
        self.0.args(args);
        self
    }

    /// Runs in `dir` instead of the test's working directory.
    pub fn current_dir(mut self, dir: impl AsRef<Path>) -> Self {
        self.0.current_dir(dir);
        self
    }

    /// Sets an environment variable of the run.
    pub fn env(mut self, key: impl AsRef<OsStr>, value: impl AsRef<OsStr>) -> Self {
        self.0.env(key, value);
        self
    }

    /// The command itself (to spawn it and wait later).
    pub fn command(self) -> Command {
        self.0
    }

    /// Runs to completion and returns the exit status with the captured stdout and stderr.
    pub fn output(mut self) -> Output {
        self.0.output().expect("running spinedrr")
    }

    /// Runs to completion with stdout and stderr passed through (a long run shows its progress).
    pub fn status(mut self) -> ExitStatus {
        self.0.status().expect("running spinedrr")
    }

    /// Runs and returns whether it succeeded, with its stderr.
    pub fn outcome(self) -> (bool, String) {
        outcome(&self.output())
    }
}

impl Default for Spinedrr {
    fn default() -> Self {
        Self::new()
    }
}

/// Runs `spinedrr ARGS` and returns its output.
pub fn spinedrr<S: AsRef<OsStr>>(args: &[S]) -> Output {
    Spinedrr::new().args(args).output()
}

/// Runs `spinedrr ARGS` and returns whether it succeeded, with its stderr.
pub fn run<S: AsRef<OsStr>>(args: &[S]) -> (bool, String) {
    outcome(&spinedrr(args))
}

/// The stderr of a run, as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Whether a run succeeded, with its stderr.
pub fn outcome(o: &Output) -> (bool, String) {
    (o.status.success(), stderr(o))
}

/// The CSV tables of a study output folder, `(file name, bytes)` sorted by name — what byte-identity
/// checks compare (the LaTeX renderings beside them are report products).
pub fn csv_tables(out: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(out.join("tables"))
        .expect("tables dir")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

/// The phantom `opts` describes, through the mesh cache the tests' CLI runs share ([`MESH_CACHE`]):
/// for the tests that *use* a phantom. The tests of the builder itself (`anatomy_phantom`,
/// `phantom_morphometry`, `anatomy_cli`'s comparison with the CLI) call `build_phantom`, which builds
/// afresh in this binary; `phantom_cache` shows the two are equal bit for bit.
pub fn phantom(
    opts: &spinedrr::anatomy::PhantomOptions,
) -> spinedrr::Result<spinedrr::anatomy::Phantom> {
    use spinedrr::anatomy::MeshCache;
    static CACHE: std::sync::OnceLock<MeshCache> = std::sync::OnceLock::new();
    spinedrr::anatomy::build_phantom_with(
        opts,
        Some(CACHE.get_or_init(|| MeshCache::new(MESH_CACHE))),
    )
}

/// The default L1–L5 phantom with its soft-tissue cylinder, built once for the whole test binary (a
/// build is ~30 s of thread time; several modules read it).
pub fn phantom_with_soft_tissue() -> &'static spinedrr::anatomy::Phantom {
    use spinedrr::anatomy::PhantomOptions;
    static P: std::sync::OnceLock<spinedrr::anatomy::Phantom> = std::sync::OnceLock::new();
    P.get_or_init(|| {
        phantom(&PhantomOptions {
            soft_tissue: true,
            ..PhantomOptions::default()
        })
        .expect("building the default phantom")
    })
}

/// The default phantom (`PhantomOptions::default()`: no soft tissue): [`phantom_with_soft_tissue`]
/// without its cylinder. `build_phantom` meshes the vertebrae and discs before, and independently of,
/// the soft tissue, so this is the phantom the default options build.
pub fn default_phantom() -> &'static spinedrr::anatomy::Phantom {
    static P: std::sync::OnceLock<spinedrr::anatomy::Phantom> = std::sync::OnceLock::new();
    P.get_or_init(|| {
        let mut p = phantom_with_soft_tissue().clone();
        p.soft_tissue = None;
        p.soft_tissue_shape = None;
        p
    })
}

/// Whether the tests run as root (`id -u` is 0): mounting, PID namespaces and slurmd need it.
pub fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

/// The C-arm the intensity-registration tests were established on: the default geometry with the LAT
/// source 750 mm from the vertebra (magnification 1.8; the default is 900 mm, 1.5, so that the L1–L5
/// segment fits the LAT detector). Their precision bounds are properties of this problem, which the
/// tests fix here rather than follow the default.
pub fn carm_lat_750() -> spinedrr::geometry::CArm {
    let text = spinedrr::geometry::DEFAULT_GEOMETRY_TOML.replace(
        "source_mm = [-900.0, -25.0, 20.0]",
        "source_mm = [-750.0, -25.0, 20.0]",
    );
    assert_ne!(text, spinedrr::geometry::DEFAULT_GEOMETRY_TOML);
    spinedrr::geometry::CArm::from_toml_str(&text, "LAT at 750 mm").unwrap()
}

/// Every text of every SVG figure under `figs` stays at least 12 px high (the bound) when the
/// figure is shown at the report's preview width: the text height plotters draws is the SVG
/// `font-size` × 1.24 (plotters-svg writes size / 1.24), scaled by preview width / figure width when
/// the figure is wider. Returns how many figures were checked.
pub fn assert_figures_legible(figs: &Path) -> usize {
    let page = f64::from(spinedrr::study::report_html::PREVIEW_WIDTH_PX);
    let mut checked = 0;
    let mut small = Vec::new();
    for e in std::fs::read_dir(figs).expect("figures") {
        let p = e.expect("entry").path();
        if p.extension().is_none_or(|x| x != "svg") {
            continue;
        }
        let s = std::fs::read_to_string(&p).expect("svg");
        let doc = roxmltree::Document::parse(&s).expect("xml");
        let root = doc.root_element();
        let width: f64 = root
            .attribute("width")
            .and_then(|w| w.parse().ok())
            .expect("width");
        let scale = (page / width).min(1.0);
        for t in doc.descendants().filter(|n| n.has_tag_name("text")) {
            let size: f64 = t
                .attribute("font-size")
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("{}: a text without font-size", p.display()));
            let shown = size * 1.24 * scale;
            if shown < 12.0 - 1e-6 && !t.text().unwrap_or("").trim().is_empty() {
                small.push(format!(
                    "{}: {:?} {shown:.1} px",
                    p.file_name().unwrap().to_string_lossy(),
                    t.text().unwrap_or("")
                ));
            }
        }
        checked += 1;
    }
    assert!(
        small.is_empty(),
        "{} texts below 12 px at the page width, e.g. {:?}",
        small.len(),
        &small[..small.len().min(8)]
    );
    checked
}

/// Every drawn figure PNG under `figs` (not the raw `heatmap_<target>_<view>_df*.png` images) has a
/// blank (near-white) border of 3 px: titles, legends and labels stay inside the canvas. Returns how
/// many were checked.
pub fn assert_figures_inside_canvas(figs: &Path) -> usize {
    let mut checked = 0;
    let mut cut = Vec::new();
    for e in std::fs::read_dir(figs).expect("figures") {
        let p = e.expect("entry").path();
        let name = p.file_name().unwrap().to_string_lossy().to_string();
        let raw = name.starts_with("heatmap_") && !name.starts_with("heatmap_panel_");
        if p.extension().is_none_or(|x| x != "png") || raw {
            continue;
        }
        let img = image::open(&p).expect("png").to_luma8();
        let (w, h) = img.dimensions();
        let dark = |x: u32, y: u32| img.get_pixel(x, y).0[0] < 200;
        let edge = (0..w).any(|x| (0..3).any(|y| dark(x, y) || dark(x, h - 1 - y)))
            || (0..h).any(|y| (0..3).any(|x| dark(x, y) || dark(w - 1 - x, y)));
        if edge {
            cut.push(name);
        }
        checked += 1;
    }
    assert!(cut.is_empty(), "drawn to the canvas edge: {cut:?}");
    checked
}

/// A C-arm-like square view of `target` from `target + offset` (mm): `n` × `n` pixels, focal length 12 n,
/// the principal point at the centre, image up along world z (y when looking along z).
pub fn view_from(target: glam::DVec3, offset: glam::DVec3, n: u32) -> spinedrr::geometry::View {
    let c = (n as f64 - 1.0) / 2.0;
    let k = spinedrr::geometry::Intrinsics {
        fx: 12.0 * n as f64,
        fy: 12.0 * n as f64,
        skew: 0.0,
        cx: c,
        cy: c,
        width: n,
        height: n,
    };
    let up = if offset.cross(glam::DVec3::Z).length() < 1e-6 * offset.length() {
        glam::DVec3::Y
    } else {
        glam::DVec3::Z
    };
    spinedrr::geometry::View::new(
        "test",
        k,
        spinedrr::geometry::RigidTransform::look_at(target + offset, target, up).unwrap(),
    )
}

/// Every file directly in `dir` with its bytes.
pub fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v: Vec<(PathBuf, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| {
            let b = std::fs::read(&p).unwrap();
            (p, b)
        })
        .collect();
    v.sort();
    v
}

/// Runs `args`, expects a refusal without a panic naming every one of `needles`, and that `dir` is
/// unchanged.
pub fn refused_untouched(dir: &Path, args: &[String], needles: &[&str]) {
    let before = snapshot(dir);
    let (ok, err) = run(args);
    assert!(!ok, "accepted: {args:?}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}: {err}");
    }
    assert_eq!(snapshot(dir), before, "{args:?} changed the folder");
}

/// `OUT/report.md`, checked to link each entry of its `## Contents` to a section of that title: a study
/// whose experiments write no such section (no Findings in a study of intensity registration alone)
/// lists none.
pub fn read_report(out: &Path) -> String {
    let md = std::fs::read_to_string(out.join("report.md"))
        .unwrap_or_else(|e| panic!("{}: {e}", out.join("report.md").display()));
    let headings: Vec<&str> = md.lines().filter_map(|l| l.strip_prefix("## ")).collect();
    let contents = md
        .split("## Contents\n")
        .nth(1)
        .and_then(|rest| rest.split("\n## ").next())
        .expect("a ## Contents section");
    let entries: Vec<&str> = contents
        .lines()
        .filter_map(|l| l.strip_prefix("- ["))
        .filter_map(|l| l.split("](#").next())
        .collect();
    assert!(!entries.is_empty(), "empty contents");
    // One block per line or run of lines, each after a blank line: CommonMark (GitHub, report.html)
    // joins two lines of text into one paragraph, and takes text right after a list item or a table
    // row into it. Headings stand alone; an image and its caption line are one figure.
    let kind = |l: &str| match l {
        _ if l.trim().is_empty() => "blank",
        _ if l.starts_with('#') => "heading",
        _ if l.starts_with('|') => "table",
        _ if l.starts_with("- ") => "list",
        _ if l.starts_with("![") => "image",
        _ if l.starts_with("_Figure ") => "caption",
        _ => "text",
    };
    for (a, b) in md.lines().zip(md.lines().skip(1)) {
        let (ka, kb) = (kind(a), kind(b));
        let apart = ["blank", "heading"].contains(&ka) || ["blank", "heading"].contains(&kb);
        let one_block =
            (ka == kb && ["table", "list"].contains(&ka)) || (ka, kb) == ("image", "caption");
        let joined = !apart && !one_block;
        assert!(
            !joined,
            "report.md: a {ka} line and a {kb} line with no blank line between (CommonMark joins them):\n{a}\n{b}"
        );
    }
    for title in entries {
        assert!(
            headings.contains(&title),
            "the contents list {title:?}, but the report has no such section (sections: {headings:?})"
        );
    }
    md
}

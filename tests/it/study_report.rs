//! The study report as a document, on a real `spinedrr study --quick` run: the composed paper-style
//! figures per target (with the right panels), SVG twins that parse as XML and hold the plotted series,
//! well-formed LaTeX tables with the right row counts, a size bound on report.html, and report.html
//! opened in headless Chromium: every image decodes, every table-of-contents link resolves, and a
//! screenshot is taken (kept under the cargo target's tmp dir to be looked at).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use spinedrr::study::StudyTables;
use spinedrr::study::config::RegistrationMethod;

/// The quick study's output, run once per test binary.
fn quick_out() -> &'static Path {
    static OUT: OnceLock<PathBuf> = OnceLock::new();
    OUT.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("study_report_quick");
        let _ = std::fs::remove_dir_all(&dir);
        let o = crate::common::Spinedrr::new()
            .args(["study", "--quick", "--out"])
            .arg(&dir)
            .output();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        dir
    })
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn svg(file: &str) -> String {
    read(&quick_out().join("figures").join(file))
}

/// Elements named `tag` (SVG namespace) in `doc`.
fn count(doc: &roxmltree::Document, tag: &str) -> usize {
    doc.descendants().filter(|n| n.has_tag_name(tag)).count()
}

fn texts(doc: &roxmltree::Document) -> Vec<String> {
    doc.descendants()
        .filter(|n| n.has_tag_name("text"))
        .map(|n| n.text().unwrap_or("").trim().to_string())
        .collect()
}

#[test]
fn every_figure_has_an_svg_twin_that_parses_and_has_real_text() {
    let figs = quick_out().join("figures");
    let mut n = 0;
    for e in std::fs::read_dir(&figs).expect("figures") {
        let p = e.expect("entry").path();
        if p.extension().is_some_and(|x| x == "svg") {
            let s = read(&p);
            let doc =
                roxmltree::Document::parse(&s).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            assert!(count(&doc, "text") > 3, "{}", p.display());
            assert!(p.with_extension("png").is_file(), "{}", p.display());
            n += 1;
        }
    }
    assert!(n >= 15, "{n} SVGs");
}

/// Text stays legible on the page: every figure's text is at least 12 px high at the report's preview
/// width (tick labels, legends, landmark numbers and keys included).
#[test]
fn every_figure_keeps_its_text_legible_at_the_page_width() {
    assert!(crate::common::assert_figures_legible(&quick_out().join("figures")) >= 15);
}

/// Titles, legends and labels stay inside the canvas: every drawn figure has a blank border.
#[test]
fn every_figure_keeps_its_titles_inside_the_canvas() {
    assert!(crate::common::assert_figures_inside_canvas(&quick_out().join("figures")) >= 15);
}

/// The Setup draws each view to scale, and the outline it draws is where the target really is: the
/// outline's vertices (depth z, offset y in the camera frame) projected through the sidecar's K,
/// v = cy + fy·y/z, span the same rows as the target's rendered reference silhouette (an extreme of
/// y/z over a convex outline lies at a vertex), to within a pixel.
#[test]
fn the_setup_drawing_places_each_target_where_its_drr_shows_it() {
    let report = crate::common::read_report(quick_out());
    let fig = report.find("![Each view drawn to scale](figures/setup_geometry.png)");
    let findings = report.find("## Findings").expect("findings");
    assert!(fig.is_some_and(|f| f < findings), "the drawing is in Setup");
    assert!(quick_out().join("figures/setup_geometry.svg").is_file());
    let refs = quick_out().join("references");
    let mut checked = 0;
    for e in std::fs::read_dir(&refs).expect("references") {
        let p = e.expect("entry").path();
        let name = p.file_name().unwrap().to_string_lossy().to_string();
        if !name.ends_with(".tiff") || name.contains("absdiff") {
            continue;
        }
        let side: serde_json::Value =
            serde_json::from_str(&read(&p.with_extension("json"))).expect("sidecar");
        let (fy, cy) = (
            side["K"][1][1].as_f64().unwrap(),
            side["K"][1][2].as_f64().unwrap(),
        );
        let outline = side["details"]["outline_depth_v_mm"]
            .as_array()
            .unwrap_or_else(|| panic!("{name}: no outline"));
        assert!(outline.len() >= 3, "{name}");
        let vs: Vec<f64> = outline
            .iter()
            .map(|p| cy + fy * p[1].as_f64().unwrap() / p[0].as_f64().unwrap())
            .collect();
        let img = spinedrr::io::read_tiff_f32(&p).expect("tiff");
        let rows: Vec<u32> = (0..img.height)
            .filter(|&v| (0..img.width).any(|u| img.get(u, v) > 0.0))
            .collect();
        let (lo, hi) = (*rows.first().unwrap(), *rows.last().unwrap());
        let (vlo, vhi) = (
            vs.iter().copied().fold(f64::MAX, f64::min),
            vs.iter().copied().fold(f64::MIN, f64::max),
        );
        assert!(
            (vlo - f64::from(lo)).abs() <= 1.0 && (vhi - f64::from(hi)).abs() <= 1.0,
            "{name}: outline rows {vlo:.1}–{vhi:.1}, silhouette rows {lo}–{hi}"
        );
        checked += 1;
    }
    assert!(checked >= 2, "{checked}");
}

/// The heatmap panel of L1: views × heatmap Δf panes (4 rasters + the colour bar), each pane titled,
/// the colour bar labelled with the images' units.
#[test]
fn the_heatmap_panel_has_four_titled_panes_and_a_unit_colour_bar() {
    let s = svg("heatmap_panel_L1.svg");
    let doc = roxmltree::Document::parse(&s).expect("xml");
    assert_eq!(count(&doc, "image"), 5);
    let t = texts(&doc);
    for pane in [
        "AP, Δf = 100 px",
        "AP, Δf = 500 px",
        "LAT, Δf = 100 px",
        "LAT, Δf = 500 px",
    ] {
        assert_eq!(t.iter().filter(|x| *x == pane).count(), 1, "{pane}: {t:?}");
    }
    assert!(t.iter().any(|x| x.contains("line integral")), "{t:?}");
    let png = image::open(quick_out().join("figures/heatmap_panel_L1.png")).expect("png");
    let (w, h) = (png.width(), png.height());
    let (sw, sh) = {
        let root = doc.root_element();
        let a = |k| root.attribute(k).and_then(|v| v.parse::<u32>().ok());
        (a("width").expect("width"), a("height").expect("height"))
    };
    assert_eq!((w, h), (sw, sh));
}

/// Landmarks AP beside LAT: two DRR backgrounds, every landmark of L1 numbered in each view, each
/// number once in the key with its name, a scale bar in each view (the views share one window size:
/// `overlay_draw`'s unit test).
#[test]
fn the_landmark_figure_shows_ap_beside_lat_with_every_landmark() {
    let tables = StudyTables::load(quick_out()).expect("tables");
    let names: std::collections::BTreeSet<&str> = tables
        .landmarks
        .iter()
        .filter(|r| r.target == "L1")
        .map(|r| r.landmark.as_str())
        .collect();
    let s = svg("landmarks_L1.svg");
    let doc = roxmltree::Document::parse(&s).expect("xml");
    assert_eq!(count(&doc, "image"), 2);
    let t = texts(&doc);
    for (i, n) in names.iter().enumerate() {
        // Names are keyed in sorted order, numbered from 1.
        assert_eq!(t.iter().filter(|x| x == n).count(), 1, "{n}: {t:?}");
        let number = (i + 1).to_string();
        assert_eq!(
            t.iter().filter(|x| **x == number).count(),
            3,
            "{number}: once in the key, once per view"
        );
    }
    assert!(
        t.iter().any(|x| x.starts_with("L1 AP:")) && t.iter().any(|x| x.starts_with("L1 LAT:"))
    );
    assert_eq!(
        t.iter()
            .filter(|x| x.ends_with("mm at the detector"))
            .count(),
        2
    );
}

/// The registration figure plots one marker per summary cell of Kabsch and direct AP+LAT in each of
/// its rotation and translation panels, and the paper's ranges as four bands.
#[test]
fn the_registration_figure_holds_every_cell_and_the_paper_bands() {
    let tables = StudyTables::load(quick_out()).expect("tables");
    let cells = tables
        .registration_summary
        .iter()
        .filter(|r| {
            r.target == "L1"
                && matches!(
                    r.method,
                    RegistrationMethod::Kabsch | RegistrationMethod::DirectApLat
                )
        })
        .count();
    assert!(cells > 0);
    let s = svg("registration_paper_L1.svg");
    let doc = roxmltree::Document::parse(&s).expect("xml");
    assert_eq!(count(&doc, "circle"), 2 * cells);
    let bands = doc
        .descendants()
        .filter(|n| n.has_tag_name("rect") && n.attribute("opacity") == Some("0.18"))
        .count();
    assert_eq!(bands, 4);
    // Dice/IoU: a min–max band per view in the focal panels (the quick grid's joint family has one Δf:
    // no band), and the paper's LAT values at Δf 100 and 500 as triangles in all four panels.
    let s = svg("silhouette_overlap.svg");
    let doc = roxmltree::Document::parse(&s).expect("xml");
    let polygons = |opacity: &str| {
        doc.descendants()
            .filter(|n| n.has_tag_name("polygon") && n.attribute("opacity") == Some(opacity))
            .count()
    };
    assert_eq!(polygons("0.2"), 2 * 2);
    assert_eq!(polygons("1"), 2 * 4);
    let t = texts(&doc);
    assert!(
        t.iter().any(|x| x == "AP mean over levels")
            && t.iter().any(|x| x == "LAT mean over levels")
    );
}

/// `\begin`/`\end` balance in order, one `\\` line per row between `\midrule` and `\bottomrule`.
fn check_tex(tex: &str) -> usize {
    let mut stack = Vec::new();
    for part in tex.split("\\begin{").skip(1) {
        stack.push(part.split('}').next().expect("env").to_string());
    }
    let ends: Vec<&str> = tex
        .split("\\end{")
        .skip(1)
        .map(|p| p.split('}').next().expect("env"))
        .collect();
    let mut expect = stack.clone();
    expect.reverse();
    assert_eq!(ends, expect, "environments of\n{tex}");
    assert!(tex.contains("\\toprule") && tex.contains("\\midrule") && tex.contains("\\bottomrule"));
    let body: Vec<&str> = tex
        .lines()
        .skip_while(|l| !l.contains("\\midrule"))
        .skip(1)
        .take_while(|l| !l.contains("\\bottomrule"))
        .collect();
    let cols = tex
        .lines()
        .find_map(|l| l.trim().strip_prefix("\\begin{tabular}{"))
        .map(|c| c.trim_end_matches('}').len())
        .expect("tabular");
    for l in &body {
        assert!(l.trim_end().ends_with("\\\\"), "{l}");
        let cells = l.split(" & ").count();
        assert_eq!(cells, cols, "{l}");
        // No unescaped specials in a cell.
        assert!(!l.replace("\\_", "").contains('_'), "{l}");
    }
    body.len()
}

#[test]
fn the_latex_tables_are_well_formed_with_the_right_rows() {
    let tables = StudyTables::load(quick_out()).expect("tables");
    let dir = quick_out().join("tables");
    let landmarks: std::collections::BTreeSet<&str> = tables
        .landmarks
        .iter()
        .filter(|r| r.target == "L1")
        .map(|r| r.landmark.as_str())
        .collect();
    assert_eq!(
        check_tex(&read(&dir.join("landmark_shift.tex"))),
        landmarks.len()
    );
    // Kabsch and direct AP+LAT, rotation and translation.
    assert_eq!(check_tex(&read(&dir.join("registration_ranges.tex"))), 4);
    // LAT Dice and IoU × Δf {100, 500} × {joint, focal}, and the AP Dice minimum.
    assert_eq!(check_tex(&read(&dir.join("silhouette_overlap.tex"))), 9);
}

/// The quick study's page stays small: previews, not full-resolution figures, are inlined.
#[test]
fn the_quick_report_is_small_and_self_contained() {
    let html = std::fs::metadata(quick_out().join("report.html")).expect("html");
    assert!(
        html.len() < 2_500_000,
        "report.html is {} bytes",
        html.len()
    );
    let md = crate::common::read_report(quick_out());
    for f in [
        "heatmap_panel_L1.png",
        "landmarks_L1.png",
        "silhouette_overlap.png",
        "registration_paper_L1.png",
    ] {
        assert!(md.contains(&format!("](figures/{f})")), "{f}");
        assert!(quick_out().join("figures").join(f).is_file(), "{f}");
    }
    // The products list names every table the first run wrote, the LaTeX ones included.
    for e in std::fs::read_dir(quick_out().join("tables")).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        assert!(
            md.contains(&format!("](tables/{name})")),
            "{name} not listed"
        );
    }
}

/// The provenance line names this build's version and commit (as git says), the BLAKE3 of the
/// `study.toml` beside the report, a date of this run and a thread count.
#[test]
fn the_report_states_its_provenance() {
    let md = crate::common::read_report(quick_out());
    let line = md
        .lines()
        .find(|l| l.starts_with(spinedrr::study::report::PROVENANCE))
        .expect("no provenance line");
    assert!(
        line.contains(&format!("spinedrr {}", env!("CARGO_PKG_VERSION"))),
        "{line}"
    );
    let git = |args: &[&str]| {
        Command::new("git")
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    // The commit the binary was built from (HEAD, unless a commit was made since the build); a checkout
    // whose build inputs are clean (CI's) was built clean, so it must not be called `-dirty`. The inputs
    // are build.rs's `INPUTS` (its `-dirty` mark covers those paths, not a test or the README), read
    // from its source here.
    let head = git(&["rev-parse", "HEAD"]).unwrap_or_else(|| "unknown".to_string());
    assert!(
        line.contains(&format!("git commit `{head}`"))
            || line.contains(&format!("git commit `{head}-dirty`")),
        "{line} vs HEAD {head}"
    );
    let script = read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("build.rs"));
    let list = script
        .split("const INPUTS")
        .nth(1)
        .and_then(|rest| rest.split("];").next())
        .expect("build.rs declares INPUTS");
    let inputs: Vec<&str> = list.split('"').skip(1).step_by(2).collect();
    assert!(
        inputs.contains(&"src") && inputs.contains(&"core/src"),
        "INPUTS as read from build.rs: {inputs:?}"
    );
    let mut status = vec!["status", "--porcelain", "--untracked-files=no", "--"];
    status.extend(&inputs);
    let clean = git(&status).is_some_and(|s| s.is_empty());
    assert!(!(clean && line.contains("-dirty`")), "{line}");
    let toml = std::fs::read(quick_out().join("study.toml")).unwrap();
    let hash = blake3::hash(&toml).to_hex().to_string();
    assert!(line.contains(&format!("(BLAKE3 `{hash}`)")), "{line}");
    // The built-in phantom and geometry read no file, and the line says so.
    assert!(
        line.contains(&format!(
            "(BLAKE3 `{hash}`) and no input file (built-in anatomy and geometry) on "
        )),
        "{line}"
    );
    assert!(!quick_out().join("inputs.csv").exists());
    let date = line
        .split(" on ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .unwrap();
    let when = humantime::parse_rfc3339(date).unwrap_or_else(|e| panic!("{date}: {e}"));
    let age = std::time::SystemTime::now().duration_since(when).unwrap();
    assert!(age.as_secs() < 6 * 3600, "{date} is not this run's date");
    let threads: usize = line
        .split(" with ")
        .nth(1)
        .unwrap()
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(threads >= 1, "{line}");
}

/// *Setup* states the built-in geometry's numbers (its comments: magnification 1.35 AP, 1.5 LAT; SDD
/// 1350 mm; 0.3 mm pixels, here binned 2× to 0.6 mm and fx 2250 px) and every target and view.
#[test]
fn the_setup_states_the_geometry_before_the_findings() {
    let md = crate::common::read_report(quick_out());
    let (setup, findings) = (
        md.find("## Setup").unwrap(),
        md.find("## Findings").unwrap(),
    );
    assert!(setup < findings);
    let view = |v: &str| {
        let l = md
            .lines()
            .find(|l| l.starts_with(&format!("| {v} | (")))
            .unwrap();
        l.split('|')
            .map(|c| c.trim().to_string())
            .collect::<Vec<_>>()
    };
    let (ap, lat) = (view("AP"), view("LAT"));
    assert_eq!(
        (ap[4].as_str(), ap[5].as_str(), ap[6].as_str()),
        ("1000", "1350", "1.350")
    );
    assert_eq!(
        (lat[4].as_str(), lat[5].as_str(), lat[6].as_str()),
        ("900", "1350", "1.500")
    );
    assert_eq!(ap[7], "0.6 × 0.6");
    assert!(
        ap[10].starts_with("2250.0, 2250.0, 255.5, 255.5"),
        "{}",
        ap[10]
    );
    for v in ["AP", "LAT"] {
        assert!(md.contains(&format!("| L1 | {v} | (")), "no L1 {v} row");
    }
}

/// The default geometry keeps the L1–L5 segment whole on the detector in both views' reference DRRs
/// (at the LAT magnification of 1.8 its ~174 mm would span ~1 040 px of the detector's 1 024): the
/// Setup says "whole" for both, and the segment's placement rule is stated. The default C-arm and
/// anatomy on a 4× binned detector (the same field of view in mm), projection at Δf = 25 px of it
/// (100 px at full resolution).
#[test]
fn the_default_segment_is_whole_in_both_views() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("study.toml");
    std::fs::write(
        &cfg,
        "experiments = [\"projection\"]\nheatmaps_df_px = []\n[anatomy]\nvoxel_mm = 1.5\n\
[geometry]\nbinning = 4\n[perturbations]\ndf_px = [25.0]\npiercing_px = [0.0]\nskew_px = []\n\
pixel_scale = []\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_spinedrr"))
        .env("SPINEDRR_CACHE_DIR", crate::common::MESH_CACHE)
        .args(["study", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = crate::common::read_report(&out);
    for v in ["AP", "LAT"] {
        let row = md
            .lines()
            .find(|l| l.starts_with(&format!("| segment | {v} |")))
            .unwrap_or_else(|| panic!("no Setup row for the segment in {v}"));
        assert!(row.ends_with("| whole |"), "{row}");
    }
    assert!(
        md.contains("is moved along z so that its levels' mean body-centre height"),
        "{md}"
    );
}

/// The browser: Debian's `chromium` (scripts/install-deps.sh installs it). A missing browser fails.
fn chromium() -> PathBuf {
    let found = ["chromium", "chromium-browser"].iter().find_map(|b| {
        std::env::var_os("PATH").and_then(|paths| {
            std::env::split_paths(&paths)
                .map(|p| p.join(b))
                .find(|p| p.is_file())
        })
    });
    found.expect("no chromium on PATH: run scripts/install-deps.sh (installs Debian's chromium)")
}

fn headless(profile: &Path) -> Command {
    let mut c = Command::new(chromium());
    c.args(["--headless", "--no-sandbox", "--disable-gpu"])
        .arg(format!("--user-data-dir={}", profile.display()));
    c
}

/// What the page reports about itself after load, appended as `<pre id="browser-check">`.
const CHECK: &str = r##"<script>
window.addEventListener("load", function () {
  var imgs = Array.from(document.images);
  var broken = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); });
  var links = Array.from(document.querySelectorAll('a[href^="#"]'));
  var dangling = links.filter(function (a) {
    return !document.getElementById(decodeURIComponent(a.getAttribute("href").slice(1)));
  });
  // Nothing may reach past the body's content box (a wide table scrolls inside its own box), and no
  // figure is drawn smaller than its preview (whose text is sized for the page's display width).
  var body = document.body.getBoundingClientRect();
  var pad = parseFloat(getComputedStyle(document.body).paddingRight);
  var boxes = Array.from(document.querySelectorAll("body > *, .wide, table, figure, img, p"));
  var overflow = boxes.filter(function (e) {
    return e.closest(".wide") !== e.parentElement && !e.closest(".wide table") &&
      e.getBoundingClientRect().right > body.right - pad + 1;
  });
  var shrunk = imgs.filter(function (i) { return i.width < 0.95 * i.naturalWidth; });
  var pre = document.createElement("pre");
  pre.id = "browser-check";
  pre.textContent = "images=" + imgs.length + " broken=" + broken.length + " links=" +
    links.length + " dangling=" + dangling.length + " nav=" +
    document.querySelectorAll("nav a").length + " overflow=" + overflow.length + " page_scrolls=" +
    (document.documentElement.scrollWidth > document.documentElement.clientWidth ? 1 : 0) +
    " shrunk=" + shrunk.length;
  document.body.appendChild(pre);
});
</script>"##;

#[test]
fn report_html_renders_in_headless_chromium() {
    let out = quick_out();
    let html = read(&out.join("report.html"));
    let embedded = html.matches("<img ").count();
    // The page itself, plus the check script, beside it (same relative links).
    let page = out.join("report_check.html");
    std::fs::write(&page, html.replace("</body>", &format!("{CHECK}</body>"))).expect("page");
    let profile = tempfile::tempdir().expect("profile");
    let url = format!("file://{}", page.display());
    let dom = headless(profile.path())
        .args([
            "--virtual-time-budget=10000",
            "--window-size=1280,2000",
            "--dump-dom",
            &url,
        ])
        .output()
        .expect("running chromium");
    let dom = String::from_utf8_lossy(&dom.stdout);
    let check = dom
        .split("<pre id=\"browser-check\">")
        .nth(1)
        .and_then(|s| s.split("</pre>").next())
        .unwrap_or_else(|| {
            panic!(
                "the check did not run; DOM starts {:?}",
                &dom[..dom.len().min(300)]
            )
        });
    let field = |k: &str| -> usize {
        check
            .split_whitespace()
            .find_map(|kv| kv.strip_prefix(&format!("{k}=")))
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{k} in {check}"))
    };
    assert_eq!(field("images"), embedded, "{check}");
    assert!(embedded >= 4, "{check}");
    assert_eq!(field("broken"), 0, "{check}");
    assert!(
        field("nav") >= 5 && field("links") >= field("nav"),
        "{check}"
    );
    assert_eq!(field("dangling"), 0, "{check}");
    assert_eq!(field("overflow"), 0, "{check}");
    assert_eq!(field("page_scrolls"), 0, "{check}");
    assert_eq!(field("shrunk"), 0, "{check}");

    let shot = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report_screenshot.png");
    let _ = std::fs::remove_file(&shot);
    let profile = tempfile::tempdir().expect("profile");
    let url = format!("file://{}", out.join("report.html").display());
    let o = headless(profile.path())
        .arg(format!("--screenshot={}", shot.display()))
        .args([
            "--window-size=1280,7000",
            "--virtual-time-budget=5000",
            &url,
        ])
        .output()
        .expect("running chromium");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&shot).expect("screenshot").to_rgb8();
    assert_eq!((img.width(), img.height()), (1280, 7000));
    // Not blank: the figures' colours are on the page.
    let distinct: std::collections::BTreeSet<[u8; 3]> =
        img.pixels().step_by(97).map(|p| p.0).collect();
    assert!(distinct.len() > 50, "{} colours", distinct.len());
}

/// The Setup's sentences about the geometry follow from its own views table: the magnification ratio and
/// the aims' distances from the detector (SDD − source–aim), which of the paper's two statements about
/// its LAT vertebra hold, and how far the level's body centre (the world origin) is from each aim.
#[test]
fn the_setup_prose_follows_from_its_views_table() {
    let md = crate::common::read_report(quick_out());
    // | view | source | aim | source–aim | SDD | magnification | …
    let row = |view: &str| -> (String, f64, f64) {
        let line = md
            .lines()
            .find(|l| l.starts_with(&format!("| {view} | (")))
            .unwrap_or_else(|| panic!("no {view} row in the Setup's views table"));
        let cells: Vec<&str> = line.split(" | ").collect();
        (
            cells[2].to_string(),
            cells[3].parse().unwrap(),
            cells[4].parse().unwrap(),
        )
    };
    let ((_, ap_src, ap_sdd), (lat_aim, lat_src, lat_sdd)) = (row("AP"), row("LAT"));
    let ratio = (lat_sdd / lat_src) / (ap_sdd / ap_src);
    assert!(ratio > 1.0, "the built-in LAT magnifies more");
    let expected = format!(
        "LAT magnifies its aim {ratio:.2} times as much as AP: in AP the aim is {ap_src:.0} mm from the \
         source and {:.0} mm from the detector, in LAT the aim is {lat_src:.0} mm from the source and \
         {:.0} mm from the detector.",
        ap_sdd - ap_src,
        lat_sdd - lat_src
    );
    assert!(md.contains(&expected), "{expected}");
    // One SDD: LAT nearer the source is farther from the detector, so only "larger" holds.
    assert_eq!(ap_sdd, lat_sdd);
    assert!(
        md.contains("with one SDD these cannot both hold, and this geometry follows \"larger\".")
    );
    let aim: Vec<f64> = lat_aim
        .trim_matches(|c| c == '(' || c == ')')
        .split(", ")
        .map(|x| x.parse().unwrap())
        .collect();
    let off = (aim[0] * aim[0] + aim[1] * aim[1] + aim[2] * aim[2]).sqrt();
    let expected = format!(
        "Each single level's body centre sits at the world origin: on AP's central ray, {off:.1} mm from \
         LAT's aim {lat_aim}."
    );
    assert!(md.contains(&expected), "{expected}");
}

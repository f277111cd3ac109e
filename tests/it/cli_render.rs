//! End-to-end runs of `spinedrr render` and `spinedrr geometry`: outputs, sidecars and bad input.

use std::path::Path;

use glam::DVec3;
use spinedrr::anatomy::{TriMesh, write_mesh};
use spinedrr::io::{Sidecar, read_tiff_f32};

use crate::common::{spinedrr, stderr};

/// A small geometry so end-to-end renders stay quick.
fn small_geometry(dir: &Path, detector: &str) -> String {
    let path = dir.join("geom.toml");
    let text = format!(
        "[detector]\n{detector}\n\n[[view]]\nname = \"ap\"\nsource_mm = [0.0, -1000.0, 0.0]\ntarget_mm = [0.0, 0.0, 0.0]\n"
    );
    std::fs::write(&path, text).unwrap();
    path.to_string_lossy().into_owned()
}

const SMALL: &str = "width = 96\nheight = 80\npixel_spacing_mm = [1.2, 1.2]\nsdd_mm = 1350.0";

#[test]
fn renders_a_mesh_with_sidecar_preview_masks_and_depth() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("box.stl");
    write_mesh(
        &mesh,
        &TriMesh::cuboid(
            "box",
            DVec3::new(-10.0, -5.0, -8.0),
            DVec3::new(10.0, 5.0, 8.0),
        ),
    )
    .unwrap();
    let geom = small_geometry(dir.path(), SMALL);
    let out = dir.path().join("o/box.tiff");
    let o = spinedrr(&[
        "render",
        "--mesh",
        &format!("{}:0.5", mesh.display()),
        "--geometry",
        &geom,
        "--perturb",
        "df=300",
        "--masks",
        "--depth",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = read_tiff_f32(&out).unwrap();
    // The central ray crosses 10 mm of box (y from −5 to 5) with μ = 0.5.
    assert!((img.get(47, 39) - 5.0).abs() < 0.05, "{}", img.get(47, 39));
    let side = Sidecar::read(&out.with_extension("json")).unwrap();
    assert_eq!(side.perturbation_spec, "df=300");
    assert_eq!((side.width, side.height), (96, 80));
    assert!((side.k[0][0] - (1350.0 / 1.2 + 300.0)).abs() < 1e-9);
    for f in [
        "box.png",
        "box_mask.png",
        "box_mask.json",
        "box_mask_box.png",
        "box_depth.tiff",
        "box_depth.json",
    ] {
        assert!(dir.path().join("o").join(f).is_file(), "{f} missing");
    }
    let depth = read_tiff_f32(&dir.path().join("o/box_depth.tiff")).unwrap();
    assert!((depth.get(47, 39) - 995.0).abs() < 0.05);
}

#[test]
fn repeat_prints_timing_json() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("s.ply");
    write_mesh(&mesh, &TriMesh::icosphere("s", DVec3::ZERO, 10.0, 3)).unwrap();
    let geom = small_geometry(dir.path(), SMALL);
    let out = dir.path().join("s.tiff");
    let o = spinedrr(&[
        "render",
        "--mesh",
        mesh.to_str().unwrap(),
        "--geometry",
        &geom,
        "--backend",
        "bvh",
        "--repeat",
        "3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let line = stderr(&o)
        .lines()
        .find(|l| l.starts_with('{'))
        .map(str::to_owned)
        .expect("a JSON line");
    let v: serde_json::Value = serde_json::from_str(&line).unwrap();
    for key in [
        "median_ms",
        "min_ms",
        "rays_per_s",
        "hits_per_s",
        "bvh_build_ms",
        "rays_repaired",
    ] {
        assert!(v.get(key).is_some(), "{key} missing in {line}");
    }
    assert_eq!(v["backend"], "bvh");
}

#[test]
fn open_mesh_warns_and_still_renders() {
    let dir = tempfile::tempdir().unwrap();
    let mut m = TriMesh::cuboid("open", DVec3::splat(-5.0), DVec3::splat(5.0));
    m.triangles.truncate(10);
    let mesh = dir.path().join("open.obj");
    write_mesh(&mesh, &m).unwrap();
    let geom = small_geometry(dir.path(), SMALL);
    let out = dir.path().join("open.tiff");
    let o = spinedrr(&[
        "render",
        "--mesh",
        mesh.to_str().unwrap(),
        "--geometry",
        &geom,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("not closed"), "{}", stderr(&o));
    assert!(out.is_file());
}

fn assert_fails(args: &[&str], needle: &str) {
    let o = spinedrr(args);
    let err = stderr(&o);
    assert!(!o.status.success(), "{args:?} should fail");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    assert!(
        err.contains(needle),
        "{args:?}: expected '{needle}' in: {err}"
    );
}

#[test]
fn bad_input_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("x.tiff");
    let out = out.to_str().unwrap();
    let good = d.join("good.stl");
    write_mesh(
        &good,
        &TriMesh::cuboid("b", DVec3::splat(-5.0), DVec3::splat(5.0)),
    )
    .unwrap();
    let good = good.to_str().unwrap();
    let geom = small_geometry(d, SMALL);

    assert_fails(
        &["render", "--mesh", "/nonexistent/v.stl", "--out", out],
        "/nonexistent/v.stl",
    );
    let garbage = d.join("garbage.stl");
    std::fs::write(&garbage, b"this is not a mesh at all").unwrap();
    assert_fails(
        &["render", "--mesh", garbage.to_str().unwrap(), "--out", out],
        "garbage.stl",
    );
    let empty = d.join("empty.obj");
    std::fs::write(&empty, b"# nothing\n").unwrap();
    assert_fails(
        &["render", "--mesh", empty.to_str().unwrap(), "--out", out],
        "empty.obj",
    );
    assert_fails(
        &[
            "render",
            "--mesh",
            good,
            "--perturb",
            "zoom=2",
            "--geometry",
            &geom,
            "--out",
            out,
        ],
        "zoom",
    );
    assert_fails(
        &[
            "render",
            "--mesh",
            good,
            "--view",
            "oblique",
            "--geometry",
            &geom,
            "--out",
            out,
        ],
        "oblique",
    );
    assert_fails(
        &[
            "render",
            "--mesh",
            good,
            "--perturb",
            "df=-5000",
            "--geometry",
            &geom,
            "--out",
            out,
        ],
        "focal",
    );
    let nan = small_geometry(d, &SMALL.replace("sdd_mm = 1350.0", "sdd_mm = nan"));
    assert_fails(
        &["render", "--mesh", good, "--geometry", &nan, "--out", out],
        "sdd_mm",
    );
    let zero_fx = small_geometry(
        d,
        "width = 64\nheight = 64\npixel_spacing_mm = [1.0, 1.0]\nsdd_mm = 1000.0\nK = [[0.0, 0.0, 32.0], [0.0, 1000.0, 32.0], [0.0, 0.0, 1.0]]",
    );
    assert_fails(
        &[
            "render",
            "--mesh",
            good,
            "--geometry",
            &zero_fx,
            "--out",
            out,
        ],
        "focal",
    );
    let empty_det = small_geometry(d, &SMALL.replace("width = 96", "width = 0"));
    assert_fails(
        &[
            "render",
            "--mesh",
            good,
            "--geometry",
            &empty_det,
            "--out",
            out,
        ],
        "width",
    );
    let huge = small_geometry(d, &SMALL.replace("width = 96", "width = 200000"));
    assert_fails(
        &["render", "--mesh", good, "--geometry", &huge, "--out", out],
        "width",
    );
    assert_fails(
        &[
            "render",
            "--mesh",
            good,
            "--geometry",
            &geom,
            "--out",
            d.join("x.png").to_str().unwrap(),
        ],
        ".tiff",
    );
    assert_fails(&["render", "--phantom", "L7", "--out", out], "L7");
    assert!(
        !Path::new(out).exists(),
        "a failed render must not leave an output"
    );
}

#[test]
fn geometry_prints_a_file_that_loads_back() {
    let o = spinedrr(&["geometry"]);
    assert!(o.status.success());
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("g.toml");
    std::fs::write(&p, &o.stdout).unwrap();
    let c = spinedrr(&["geometry", "--check", p.to_str().unwrap()]);
    assert!(c.status.success(), "{}", stderr(&c));
    assert!(String::from_utf8_lossy(&c.stdout).contains("view lat"));
}

#[test]
fn the_built_in_segment_renders_in_both_views() {
    // Unpaired rays of the L1–L5 phantom once left negative pixels, which the negative-image check
    // (rightly) refused: an unpaired ray's sum is kept non-negative.
    let dir = tempfile::tempdir().unwrap();
    for view in ["ap", "lat"] {
        let out = dir.path().join(format!("{view}.tiff"));
        let o = spinedrr(&[
            "render",
            "--phantom",
            "L1-L5",
            "--view",
            view,
            "--out",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            o.status.success() && !err.contains("panicked"),
            "{view}: {err}"
        );
        let img = spinedrr::io::read_tiff_f32(&out).unwrap();
        assert!(
            img.data.iter().all(|&x| x >= 0.0),
            "{view}: a negative pixel"
        );
        assert!(
            img.data.iter().any(|&x| x > 1.0),
            "{view}: the segment is on the detector"
        );
    }
}

//! Mesh file round trips (STL binary/ASCII, OBJ, PLY ASCII/binary) and errors naming the file.

use std::path::Path;

use glam::{DMat4, DVec3};
use spinedrr::anatomy::{
    MeshFormat, ScalarGrid, Structure, TriMesh, extract_isosurface, read_mesh, write_mesh,
    write_mesh_as,
};

/// A closed, labelled test mesh with many shared vertices (a marching-tetrahedra ellipsoid).
fn sample_mesh() -> TriMesh {
    let f = |p: DVec3| (p / DVec3::new(9.0, 6.0, 4.0)).length() - 1.0;
    let affine = DMat4::from_translation(DVec3::new(-10.3, -7.1, -5.2))
        * DMat4::from_scale(DVec3::splat(0.7));
    let g = ScalarGrid::from_fn([31, 22, 17], affine, f).unwrap();
    let mut m = extract_isosurface(&g, 0.0).unwrap();
    m.name = "ellipsoid".into();
    m.labels = (0..m.triangles.len())
        .map(|i| {
            if m.corners(i)[0].z > 0.0 {
                Structure::Spinous as u8
            } else {
                Structure::Body as u8
            }
        })
        .collect();
    m
}

fn f32_round(v: DVec3) -> DVec3 {
    v.as_vec3().as_dvec3()
}

/// Triangle-by-triangle comparison of corner positions after `map` (files keep triangle order).
fn assert_same_triangles(a: &TriMesh, b: &TriMesh, map: impl Fn(DVec3) -> DVec3, what: &str) {
    assert_eq!(a.triangles.len(), b.triangles.len(), "{what}");
    for i in 0..a.triangles.len() {
        assert_eq!(a.corners(i).map(&map), b.corners(i), "{what}: triangle {i}");
    }
    let chk = b.check();
    assert!(chk.is_watertight(), "{what}: {chk:?}");
    assert_eq!(
        b.vertices.len(),
        a.vertices.len(),
        "{what}: welded vertex count"
    );
}

#[test]
fn stl_binary_and_ascii_round_trip_and_weld() {
    let m = sample_mesh();
    let dir = tempfile::tempdir().unwrap();
    for (format, name) in [
        (MeshFormat::StlBinary, "m.stl"),
        (MeshFormat::StlAscii, "a.stl"),
    ] {
        let p = dir.path().join(name);
        write_mesh_as(&p, &m, format).unwrap();
        let back = read_mesh(&p).unwrap();
        assert_same_triangles(&m, &back, f32_round, name);
        if format == MeshFormat::StlBinary {
            assert_eq!(back.labels, m.labels, "labels ride in the attribute word");
        }
        assert!((back.volume() / m.volume() - 1.0).abs() < 1e-5);
    }
}

#[test]
fn obj_and_ply_round_trip_exactly_with_labels() {
    let m = sample_mesh();
    let dir = tempfile::tempdir().unwrap();
    for (format, name) in [
        (MeshFormat::Obj, "m.obj"),
        (MeshFormat::PlyAscii, "a.ply"),
        (MeshFormat::PlyBinary, "b.ply"),
    ] {
        let p = dir.path().join(name);
        write_mesh_as(&p, &m, format).unwrap();
        let back = read_mesh(&p).unwrap();
        assert_eq!(back.vertices, m.vertices, "{name}");
        assert_eq!(back.triangles, m.triangles, "{name}");
        assert_eq!(back.labels, m.labels, "{name}");
        assert!(back.check().is_watertight());
    }
    // The extension picks the default format.
    let p = dir.path().join("d.ply");
    write_mesh(&p, &m).unwrap();
    assert!(
        std::fs::read(&p)
            .unwrap()
            .windows(20)
            .any(|w| w == b"binary_little_endian")
    );
}

#[test]
fn foreign_files_with_polygons_and_float_ply_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("quad.obj");
    std::fs::write(
        &obj,
        "# cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
         f 1/1 4/1 3/1 2/1\nf 5 6 7 8\nf 1 2 6 5\nf 4 8 7 3\nf -8 -4 -1\nf 1 -1 -5\nf 2 3 7 6\n",
    )
    .unwrap();
    let m = read_mesh(&obj).unwrap();
    assert_eq!(m.triangles.len(), 12);
    assert!(m.check().is_watertight(), "{:?}", m.check());
    assert!((m.volume() - 1.0).abs() < 1e-12);
    let ply = dir.path().join("tri.ply");
    std::fs::write(
        &ply,
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n\
         0 0 0 255\n1 0 0 0\n1 1 0 0\n0 1 0 0\n4 0 1 2 3\n",
    )
    .unwrap();
    let m = read_mesh(&ply).unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert!(m.labels.is_empty());
}

fn err_of(path: &Path) -> String {
    let e = read_mesh(path).unwrap_err().to_string();
    assert!(
        e.contains(&path.display().to_string()),
        "error does not name the file: {e}"
    );
    e
}

#[test]
fn bad_files_give_errors_naming_the_path() {
    let m = sample_mesh();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    err_of(&d.join("missing.stl"));
    // Truncated binary STL.
    let stl = d.join("cut.stl");
    write_mesh(&stl, &m).unwrap();
    let bytes = std::fs::read(&stl).unwrap();
    std::fs::write(&stl, &bytes[..bytes.len() - 30]).unwrap();
    assert!(err_of(&stl).contains("truncated"));
    // Truncated ASCII STL.
    let ascii = d.join("cut_ascii.stl");
    write_mesh_as(&ascii, &m, MeshFormat::StlAscii).unwrap();
    let text = std::fs::read_to_string(&ascii).unwrap();
    std::fs::write(&ascii, &text[..text.len() / 2]).unwrap();
    err_of(&ascii);
    // Zero triangles.
    let empty = d.join("empty.stl");
    std::fs::write(&empty, "solid e\nendsolid e\n").unwrap();
    assert!(err_of(&empty).contains("no triangles"));
    // Wrong format behind a mesh extension.
    let junk = d.join("junk.ply");
    std::fs::write(&junk, "this is not a mesh").unwrap();
    err_of(&junk);
    let junk_stl = d.join("junk.stl");
    std::fs::write(&junk_stl, [7u8; 200]).unwrap();
    err_of(&junk_stl);
    // Truncated binary PLY.
    let ply = d.join("cut.ply");
    write_mesh(&ply, &m).unwrap();
    let bytes = std::fs::read(&ply).unwrap();
    std::fs::write(&ply, &bytes[..bytes.len() - 7]).unwrap();
    assert!(err_of(&ply).contains("truncated"));
    // OBJ face beyond the vertices.
    let obj = d.join("bad.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n").unwrap();
    assert!(err_of(&obj).contains("line 4"));
    // Unknown extension.
    let txt = d.join("mesh.txt");
    std::fs::write(&txt, "x").unwrap();
    err_of(&txt);
}

//! Hostile input files through the real binary: every one is refused with a non-zero exit, no panic,
//! and a message naming the file and the field or value at fault — and nothing is allocated from a
//! size a header merely claims (each case runs in well under a second).

use std::path::{Path, PathBuf};

use glam::DMat4;
use spinedrr::anatomy::ct::{CtVolume, write_ct};

use crate::common::run;

/// Runs `spinedrr render ARGS --out DIR/out.tiff`; asserts failure without a panic; returns stderr.
fn refused(dir: &Path, args: &[&str]) -> String {
    let out = dir.join("out.tiff").display().to_string();
    let mut all = vec!["render"];
    all.extend_from_slice(args);
    all.extend(["--out", &out]);
    let (ok, err) = run(&all);
    assert!(!ok, "{args:?} must fail");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    assert!(!Path::new(&out).exists(), "{args:?} wrote an image");
    err
}

/// A valid little-endian float32 NIfTI file (vox_offset 352) of a 6×5×4 volume.
fn good_nifti(dir: &Path, name: &str) -> (PathBuf, Vec<u8>) {
    let p = dir.join(name);
    let ct = CtVolume::filled([6, 5, 4], 100.0, DMat4::IDENTITY).unwrap();
    write_ct(&p, &ct).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    (p, bytes)
}

/// `bytes` with `patch` written at `offset`, saved as `name`.
fn patched(dir: &Path, name: &str, bytes: &[u8], offset: usize, patch: &[u8]) -> String {
    let mut b = bytes.to_vec();
    b[offset..offset + patch.len()].copy_from_slice(patch);
    let p = dir.join(name);
    std::fs::write(&p, b).unwrap();
    p.display().to_string()
}

#[test]
fn nifti_headers_are_refused_naming_the_field_and_the_value_as_stated() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (_, b) = good_nifti(d, "good.nii");
    let cases: Vec<(String, &str)> = vec![
        (
            patched(d, "off.nii", &b, 108, &1e30f32.to_le_bytes()),
            "vox_offset = 1",
        ),
        (
            patched(d, "neg.nii", &b, 108, &(-8f32).to_le_bytes()),
            "vox_offset = -8",
        ),
        (
            patched(d, "low.nii", &b, 108, &100f32.to_le_bytes()),
            "vox_offset = 100",
        ),
        (
            patched(d, "past.nii", &b, 108, &1e6f32.to_le_bytes()),
            "before the voxel data begins",
        ),
        (
            patched(d, "size.nii", &b, 0, &1000i32.to_le_bytes()),
            "sizeof_hdr = 1000",
        ),
        (
            patched(d, "neg_dim.nii", &b, 42, &(-5i16).to_le_bytes()),
            "dim[1] = -5",
        ),
        (
            patched(d, "nine.nii", &b, 40, &9i16.to_le_bytes()),
            "dim[0] = 9",
        ),
        (
            patched(d, "bitpix.nii", &b, 72, &8i16.to_le_bytes()),
            "bitpix = 8",
        ),
    ];
    for (file, expect) in &cases {
        let err = refused(d, &["--ct", file]);
        assert!(err.contains(file.as_str()), "must name {file}: {err}");
        assert!(err.contains(expect), "expected '{expect}' in: {err}");
    }
    // dim[0] = 9 is reported as the file states it, not byte-swapped (9 → 2304).
    assert!(!refused(d, &["--ct", &cases[6].0]).contains("2304"));
}

#[test]
fn nifti_dims_claiming_gigabytes_in_a_small_file_are_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (_, b) = good_nifti(d, "good.nii");
    // 30000³ voxels: more than the reader accepts at all.
    let mut huge = b.clone();
    for i in 1..=3 {
        huge[40 + 2 * i..42 + 2 * i].copy_from_slice(&30000i16.to_le_bytes());
    }
    let f = d.join("huge.nii");
    std::fs::write(&f, &huge).unwrap();
    let err = refused(d, &["--ct", &f.display().to_string()]);
    assert!(err.contains("huge.nii") && err.contains("voxels"), "{err}");
    // 1200³ float32 = 6.9 GB declared in a 832-byte file, plain and gzip: truncated, nothing reserved.
    let mut big = b.clone();
    for i in 1..=3 {
        big[40 + 2 * i..42 + 2 * i].copy_from_slice(&1200i16.to_le_bytes());
    }
    let f = d.join("big.nii");
    std::fs::write(&f, &big).unwrap();
    let gz = d.join("big.nii.gz");
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    std::io::Write::write_all(&mut enc, &big).unwrap();
    std::fs::write(&gz, enc.finish().unwrap()).unwrap();
    for f in [f, gz] {
        let name = f.display().to_string();
        let err = refused(d, &["--ct", &name]);
        assert!(err.contains(&name) && err.contains("truncated"), "{err}");
        assert!(err.contains(&(1200u64.pow(3) * 4).to_string()), "{err}");
    }
}

#[test]
fn non_finite_ct_voxels_are_refused_with_their_count_and_the_first() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut ct = CtVolume::filled([6, 5, 4], 100.0, DMat4::IDENTITY).unwrap();
    let first = ct.linear(2, 3, 1);
    ct.values[first] = f32::NAN;
    let last = ct.linear(5, 4, 3);
    ct.values[last] = f32::INFINITY;
    for name in ["nan.nii", "nan.nii.gz"] {
        let p = d.join(name);
        write_ct(&p, &ct).unwrap();
        let file = p.display().to_string();
        let err = refused(d, &["--ct", &file]);
        assert!(err.contains(&file), "{err}");
        assert!(err.contains("2 voxel(s) are not finite"), "{err}");
        assert!(
            err.contains(&format!("voxel {first} at (i, j, k) = (2, 3, 1)")),
            "{err}"
        );
    }
    // The same voxels scaled by scl_slope = 1e38 from finite values overflow to infinity: refused too.
    let mut ok = CtVolume::filled([6, 5, 4], 100.0, DMat4::IDENTITY).unwrap();
    ok.values[0] = 10.0;
    let p = d.join("scaled.nii");
    write_ct(&p, &ok).unwrap();
    let b = std::fs::read(&p).unwrap();
    let f = patched(d, "scaled.nii", &b, 112, &1e38f32.to_le_bytes());
    assert!(refused(d, &["--ct", &f]).contains("not finite"));
}

/// A binary little-endian PLY: `header` lines between the format line and `end_header`, then `body`.
fn ply(dir: &Path, name: &str, header: &str, body: &[u8]) -> String {
    let mut b = format!("ply\nformat binary_little_endian 1.0\n{header}end_header\n").into_bytes();
    b.extend_from_slice(body);
    let p = dir.join(name);
    std::fs::write(&p, b).unwrap();
    p.display().to_string()
}

#[test]
fn mesh_counts_beyond_the_file_are_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Binary STL claiming 2³² − 1 triangles in 100 bytes.
    let mut stl = vec![0u8; 100];
    stl[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    let f = d.join("claims.stl");
    std::fs::write(&f, &stl).unwrap();
    let err = refused(d, &["--mesh", &f.display().to_string()]);
    assert!(
        err.contains("claims.stl") && err.contains("4294967295 triangles"),
        "{err}"
    );
    // PLY declaring 4·10⁹ vertices in a 40-byte body.
    let f = ply(
        d,
        "rows.ply",
        "element vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\n",
        &[0u8; 40],
    );
    let err = refused(d, &["--mesh", &f]);
    assert!(
        err.contains("rows.ply") && err.contains("4000000000 rows"),
        "{err}"
    );
    // Elements without properties read no bytes: their rows are bounded in total, so they cannot spin.
    let f = ply(d, "spin.ply", &"element pad 30\n".repeat(4), &[0u8; 40]);
    let err = refused(d, &["--mesh", &f]);
    assert!(
        err.contains("spin.ply") && err.contains("120 rows in all"),
        "{err}"
    );
    // A face list whose length word says 4·10⁹ indices.
    let mut body: Vec<u8> = [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]]
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    body.extend_from_slice(&4_000_000_000u32.to_le_bytes());
    body.extend_from_slice(&[0u8; 12]);
    let f = ply(
        d,
        "list.ply",
        "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
         element face 1\nproperty list uint int vertex_indices\n",
        &body,
    );
    let err = refused(d, &["--mesh", &f]);
    assert!(
        err.contains("list.ply") && err.contains("list length 4000000000"),
        "{err}"
    );
}

#[test]
fn a_perturbation_key_given_twice_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    for spec in ["df=100,df=200", "dcx=1,skew=2,dcx=1"] {
        let err = refused(dir.path(), &["--phantom", "L3", "--perturb", spec]);
        let key = spec.split('=').next().unwrap();
        assert!(err.contains(&format!("'{key}' is given twice")), "{err}");
    }
    let err = refused(dir.path(), &["--phantom", "L3", "--perturb", "df=1e999"]);
    assert!(
        err.contains("perturbation df") && err.contains("finite"),
        "{err}"
    );
}

//! NIfTI round trips on files the tests write themselves, and clear errors on bad files.

use std::path::Path;

use glam::{DMat3, DMat4, DVec3};
use ndarray::{Array, IxDyn, ShapeBuilder};
use nifti::NiftiHeader;
use nifti::writer::WriterOptions;
use spinedrr::anatomy::ct::{
    CtVolume, LabelMap, Volume, VoxelMask, read_ct, read_labels, write_ct, write_labels,
};

/// An oblique affine whose entries are exact in float32 (the sform is stored as float32):
/// rotation by the 3-4-5 angle about z, anisotropic spacing, an origin.
fn oblique_affine() -> DMat4 {
    let r = DMat3::from_cols(
        DVec3::new(0.75, 1.0, 0.0),
        DVec3::new(-1.0, 0.75, 0.0),
        DVec3::new(0.0, 0.0, 2.5),
    ); // columns: 1.25 mm, 1.25 mm, 2.5 mm voxels
    DMat4::from_mat3_translation(r, DVec3::new(-120.5, 35.25, -400.0))
}

fn f32_exact(m: DMat4) -> DMat4 {
    DMat4::from_cols_array(&m.to_cols_array().map(|v| v as f32 as f64))
}

fn sphere_ct(dims: [usize; 3], affine: DMat4, centre: DVec3, r: f64, hu: f32) -> CtVolume {
    let mut v = Volume::filled(dims, -1000.0f32, affine).unwrap();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                if (DVec3::new(i as f64, j as f64, k as f64) - centre).length() <= r {
                    let n = v.linear(i, j, k);
                    v.values[n] = hu;
                }
            }
        }
    }
    v
}

#[test]
fn box_and_sphere_ct_round_trip_exactly_nii_and_gz() {
    let dir = tempfile::tempdir().unwrap();
    let dims = [13, 11, 7];
    let mut boxed = Volume::filled(dims, 0.0f32, oblique_affine()).unwrap();
    for k in 2..5 {
        for j in 3..8 {
            for i in 4..10 {
                let n = boxed.linear(i, j, k);
                boxed.values[n] = 1234.5;
            }
        }
    }
    let sphere = sphere_ct(
        dims,
        DMat4::from_scale(DVec3::new(0.5, 0.75, 1.5)),
        DVec3::new(6.0, 5.0, 3.0),
        3.2,
        250.25,
    );
    for (name, vol) in [("box.nii.gz", &boxed), ("sphere.nii", &sphere)] {
        let path = dir.path().join(name);
        write_ct(&path, vol).unwrap();
        let back = read_ct(&path).unwrap();
        assert_eq!(back.dims, vol.dims);
        assert_eq!(back.values, vol.values, "{name}");
        assert_eq!(back.index_to_world, f32_exact(vol.index_to_world), "{name}");
    }
    // The oblique affine is exact in float32, so it round-trips bit for bit.
    assert_eq!(
        read_ct(&dir.path().join("box.nii.gz"))
            .unwrap()
            .index_to_world,
        oblique_affine()
    );
}

#[test]
fn label_map_with_two_vertebrae_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let dims = [10, 9, 12];
    let mut seg = LabelMap::filled(dims, 0, oblique_affine()).unwrap();
    for k in 0..dims[2] {
        for j in 2..7 {
            for i in 2..8 {
                let n = seg.linear(i, j, k);
                seg.values[n] = if k < 5 {
                    31
                } else if k > 6 {
                    30
                } else {
                    0
                };
            }
        }
    }
    for (name, big) in [("seg.nii.gz", false), ("seg16.nii.gz", true)] {
        let mut s = seg.clone();
        if big {
            s.values[0] = 1000; // forces uint16 storage
        }
        let path = dir.path().join(name);
        write_labels(&path, &s).unwrap();
        let back = read_labels(&path).unwrap();
        assert_eq!(back, s);
    }
    let back = read_labels(&dir.path().join("seg.nii.gz")).unwrap();
    assert_eq!(back.labels_present(), vec![30, 31]);
    assert_eq!(back.count(31), 6 * 5 * 5);
    let mask = VoxelMask::from_labels(&back, &[30]).unwrap();
    assert_eq!(mask.bbox, ([2, 2, 7], [7, 6, 11]));
    let err = VoxelMask::from_labels(&back, &[29])
        .unwrap_err()
        .to_string();
    assert!(err.contains("29") && err.contains("[30, 31]"), "{err}");
}

/// Writes `data` (shape nx, ny, nz[, nt]) through the nifti crate with a caller-made header.
fn write_raw<T: nifti::DataElement + bytemuck::Pod>(
    path: &Path,
    shape: &[usize],
    data: Vec<T>,
    h: &NiftiHeader,
) {
    let a = Array::from_shape_vec(IxDyn(shape).f(), data).unwrap();
    WriterOptions::new(path)
        .reference_header(h)
        .write_nifti(&a)
        .unwrap();
}

fn patch(path: &Path, offset: usize, bytes: &[u8]) {
    let mut b = std::fs::read(path).unwrap();
    b[offset..offset + bytes.len()].copy_from_slice(bytes);
    std::fs::write(path, b).unwrap();
}

#[test]
fn int16_ct_with_slope_and_intercept() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ct16.nii");
    let raw: Vec<i16> = (0..4 * 3 * 2).map(|n| (n * 37 - 300) as i16).collect();
    let h = NiftiHeader {
        sform_code: 1,
        srow_x: [0.8, 0.0, 0.0, 1.0],
        srow_y: [0.0, 0.8, 0.0, 2.0],
        srow_z: [0.0, 0.0, 3.0, 3.0],
        ..NiftiHeader::default()
    };
    write_raw(&path, &[4, 3, 2], raw.clone(), &h);
    // The crate's writer forces slope 1; set scl_slope = 0.5, scl_inter = -1024 (header bytes 112..120).
    patch(&path, 112, &0.5f32.to_ne_bytes());
    patch(&path, 116, &(-1024.0f32).to_ne_bytes());
    let ct = read_ct(&path).unwrap();
    let want: Vec<f32> = raw.iter().map(|&r| r as f32 * 0.5 - 1024.0).collect();
    assert_eq!(ct.values, want);
    let s = f64::from(0.8f32);
    assert_eq!(
        ct.voxel_centre(1, 2, 1),
        DVec3::new(s + 1.0, 2.0 * s + 2.0, 3.0 + 3.0)
    );
}

#[test]
fn qform_only_affine_follows_the_standard() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("q.nii.gz");
    // 90° about z: quaternion (a, b, c, d) = (cos 45°, 0, 0, sin 45°); qfac = −1 flips k.
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let mut h = NiftiHeader {
        qform_code: 1,
        sform_code: 0,
        quatern_d: s,
        quatern_x: 10.0,
        quatern_y: -20.0,
        quatern_z: 30.0,
        ..NiftiHeader::default()
    };
    h.pixdim = [-1.0, 2.0, 3.0, 4.0, 1.0, 1.0, 1.0, 1.0];
    write_raw(&path, &[3, 4, 5], vec![7u8; 60], &h);
    let ct = read_ct(&path).unwrap();
    // R = [[0, −1, 0], [1, 0, 0], [0, 0, 1]]; columns scaled by (2, 3, −4).
    let want = DMat4::from_cols_array_2d(&[
        [0.0, 2.0, 0.0, 0.0],
        [-3.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, -4.0, 0.0],
        [10.0, -20.0, 30.0, 1.0],
    ]);
    let got = ct.index_to_world.to_cols_array();
    for (g, w) in got.iter().zip(want.to_cols_array()) {
        assert!((g - w).abs() < 1e-6, "{:?}", ct.index_to_world);
    }
    assert!(ct.values.iter().all(|&v| v == 7.0));
}

#[test]
fn four_d_with_one_frame_is_a_volume() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t1.nii");
    write_raw(
        &path,
        &[2, 2, 2, 1],
        vec![1.5f32; 8],
        &NiftiHeader {
            sform_code: 1,
            srow_x: [1.0, 0.0, 0.0, 0.0],
            srow_y: [0.0, 1.0, 0.0, 0.0],
            srow_z: [0.0, 0.0, 1.0, 0.0],
            ..NiftiHeader::default()
        },
    );
    assert_eq!(read_ct(&path).unwrap().dims, [2, 2, 2]);
}

fn err_of(path: &Path) -> String {
    let e = read_ct(path).expect_err("must be rejected").to_string();
    assert!(
        e.contains(&path.display().to_string()),
        "error must name the file: {e}"
    );
    e
}

#[test]
fn bad_files_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good = CtVolume::filled([8, 8, 8], 100.0, DMat4::IDENTITY).unwrap();
    let gz = dir.path().join("good.nii.gz");
    write_ct(&gz, &good).unwrap();
    let bytes = std::fs::read(&gz).unwrap();

    let trunc = dir.path().join("trunc.nii.gz");
    std::fs::write(&trunc, &bytes[..bytes.len() / 2]).unwrap();
    let e = err_of(&trunc);
    assert!(e.contains("truncated") || e.contains("corrupt"), "{e}");

    let corrupt = dir.path().join("corrupt.nii.gz");
    let mut c = bytes.clone();
    for b in &mut c[20..60] {
        *b ^= 0x5a;
    }
    std::fs::write(&corrupt, &c).unwrap();
    err_of(&corrupt);

    let plain = dir.path().join("plain.nii");
    write_ct(&plain, &good).unwrap();
    let magic = dir.path().join("magic.nii");
    std::fs::copy(&plain, &magic).unwrap();
    patch(&magic, 344, b"xyz\0");
    assert!(err_of(&magic).contains("magic"));

    let short = dir.path().join("short.nii");
    let b = std::fs::read(&plain).unwrap();
    std::fs::write(&short, &b[..b.len() - 10]).unwrap();
    assert!(err_of(&short).contains("truncated"));

    let n2 = dir.path().join("n2.nii");
    let mut h2 = vec![0u8; 600];
    h2[..4].copy_from_slice(&540i32.to_le_bytes());
    h2[4..8].copy_from_slice(b"n+2\0");
    std::fs::write(&n2, h2).unwrap();
    assert!(err_of(&n2).contains("NIfTI-2"));

    let empty = dir.path().join("empty.nii");
    std::fs::write(&empty, b"").unwrap();
    err_of(&empty);

    let id = NiftiHeader {
        sform_code: 1,
        srow_x: [1.0, 0.0, 0.0, 0.0],
        srow_y: [0.0, 1.0, 0.0, 0.0],
        srow_z: [0.0, 0.0, 1.0, 0.0],
        ..NiftiHeader::default()
    };
    let rgb = dir.path().join("rgb.nii");
    let a = Array::from_shape_vec(IxDyn(&[2, 2, 2]).f(), vec![[1u8, 2, 3]; 8]).unwrap();
    WriterOptions::new(&rgb)
        .reference_header(&id)
        .write_rgb_nifti(&a)
        .unwrap();
    assert!(err_of(&rgb).contains("unsupported datatype"));

    let flat = dir.path().join("flat.nii");
    write_raw(&flat, &[4, 4], vec![0i16; 16], &id);
    assert!(err_of(&flat).contains("2-D"));

    let movie = dir.path().join("movie.nii");
    write_raw(&movie, &[2, 2, 2, 3], vec![0i16; 24], &id);
    assert!(err_of(&movie).contains("frames"));

    let singular = dir.path().join("singular.nii");
    let hs = NiftiHeader {
        sform_code: 1,
        srow_x: [1.0, 2.0, 0.0, 0.0],
        srow_y: [2.0, 4.0, 0.0, 0.0],
        srow_z: [0.0, 0.0, 1.0, 0.0],
        ..NiftiHeader::default()
    };
    write_raw(&singular, &[2, 2, 2], vec![0i16; 8], &hs);
    assert!(err_of(&singular).contains("singular"));

    let frac = dir.path().join("frac.nii");
    write_raw(&frac, &[2, 2, 2], vec![0.5f32; 8], &id);
    let e = read_labels(&frac).unwrap_err().to_string();
    assert!(e.contains("not a label"), "{e}");

    let missing = dir.path().join("missing.nii.gz");
    assert!(err_of(&missing).contains("missing.nii.gz"));
}

/// A `.nii.gz` of several gzip members (`cat a.gz b.gz`, pigz, bgzip) reads like the one-member file:
/// every member is decoded, not just the first (which used to be reported as "truncated").
#[test]
fn multi_member_gzip_reads_every_member() {
    use std::io::Write;
    let dir = tempfile::tempdir().unwrap();
    let vol = sphere_ct(
        [9, 8, 7],
        oblique_affine(),
        DVec3::new(4.0, 4.0, 3.0),
        2.5,
        700.0,
    );
    let plain = dir.path().join("ct.nii");
    write_ct(&plain, &vol).unwrap();
    let bytes = std::fs::read(&plain).unwrap();
    let mut multi = Vec::new();
    // Three members, split inside the header and inside the voxels.
    for part in [&bytes[..100], &bytes[100..900], &bytes[900..]] {
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        gz.write_all(part).unwrap();
        multi.extend(gz.finish().unwrap());
    }
    let path = dir.path().join("multi.nii.gz");
    std::fs::write(&path, multi).unwrap();
    let back = read_ct(&path).unwrap();
    let single = read_ct(&plain).unwrap();
    assert_eq!(back.dims, single.dims);
    assert_eq!(back.values, single.values);
    assert_eq!(back.index_to_world, single.index_to_world);
}

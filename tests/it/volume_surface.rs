//! Surfaces from label maps and the phantom's synthetic CT.

use glam::{DMat3, DMat4, DVec3};
use spinedrr::anatomy::PhantomOptions;
use spinedrr::anatomy::ct::{LabelMap, SurfaceOptions, label_surface, read_labels, write_labels};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::anatomy::synthetic_ct::{SyntheticCtOptions, TissueHu, synthetic_ct};
use spinedrr::anatomy::vertebra::Level;

fn sphere_labels(a: DMat4) -> LabelMap {
    let dims = [30, 28, 26];
    let mut seg = LabelMap::filled(dims, 0, a).unwrap();
    let c = DVec3::new(14.2, 13.7, 12.9);
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                if (DVec3::new(i as f64, j as f64, k as f64) - c).length() <= 9.3 {
                    let n = seg.linear(i, j, k);
                    seg.values[n] = 31;
                }
            }
        }
    }
    // A stray island of the same label, and another label touching nothing.
    let n = seg.linear(1, 1, 1);
    seg.values[n] = 31;
    let n = seg.linear(28, 26, 24);
    seg.values[n] = 30;
    seg
}

#[test]
fn sphere_label_mesh_volume_matches_voxel_volume_and_is_watertight() {
    let rot = DMat3::from_axis_angle(DVec3::new(0.3, -1.0, 0.2).normalize(), 0.4);
    let a = DMat4::from_mat3_translation(
        rot * DMat3::from_diagonal(DVec3::new(0.8, 0.9, 1.25)),
        DVec3::new(5.0, -3.0, 100.0),
    );
    let seg = sphere_labels(a);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("seg.nii.gz");
    write_labels(&path, &seg).unwrap();
    let seg = read_labels(&path).unwrap();
    let voxel_volume = (seg.count(31) - 1) as f64 * seg.voxel_volume_mm3();
    for smooth in [0, 10] {
        let opts = SurfaceOptions {
            smooth_iterations: smooth,
            ..Default::default()
        };
        let mesh = label_surface(&seg, 31, &opts).unwrap();
        assert!(mesh.check().is_watertight(), "{:?}", mesh.check());
        let v = mesh.volume();
        assert!(
            (v - voxel_volume).abs() <= 0.02 * voxel_volume,
            "smooth {smooth}: mesh {v} vs voxels {voxel_volume}"
        );
        // The stray voxel at (1, 1, 1) was dropped: every vertex is near the sphere.
        let centre = seg
            .index_to_world
            .transform_point3(DVec3::new(14.2, 13.7, 12.9));
        assert!(mesh.vertices.iter().all(|p| (*p - centre).length() < 15.0));
    }
    let keep_all = SurfaceOptions {
        largest_component: false,
        ..Default::default()
    };
    let both = label_surface(&seg, 31, &keep_all).unwrap();
    let largest = label_surface(&seg, 31, &SurfaceOptions::default()).unwrap();
    assert!(both.volume() > largest.volume() && both.vertices.len() > largest.vertices.len());
    let e = label_surface(&seg, 29, &SurfaceOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("29") && e.contains("[30, 31]"), "{e}");
}

#[test]
fn synthetic_ct_of_one_level_has_the_phantom_tissues_and_labels() {
    let phantom = crate::common::phantom(&PhantomOptions {
        levels: vec![Level::L2],
        voxel_mm: 1.0,
        discs: false,
        ..Default::default()
    })
    .unwrap();
    let opts = SyntheticCtOptions {
        voxel_mm: 1.0,
        supersample: 1,
        labels: LabelConvention::Verse,
        ..Default::default()
    };
    let (ct, seg) = synthetic_ct(&phantom, &opts).unwrap();
    assert!(ct.same_grid(&seg));
    assert_eq!(seg.labels_present(), vec![21], "VerSe L2 = 21");
    let hu = TissueHu::default();
    let lm = &phantom.vertebrae[0].landmarks;
    let centre = lm.get("center").unwrap();
    let idx = ct.world_to_index().transform_point3(centre).round();
    let v = ct.get(idx.x as usize, idx.y as usize, idx.z as usize);
    assert_eq!(v, hu.cancellous, "body centre is cancellous bone");
    assert_eq!(ct.get(0, 0, 0), hu.air);
    // The labelled volume matches the cortical mesh's enclosed volume (both from the same SDF).
    let labelled = seg.count(21) as f64 * ct.voxel_volume_mm3();
    let mesh_volume = phantom.vertebrae[0].cortical.volume();
    assert!(
        (labelled - mesh_volume).abs() < 0.03 * mesh_volume,
        "{labelled} vs {mesh_volume}"
    );
    // And the surface extracted from that label map is watertight with the same volume.
    let s = label_surface(&seg, 21, &SurfaceOptions::default()).unwrap();
    assert!(s.check().is_watertight());
    assert!(
        (s.volume() - mesh_volume).abs() < 0.03 * mesh_volume,
        "{} vs {mesh_volume}",
        s.volume()
    );
}

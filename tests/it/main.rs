//! The integration tests: one crate, one binary, linked once (matklad, "Delete Cargo Integration
//! Tests"). Each module is one former `tests/NAME.rs`; `common` is the shared runner of the binary.

mod analysis_cli;
mod analysis_metrics;
mod anatomy_cli;
mod anatomy_isosurface;
mod anatomy_meshio;
mod anatomy_phantom;
mod calibration;
mod calibration_cli;
mod calibration_study;
mod cli_hardening;
mod cli_render;
mod cli_values;
mod common;
mod ct_structures;
mod fuzz_regressions;
#[cfg(feature = "gpu")]
mod gpu_ct;
#[cfg(feature = "gpu")]
mod gpu_mesh;
#[cfg(feature = "gpu")]
mod gpu_mesh_cli;
#[cfg(feature = "gpu")]
mod gpu_registration;
mod landmark_formats;
mod meshing_cli;
mod meshing_decimate;
mod meshing_landmarks;
mod nifti_io;
mod output_sets;
mod outputs_only_ours;
mod outputs_spare_inputs;
mod phantom_cache;
mod phantom_morphometry;
mod physical_geometry;
mod readers_hardening;
mod real_ct;
mod registration_cli;
mod registration_intensity;
mod registration_intensity_cli;
mod registration_intensity_ct;
mod registration_solvers;
mod render_models;
mod render_products;
mod render_thickness;
mod spectral;
mod spectral_implant_pose;
mod spectral_implants;
mod study_cohort;
mod study_ct;
mod study_folder_safety;
mod study_hardening;
mod study_intensity;
mod study_meshes;
mod study_physical;
mod study_physics;
mod study_report;
mod study_resume;
mod study_screws;
mod study_shard;
mod study_shard_concurrency;
mod study_slurm;
mod volume_cli;
mod volume_drr;
mod volume_surface;

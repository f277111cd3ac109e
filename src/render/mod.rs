//! Rendering: thickness DRRs of triangle meshes (Embree or the pure-Rust BVH) and CT volume DRRs.

pub mod volume;

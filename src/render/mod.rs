//! Rendering: thickness DRRs of triangle meshes (Embree or the pure-Rust BVH).

//! The `spinedrr` Python module: the spinedrr library with numpy arrays in and out.
//!
//! Conventions (as the CLI's): world frame RAS+ in millimetres; camera frame OpenCV's (origin at the
//! X-ray source, +z toward the detector, +x along rows, +y down); pixel centres at integer coordinates;
//! `x ~ K [R | t] X`, `K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`. Images are float32 `H × W`
//! (row v, column u). Renders, phantom builds, comparisons and registrations release the GIL. Errors
//! are `ValueError` (bad values, bad file content), `OSError` (files), `TypeError` (wrong argument
//! types or dtypes), with the library's messages.
//!
//! `lib_bridge` holds every call into the library; `arrays` the numpy checks and hand-over; the other
//! files one Python-facing area each.

use pyo3::prelude::*;

mod analysis;
mod anatomy;
mod arrays;
mod errors;
mod geometry;
mod lib_bridge;
mod render;
mod spectral;

/// spinedrr: calibration-sensitivity analysis of vertebral DRRs — thickness DRRs of meshes, CT DRRs,
/// projection-domain metrics and landmark 2D–3D registration, with numpy arrays in and out.
///
/// Conventions (the CLI's): world frame RAS+ in millimetres; camera frame OpenCV's (origin at the X-ray
/// source, +z along the central ray toward the detector, +x along detector rows, +y down the
/// detector); pixel centres at integer coordinates; ``x ~ K [R | t] X`` with
/// ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``. Images are float32 ``H × W`` arrays (row v, column
/// u). Renders, phantom builds, comparisons and registrations release the GIL. Errors: ``ValueError``
/// (bad values or file content), ``OSError`` (files), ``TypeError`` (wrong types or dtypes), with the
/// library's messages.
#[pymodule]
#[pyo3(name = "spinedrr")]
fn spinedrr_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", lib_bridge::VERSION)?;
    m.add("MU_WATER_PER_MM", lib_bridge::MU_WATER_PER_MM)?;
    m.add_class::<geometry::PyCArm>()?;
    m.add_class::<geometry::PyView>()?;
    m.add_class::<geometry::PyPerturbation>()?;
    m.add_class::<anatomy::PyMesh>()?;
    m.add_class::<anatomy::PyPhantom>()?;
    m.add_class::<render::PyRenderer>()?;
    m.add_class::<render::PyCtRenderer>()?;
    m.add_function(wrap_pyfunction!(anatomy::phantom, m)?)?;
    m.add_function(wrap_pyfunction!(anatomy::read_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(render::render_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(render::render_ct, m)?)?;
    m.add_function(wrap_pyfunction!(render::intensity, m)?)?;
    m.add_function(wrap_pyfunction!(spectral::material_mu_rho, m)?)?;
    m.add_function(wrap_pyfunction!(spectral::spectrum, m)?)?;
    m.add_function(wrap_pyfunction!(spectral::render_spectral, m)?)?;
    m.add_function(wrap_pyfunction!(analysis::compare, m)?)?;
    m.add_function(wrap_pyfunction!(analysis::register, m)?)?;
    Ok(())
}

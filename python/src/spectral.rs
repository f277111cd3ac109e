//! The spectral model from Python: materials' attenuation, spectra and polychromatic renders.

use numpy::PyArray1;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::anatomy::PyMesh;
use crate::arrays::image_to_py;
use crate::errors::{IntoPy, json_to_py};
use crate::geometry::PyView;
use crate::lib_bridge as lib;

/// μ/ρ (cm²/g) of a built-in material at ``energies_kev`` (1–200 keV), from the embedded NIST SRD 126
/// element tables by the mixture rule; with ``energy_absorption=True`` μ_en/ρ. Materials: ``air``,
/// ``water``, ``adipose``, ``soft_tissue``, ``cortical_bone``, ``cancellous_bone``, ``titanium``
/// (Ti-6Al-4V), ``steel`` (316L), ``cobalt_chrome``, ``peek``, ``aluminium``, ``copper``, ``csi``.
#[pyfunction]
#[pyo3(signature = (name, energies_kev, energy_absorption=false))]
pub fn material_mu_rho<'py>(
    py: Python<'py>,
    name: &str,
    energies_kev: Vec<f64>,
    energy_absorption: bool,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let v = lib::material_coefficients(name, &energies_kev, energy_absorption).py_err()?;
    Ok(PyArray1::from_vec(py, v))
}

/// The spectrum ``spinedrr render --spectrum SPEC --filter FILTERS --detector DETECTOR`` uses, as its
/// sidecar records it: a dict with ``energies_kev``, ``fluence``, ``mean_energy_kev``, ``hvl_al_mm``,
/// ``filtration``, ``detector`` and ``detector_weights`` (Φ·η·E normalised). ``spec``: a tube potential
/// in kV (TASMIP, 30–140), ``"mono:E"`` or a spectrum file; ``filters``: ``"al:2.5,cu:0.1"``.
#[pyfunction]
#[pyo3(signature = (spec, filters="", detector="csi:0.6"))]
pub fn spectrum<'py>(
    py: Python<'py>,
    spec: &str,
    filters: &str,
    detector: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let m = lib::spectral_model(spec, filters, detector).py_err()?;
    json_to_py(py, &m.summary())
}

/// A polychromatic DRR: ``spinedrr render --spectrum …`` bit for bit. ``meshes``: a sequence of
/// ``(Mesh, attenuation)`` or ``(Mesh, attenuation, object)`` where attenuation is μ (float, mm⁻¹) or
/// ``"MATERIAL[@DENSITY]"``; or ``phantom="L1-L5"`` (with ``soft_tissue``, and ``screws`` for two titanium
/// pedicle screws per level, as ``--screws``) for the phantom's tissues.
/// Returns ``(image, spectral)``: ``−ln(I/I0)`` float32 H × W and the sidecar's ``spectral`` record.
/// Meshes partly inside another raise a ``RuntimeWarning``.
#[pyfunction]
#[pyo3(signature = (view, spectrum, meshes=None, phantom=None, soft_tissue=false, screws=false, filters="", detector="csi:0.6", backend="raster"))]
#[allow(clippy::too_many_arguments)]
pub fn render_spectral<'py>(
    py: Python<'py>,
    view: &PyView,
    spectrum: &str,
    meshes: Option<&Bound<'py, PyAny>>,
    phantom: Option<String>,
    soft_tissue: bool,
    screws: bool,
    filters: &str,
    detector: &str,
    backend: &str,
) -> PyResult<Bound<'py, PyTuple>> {
    let mut items = Vec::new();
    if let Some(ms) = meshes {
        for (i, item) in ms.try_iter()?.enumerate() {
            let item = item?;
            let bad = || {
                PyTypeError::new_err(format!(
                    "meshes[{i}] must be a (Mesh, attenuation) or (Mesh, attenuation, object) tuple, \
                     attenuation a float μ or a 'MATERIAL[@DENSITY]' string"
                ))
            };
            let t = item.cast::<PyTuple>().map_err(|_| bad())?;
            if !(2..=3).contains(&t.len()) {
                return Err(bad());
            }
            let mesh = t
                .get_item(0)?
                .cast::<PyMesh>()
                .map_err(|_| bad())?
                .get()
                .inner
                .clone();
            let a = t.get_item(1)?;
            let attenuation = if let Ok(mu) = a.extract::<f64>() {
                // The shortest round-trip decimal, parsed as the CLI parses `FILE:MU`.
                format!("{mu:?}")
            } else {
                a.extract::<String>().map_err(|_| bad())?
            };
            let object = match t.len() {
                3 => t.get_item(2)?.extract().map_err(|_| bad())?,
                _ => mesh.name.clone(),
            };
            items.push((mesh, object, attenuation));
        }
    }
    if items.is_empty() == phantom.is_none() {
        return Err(PyTypeError::new_err(
            "give exactly one of meshes (a non-empty sequence) and phantom",
        ));
    }
    let model = lib::spectral_model(spectrum, filters, detector).py_err()?;
    let backend = lib::backend(backend).py_err()?;
    let v = view.inner.clone();
    let (image, summary, warnings) = py
        .detach(|| {
            lib::render_spectral(
                items,
                phantom.as_deref().map(|l| (l, soft_tissue, screws)),
                model,
                backend,
                &v,
            )
        })
        .py_err()?;
    for w in warnings {
        let category = py.get_type::<pyo3::exceptions::PyRuntimeWarning>();
        let text = std::ffi::CString::new(w.replace('\0', " "))?;
        PyErr::warn(py, category.as_any(), &text, 1)?;
    }
    PyTuple::new(
        py,
        [
            image_to_py(py, image)?.into_any(),
            json_to_py(py, &summary)?,
        ],
    )
}

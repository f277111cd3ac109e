//! The spectral model from Python: materials' attenuation, spectra and polychromatic renders.

use numpy::PyArray1;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::anatomy::PyMesh;
use std::sync::Arc;

use crate::arrays::{image_to_py, matrix};
use crate::errors::{IntoPy, json_to_py};
use crate::geometry::PyView;
use crate::lib_bridge as lib;
use crate::lib_bridge::TriMesh;
use crate::render::{hu_values, mask_values};

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

/// A polychromatic DRR: ``spinedrr render --spectrum …`` bit for bit. The anatomy, exactly one of:
/// ``meshes``, a sequence of ``(Mesh, attenuation)`` or ``(Mesh, attenuation, object)`` where attenuation
/// is μ (float, mm⁻¹) or ``"MATERIAL[@DENSITY]"`` (``--mesh``); ``phantom="L1-L5"`` (with ``soft_tissue``,
/// and ``screws`` for two titanium pedicle screws per level, as ``--screws``); or ``ct``, a nibabel-style
/// (i, j, k) HU array with its 4 × 4 ``affine``, an optional boolean ``mask`` and ``placement`` (as
/// ``render_ct``; ``--ct``). Implants, with any of them: ``implants``, a sequence of ``(Mesh,
/// "MATERIAL[@DENSITY]")`` or ``(Mesh, "MATERIAL[@DENSITY]", pose)`` with ``pose`` a row-major 4 × 4
/// rigid transform applied to the mesh (``--implant FILE:MATERIAL[:POSE.json]``); ``screws_at``, a
/// mapping of landmark names to points (mm) whose ``PREFIXpedicle_entry`` / ``PREFIXpedicle_tip`` pairs
/// each take a titanium pedicle screw (``--screws-at``). A CT's implants are in its file's world and
/// move with its placement. Implants displace whatever they occupy. ``backend``: ``raster``, ``embree``,
/// ``bvh`` or ``gpu`` (the material channels of meshes or a CT render on the GPU and the energy sum runs
/// there too; implants are refused there: they are cut out along paired crossings, which the GPU does not
/// keep).
/// Returns ``(image, spectral)``: ``−ln(I/I0)`` float32 H × W and the sidecar's ``spectral`` record.
/// Meshes partly inside another raise a ``RuntimeWarning``.
#[pyfunction]
#[pyo3(signature = (view, spectrum, meshes=None, phantom=None, soft_tissue=false, screws=false, filters="", detector="csi:0.6", backend="raster", ct=None, affine=None, mask=None, placement="volume-centre", implants=None, screws_at=None))]
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
    ct: Option<&Bound<'py, PyAny>>,
    affine: Option<&Bound<'py, PyAny>>,
    mask: Option<&Bound<'py, PyAny>>,
    placement: &str,
    implants: Option<&Bound<'py, PyAny>>,
    screws_at: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyTuple>> {
    let items = mesh_items(meshes, "meshes", 2..=3, |i, t, mesh| {
        let a = t.get_item(1)?;
        let attenuation = if let Ok(mu) = a.extract::<f64>() {
            // The shortest round-trip decimal, parsed as the CLI parses `FILE:MU`.
            format!("{mu:?}")
        } else {
            a.extract::<String>().map_err(|_| bad_mesh(i, "meshes"))?
        };
        let object = match t.len() {
            3 => t
                .get_item(2)?
                .extract()
                .map_err(|_| bad_mesh(i, "meshes"))?,
            _ => mesh.name.clone(),
        };
        Ok((mesh, object, attenuation))
    })?;
    let given =
        usize::from(!items.is_empty()) + usize::from(phantom.is_some()) + usize::from(ct.is_some());
    if given != 1 {
        return Err(PyTypeError::new_err(
            "give exactly one of meshes (a non-empty sequence), phantom and ct",
        ));
    }
    if ct.is_none() && (affine.is_some() || mask.is_some()) {
        return Err(PyTypeError::new_err("affine and mask go with ct"));
    }
    let anatomy = match (ct, phantom.as_deref()) {
        (Some(hu), _) => {
            let affine = affine
                .ok_or_else(|| PyTypeError::new_err("ct needs its 4 × 4 affine (affine=…)"))?;
            let (dims, values) = hu_values(hu)?;
            let affine = matrix::<4, 4>(affine, "affine")?;
            let keep = mask.map(|m| mask_values(m, dims)).transpose()?;
            let volume = lib::ct_volume(dims, values, affine).py_err()?;
            lib::SpectralAnatomy::Ct(volume, keep, placement)
        }
        (None, Some(levels)) => lib::SpectralAnatomy::Phantom(levels, soft_tissue, screws),
        (None, None) => lib::SpectralAnatomy::Meshes(items),
    };
    let implant_meshes = mesh_items(implants, "implants", 2..=3, |i, t, mesh| {
        let material: String = t
            .get_item(1)?
            .extract()
            .map_err(|_| bad_mesh(i, "implants"))?;
        let pose = match t.len() {
            3 => Some(matrix::<4, 4>(
                &t.get_item(2)?,
                &format!("implants[{i}] pose"),
            )?),
            _ => None,
        };
        Ok((mesh, material, pose))
    })?;
    let plan = match screws_at {
        Some(m) => m
            .extract::<std::collections::BTreeMap<String, [f64; 3]>>()
            .map_err(|_| {
                PyTypeError::new_err(
                    "screws_at must map landmark names to points [x, y, z] (mm), e.g. \
                     {'left_pedicle_entry': …, 'left_pedicle_tip': …}",
                )
            })?
            .into_iter()
            .collect(),
        None => Vec::new(),
    };
    let implants = lib::SpectralImplants {
        meshes: implant_meshes,
        plan,
    };
    let model = lib::spectral_model(spectrum, filters, detector).py_err()?;
    let backend = lib::backend(backend).py_err()?;
    let v = view.inner.clone();
    let (image, summary, warnings) = py
        .detach(|| lib::render_spectral(anatomy, implants, model, backend, &v))
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

fn bad_mesh(i: usize, what: &str) -> PyErr {
    PyTypeError::new_err(match what {
        "implants" => format!(
            "implants[{i}] must be a (Mesh, 'MATERIAL[@DENSITY]') or (Mesh, 'MATERIAL[@DENSITY]', pose 4 × 4) \
             tuple"
        ),
        _ => format!(
            "meshes[{i}] must be a (Mesh, attenuation) or (Mesh, attenuation, object) tuple, attenuation \
             a float μ or a 'MATERIAL[@DENSITY]' string"
        ),
    })
}

/// The items of a sequence of tuples whose first element is a ``Mesh`` and whose length is in `lens`,
/// each made by `item(index, tuple, mesh)`; an absent sequence is empty.
fn mesh_items<'py, T>(
    seq: Option<&Bound<'py, PyAny>>,
    what: &str,
    lens: std::ops::RangeInclusive<usize>,
    item: impl Fn(usize, &Bound<'py, PyTuple>, Arc<TriMesh>) -> PyResult<T>,
) -> PyResult<Vec<T>> {
    let mut out = Vec::new();
    let Some(seq) = seq else {
        return Ok(out);
    };
    for (i, it) in seq.try_iter()?.enumerate() {
        let it = it?;
        let t = it.cast::<PyTuple>().map_err(|_| bad_mesh(i, what))?;
        if !lens.contains(&t.len()) {
            return Err(bad_mesh(i, what));
        }
        let mesh = t
            .get_item(0)?
            .cast::<PyMesh>()
            .map_err(|_| bad_mesh(i, what))?
            .get()
            .inner
            .clone();
        out.push(item(i, t, mesh)?);
    }
    Ok(out)
}

//! `compare` and `register`: projection-domain metrics and landmark 2D–3D registration, returning the
//! records `spinedrr compare` (metrics.json) and `spinedrr register` (R.json) write.

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString, PyTuple};

use crate::arrays::{image, mask};
use crate::errors::{IntoPy, json_to_py};
use crate::geometry::PyView;
use crate::lib_bridge as lib;

fn mask_pairs(masks: &Bound<'_, PyDict>, w: u32, h: u32) -> PyResult<Vec<lib::MaskPair>> {
    let mut out = Vec::with_capacity(masks.len());
    for (name, pair) in masks.iter() {
        let name: String = name
            .extract()
            .map_err(|_| PyTypeError::new_err("masks keys must be structure names (str)"))?;
        let bad = || {
            PyTypeError::new_err(format!(
                "masks['{name}'] must be a (reference, perturbed) tuple of bool arrays"
            ))
        };
        let t = pair.cast::<PyTuple>().map_err(|_| bad())?;
        if t.len() != 2 {
            return Err(bad());
        }
        out.push(lib::MaskPair {
            reference: mask(&t.get_item(0)?, &format!("masks['{name}'][0]"), w, h)?,
            perturbed: mask(&t.get_item(1)?, &format!("masks['{name}'][1]"), w, h)?,
            name,
            width: w,
            height: h,
        });
    }
    Ok(out)
}

fn landmark_list(landmarks: &Bound<'_, PyDict>) -> PyResult<Vec<lib::Landmark>> {
    let mut out = Vec::with_capacity(landmarks.len());
    for (name, p) in landmarks.iter() {
        let name: String = name
            .extract()
            .map_err(|_| PyTypeError::new_err("landmarks keys must be names (str)"))?;
        let xyz: [f64; 3] = p.extract().map_err(|_| {
            PyTypeError::new_err(format!(
                "landmarks['{name}'] must be 3 numbers [x, y, z] (mm)"
            ))
        })?;
        if !xyz.iter().all(|v| v.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "landmarks['{name}'] is not finite: {xyz:?}"
            )));
        }
        out.push(lib::landmark(name, xyz));
    }
    Ok(out)
}

/// Every metric of ``spinedrr compare`` between a reference and a perturbed DRR (float32 H × W).
///
/// ``masks``: ``{name: (reference_mask, perturbed_mask)}`` bool H × W silhouettes (with more than one
/// and none called ``"vertebra"``, their union is added as ``"vertebra"``); ``landmarks``:
/// ``{name: [x, y, z]}`` world mm, projected with ``views = (reference_view, perturbed_view)``.
/// Returns ``{"image": {...}, "silhouettes": [...], "landmarks": [...]}``, the entries of
/// ``metrics.json`` with the same numbers (a NaN metric is ``None``, as JSON's ``null``). The GIL is
/// released while it computes.
#[pyfunction]
#[pyo3(signature = (reference, perturbed, masks=None, landmarks=None, views=None))]
pub fn compare<'py>(
    py: Python<'py>,
    reference: &Bound<'py, PyAny>,
    perturbed: &Bound<'py, PyAny>,
    masks: Option<&Bound<'py, PyDict>>,
    landmarks: Option<&Bound<'py, PyDict>>,
    views: Option<(PyRef<'py, PyView>, PyRef<'py, PyView>)>,
) -> PyResult<Bound<'py, PyAny>> {
    let a = image(reference, "reference")?;
    let b = image(perturbed, "perturbed")?;
    if (a.width, a.height) != (b.width, b.height) {
        return Err(PyValueError::new_err(format!(
            "the images differ in size: {}×{} vs {}×{}",
            a.width, a.height, b.width, b.height
        )));
    }
    let pairs = match masks {
        Some(m) => mask_pairs(m, a.width, a.height)?,
        None => Vec::new(),
    };
    let lms = match landmarks {
        Some(l) => landmark_list(l)?,
        None => Vec::new(),
    };
    let views = views.map(|(r, p)| (r.inner.clone(), p.inner.clone()));
    let record = py
        .detach(|| {
            let v = views.as_ref().map(|(r, p)| (r, p));
            lib::compare(&a, &b, &pairs, &lms, v)
        })
        .py_err()?;
    json_to_py(py, &record)
}

/// ``ndarray.tolist()`` for ``json.dumps(default=…)``, so problem dicts may hold numpy arrays.
#[pyfunction]
fn _tolist<'py>(o: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    o.call_method0("tolist")
}

/// Landmark 2D–3D registration, ``spinedrr register`` on the same problem with the same numbers.
///
/// ``problem``: the problem JSON document as a dict (``{"landmarks_3d": {name: [x, y, z]}, "views":
/// [{"name", "K", "world_to_camera", "observed": {name: [u, v]}}], "init"?: {"R", "t"}, "truth"?:
/// {"R", "t"}}``; numpy arrays allowed) or as JSON text. ``method``: ``direct``, ``kabsch``,
/// ``opencv`` (= ``opencv-iterative``) or ``opencv-sqpnp``. Returns the ``R.json`` record: ``R``,
/// ``t`` (model → world), ``residual_px``, ``iterations``, ``converged``, ``method``, ``views``, and
/// ``rot_err_deg``/``trans_err_mm`` when the problem has a truth. The GIL is released while it solves.
#[pyfunction]
#[pyo3(signature = (problem, method="direct", views=None, noise_px=0.0, seed=0, init_rot_deg=None, init_trans_mm=None, max_iterations=100))]
#[allow(clippy::too_many_arguments)]
pub fn register<'py>(
    py: Python<'py>,
    problem: &Bound<'py, PyAny>,
    method: &str,
    views: Option<Vec<String>>,
    noise_px: f64,
    seed: u64,
    init_rot_deg: Option<f64>,
    init_trans_mm: Option<f64>,
    max_iterations: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let text: String = if problem.is_instance_of::<PyString>() {
        problem.extract()?
    } else if problem.is_instance_of::<PyDict>() {
        let kwargs = PyDict::new(py);
        kwargs.set_item("default", wrap_pyfunction!(_tolist, py)?)?;
        kwargs.set_item("allow_nan", false)?;
        let json = py.import("json")?;
        json.call_method("dumps", (problem,), Some(&kwargs))
            .map_err(|e| {
                PyValueError::new_err(format!(
                    "problem: {} (a NaN or infinite number, or a value JSON cannot hold)",
                    e.value(py)
                ))
            })?
            .extract()?
    } else {
        return Err(PyTypeError::new_err(
            "problem must be a dict (the problem JSON document) or its JSON text",
        ));
    };
    let args = lib::RegisterRequest {
        method: method.to_string(),
        views: views.unwrap_or_default(),
        noise_px,
        seed,
        init_rot_deg,
        init_trans_mm,
        max_iterations,
    };
    let record = py.detach(|| lib::register(&text, &args)).py_err()?;
    json_to_py(py, &record)
}

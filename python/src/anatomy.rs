//! `Mesh`, `phantom()` and `read_mesh()`: triangle meshes and the parametric lumbar phantom.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{points3, read_vec, rows_to_py};
use crate::errors::IntoPy;
use crate::lib_bridge as lib;

/// A closed triangle mesh in world mm: ``vertices`` (N, 3) float64, ``faces`` (M, 3) uint32 (counter-
/// clockwise seen from outside), ``labels`` (M,) uint8 structure ids (0 = unlabelled).
///
/// ``Mesh(vertices, faces, labels=None, name="mesh")`` checks indices and labels (ValueError).
#[pyclass(module = "spinedrr", name = "Mesh", frozen)]
#[derive(Clone)]
pub struct PyMesh {
    pub inner: lib::MeshRef,
}

#[pymethods]
impl PyMesh {
    #[new]
    #[pyo3(signature = (vertices, faces, labels=None, name="mesh"))]
    fn new(
        vertices: &Bound<'_, PyAny>,
        faces: &Bound<'_, PyAny>,
        labels: Option<&Bound<'_, PyAny>>,
        name: &str,
    ) -> PyResult<Self> {
        let v = points3(vertices, "vertices")?;
        let (_, f) = read_vec::<u32>(faces, "faces", "uint32", &[None, Some(3)])?;
        let f: Vec<[u32; 3]> = f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let l = match labels {
            Some(l) => Some(read_vec::<u8>(l, "labels", "uint8", &[Some(f.len())])?.1),
            None => None,
        };
        Ok(PyMesh {
            inner: Arc::new(lib::mesh(name, &v, &f, l).py_err()?),
        })
    }

    #[getter]
    fn name(&self) -> String {
        self.inner.name.clone()
    }

    /// (N, 3) float64, world mm.
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let v: Vec<[f64; 3]> = self.inner.vertices.iter().map(|p| p.to_array()).collect();
        rows_to_py(py, &v)
    }

    /// (M, 3) uint32 vertex indices.
    #[getter]
    fn faces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u32>>> {
        rows_to_py(py, &self.inner.triangles)
    }

    /// (M,) uint8 structure id per face (see ``structure_names``); zeros when the mesh has none.
    #[getter]
    fn labels<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u8>> {
        let mut l = self.inner.labels.clone();
        l.resize(self.inner.triangles.len(), 0);
        PyArray1::from_vec(py, l)
    }

    fn __len__(&self) -> usize {
        self.inner.triangles.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "Mesh({:?}, {} vertices, {} faces)",
            self.inner.name,
            self.inner.vertices.len(),
            self.inner.triangles.len()
        )
    }
}

/// The parametric lumbar phantom as ``spinedrr render --phantom`` renders it.
///
/// ``scene``: list of ``(Mesh, mu_per_mm, object)``, the cortical surface of each level (object = level
/// name), its cancellous core with the differential μ, discs and soft tissue — pass it to
/// ``render_mesh``. ``meshes``: the same meshes. ``landmarks``: ``{"L3/name": array([x, y, z])}`` in
/// world mm, named as ``spinedrr compare --landmarks landmarks.json`` names them.
#[pyclass(module = "spinedrr", name = "Phantom", frozen)]
pub struct PyPhantom {
    scene: Vec<lib::SceneMesh>,
    landmarks: Vec<lib::Landmark>,
}

#[pymethods]
impl PyPhantom {
    #[getter]
    fn scene(&self) -> Vec<(PyMesh, f64, String)> {
        (self.scene.iter())
            .map(|m| {
                let mesh = PyMesh {
                    inner: m.mesh.clone(),
                };
                (mesh, m.mu_per_mm, m.object.clone())
            })
            .collect()
    }

    #[getter]
    fn meshes(&self) -> Vec<PyMesh> {
        (self.scene.iter())
            .map(|m| PyMesh {
                inner: m.mesh.clone(),
            })
            .collect()
    }

    #[getter]
    fn landmarks<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for l in &self.landmarks {
            d.set_item(
                &l.name,
                PyArray1::from_vec(py, l.position.to_array().to_vec()),
            )?;
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        format!(
            "Phantom({} meshes, {} landmarks)",
            self.scene.len(),
            self.landmarks.len()
        )
    }
}

/// Builds the phantom: ``levels`` such as ``"L3"``, ``"L1-L5"`` or ``"L1,L3"``; discs between adjacent
/// levels; ``soft_tissue`` adds the 300 × 220 mm outline. The GIL is released while it builds.
#[pyfunction]
#[pyo3(signature = (levels="L1-L5", soft_tissue=false, discs=true))]
pub fn phantom(
    py: Python<'_>,
    levels: &str,
    soft_tissue: bool,
    discs: bool,
) -> PyResult<PyPhantom> {
    let parts = py
        .detach(|| lib::phantom(levels, soft_tissue, discs))
        .py_err()?;
    Ok(PyPhantom {
        scene: parts.scene,
        landmarks: parts.landmarks,
    })
}

/// Reads a mesh file (STL, OBJ or PLY; the format from the extension). Raises OSError / ValueError.
#[pyfunction]
pub fn read_mesh(py: Python<'_>, path: PathBuf) -> PyResult<PyMesh> {
    let m = py.detach(|| lib::read_mesh(&path)).py_err()?;
    Ok(PyMesh { inner: Arc::new(m) })
}

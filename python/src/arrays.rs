//! numpy in and out: checked views of input arrays (dtype, shape, layout, with messages that name the
//! argument) and zero-copy hand-over of output buffers.

use numpy::ndarray::Array2;
use numpy::{
    Element, IntoPyArray, PyArray2, PyArrayDescrMethods, PyArrayMethods, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::lib_bridge::ImageF32;

/// The array behind `obj`, or a `TypeError` naming `what`.
pub fn untyped<'a, 'py>(
    obj: &'a Bound<'py, PyAny>,
    what: &str,
) -> PyResult<&'a Bound<'py, PyUntypedArray>> {
    obj.cast::<PyUntypedArray>().map_err(|_| {
        let ty = obj
            .get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_else(|_| "?".into());
        PyTypeError::new_err(format!("{what} must be a numpy array, got {ty}"))
    })
}

/// Checks `dtype` is `T`'s; `TypeError` otherwise.
pub fn check_dtype<T: Element>(
    arr: &Bound<'_, PyUntypedArray>,
    what: &str,
    dtype: &str,
) -> PyResult<()> {
    if arr.dtype().is_equiv_to(&numpy::dtype::<T>(arr.py())) {
        return Ok(());
    }
    Err(PyTypeError::new_err(format!(
        "{what} must have dtype {dtype}, got {} (convert with .astype(np.{dtype}))",
        arr.dtype()
    )))
}

/// Checks the shape against `expected`, where `None` is any extent; `ValueError` otherwise.
pub fn check_shape(
    arr: &Bound<'_, PyUntypedArray>,
    what: &str,
    expected: &[Option<usize>],
) -> PyResult<()> {
    let shape = arr.shape();
    let fits = shape.len() == expected.len()
        && shape
            .iter()
            .zip(expected)
            .all(|(&n, e)| e.is_none_or(|e| e == n));
    if fits {
        return Ok(());
    }
    let want: Vec<String> = (expected.iter().enumerate())
        .map(|(i, e)| e.map_or_else(|| ["N", "M", "K"][i.min(2)].to_string(), |n| n.to_string()))
        .collect();
    Err(PyValueError::new_err(format!(
        "{what} must have shape ({}), got {shape:?}",
        want.join(", ")
    )))
}

/// Checks the array is C-contiguous (row-major, no strides); `ValueError` otherwise.
pub fn check_c_contiguous(arr: &Bound<'_, PyUntypedArray>, what: &str) -> PyResult<()> {
    if arr.is_c_contiguous() {
        return Ok(());
    }
    Err(PyValueError::new_err(format!(
        "{what} must be a C-contiguous array (row-major without strides); pass np.ascontiguousarray({what})"
    )))
}

/// A C-contiguous array of `T` with the expected shape, copied out in row-major order.
pub fn read_vec<T: Element + Copy>(
    obj: &Bound<'_, PyAny>,
    what: &str,
    dtype: &str,
    shape: &[Option<usize>],
) -> PyResult<(Vec<usize>, Vec<T>)> {
    let arr = untyped(obj, what)?;
    check_dtype::<T>(arr, what, dtype)?;
    check_shape(arr, what, shape)?;
    check_c_contiguous(arr, what)?;
    let typed = arr.cast::<numpy::PyArrayDyn<T>>()?.readonly();
    let slice = typed
        .as_slice()
        .map_err(|e| PyValueError::new_err(format!("{what}: {e}")))?;
    Ok((arr.shape().to_vec(), slice.to_vec()))
}

/// An `(N, 3)` float64 array as rows.
pub fn points3(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let (_, v) = read_vec::<f64>(obj, what, "float64", &[None, Some(3)])?;
    Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// A fixed-size float64 matrix (`R × C`).
pub fn matrix<const R: usize, const C: usize>(
    obj: &Bound<'_, PyAny>,
    what: &str,
) -> PyResult<[[f64; C]; R]> {
    let (_, v) = read_vec::<f64>(obj, what, "float64", &[Some(R), Some(C)])?;
    let mut m = [[0.0; C]; R];
    for (r, row) in m.iter_mut().enumerate() {
        row.copy_from_slice(&v[r * C..(r + 1) * C]);
    }
    Ok(m)
}

/// A float32 `H × W` image as the library's row-major [`ImageF32`].
pub fn image(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<ImageF32> {
    let (shape, data) = read_vec::<f32>(obj, what, "float32", &[None, None])?;
    let size = |n: usize| {
        u32::try_from(n)
            .map_err(|_| PyValueError::new_err(format!("{what}: {n} pixels is too large")))
    };
    Ok(ImageF32 {
        width: size(shape[1])?,
        height: size(shape[0])?,
        data,
    })
}

/// A boolean `H × W` mask, checked against the image size.
pub fn mask(obj: &Bound<'_, PyAny>, what: &str, width: u32, height: u32) -> PyResult<Vec<bool>> {
    let (_, v) = read_vec::<bool>(
        obj,
        what,
        "bool_",
        &[Some(height as usize), Some(width as usize)],
    )?;
    Ok(v)
}

/// Moves a row-major `height × width` buffer into a numpy array without copying it.
pub fn into_2d<'py, T: Element>(
    py: Python<'py>,
    height: u32,
    width: u32,
    data: Vec<T>,
) -> PyResult<Bound<'py, PyArray2<T>>> {
    let a = Array2::from_shape_vec((height as usize, width as usize), data)
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(format!("image buffer: {e}")))?;
    Ok(a.into_pyarray(py))
}

/// Moves an image into a float32 `H × W` numpy array without copying it.
pub fn image_to_py(py: Python<'_>, img: ImageF32) -> PyResult<Bound<'_, PyArray2<f32>>> {
    into_2d(py, img.height, img.width, img.data)
}

/// Copies rows of a fixed width into an `(N, C)` numpy array.
pub fn rows_to_py<'py, T: Element + Copy, const C: usize>(
    py: Python<'py>,
    rows: &[[T; C]],
) -> PyResult<Bound<'py, PyArray2<T>>> {
    let flat: Vec<T> = rows.iter().flatten().copied().collect();
    let a = Array2::from_shape_vec((rows.len(), C), flat)
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(format!("array: {e}")))?;
    Ok(a.into_pyarray(py))
}

//! Numbers in from Python (any array-like, converted by NumPy; shapes and finiteness checked, a `ValueError`
//! otherwise) and arrays out.

use numpy::{AllowTypeChange, PyArray1, PyArrayLikeDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// Rows of `N` finite numbers from a `(rows, N)` array-like, or from an `(N,)` one as a single row when `flat_ok`.
/// Returns the rows and whether the input was flat. `rows` is the count required, if any.
pub fn rows<const N: usize>(
    obj: &Bound<'_, PyAny>,
    what: &str,
    rows: Option<usize>,
    flat_ok: bool,
) -> PyResult<(Vec<[f64; N]>, bool)> {
    let array: PyArrayLikeDyn<'_, f64, AllowTypeChange> = obj
        .extract()
        .map_err(|e| PyValueError::new_err(format!("{what} must be an array of numbers: {e}")))?;
    let shape = array.shape().to_vec();
    let (n, flat) = match (shape.as_slice(), rows) {
        ([m], _) if *m == N && flat_ok && rows.is_none_or(|r| r == 1) => (1, true),
        ([r, m], Some(want)) if *m == N && *r == want => (want, false),
        ([r, m], None) if *m == N => (*r, false),
        _ => {
            let want = match (rows, flat_ok) {
                (Some(r), _) => format!("({r}, {N})"),
                (None, true) => format!("({N},) or (n, {N})"),
                (None, false) => format!("(n, {N})"),
            };
            return Err(PyValueError::new_err(format!(
                "{what} must have shape {want}, got {}",
                shape_text(&shape)
            )));
        }
    };
    let view = array.as_array();
    let mut out = vec![[0.0; N]; n];
    for (i, v) in view.iter().enumerate() {
        if !v.is_finite() {
            return Err(PyValueError::new_err(format!(
                "{what} must be finite, got {v} at flat index {i}"
            )));
        }
        out[i / N][i % N] = *v;
    }
    Ok((out, flat))
}

/// One row of `N` finite numbers from an `(N,)` array-like.
pub fn row<const N: usize>(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<[f64; N]> {
    let array: PyArrayLikeDyn<'_, f64, AllowTypeChange> = obj
        .extract()
        .map_err(|e| PyValueError::new_err(format!("{what} must be an array of numbers: {e}")))?;
    if array.shape() != [N] {
        return Err(PyValueError::new_err(format!(
            "{what} must have shape ({N},), got {}",
            shape_text(array.shape())
        )));
    }
    let mut out = [0.0; N];
    for (o, v) in out.iter_mut().zip(array.as_array().iter()) {
        if !v.is_finite() {
            return Err(PyValueError::new_err(format!(
                "{what} must be finite, got {v}"
            )));
        }
        *o = *v;
    }
    Ok(out)
}

/// A shape as Python prints it: `(2,)`, `(3, 2)`.
fn shape_text(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// A new `(N,)` float64 array.
pub fn vector<'py, const N: usize>(py: Python<'py>, v: &[f64; N]) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, v)
}

/// A new float64 array of `shape` holding `data` (row-major).
pub fn f64s<'py>(py: Python<'py>, data: Vec<f64>, shape: &[usize]) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, data).reshape(shape)?.into_any())
}

/// A new uint8 array of `shape` holding `data` (row-major).
pub fn u8s<'py>(py: Python<'py>, data: Vec<u8>, shape: &[usize]) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, data).reshape(shape)?.into_any())
}

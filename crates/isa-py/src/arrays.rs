//! NumPy in and out. In: strict argument checks (dtype, number of dimensions, shape,
//! C-contiguity, finiteness) whose messages name the argument, what was expected and what was
//! given. Out: row-major arrays from vectors or from per-row fixed-size items.

use numpy::ndarray::Array2;
use numpy::prelude::*;
use numpy::{Element, PyArray1, PyArray2, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArray};
use pyo3::prelude::*;
use pyo3::types::PyList;

use isa_core::criterion::RawTargets;
use isa_core::{DepthStore, Part, TrainingSet};

use crate::errors::input_err;

/// "float64 array of shape (10, 3)" or the Python type name.
pub fn describe(obj: &Bound<'_, PyAny>) -> String {
    if let Ok(a) = obj.cast::<PyUntypedArray>() {
        let dt = a
            .dtype()
            .str()
            .map(|s| s.to_string())
            .unwrap_or_else(|_| "?".into());
        let contig = if a.is_c_contiguous() {
            ""
        } else {
            " (not C-contiguous)"
        };
        let dims: Vec<String> = a.shape().iter().map(|d| d.to_string()).collect();
        let tuple = if dims.len() == 1 {
            format!("({},)", dims[0])
        } else {
            format!("({})", dims.join(", "))
        };
        format!("{dt} array of shape {tuple}{contig}")
    } else {
        obj.get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_else(|_| "?".into())
    }
}

/// A 3x3 matrix argument (any nested sequence of numbers), rows as given.
pub fn mat3_rows(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<[[f64; 3]; 3]> {
    obj.extract().map_err(|_| {
        input_err(format!(
            "{name}: expected a 3x3 matrix, got {}",
            describe(obj)
        ))
    })
}

/// A 3-vector argument (any sequence of 3 numbers).
pub fn vec3(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<[f64; 3]> {
    obj.extract()
        .map_err(|_| input_err(format!("{name}: expected 3 numbers, got {}", describe(obj))))
}

/// A pose's translation argument `t` (`#[pyo3(from_py_with = t_arg)]`).
pub fn t_arg(obj: &Bound<'_, PyAny>) -> PyResult<[f64; 3]> {
    vec3(obj, "t")
}

/// Borrows `obj` as a C-contiguous `dtype` array of `ndim` dimensions whose shape matches
/// `shape` (None = any size). `want` names the dtype for messages.
pub fn array<'py, T: Element>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    want: &str,
    shape: &[Option<usize>],
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    let expect = {
        let dims: Vec<String> = shape
            .iter()
            .map(|d| d.map_or("n".into(), |v| v.to_string()))
            .collect();
        format!("a C-contiguous {want} array of shape ({})", dims.join(", "))
    };
    let arr = obj
        .cast::<PyArrayDyn<T>>()
        .map_err(|_| input_err(format!("{name}: expected {expect}, got {} (convert with np.ascontiguousarray({name}, dtype=np.{want}))", describe(obj))))?;
    let sh = arr.shape();
    if sh.len() != shape.len()
        || sh
            .iter()
            .zip(shape)
            .any(|(s, w)| w.is_some_and(|w| w != *s))
    {
        return Err(input_err(format!(
            "{name}: expected {expect}, got {}",
            describe(obj)
        )));
    }
    if !arr.is_c_contiguous() {
        return Err(input_err(format!(
            "{name}: expected {expect}, got a non-contiguous array (use np.ascontiguousarray({name}))"
        )));
    }
    Ok(arr.readonly())
}

/// Checks a float array has no NaN or infinity.
pub fn check_finite(a: &[f32], name: &str, cols: usize) -> PyResult<()> {
    if let Some(k) = a.iter().position(|v| !v.is_finite()) {
        let cols = cols.max(1);
        return Err(input_err(format!(
            "{name}[{}, {}] is not finite ({})",
            k / cols,
            k % cols,
            a[k]
        )));
    }
    Ok(())
}

/// Copies a list of uint16 2D C-contiguous depth images (mm, 0 = missing) into a store.
pub fn depth_store(images: &Bound<'_, PyAny>) -> PyResult<DepthStore> {
    let list = images.cast::<PyList>().map_err(|_| {
        input_err(format!(
            "images: expected a list of uint16 2D arrays, got {}",
            describe(images)
        ))
    })?;
    let mut store = DepthStore::new();
    for (i, img) in list.iter().enumerate() {
        let a = array::<u16>(&img, &format!("images[{i}]"), "uint16", &[None, None])?;
        let sh = a.shape().to_vec();
        store
            .push(sh[1], sh[0], as_slice(&a, &format!("images[{i}]"))?)
            .map_err(crate::errors::to_py)?;
    }
    Ok(store)
}

/// The rows of a checked C-contiguous `dtype` array of shape `(n, N)` (`want` names the dtype
/// for messages, as in [`array`]).
pub fn fixed_rows<T: Element + Copy, const N: usize>(
    obj: &Bound<'_, PyAny>,
    name: &str,
    want: &str,
) -> PyResult<Vec<[T; N]>> {
    let a = array::<T>(obj, name, want, &[None, Some(N)])?;
    Ok(as_slice(&a, name)?
        .chunks_exact(N)
        .map(|c| c.try_into().expect("rows of N values"))
        .collect())
}

/// Copies `(P, 3)` int32 parts.
pub fn parts(obj: &Bound<'_, PyAny>) -> PyResult<Vec<Part>> {
    fixed_rows(obj, "parts", "int32")
}

/// A checked C-contiguous float32 array of `shape` with finite values.
pub fn f32_array<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    shape: &[Option<usize>],
) -> PyResult<PyReadonlyArrayDyn<'py, f32>> {
    let a = array::<f32>(obj, name, "float32", shape)?;
    let cols = a.shape().get(1).copied().unwrap_or(1);
    check_finite(as_slice(&a, name)?, name, cols)?;
    Ok(a)
}

/// A training set's per-part targets as `Forest.fit` takes them: `offsets` (P, 3), `rotations`
/// (P, 4), `link_angles` (P, L) and `node_offsets` (P, 3N) or None; float32, finite. Borrowed.
pub struct Targets<'py> {
    pub offsets: PyReadonlyArrayDyn<'py, f32>,
    pub rotations: PyReadonlyArrayDyn<'py, f32>,
    pub link_angles: Option<PyReadonlyArrayDyn<'py, f32>>,
    pub node_offsets: Option<PyReadonlyArrayDyn<'py, f32>>,
}

impl<'py> Targets<'py> {
    /// Checks the arrays; `n` parts (None: as many as `offsets` has rows).
    pub fn new(
        n: Option<usize>,
        offsets: &Bound<'py, PyAny>,
        rotations: &Bound<'py, PyAny>,
        link_angles: Option<&Bound<'py, PyAny>>,
        node_offsets: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Self> {
        let offsets = f32_array(offsets, "offsets", &[n, Some(3)])?;
        let n = Some(offsets.shape()[0]);
        let per_part = |o: Option<&Bound<'py, PyAny>>, name: &str| {
            given(o).map(|o| f32_array(o, name, &[n, None])).transpose()
        };
        Ok(Targets {
            rotations: f32_array(rotations, "rotations", &[n, Some(4)])?,
            link_angles: per_part(link_angles, "link_angles")?,
            node_offsets: per_part(node_offsets, "node_offsets")?,
            offsets,
        })
    }

    /// The number of parts.
    pub fn n_parts(&self) -> usize {
        self.offsets.shape()[0]
    }

    /// The core's view of the arrays.
    pub fn raw(&self) -> RawTargets<'_> {
        fn flat<'a>(a: &'a PyReadonlyArrayDyn<'_, f32>) -> &'a [f32] {
            a.as_slice().expect("checked contiguous")
        }
        fn cols<'a>(a: &'a PyReadonlyArrayDyn<'_, f32>) -> (&'a [f32], usize) {
            (flat(a), a.shape()[1])
        }
        RawTargets {
            offsets: flat(&self.offsets),
            rotations: flat(&self.rotations),
            link_angles: self.link_angles.as_ref().map(cols),
            node_offsets: self.node_offsets.as_ref().map(cols),
        }
    }
}

/// The depth crops and parts of a training set as `TrainSet` takes them
/// (`images`, `parts`), to which [`TrainParts::targets`] adds the per-part targets.
pub struct TrainParts {
    pub store: DepthStore,
    pub parts: Vec<Part>,
}

impl TrainParts {
    pub fn new(images: &Bound<'_, PyAny>, parts: &Bound<'_, PyAny>) -> PyResult<Self> {
        let store = depth_store(images)?;
        let parts = self::parts(parts)?;
        Ok(TrainParts { store, parts })
    }

    /// The [`Targets`] of these parts (one row per part).
    pub fn targets<'py>(
        &self,
        offsets: &Bound<'py, PyAny>,
        rotations: &Bound<'py, PyAny>,
        link_angles: Option<&Bound<'py, PyAny>>,
        node_offsets: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Targets<'py>> {
        let n = Some(self.parts.len());
        Targets::new(n, offsets, rotations, link_angles, node_offsets)
    }

    /// The core's training set: these parts with `targets`.
    pub fn training_set<'a>(&'a self, targets: &'a Targets<'_>) -> TrainingSet<'a> {
        TrainingSet {
            store: &self.store,
            parts: &self.parts,
            targets: targets.raw(),
        }
    }
}

/// The contiguous data of a checked array.
pub fn as_slice<'a, T: Element>(a: &'a PyReadonlyArrayDyn<'_, T>, name: &str) -> PyResult<&'a [T]> {
    a.as_slice().map_err(|e| input_err(format!("{name}: {e}")))
}

/// `None` for an absent or `None` optional argument.
pub fn given<'a, 'py>(o: Option<&'a Bound<'py, PyAny>>) -> Option<&'a Bound<'py, PyAny>> {
    o.filter(|x| !x.is_none())
}

/// A (rows, cols) array of row-major `data`.
pub fn matrix<'py, T: Element>(
    py: Python<'py>,
    rows: usize,
    cols: usize,
    data: Vec<T>,
) -> Bound<'py, PyArray2<T>> {
    Array2::from_shape_vec((rows, cols), data)
        .expect("rows * cols values")
        .into_pyarray(py)
}

/// A (n, N) array, one row per item.
pub fn rows<'py, T: Element + Copy, const N: usize>(
    py: Python<'py>,
    items: impl ExactSizeIterator<Item = [T; N]>,
) -> Bound<'py, PyArray2<T>> {
    let n = items.len();
    let flat: Vec<T> = items.flatten().collect();
    matrix(py, n, N, flat)
}

/// A 1-D array.
pub fn vector<'py, T: Element>(py: Python<'py>, data: Vec<T>) -> Bound<'py, PyArray1<T>> {
    PyArray1::from_vec(py, data)
}

/// `dict[name] = value.name` for each field `name` of a core result (the result dicts use the
/// core's field names as keys).
macro_rules! set_fields {
    ($dict:expr, $value:expr; $($field:ident),+ $(,)?) => {
        $( $dict.set_item(stringify!($field), &$value.$field)?; )+
    };
}
pub(crate) use set_fields;

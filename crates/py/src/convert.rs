//! What every entry point shares: the panic guard, arrays in, JSON out, and the record an
//! entry point works on (a [`Record`] from `read_record`, or arrays and a sample interval).

use crate::Error;
use crate::record::Record;
use boucwen_lab::record::{self, ImportInfo};
use numpy::PyReadonlyArray1;
use numpy::ndarray::ArrayView1;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use serde_json::Value;
use std::panic::{AssertUnwindSafe, catch_unwind};

/// The source name of a record given as arrays, unless the caller names it.
pub const ARRAYS: &str = "<arrays>";

/// Runs `f` without the GIL, with a panic caught and turned into [`Error`]: no Rust panic
/// crosses into Python. `f`'s own error is the library's message.
pub fn guarded<T: Send>(
    py: Python<'_>,
    what: &str,
    f: impl FnOnce() -> Result<T, String> + Send,
) -> PyResult<T> {
    let out = py.detach(|| catch_unwind(AssertUnwindSafe(f)));
    match out {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(msg)) => Err(Error::new_err(msg)),
        Err(panic) => {
            let why = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "no message".into());
            Err(Error::new_err(format!("{what}: internal error (a bug in boucwen, please report it): {why}")))
        }
    }
}

/// A 1-D sequence of numbers as `f64` samples: a float64 array is read as it is; anything
/// else NumPy can make one of (a list, a float32 array, a pandas Series) is converted first.
pub fn floats(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<f64>> {
    if let Ok(a) = obj.extract::<PyReadonlyArray1<'_, f64>>() {
        return Ok(samples(a.as_array()));
    }
    let py = obj.py();
    let kwargs = PyDict::new(py);
    kwargs.set_item("dtype", "float64")?;
    let converted = py
        .import("numpy")?
        .call_method("asarray", (obj,), Some(&kwargs))
        .map_err(|e| Error::new_err(format!("{what}: not an array of numbers ({e})")))?;
    match converted.extract::<PyReadonlyArray1<'_, f64>>() {
        Ok(a) => Ok(samples(a.as_array())),
        Err(_) => {
            let shape = converted.getattr("shape").and_then(|s| s.str()).map(|s| s.to_string());
            Err(Error::new_err(format!(
                "{what}: expected a 1-D array of samples, got shape {}",
                shape.unwrap_or_else(|_| "?".into())
            )))
        }
    }
}

fn samples(a: ArrayView1<'_, f64>) -> Vec<f64> {
    match a.as_slice() {
        Some(s) => s.to_vec(),
        None => a.iter().copied().collect(),
    }
}

/// A JSON value as Python objects: objects as dicts, arrays as lists, `null` as `None`.
pub fn to_py(py: Python<'_>, v: &Value) -> PyResult<Py<PyAny>> {
    Ok(match v {
        Value::Null => py.None(),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any().unbind(),
        Value::Number(n) => {
            if let Some(i) = n.as_i64() {
                i.into_pyobject(py)?.into_any().unbind()
            } else if let Some(u) = n.as_u64() {
                u.into_pyobject(py)?.into_any().unbind()
            } else {
                n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any().unbind()
            }
        }
        Value::String(s) => s.into_pyobject(py)?.into_any().unbind(),
        Value::Array(a) => {
            let items = a.iter().map(|x| to_py(py, x)).collect::<PyResult<Vec<_>>>()?;
            PyList::new(py, items)?.into_any().unbind()
        }
        Value::Object(o) => {
            let d = PyDict::new(py);
            for (k, x) in o {
                d.set_item(k, to_py(py, x)?)?;
            }
            d.into_any().unbind()
        }
    })
}

/// The record an entry point works on: `read_record`'s (then `y` and `ts` are not given),
/// or `u`, `y` and `ts` (s) as arrays, the first sample at `t0` (s).
pub struct Input {
    /// The record, checked as the importer checks one.
    pub record: record::Record,
    /// How it was read, if it came from a file.
    pub info: Option<ImportInfo>,
}

impl Input {
    pub fn of(
        u: &Bound<'_, PyAny>,
        y: Option<&Bound<'_, PyAny>>,
        ts: Option<f64>,
        t0: f64,
        source: Option<&str>,
    ) -> PyResult<Self> {
        if let Ok(r) = u.cast::<Record>() {
            if y.is_some() || ts.is_some() {
                return Err(Error::new_err(
                    "a Record carries its own y and ts: give either a Record or u, y and ts",
                ));
            }
            let r = r.borrow();
            let mut record = r.to_lab(u.py())?;
            if let Some(s) = source {
                record.source = s.to_string();
            }
            return Ok(Input { record, info: Some(r.info.clone()) });
        }
        let (Some(y), Some(ts)) = (y, ts) else {
            return Err(Error::new_err(
                "give u, y and ts (the sample interval, s), or a Record from read_record",
            ));
        };
        let (u, y) = (floats(u, "u")?, floats(y, "y")?);
        let record = record::Record::new(source.unwrap_or(ARRAYS), t0, ts, u, y, None)
            .map_err(|e| Error::new_err(e.to_string()))?;
        Ok(Input { record, info: None })
    }

    /// The record's name in messages and JSON (`file`).
    pub fn name(&self) -> String {
        self.record.source.clone()
    }

    /// How the record was read, as the commands' JSON has it (`import`), if from a file.
    pub fn import_json(&self) -> Option<serde_json::Value> {
        let r = &self.record;
        self.info.as_ref().map(|i| crate::record::import_json(i, r.len(), r.ts))
    }

    /// `window = (start_s, end_s)` in samples of the record, as `--window START:END` reads it
    /// (seconds of the record's time axis, rounded to the nearest sample).
    pub fn window(&self, window: Option<(f64, f64)>) -> PyResult<Option<(usize, usize)>> {
        let Some((a, b)) = window else { return Ok(None) };
        let r = &self.record;
        let t_end = r.t0 + r.len() as f64 * r.ts;
        let k = |t: f64| ((t - r.t0) / r.ts).round();
        let (s, e) = (k(a), k(b));
        if !(a.is_finite() && b.is_finite() && s >= 0.0 && e <= r.len() as f64 && e > s) {
            let p = record::for_people;
            return Err(Error::new_err(format!(
                "{}: window ({}, {}) is not a part of the record, which runs from {} to {} s",
                r.source,
                p(a),
                p(b),
                p(r.t0),
                p(t_end)
            )));
        }
        Ok(Some((s as usize, e as usize)))
    }
}

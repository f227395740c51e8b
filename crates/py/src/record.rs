//! `read_record`: a record file read by the importer every command uses
//! ([`boucwen_lab::record::import`]), as arrays and what the importer said.

use crate::Error;
use crate::convert::{guarded, to_py};
use boucwen_lab::record::{
    self, ColumnMap, ImportInfo, ImportOptions, Imported, LengthUnit, TimeUnit, VoltUnit,
};
use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// A record as read: `t` (s), `u` (V), `y` (µm) and, for a tracking run, `d` (µm), each a
/// 1-D float64 array, read-only (they are what the importer read, and what `identify(rec)`
/// and `diagnose(rec)` use); `ts` and `t0` (s); `source` (the file); `notes` (how the file
/// was read, one line, as the commands print it after "read as") and `import_info` (the same
/// as the `import` object of `boucwen diagnose --json`).
#[pyclass(module = "boucwen", frozen)]
pub struct Record {
    source: String,
    ts: f64,
    t0: f64,
    u: Py<PyArray1<f64>>,
    y: Py<PyArray1<f64>>,
    d: Option<Py<PyArray1<f64>>>,
    /// How the file was read.
    pub info: ImportInfo,
}

impl Record {
    /// The importer's record as arrays: its samples moved into NumPy, not copied.
    fn new(py: Python<'_>, imported: Imported) -> PyResult<Self> {
        let Imported { record: r, info } = imported;
        let array = |v: Vec<f64>| -> PyResult<Py<PyArray1<f64>>> {
            let a = PyArray1::from_vec(py, v);
            let kwargs = PyDict::new(py);
            kwargs.set_item("write", false)?;
            a.call_method("setflags", (), Some(&kwargs))?;
            Ok(a.unbind())
        };
        Ok(Record {
            source: r.source,
            ts: r.ts,
            t0: r.t0,
            u: array(r.u)?,
            y: array(r.y)?,
            d: r.d.map(array).transpose()?,
            info,
        })
    }

    /// The library's record (the samples copied; checked when the file was read).
    pub fn to_lab(&self, py: Python<'_>) -> PyResult<record::Record> {
        let v =
            |a: &Py<PyArray1<f64>>| -> PyResult<Vec<f64>> { Ok(a.bind(py).readonly().as_slice()?.to_vec()) };
        Ok(record::Record {
            source: self.source.clone(),
            ts: self.ts,
            t0: self.t0,
            u: v(&self.u)?,
            y: v(&self.y)?,
            d: self.d.as_ref().map(v).transpose()?,
        })
    }

    /// Samples.
    pub fn len(&self, py: Python<'_>) -> usize {
        self.u.bind(py).len()
    }
}

#[pymethods]
impl Record {
    /// Sample times `t0 + k·ts` (s), computed on each access.
    #[getter]
    fn t<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, (0..self.len(py)).map(|k| self.t0 + k as f64 * self.ts).collect())
    }

    /// The drive (V).
    #[getter]
    fn u<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.u.bind(py).clone()
    }

    /// The output (µm).
    #[getter]
    fn y<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.y.bind(py).clone()
    }

    /// The reference (µm) of a tracking run, else `None`.
    #[getter]
    fn d<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.d.as_ref().map(|d| d.bind(py).clone())
    }

    /// The sample interval (s).
    #[getter]
    fn ts(&self) -> f64 {
        self.ts
    }

    /// The time of the first sample (s).
    #[getter]
    fn t0(&self) -> f64 {
        self.t0
    }

    /// The file it was read from.
    #[getter]
    fn source(&self) -> &str {
        &self.source
    }

    /// How the file was read, one line ("comma-separated, with a header; t = …").
    #[getter]
    fn notes(&self) -> String {
        self.info.describe()
    }

    /// How the file was read, as a dict (`import` in `boucwen diagnose --json`).
    #[getter]
    fn import_info(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        to_py(py, &import_json(&self.info, self.len(py), self.ts))
    }

    fn __len__(&self, py: Python<'_>) -> usize {
        self.len(py)
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "Record({:?}: {} samples every {} s from t0 = {} s)",
            self.source,
            self.len(py),
            record::for_people(self.ts),
            record::for_people(self.t0)
        )
    }
}

/// Reads a record file as the commands do (any separator, header or not, units in the
/// header, a preamble, decimal commas, a few missing samples, isolated spikes repaired).
///
/// `columns`: which column is which, as `--columns` ("t=1,u=2,y=3") or a dict
/// (`{"u": "Voltage", "y": 3}`: names, or positions from 1). `units`: a dict of the units
/// the file does not state, `{"t": "s"|"ms"|"us", "u": "V"|"mV"|"kV", "y": "m"|"mm"|"um"|"nm"}`.
/// `sample_rate` (Hz) for a file without a time column; `keep_spikes` as `--keep-spikes`.
#[pyfunction]
#[pyo3(signature = (path, columns=None, units=None, sample_rate=None, keep_spikes=false))]
pub fn read_record(
    py: Python<'_>,
    path: PathBuf,
    columns: Option<&Bound<'_, PyAny>>,
    units: Option<&Bound<'_, PyDict>>,
    sample_rate: Option<f64>,
    keep_spikes: bool,
) -> PyResult<Record> {
    let opts = options(columns, units, sample_rate, keep_spikes)?;
    let imported = guarded(py, "read_record", || record::import(&path, &opts).map_err(|e| e.to_string()))?;
    Record::new(py, imported)
}

/// The importer's options from `read_record`'s arguments (the flags' own parsers).
fn options(
    columns: Option<&Bound<'_, PyAny>>,
    units: Option<&Bound<'_, PyDict>>,
    sample_rate: Option<f64>,
    keep_spikes: bool,
) -> PyResult<ImportOptions> {
    let bad = |e: record::OptionError| Error::new_err(e.to_string());
    let columns = match columns {
        None => None,
        Some(c) => {
            let spec = if let Ok(d) = c.cast::<PyDict>() {
                let mut parts = vec![];
                for (role, col) in d.iter() {
                    parts.push(format!("{}={}", role.str()?, col.str()?));
                }
                parts.join(",")
            } else {
                c.extract::<String>().map_err(|_| {
                    Error::new_err("columns: a spec like \"t=1,u=2,y=3\" or a dict {\"u\": \"Voltage\"}")
                })?
            };
            Some(spec.parse::<ColumnMap>().map_err(bad)?)
        }
    };
    if let Some(hz) = sample_rate {
        if !(hz.is_finite() && hz > 0.0) {
            return Err(Error::new_err(format!(
                "sample_rate {}: must be a positive number of Hz",
                record::for_people(hz)
            )));
        }
    }
    let mut opts =
        ImportOptions { columns, sample_rate_hz: sample_rate, keep_spikes, ..ImportOptions::default() };
    if let Some(units) = units {
        for (k, v) in units.iter() {
            let (k, v) = (k.str()?.to_string(), v.str()?.to_string());
            match k.as_str() {
                "t" => opts.t_unit = Some(v.parse::<TimeUnit>().map_err(bad)?),
                "u" => opts.u_unit = Some(v.parse::<VoltUnit>().map_err(bad)?),
                "y" | "d" => opts.y_unit = Some(v.parse::<LengthUnit>().map_err(bad)?),
                other => {
                    return Err(Error::new_err(format!(
                        "units: {other:?} is not a signal; the keys are \"t\", \"u\" and \"y\""
                    )));
                }
            }
        }
    }
    Ok(opts)
}

pub use boucwen_lab::report::import_json;

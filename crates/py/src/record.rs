//! `read_record`: a record file read by the importer every command uses
//! ([`boucwen_lab::record::import`]), as arrays and what the importer said.

use crate::Error;
use crate::convert::{guarded, to_py};
use boucwen_lab::record::{
    self, ColumnMap, ImportOptions, Imported, LengthUnit, TimeSource, TimeUnit, VoltUnit,
};
use numpy::{PyArray1, ToPyArray};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// A record as read: `t` (s), `u` (V), `y` (µm) and, for a tracking run, `d` (µm), each a
/// 1-D float64 array; `ts` and `t0` (s); `source` (the file); `notes` (how the file was
/// read, one line, as the commands print it after "read as") and `import_info` (the same as
/// the `import` object of `boucwen diagnose --json`).
#[pyclass(module = "boucwen", frozen)]
pub struct Record {
    /// The record and how its file was read.
    pub imported: Imported,
}

#[pymethods]
impl Record {
    /// Sample times `t0 + k·ts` (s).
    #[getter]
    fn t<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let r = &self.imported.record;
        PyArray1::from_vec(py, (0..r.len()).map(|k| r.time(k)).collect())
    }

    /// The drive (V).
    #[getter]
    fn u<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.imported.record.u.to_pyarray(py)
    }

    /// The output (µm).
    #[getter]
    fn y<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.imported.record.y.to_pyarray(py)
    }

    /// The reference (µm) of a tracking run, else `None`.
    #[getter]
    fn d<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.imported.record.d.as_ref().map(|d| d.to_pyarray(py))
    }

    /// The sample interval (s).
    #[getter]
    fn ts(&self) -> f64 {
        self.imported.record.ts
    }

    /// The time of the first sample (s).
    #[getter]
    fn t0(&self) -> f64 {
        self.imported.record.t0
    }

    /// The file it was read from.
    #[getter]
    fn source(&self) -> &str {
        &self.imported.record.source
    }

    /// How the file was read, one line ("comma-separated, with a header; t = …").
    #[getter]
    fn notes(&self) -> String {
        self.imported.info.describe()
    }

    /// How the file was read, as a dict (`import` in `boucwen diagnose --json`).
    #[getter]
    fn import_info(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        to_py(py, &import_json(&self.imported))
    }

    fn __len__(&self) -> usize {
        self.imported.record.len()
    }

    fn __repr__(&self) -> String {
        let r = &self.imported.record;
        format!(
            "Record({:?}: {} samples every {} s from t0 = {} s)",
            r.source,
            r.len(),
            record::for_people(r.ts),
            record::for_people(r.t0)
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
    Ok(Record { imported })
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

/// How the record was read, as the `import` object of `boucwen diagnose --json` and
/// `identify --json` (the same fields as the command's; crates/py/tests compares them).
pub fn import_json(i: &Imported) -> serde_json::Value {
    let columns: serde_json::Map<String, serde_json::Value> =
        i.info.columns.iter().map(|(role, from)| (role.to_string(), serde_json::json!(from))).collect();
    serde_json::json!({
        "separator": i.info.separator.name(),
        "decimal_comma": i.info.decimal_comma,
        "cut_short_line": i.info.cut_short,
        "missing": i.info.missing.map(|m| serde_json::json!({ "count": m.count, "first_s": m.first_s })),
        "preamble": i.info.preamble.map(|p| serde_json::json!({ "lines": p.lines, "table_line": p.table_line })),
        "header": i.info.header,
        "columns": columns,
        "t_unit": i.info.t_unit.name(),
        "u_unit": i.info.u_unit.name(),
        "y_unit": i.info.y_unit.name(),
        "sample_rate_hz": match i.info.time { TimeSource::SampleRate(hz) => Some(hz), TimeSource::Column(_) => None },
        "samples": i.record.len(),
        "ts_s": i.record.ts,
        "spikes": i.info.spikes.as_ref().map(|s| serde_json::json!({
            "count": s.count,
            "departure_um": s.departure_um,
            "first_s": s.first_s,
        })),
    })
}

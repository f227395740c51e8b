//! `sweep`: the paper's identification and compensation experiments over a frequency range
//! on the virtual bimorph, as `boucwen sweep` (crates/cli/src/cmd_sweep.rs), the table as a
//! dict of arrays.

use crate::Error;
use crate::convert::guarded;
use boucwen_lab::design::ResponseSource;
use boucwen_lab::experiments::sweep::{self as lab, CSV_HEADER, HarmonicChoice, SweepOptions};
use boucwen_lab::report;
use boucwen_sim::Scenario;
use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// Runs the sweep (on all cores) and returns its table: a dict with one float64 array per
/// column of `sweep.csv` (`freq_hz`, `rms_extended_um`, …; `NaN` where a model or a loop was
/// not stable; the harmonic orders as int64), in the CSV's order.
///
/// `from_hz`, `to_hz`, `step_hz`, `seconds`, `scenario` (a TOML file; the paper's actuator
/// if `None`), `harmonics` ("auto" or "paper") and `phase` ("probe", "model" or "table") as
/// the command's flags; `out`, a directory to write `sweep.csv` and the figures into too.
#[pyfunction]
#[pyo3(signature = (*, from_hz=1.0, to_hz=50.0, step_hz=1.0, seconds=15.0, scenario=None, harmonics="auto",
    phase="probe", out=None))]
#[allow(clippy::too_many_arguments)]
pub fn sweep<'py>(
    py: Python<'py>,
    from_hz: f64,
    to_hz: f64,
    step_hz: f64,
    seconds: f64,
    scenario: Option<PathBuf>,
    harmonics: &str,
    phase: &str,
    out: Option<PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    let harmonics = match harmonics {
        "auto" => HarmonicChoice::Auto,
        "paper" => HarmonicChoice::Paper,
        other => return Err(Error::new_err(format!("harmonics {other:?}: \"auto\" or \"paper\""))),
    };
    let response = match phase {
        "probe" => ResponseSource::Probe,
        "model" => ResponseSource::Model,
        "table" => ResponseSource::Table { flip_hz: 66.0 },
        other => return Err(Error::new_err(format!("phase {other:?}: \"probe\", \"model\" or \"table\""))),
    };
    let result = guarded(py, "sweep", || {
        let scenario = match &scenario {
            Some(p) => Scenario::from_path(p).map_err(|e| e.to_string())?,
            None => Scenario::default(),
        };
        let mut opts = SweepOptions::paper(seconds);
        opts.freqs = lab::frequencies(from_hz, to_hz, step_hz).map_err(|e| e.to_string())?;
        opts.scenario = scenario;
        opts.harmonics = harmonics;
        opts.response = response;
        let result = lab::run(&opts, &|| {}).map_err(|e| e.to_string())?;
        if let Some(dir) = &out {
            report::write_sweep(&result, dir).map_err(|e| e.to_string())?;
        }
        Ok(result)
    })?;
    // The columns by the CSV's header, the values from the rows' own serialisation (one list
    // of names: the CSV's).
    let rows: Vec<serde_json::Value> = result
        .rows
        .iter()
        .map(|r| serde_json::to_value(r).map_err(|e| Error::new_err(format!("sweep row as JSON: {e}"))))
        .collect::<PyResult<_>>()?;
    let d = PyDict::new(py);
    for name in CSV_HEADER.split(',') {
        let values = rows.iter().map(|r| &r[name]);
        if name.ends_with("_order") {
            let v: Vec<i64> = values.map(|x| x.as_i64().unwrap_or(0)).collect();
            d.set_item(name, PyArray1::from_vec(py, v))?;
        } else {
            // NaN is serialised as null.
            let v: Vec<f64> = values.map(|x| x.as_f64().unwrap_or(f64::NAN)).collect();
            d.set_item(name, PyArray1::from_vec(py, v))?;
        }
    }
    Ok(d)
}

//! `identify` and the [`Model`] it returns: parameters, free run, the model file, `compare`.
//! The same calls as `boucwen identify` (crates/cli/src/cmd_identify.rs), `simulate --model`
//! and `compare`.

use crate::Error;
use crate::convert::{Input, floats, guarded, to_py};
use boucwen_lab::identify::{self as lab, Method, Options, Structure, compare, families};
use boucwen_lab::model::{Family, ModelFile, TermModel};
use boucwen_lab::report::diagnosis::instability_text;
use boucwen_lab::report::identify as report;
use boucwen_lab::rules::Rules;
use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde_json::{Value, json};
use std::path::PathBuf;

/// A fitted model of any family (the paper's actuator, the Bouc–Wen oscillator, a linear
/// model) with the sample interval it runs at: what `boucwen identify --save` writes.
///
/// `params` (dict, the model file's units), `family`, `name`, `ts`, `fitted_on`,
/// `held_out_rms_um`; `report`: the identification as `boucwen identify --json` prints it
/// (`None` for a model loaded from a file).
#[pyclass(module = "boucwen", frozen)]
pub struct Model {
    file: ModelFile,
    report: Option<Value>,
}

#[pymethods]
impl Model {
    /// Every parameter by name, in the model file's units (the actuator's `a1`, `a2`, `A1`,
    /// `A`, `A0`, `gamma`, `beta`, branches, drift, delay; the oscillator's seven SI
    /// parameters; the linear model's `b0…`, `f1…`).
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, v) in self.file.model.parameters() {
            d.set_item(name, v)?;
        }
        Ok(d)
    }

    /// "actuator", "oscillator" or "linear".
    #[getter]
    fn family(&self) -> &'static str {
        self.file.model.family().name()
    }

    /// A short name: "enhanced(3)", "oscillator", "linear(nb=2,nf=3,nk=1)".
    #[getter]
    fn name(&self) -> String {
        self.file.model.name()
    }

    /// The sample interval it runs at (s).
    #[getter]
    fn ts(&self) -> f64 {
        self.file.ts_s
    }

    /// The record it was fitted on.
    #[getter]
    fn fitted_on(&self) -> Option<String> {
        self.file.fitted_on.clone()
    }

    /// Its free-run RMS error on the held-out part of that record (µm).
    #[getter]
    fn held_out_rms_um(&self) -> Option<f64> {
        self.file.held_out_rms_um
    }

    /// The identification as `boucwen identify --json` prints it; `None` if loaded.
    #[getter]
    fn report(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        match &self.report {
            Some(v) => to_py(py, v),
            None => Ok(py.None()),
        }
    }

    /// The free-run output (µm) for the drive `u` (V) from rest, as `simulate --model`;
    /// with `periodic=True`, `u` is one period of a periodic drive and the output is the
    /// steady state (the period run once before), as `compare --periodic`.
    #[pyo3(signature = (u, periodic=false))]
    fn simulate<'py>(
        &self,
        py: Python<'py>,
        u: &Bound<'py, PyAny>,
        periodic: bool,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let u = floats(u, "u")?;
        let m = &self.file;
        let y = guarded(py, "simulate", || {
            if periodic {
                m.model.simulate_periodic(&u, m.ts_s, compare::PERIODIC_WARMUP)
            } else {
                m.model.simulate(&u, m.ts_s)
            }
            .map_err(|e| format!("the model cannot run on this drive: {e}"))
        })?;
        Ok(PyArray1::from_vec(py, y))
    }

    /// Runs the model on another record's drive and scores it against its output, as
    /// `boucwen compare`: a dict with `rms_um`, `fit_pct`, `nrmse`, `output_rms_um`,
    /// `window_samples`, `model`, `fitted_on`, `file` (the fields of `compare --json`) and
    /// `simulated` (the model's output, µm). Give `u` and `y` (arrays at the model's `ts`)
    /// or a Record; `window = (start_s, end_s)` as `--window`; `periodic` as `--periodic`.
    #[pyo3(signature = (u, y=None, *, window=None, periodic=false, t0=0.0))]
    fn compare<'py>(
        &self,
        py: Python<'py>,
        u: &Bound<'py, PyAny>,
        y: Option<&Bound<'py, PyAny>>,
        window: Option<(f64, f64)>,
        periodic: bool,
        t0: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let ts = y.is_some().then_some(self.file.ts_s);
        let input = Input::of(u, y, ts, t0, None)?;
        let window = input.window(window)?;
        let name = input.name();
        let m = &self.file;
        let r = &input.record;
        let c = guarded(py, "compare", || {
            compare::compare(m, r, window, periodic).map_err(|e| format!("{name}: {e}"))
        })?;
        let mut j = report::comparison_json(&c, m);
        j["file"] = json!(name);
        let d = to_py(py, &j)?.into_bound(py).cast_into::<PyDict>()?;
        d.set_item("simulated", PyArray1::from_vec(py, c.simulated))?;
        Ok(d)
    }

    /// Writes the model file (the format `boucwen identify --save` writes and `boucwen
    /// compare` reads), atomically.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let f = &self.file;
        guarded(py, "save", || f.write(&path).map_err(|e| e.to_string()))
    }

    /// Reads a model file (`boucwen identify --save`, or `Model.save`).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Model> {
        let file = guarded(py, "load", || ModelFile::read(&path).map_err(|e| e.to_string()))?;
        Ok(Model { file, report: None })
    }

    /// The model file's text (JSON).
    fn to_json(&self) -> String {
        self.file.to_json()
    }

    fn __repr__(&self) -> String {
        let held = self.file.held_out_rms_um.map_or(String::new(), |v| format!(", held out {v:.4} µm RMS"));
        format!("Model({}: {}, ts = {} s{held})", self.family(), self.name(), self.file.ts_s)
    }
}

/// Fits a model to a record and returns it, as `boucwen identify --save`: the steady window
/// found in the record, `fit_fraction` of it fitted (whole periods of a periodic drive), the
/// rest held out.
///
/// Give `u` (V), `y` (µm) and `ts` (s), or a Record from `read_record` alone. `model`:
/// "auto" (every family fitted, one kept by the rules' stated choice), "extended",
/// "enhanced" (with `harmonics`, else the odd harmonic that stands out), "oscillator" or
/// "linear". `method`: "oe" (output error) or "rls" (the paper's RLS; extended or enhanced
/// only). `drive_hz`, `invertible`, `window = (start_s, end_s)` as the command's flags;
/// `source` names the record in messages and in the model file (`fitted_on`).
/// Raises `boucwen.Error` with the command's message when no stable model is found.
#[pyfunction]
#[pyo3(signature = (u, y=None, ts=None, *, model="auto", method="oe", harmonics=None, fit_fraction=0.5,
    drive_hz=None, invertible=false, window=None, t0=0.0, source=None))]
#[allow(clippy::too_many_arguments)]
pub fn identify(
    py: Python<'_>,
    u: &Bound<'_, PyAny>,
    y: Option<&Bound<'_, PyAny>>,
    ts: Option<f64>,
    model: &str,
    method: &str,
    harmonics: Option<Vec<u32>>,
    fit_fraction: f64,
    drive_hz: Option<f64>,
    invertible: bool,
    window: Option<(f64, f64)>,
    t0: f64,
    source: Option<String>,
) -> PyResult<Model> {
    let input = Input::of(u, y, ts, t0, source.as_deref())?;
    let given = input.window(window)?;
    let families = match model {
        "linear" => Some(vec![Family::Linear]),
        "oscillator" => Some(vec![Family::Oscillator]),
        "auto" => Some(Family::ALL.to_vec()),
        "extended" | "enhanced" => None,
        other => {
            return Err(Error::new_err(format!(
                "model {other:?}: one of \"auto\", \"extended\", \"enhanced\", \"oscillator\", \"linear\""
            )));
        }
    };
    let method = match method {
        "oe" => Method::Oe,
        "rls" => Method::Rls,
        other => return Err(Error::new_err(format!("method {other:?}: \"oe\" or \"rls\""))),
    };
    let harmonics = harmonics.unwrap_or_default();
    if families.is_some() && (method == Method::Rls || !harmonics.is_empty()) {
        return Err(Error::new_err(
            "method \"rls\" and harmonics go with model \"extended\" or \"enhanced\"",
        ));
    }
    let opts = Options {
        structure: if model == "enhanced" { Structure::Enhanced } else { Structure::Extended },
        harmonics,
        method,
        fit_fraction,
        drive_hz,
        invertible,
    };
    let import = input.import_json();
    let Input { record: r, .. } = input;
    let name = r.source.clone();
    let (file, mut j) = guarded(py, "identify", || run(&r, given, families, &opts, &name))?;
    j["file"] = json!(name);
    if let Some(i) = import {
        j["import"] = i;
    }
    Ok(Model { file, report: Some(j) })
}

/// `boucwen identify` without the printing: the model file `--save` writes and the JSON of
/// `--json`, or the command's error.
fn run(
    r: &boucwen_lab::record::Record,
    given: Option<(usize, usize)>,
    families: Option<Vec<Family>>,
    opts: &Options,
    name: &str,
) -> Result<(ModelFile, Value), String> {
    let rules = Rules::default();
    r.validate_for_fit(rules.sine.min_samples).map_err(|e| e.to_string())?;
    let fail = |e: lab::IdentifyError| match e {
        lab::IdentifyError::Option(why) => why,
        e => format!("{name}: {e}"),
    };
    let file = |model, held| ModelFile {
        model,
        ts_s: r.ts,
        u_unit: "V".into(),
        fitted_on: Some(name.to_string()),
        held_out_rms_um: held,
    };
    if let Some(families) = families {
        let c = families::compare(r, given, &families, opts, &rules).map_err(fail)?;
        let kept = &c.scores[c.chosen];
        let Ok(model) = &kept.model else {
            return Err(format!("{name}: the {} model could not be fitted", kept.family.name()));
        };
        if kept.held_rms_um.is_none() {
            return Err(format!(
                "{name}: the {} model's free run is not stable held out",
                kept.family.name()
            ));
        }
        return Ok((file(model.clone(), kept.held_rms_um), report::families_json(&c)));
    }
    let o = lab::identify(r, given, opts, &rules).map_err(fail)?;
    if let Some(why) = &o.check.unstable {
        return Err(format!(
            "{name}: no stable model was found ({} by {}): {}",
            o.model.name(),
            o.method.name(),
            instability_text(why)
        ));
    }
    let model = boucwen_lab::model::Model::Actuator(TermModel::from(o.model.clone()));
    Ok((file(model, Some(o.held_rms_um)), report::json(&o)))
}

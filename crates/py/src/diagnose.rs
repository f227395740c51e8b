//! `diagnose` and the [`Diagnosis`] it returns: the findings with their typed evidence, the
//! JSON of `boucwen diagnose --json` and its report. The same calls as one record of
//! `boucwen diagnose` (crates/cli/src/cmd_diagnose.rs): a record that steps through several
//! sines is diagnosed step by step, any other by the drive found in it.

use crate::Error;
use crate::convert::{Input, guarded, to_py};
use boucwen_lab::diagnose as lab;
use boucwen_lab::diagnose::periodic::Realisation;
use boucwen_lab::diagnose::steps::{self, SineStep};
use boucwen_lab::record::Record;
use boucwen_lab::report::diagnosis as text;
use boucwen_lab::rules::Rules;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use serde_json::{Value, json};

/// What `diagnose` found.
///
/// `analysis`: "sine", "periodic" or "steps" (a record stepping through several sines);
/// `findings`: the findings, most important first, each a dict with `kind`, `cause` (the
/// sentence), `kept`, `residual_share`, … and `evidence` (the typed facts, `{"type": …}`);
/// for "steps", every step's in order. `gain_pct`: how much the extended model lowers the
/// baseline's held-out RMS. `steps`: each step's JSON object ("steps" only).
/// `to_json()` is what `boucwen diagnose --json` prints (one line; one per step);
/// `as_dict()` the same as Python objects; `report` the command's text.
#[pyclass(module = "boucwen", frozen)]
pub struct Diagnosis {
    /// The JSON lines of `--json`.
    lines: Vec<Value>,
    /// The text report.
    text: String,
    /// "sine", "periodic" or "steps".
    analysis: String,
}

#[pymethods]
impl Diagnosis {
    /// "sine", "periodic" or "steps".
    #[getter]
    fn analysis(&self) -> &str {
        &self.analysis
    }

    /// The findings, most important first (every step's, in order, for "steps").
    #[getter]
    fn findings(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let all: Vec<Value> = self
            .lines
            .iter()
            .filter_map(|l| l.get("findings").and_then(Value::as_array))
            .flatten()
            .cloned()
            .collect();
        to_py(py, &Value::Array(all))
    }

    /// How much the extended model lowers the baseline's held-out RMS (%); `None` for steps.
    #[getter]
    fn gain_pct(&self) -> Option<f64> {
        match self.analysis.as_str() {
            "steps" => None,
            _ => self.lines.first().and_then(|l| l.get("gain_pct")).and_then(Value::as_f64),
        }
    }

    /// Each step's JSON object for a stepped record, else `None`.
    #[getter]
    fn steps(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        if self.analysis != "steps" {
            return Ok(py.None());
        }
        let items = self.lines.iter().map(|l| to_py(py, l)).collect::<PyResult<Vec<_>>>()?;
        Ok(PyList::new(py, items)?.into_any().unbind())
    }

    /// The command's text report (what `boucwen diagnose` prints without `--json`).
    #[getter]
    fn report(&self) -> &str {
        &self.text
    }

    /// The JSON object as Python objects (a list of them for a stepped record).
    fn as_dict(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        match self.lines.as_slice() {
            [one] if self.analysis != "steps" => to_py(py, one),
            lines => to_py(py, &Value::Array(lines.to_vec())),
        }
    }

    /// What `boucwen diagnose --json` prints: one JSON object per line (one per step).
    fn to_json(&self) -> String {
        self.lines.iter().map(Value::to_string).collect::<Vec<_>>().join("\n")
    }

    fn __repr__(&self) -> String {
        let kinds: Vec<String> = self
            .lines
            .iter()
            .filter_map(|l| l.get("findings").and_then(Value::as_array))
            .flatten()
            .filter_map(|f| f.get("kind").and_then(Value::as_str).map(str::to_string))
            .collect();
        format!(
            "Diagnosis({}: {})",
            self.analysis,
            if kinds.is_empty() { "no findings".into() } else { kinds.join(", ") }
        )
    }
}

/// Diagnoses a record as `boucwen diagnose`: what the extended model gets wrong, the cause,
/// the term that removes it and the gain.
///
/// Give `u` (V), `y` (µm) and `ts` (s), or a Record from `read_record` alone (then
/// `to_json()` carries `file` and `import` as the command's). `rules`: `None` (the
/// defaults), a TOML or JSON file (as `--rules`), or a dict of overrides
/// (`{"sine": {"min_periods": 6}}`). `window = (start_s, end_s)` as `--window`.
#[pyfunction]
#[pyo3(signature = (u, y=None, ts=None, *, rules=None, window=None, t0=0.0, source=None))]
#[allow(clippy::too_many_arguments)]
pub fn diagnose(
    py: Python<'_>,
    u: &Bound<'_, PyAny>,
    y: Option<&Bound<'_, PyAny>>,
    ts: Option<f64>,
    rules: Option<&Bound<'_, PyAny>>,
    window: Option<(f64, f64)>,
    t0: f64,
    source: Option<String>,
) -> PyResult<Diagnosis> {
    let rules = rules_of(py, rules)?;
    let input = Input::of(u, y, ts, t0, source.as_deref())?;
    let given = input.window(window)?;
    let import = input.import_json();
    let read_as = input.info.as_ref().map_or(String::new(), |i| format!("read as {}\n", i.describe()));
    let record = input.record;
    let read = Read { import, read_as };
    guarded(py, "diagnose", || one(&record, &read, given, &rules))
}

/// The rules: the defaults, a file's overrides (TOML, or JSON by its name), or a dict's.
fn rules_of(py: Python<'_>, rules: Option<&Bound<'_, PyAny>>) -> PyResult<Rules> {
    let Some(rules) = rules else { return Ok(Rules::default()) };
    let (name, text) = if rules.cast::<PyDict>().is_ok() {
        let text: String = py.import("json")?.call_method1("dumps", (rules,))?.extract()?;
        ("rules.json".to_string(), text)
    } else {
        let path: std::path::PathBuf = rules
            .extract()
            .map_err(|_| Error::new_err("rules: None, a file (TOML or .json) or a dict of overrides"))?;
        let name = path.display().to_string();
        let text = std::fs::read_to_string(&path).map_err(|e| Error::new_err(format!("{name}: {e}")))?;
        (name, text)
    };
    Rules::parse(&name, &text).map_err(|e| Error::new_err(e.to_string()))
}

/// How a record from a file was read: the JSON's `import` and the report's first line.
struct Read {
    import: Option<Value>,
    read_as: String,
}

/// One record, as the command's `one`: the JSON lines and the text, or the one-line error.
fn one(r: &Record, read: &Read, given: Option<(usize, usize)>, rules: &Rules) -> Result<Diagnosis, String> {
    let name = r.source.clone();
    r.validate_for_fit(rules.sine.min_samples).map_err(|e| e.to_string())?;
    if given.is_none() {
        if let Some(steps) = steps::diagnose_steps(&r.u, &r.y, r.ts, r.t0, rules) {
            return stepped(r, read, &name, &steps, rules);
        }
    }
    let rec = Realisation { u: &r.u, y: &r.y, t0: r.t0, given };
    let d = lab::diagnose_drive(&[rec], r.ts, rules).map_err(|e| format!("{name}: {e}"))?;
    let mut j = text::json(&d, rules);
    j["file"] = json!(name);
    if let Some(i) = &read.import {
        j["import"] = i.clone();
    }
    let analysis = j["analysis"].as_str().unwrap_or("sine").to_string();
    Ok(Diagnosis {
        lines: vec![j],
        text: format!("{}{}", read.read_as, text::text(&d, &name, rules)),
        analysis,
    })
}

/// A record that steps through several sines, as the command's `stepped`.
fn stepped(
    r: &Record,
    read: &Read,
    name: &str,
    steps: &[SineStep],
    rules: &Rules,
) -> Result<Diagnosis, String> {
    let t = |k: usize| r.t0 + k as f64 * r.ts;
    if steps.iter().all(|s| s.outcome.is_err()) {
        let first = steps[0].outcome.as_ref().err().map(ToString::to_string).unwrap_or_default();
        return Err(format!(
            "{name}: {}; none could be: the first ({:.3} Hz) because {first}",
            text::steps_sentence(steps, r.ts, r.t0),
            steps[0].segment.freq_hz
        ));
    }
    let mut out = format!("{}{name}: {}\n", read.read_as, text::steps_sentence(steps, r.ts, r.t0));
    let mut lines = vec![];
    for (i, s) in steps.iter().enumerate() {
        let (from, to) = (t(s.segment.start), t(s.segment.end));
        let label = format!("{name} [step {} of {}: {:.3} Hz]", i + 1, steps.len(), s.segment.freq_hz);
        let step_json = json!({
            "index": i + 1, "of": steps.len(), "freq_hz": s.segment.freq_hz,
            "amplitude_v": s.segment.amplitude_v, "from_s": from, "to_s": to,
        });
        match &s.outcome {
            Ok(d) => {
                let mut j = text::json(d, rules);
                j["file"] = json!(name);
                j["step"] = step_json;
                if let Some(i) = &read.import {
                    j["import"] = i.clone();
                }
                lines.push(j);
                out.push_str(&format!(
                    "\n== step {} of {}: {from} to {to} s ==\n{}",
                    i + 1,
                    steps.len(),
                    text::text(d, &label, rules)
                ));
            }
            Err(e) => {
                lines.push(json!({"file": name, "step": step_json, "error": format!("{label}: {e}")}));
                out.push_str(&format!(
                    "\n== step {} of {}: {from} to {to} s ==\n{label}: {e}\n",
                    i + 1,
                    steps.len()
                ));
            }
        }
    }
    let across: Vec<String> = steps.iter().map(text::step_line).collect();
    out.push_str(&format!("\nacross the steps (held out):\n{}\n", across.join("\n")));
    Ok(Diagnosis { lines, text: out, analysis: "steps".into() })
}

//! The model file: a fitted model of any family, versioned, with the units it runs in, so a
//! model fitted on one record can be tested on another (`boucwen compare`) or run on a new
//! drive (`boucwen simulate --model`).
//!
//! ```json
//! {
//!   "format": "boucwen-model", "version": 1,
//!   "family": "oscillator", "ts_s": 0.0013333333,
//!   "units": { "u": "V", "y": "um" },
//!   "fitted_on": "train.csv", "held_out_rms_um": 7.35,
//!   "model": { "params": { "m": 2.0, "c": 10.0, … }, "substeps": 20, "output": "FirDecimation" }
//! }
//! ```
//! `model` holds the family's parameters: the actuator's AR part, Bouc–Wen parameters,
//! branches, drift, delay and terms; the oscillator's seven parameters (SI, metres) and its
//! integration; the linear model's `b`, `f`, `nk`. `units.u` is the unit the drive was
//! imported in (the importer converts mV and kV to V; a force is read as it is written) and
//! `units.y` is µm. A file of another format, a later version, an unknown field, a value
//! that is not finite or a model that cannot run is refused with one line naming the file
//! and the field.

use super::host::{Branch, HostModel, MAX_BRANCHES, MAX_DELAY};
use super::linear::LinearModel;
use super::oscillator::OscillatorModel;
use super::terms::Terms;
use super::{Model, TermModel};
use boucwen_core::model::{BoucWenParams, ExtendedParams};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// The file's `format`.
pub const FORMAT: &str = "boucwen-model";
/// The version this build writes and reads.
pub const VERSION: u32 = 1;
/// The largest model file read (bytes): a model is a few kB.
pub const MAX_BYTES: u64 = 1 << 20;
/// The most coefficients of a linear model's `B` or `F`.
pub const MAX_LINEAR_ORDER: usize = 64;
/// The most integration substeps of an oscillator per sample.
pub const MAX_SUBSTEPS: usize = 1000;

/// A model with what it needs to run on a record.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelFile {
    /// The model.
    pub model: Model,
    /// Its sample interval (s).
    pub ts_s: f64,
    /// The drive's unit.
    pub u_unit: String,
    /// The record it was fitted on.
    pub fitted_on: Option<String>,
    /// Its held-out RMS there (µm).
    pub held_out_rms_um: Option<f64>,
}

/// Reads a model file of at most [`MAX_BYTES`] and parses its text with `parse`; every error
/// names the file (the model files of one and of several inputs and outputs).
pub fn read_with<T>(path: &Path, parse: impl Fn(&str) -> Result<T, String>) -> Result<T, ModelFileError> {
    let file = path.display().to_string();
    let err = |what: String| ModelFileError { file: file.clone(), what };
    let len = std::fs::metadata(path).map_err(|e| err(format!("cannot read it: {e}")))?.len();
    if len > MAX_BYTES {
        return Err(err(format!("{len} bytes; a model file is at most {MAX_BYTES}")));
    }
    let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read it: {e}")))?;
    parse(&text).map_err(err)
}

/// Why a model file was refused.
#[derive(Debug)]
pub struct ModelFileError {
    /// The file.
    pub file: String,
    /// What is wrong, in one line.
    pub what: String,
}

impl fmt::Display for ModelFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.file, self.what)
    }
}

impl std::error::Error for ModelFileError {}

/// The units a model runs in (`units` of every model file).
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Units {
    pub(crate) u: String,
    pub(crate) y: String,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    format: String,
    version: u32,
    family: String,
    ts_s: f64,
    units: Units,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fitted_on: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    held_out_rms_um: Option<f64>,
    model: serde_json::Value,
}

/// The actuator in the file: eq. (9)'s AR part, the Bouc–Wen parameters, the branches, the
/// drift polynomial, the delay and the terms.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ActuatorFile {
    ar: [f64; 2],
    a1: f64,
    a: f64,
    a0: f64,
    gamma: f64,
    beta: f64,
    drive_hz: f64,
    #[serde(default)]
    branches: Vec<BranchFile>,
    #[serde(default)]
    drift: Vec<f64>,
    #[serde(default)]
    delay: f64,
    #[serde(default)]
    terms: Terms,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct BranchFile {
    order: u32,
    alpha_s: f64,
    alpha_c: f64,
    #[serde(default)]
    ar: [f64; 2],
}

impl ModelFile {
    /// The file's JSON text.
    pub fn to_json(&self) -> String {
        let (family, model) = match &self.model {
            Model::Actuator(m) => {
                let h = &m.host;
                let bw = h.ext.bw;
                let f = ActuatorFile {
                    ar: h.ext.ar,
                    a1: bw.a1,
                    a: bw.a,
                    a0: bw.a0,
                    gamma: bw.gamma,
                    beta: bw.beta,
                    drive_hz: h.drive_hz,
                    branches: h
                        .branches
                        .iter()
                        .map(|b| BranchFile {
                            order: b.order,
                            alpha_s: b.alpha_s,
                            alpha_c: b.alpha_c,
                            ar: b.ar,
                        })
                        .collect(),
                    drift: h.drift.clone(),
                    delay: h.delay,
                    terms: m.terms.clone(),
                };
                ("actuator", serde_json::to_value(f))
            }
            Model::Oscillator(o) => ("oscillator", serde_json::to_value(o)),
            Model::Linear(l) => ("linear", serde_json::to_value(l)),
        };
        let header = Header {
            format: FORMAT.into(),
            version: VERSION,
            family: family.into(),
            ts_s: self.ts_s,
            units: Units { u: self.u_unit.clone(), y: "um".into() },
            fitted_on: self.fitted_on.clone(),
            held_out_rms_um: self.held_out_rms_um.filter(|v| v.is_finite()),
            model: model.unwrap_or(serde_json::Value::Null),
        };
        serde_json::to_string_pretty(&header).unwrap_or_default() + "\n"
    }

    /// Writes the file atomically.
    pub fn write(&self, path: &Path) -> Result<(), crate::record::RecordError> {
        crate::record::write_atomic(path, self.to_json().as_bytes())
    }

    /// Reads and checks a model file.
    pub fn read(path: &Path) -> Result<Self, ModelFileError> {
        read_with(path, Self::parse)
    }

    /// Parses and checks a model file's text; the error says what is wrong and where.
    pub fn parse(text: &str) -> Result<Self, String> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let v: serde_json::Value = serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
        match v.get("format").and_then(|f| f.as_str()) {
            Some(FORMAT) => {}
            Some(other) => {
                return Err(format!(
                    "\"format\" is {:?}: not a model file (expected {FORMAT:?})",
                    crate::record::excerpt(other)
                ));
            }
            None => return Err(format!("no \"format\": not a model file (expected \"format\": {FORMAT:?})")),
        }
        match v.get("version") {
            Some(n) if n.as_u64() == Some(u64::from(VERSION)) => {}
            Some(n) if n.as_u64().is_some_and(|n| n > u64::from(VERSION)) => {
                return Err(format!(
                    "version {n}: this build reads version {VERSION}; a newer boucwen wrote it"
                ));
            }
            Some(n) => return Err(format!("\"version\" is {n}; expected {VERSION}")),
            None => return Err(format!("no \"version\" (expected {VERSION})")),
        }
        if v.get("family").and_then(|f| f.as_str()) == Some("mimo") {
            return Err("\"family\" is \"mimo\": a model of several inputs and outputs (boucwen_lab::mimo::MimoModelFile reads it)".into());
        }
        let h: Header = serde_json::from_value(v).map_err(|e| format!("{e}"))?;
        if !(h.ts_s.is_finite() && h.ts_s > 0.0 && h.ts_s < 1e3) {
            return Err(format!("\"ts_s\" is {}: a sample interval in seconds, > 0", h.ts_s));
        }
        if h.units.y != "um" {
            return Err(format!(
                "\"units.y\" is {:?}; models run in \"um\"",
                crate::record::excerpt(&h.units.y)
            ));
        }
        let model = match h.family.as_str() {
            "actuator" => Model::Actuator(actuator(h.model, h.ts_s)?),
            "oscillator" => {
                let o: OscillatorModel =
                    serde_json::from_value(h.model).map_err(|e| format!("\"model\" (oscillator): {e}"))?;
                o.params.validate().map_err(|e| format!("\"model.params\": {e}"))?;
                if !(1..=MAX_SUBSTEPS).contains(&o.substeps) {
                    return Err(format!("\"model.substeps\" is {}: 1 to {MAX_SUBSTEPS}", o.substeps));
                }
                Model::Oscillator(o)
            }
            "linear" => {
                let l: LinearModel =
                    serde_json::from_value(h.model).map_err(|e| format!("\"model\" (linear): {e}"))?;
                let bad = l.b.is_empty()
                    || l.b.len() > MAX_LINEAR_ORDER
                    || l.f.len() > MAX_LINEAR_ORDER
                    || l.nk > MAX_LINEAR_ORDER
                    || l.b.iter().chain(&l.f).any(|v| !v.is_finite());
                if bad {
                    return Err(format!(
                        "\"model\" (linear): b needs 1 to {MAX_LINEAR_ORDER} finite coefficients, f and nk at most {MAX_LINEAR_ORDER}"
                    ));
                }
                Model::Linear(l)
            }
            other => {
                return Err(format!(
                    "\"family\" is {:?}: one of \"actuator\", \"oscillator\", \"linear\", \"mimo\"",
                    crate::record::excerpt(other)
                ));
            }
        };
        Ok(ModelFile {
            model,
            ts_s: h.ts_s,
            u_unit: h.units.u,
            fitted_on: h.fitted_on,
            held_out_rms_um: h.held_out_rms_um,
        })
    }
}

fn actuator(v: serde_json::Value, ts: f64) -> Result<TermModel, String> {
    let f: ActuatorFile = serde_json::from_value(v).map_err(|e| format!("\"model\" (actuator): {e}"))?;
    let scalars = [f.a1, f.a, f.a0, f.gamma, f.beta, f.drive_hz, f.delay];
    if f.ar.iter().chain(&scalars).chain(&f.drift).any(|v| !v.is_finite()) {
        return Err("\"model\" (actuator): every parameter must be finite".into());
    }
    if f.branches.len() > MAX_BRANCHES {
        return Err(format!("\"model.branches\": {} branches, at most {MAX_BRANCHES}", f.branches.len()));
    }
    if f.drift.len() > 8 {
        return Err(format!("\"model.drift\": {} coefficients, at most 8", f.drift.len()));
    }
    if !(0.0..=MAX_DELAY).contains(&f.delay) {
        return Err(format!("\"model.delay\" is {}: 0 to {MAX_DELAY} samples", f.delay));
    }
    let t = &f.terms;
    let term_numbers = t.input_clamp.iter().chain(&t.output_clamp).flatten().copied().chain([t.q_ref_um]);
    let creep_ok = t.creep.len() <= 4
        && t.creep.iter().all(|c| c.tau_s.is_finite() && c.tau_s > 0.0 && c.gain.is_finite());
    let stiff_ok = t.stiffening.len() <= 4
        && t.stiffening.iter().all(|s| s.power >= 2 && s.power <= 9 && s.coeff.is_finite());
    if term_numbers.into_iter().any(|v| !v.is_finite()) || !creep_ok || !stiff_ok || t.extra_delay > 10_000 {
        return Err("\"model.terms\": a clamp, creep, stiffening or delay out of range".into());
    }
    let mut branches = Vec::with_capacity(f.branches.len());
    for b in &f.branches {
        if b.order < 2 || f64::from(b.order) * f.drive_hz >= 0.5 / ts {
            return Err(format!(
                "\"model.branches\": order {} at {} Hz is below 2 or at or above Nyquist",
                b.order, f.drive_hz
            ));
        }
        if ![b.alpha_s, b.alpha_c, b.ar[0], b.ar[1]].iter().all(|v| v.is_finite()) {
            return Err(format!("\"model.branches\": order {} has a value that is not finite", b.order));
        }
        branches.push(Branch { order: b.order, alpha_s: b.alpha_s, alpha_c: b.alpha_c, ar: b.ar });
    }
    let host = HostModel {
        ext: ExtendedParams {
            bw: BoucWenParams { a1: f.a1, a: f.a, a0: f.a0, gamma: f.gamma, beta: f.beta },
            ar: f.ar,
        },
        drive_hz: f.drive_hz,
        branches,
        drift: f.drift,
        delay: f.delay,
    };
    Ok(TermModel { host, terms: f.terms })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::oscillator::{OscillatorParams, OutputSampling};

    fn files() -> Vec<ModelFile> {
        let host = HostModel {
            ext: ExtendedParams {
                bw: BoucWenParams { a1: 0.3, a: 0.1, a0: 0.01, gamma: 0.2, beta: 0.1 },
                ar: [1.6, -0.7],
            },
            drive_hz: 23.0,
            branches: vec![Branch { order: 3, alpha_s: 0.1, alpha_c: -0.2, ar: [0.0, 0.0] }],
            drift: vec![0.5],
            delay: 0.25,
        };
        let models = [
            Model::Actuator(TermModel::from(host)),
            Model::Oscillator(OscillatorModel {
                params: OscillatorParams::BENCHMARK,
                substeps: 20,
                output: OutputSampling::FirDecimation,
            }),
            Model::Linear(LinearModel { b: vec![0.1, 0.2], f: vec![-0.5, 0.1], nk: 1 }),
        ];
        models
            .into_iter()
            .map(|model| ModelFile {
                model,
                ts_s: 1e-3,
                u_unit: "V".into(),
                fitted_on: Some("a.csv".into()),
                held_out_rms_um: Some(0.5),
            })
            .collect()
    }

    #[test]
    fn every_family_survives_its_file() {
        for f in files() {
            let back = ModelFile::parse(&f.to_json()).expect("parse");
            assert_eq!(back, f);
        }
    }

    #[test]
    fn a_bad_file_gets_one_line_naming_what() {
        let good = files()[1].to_json();
        let cases = [
            ("{}", "no \"format\""),
            ("[1", "not JSON"),
            (&good.replace("\"version\": 1", "\"version\": 7"), "newer boucwen"),
            (&good.replace("\"version\": 1", "\"version\": -1"), "\"version\" is -1"),
            (&good.replace("\"oscillator\"", "\"spring\""), "\"family\" is \"spring\""),
            (&good.replace("\"m\": 2.0", "\"m\": -2.0"), "model.params"),
            (&good.replace("\"substeps\": 20", "\"substeps\": 0"), "substeps"),
            (&good.replace("\"units\"", "\"extra\": 1, \"units\""), "unknown field"),
        ];
        for (text, want) in cases {
            let e = ModelFile::parse(text).expect_err(want);
            assert!(e.contains(want) && !e.contains('\n'), "{want}: {e}");
        }
    }
}

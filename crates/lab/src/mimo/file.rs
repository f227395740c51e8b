//! The model file of a model with several inputs and outputs: the same header as every
//! model file ([`crate::model::file`]: `format`, `version`, `family`, `ts_s`, `units`,
//! `fitted_on`), family `"mimo"`, and the [`MimoModel`] under `model`.
//!
//! ```json
//! {
//!   "format": "boucwen-model", "version": 1, "family": "mimo", "ts_s": 0.00015625,
//!   "units": { "u": "V", "y": "um" }, "fitted_on": "fine-steering-mirror",
//!   "held_out_um": [0.09, 0.14, 0.20],
//!   "model": { "sample_rate_hz": 6400.0, "inputs": 3, "outputs": 3, "modes": [ … ], … }
//! }
//! ```
//! `period_samples` is the period of the drives it was fitted on (`simulate --model` takes a
//! drive of whole such periods as periodic). `"sample_rate_given": false` marks a model fitted on NumPy files without a sample rate:
//! it runs per sample, on any drive's rows. `held_out_um` is the benchmark's metric per level on the realisations kept apart during
//! the fit. A file that is not this, a value that is not finite, a model whose sizes do not
//! agree or that is not stable is refused with one line naming the file and the field.

use super::model::MimoModel;
use crate::model::ModelFileError;
use crate::model::file::{FORMAT, Units, VERSION};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The family named in the file.
pub const FAMILY: &str = "mimo";

/// A MIMO model with what it needs to run on a record.
#[derive(Clone, Debug, PartialEq)]
pub struct MimoModelFile {
    /// The model.
    pub model: MimoModel,
    /// The record it was fitted on.
    pub fitted_on: Option<String>,
    /// The benchmark's metric per level on the realisations kept apart (µm).
    pub held_out_um: Vec<f64>,
    /// Whether the record gave its sample rate; without it the model runs per sample (its
    /// `sample_rate_hz` is 1) and takes any drive's rows as its samples.
    pub rate_given: bool,
    /// Samples per period of the periodic drives it was fitted on.
    pub period_samples: Option<usize>,
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
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    held_out_um: Vec<f64>,
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    sample_rate_given: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    period_samples: Option<usize>,
    model: MimoModel,
}

fn yes() -> bool {
    true
}

fn is_true(b: &bool) -> bool {
    *b
}

/// Whether a model file's text names the family `"mimo"` (read it with
/// [`MimoModelFile::parse`], not [`crate::model::ModelFile::parse`]).
pub fn is_mimo(text: &str) -> bool {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    serde_json::from_str::<serde_json::Value>(text)
        .ok()
        .is_some_and(|v| v.get("family").and_then(|f| f.as_str()) == Some(FAMILY))
}

impl MimoModelFile {
    /// The file's JSON text.
    pub fn to_json(&self) -> String {
        let header = Header {
            format: FORMAT.into(),
            version: VERSION,
            family: FAMILY.into(),
            ts_s: 1.0 / self.model.sample_rate_hz,
            units: Units { u: "V".into(), y: "um".into() },
            fitted_on: self.fitted_on.clone(),
            held_out_um: self.held_out_um.iter().copied().filter(|v| v.is_finite()).collect(),
            sample_rate_given: self.rate_given,
            period_samples: self.period_samples,
            model: self.model.clone(),
        };
        serde_json::to_string_pretty(&header).unwrap_or_default() + "\n"
    }

    /// Writes the file atomically.
    pub fn write(&self, path: &Path) -> Result<(), crate::record::RecordError> {
        crate::record::write_atomic(path, self.to_json().as_bytes())
    }

    /// Reads and checks a file.
    pub fn read(path: &Path) -> Result<Self, ModelFileError> {
        crate::model::file::read_with(path, Self::parse)
    }

    /// Parses and checks a file's text; the error says what is wrong and where.
    pub fn parse(text: &str) -> Result<Self, String> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let h: Header = serde_json::from_str(text).map_err(|e| format!("not a MIMO model file: {e}"))?;
        if h.format != FORMAT {
            return Err(format!(
                "\"format\" is {:?}: expected {FORMAT:?}",
                crate::record::excerpt(&h.format)
            ));
        }
        if h.version != VERSION {
            return Err(format!("\"version\" is {}; this build reads {VERSION}", h.version));
        }
        if h.family != FAMILY {
            return Err(format!(
                "\"family\" is {:?}; expected {FAMILY:?}",
                crate::record::excerpt(&h.family)
            ));
        }
        if h.units.u != "V" || h.units.y != "um" {
            return Err("\"units\": MIMO models run in V and um".into());
        }
        let fs = h.model.sample_rate_hz;
        if !(fs.is_finite() && fs > 0.0) || ((1.0 / fs - h.ts_s) / h.ts_s).abs() > 1e-9 {
            return Err(format!("\"ts_s\" {} and \"model.sample_rate_hz\" {fs} disagree", h.ts_s));
        }
        h.model.validate().map_err(|e| format!("\"model\": {e}"))?;
        if h.period_samples.is_some_and(|n| n < 2) {
            return Err("\"period_samples\": at least 2".into());
        }
        Ok(Self {
            model: h.model,
            fitted_on: h.fitted_on,
            held_out_um: h.held_out_um,
            rate_given: h.sample_rate_given,
            period_samples: h.period_samples,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mimo::linear::{ModalSs, Mode};
    use nalgebra::DMatrix;

    fn model() -> MimoModel {
        let ss = ModalSs {
            modes: vec![Mode::Pair { sigma: 0.9, omega: 0.3 }],
            b: DMatrix::from_row_slice(2, 2, &[1.0, 0.5, -0.25, 2.0]),
            c: DMatrix::from_row_slice(1, 2, &[0.3, -0.7]),
            d: DMatrix::from_row_slice(1, 2, &[0.0, 0.1]),
        };
        MimoModel::linear(&ss, 6400.0)
    }

    #[test]
    fn round_trip_and_refusals() {
        let f = MimoModelFile {
            model: model(),
            fitted_on: Some("fsm".into()),
            held_out_um: vec![0.1, 0.2],
            rate_given: false,
            period_samples: Some(8192),
        };
        let text = f.to_json();
        assert!(is_mimo(&text));
        assert_eq!(MimoModelFile::parse(&text).unwrap(), f);
        let bad = text.replace("\"sigma\": 0.9", "\"sigma\": 1.2");
        assert!(MimoModelFile::parse(&bad).unwrap_err().contains("\"model\""), "unstable refused");
        let bad = text.replace("\"version\": 1", "\"version\": 2");
        assert!(MimoModelFile::parse(&bad).unwrap_err().contains("version"));
        // The single-input reader names the family it does not read.
        let e = crate::model::ModelFile::parse(&text).unwrap_err();
        assert!(e.contains("mimo"), "{e}");
    }
}

//! `compare`: a model from a file run in free simulation on another record's drive, scored
//! against its output (MATLAB's `compare`).
//!
//! The model runs from rest at the record's first sample (or, with `periodic`, in steady
//! state on the record as one period of a periodic drive: the period is run once before the
//! scored one). The scores, over the window (the whole record by default):
//! - `rms_um`: `√(mean (y − ŷ)²)`;
//! - `fit_pct`: `100·(1 − ‖y − ŷ‖/‖y − ȳ‖)`;
//! - `nrmse`: `‖y − ŷ‖/‖y − ȳ‖` (so `fit_pct = 100·(1 − nrmse)`).

use crate::model::{ModelError, ModelFile};
use crate::record::Record;
use crate::signal::analysis;
use std::fmt;

/// Warm-up periods of a steady-state comparison.
pub const PERIODIC_WARMUP: usize = 1;

/// What `compare` measured.
#[derive(Clone, Debug)]
pub struct Comparison {
    /// The model's output over the record (µm).
    pub simulated: Vec<f64>,
    /// The scored samples.
    pub window: (usize, usize),
    /// RMS of the error (µm).
    pub rms_um: f64,
    /// Fit (%).
    pub fit_pct: f64,
    /// Normalised RMS error.
    pub nrmse: f64,
    /// RMS of the output about its mean over the window (µm).
    pub output_rms_um: f64,
}

/// Why a model could not be compared on a record.
#[derive(Debug)]
pub enum CompareError {
    /// The model's sample interval is not the record's.
    SampleInterval {
        /// The model's (s).
        model_s: f64,
        /// The record's (s).
        record_s: f64,
    },
    /// The model cannot run on the record's drive.
    Model(ModelError),
    /// The window holds too few samples.
    Window {
        /// Samples in it.
        samples: usize,
    },
}

impl fmt::Display for CompareError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CompareError::SampleInterval { model_s, record_s } => write!(
                f,
                "the model was fitted at a sample interval of {model_s:.9} s and the record has {record_s:.9} s; resample the record"
            ),
            CompareError::Model(e) => write!(f, "the model cannot run on this drive: {e}"),
            CompareError::Window { samples } => {
                write!(f, "the window holds {samples} samples; compare needs at least 2")
            }
        }
    }
}

impl std::error::Error for CompareError {}

/// Relative difference of sample intervals accepted as the same (a time column written with
/// 8 decimals at 750 Hz is off by 2.5·10⁻⁶).
pub const TS_TOLERANCE: f64 = 1e-4;

/// Runs `m` on `r`'s drive and scores it over `window` (samples; the whole record if `None`).
pub fn compare(
    m: &ModelFile,
    r: &Record,
    window: Option<(usize, usize)>,
    periodic: bool,
) -> Result<Comparison, CompareError> {
    if ((m.ts_s - r.ts) / r.ts).abs() > TS_TOLERANCE {
        return Err(CompareError::SampleInterval { model_s: m.ts_s, record_s: r.ts });
    }
    let simulated = if periodic {
        m.model.simulate_periodic(&r.u, r.ts, PERIODIC_WARMUP)
    } else {
        m.model.simulate(&r.u, r.ts)
    }
    .map_err(CompareError::Model)?;
    let (a, b) = window.unwrap_or((0, r.len()));
    if b <= a + 1 || b > r.len() {
        return Err(CompareError::Window { samples: b.saturating_sub(a) });
    }
    let (y, yh) = (&r.y[a..b], &simulated[a..b]);
    let rms_um = analysis::rms_diff(y, yh);
    let mean = analysis::mean(y);
    let output_rms_um = (y.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / y.len() as f64).sqrt();
    let nrmse = rms_um / output_rms_um;
    Ok(Comparison { simulated, window: (a, b), rms_um, fit_pct: 100.0 * (1.0 - nrmse), nrmse, output_rms_um })
}

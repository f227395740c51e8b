//! `design`: the board's compensator from records and the [`Design`] file that carries it,
//! as `boucwen board design` (crates/cli/src/cmd_board.rs).

use crate::Error;
use crate::convert::{guarded, to_py};
use crate::record::Record;
use boucwen_lab::design::board::{self as board_design, DesignFile, DesignOptions, HarmonicChoice};
use boucwen_lab::design::closed_loop;
use boucwen_lab::record;
use boucwen_link::message::SafetyParams;
use pyo3::prelude::*;
use std::path::PathBuf;

/// The board's design file: the records it came from, the model, the harmonics found and
/// cancelled, the reference, the prediction, and the `f32` values the board gets.
/// `to_json()` is the file's text (what `boucwen board design -o` writes); `save(path)`
/// writes it; `as_dict()` is the same as Python objects; `Design.load(path)` reads and checks
/// one as `boucwen board load` does.
#[pyclass(module = "boucwen", frozen)]
pub struct Design {
    file: DesignFile,
}

#[pymethods]
impl Design {
    /// The design file's text (pretty JSON with a final newline).
    fn to_json(&self) -> String {
        self.file.to_json()
    }

    /// The design file as Python objects: its text read back, so the board's `f32` values
    /// are the numbers the file shows (as `json.loads` of the file gives them).
    fn as_dict(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let v: serde_json::Value = serde_json::from_str(&self.file.to_json())
            .map_err(|e| Error::new_err(format!("design as JSON: {e}")))?;
        to_py(py, &v)
    }

    /// Writes the design file, atomically.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let f = &self.file;
        guarded(py, "save", || f.write(&path).map_err(|e| e.to_string()))
    }

    /// Reads and checks a design file (format, version, every value as the board will).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Design> {
        let file = guarded(py, "load", || DesignFile::read(&path).map_err(|e| e.to_string()))?;
        Ok(Design { file })
    }

    /// The predicted tracking RMSE on the model (µm), after the settling time.
    #[getter]
    fn design_rmse_um(&self) -> f64 {
        self.file.prediction.design_rmse_um
    }

    fn __repr__(&self) -> String {
        let r = &self.file.reference;
        let h: Vec<String> = self.file.harmonics_cancelled.iter().map(|h| h.order.to_string()).collect();
        format!(
            "Design({} Hz, {:.3} µm, cancels [{}], predicted {:.4} µm RMSE)",
            r.freq_hz,
            r.amplitude_um,
            h.join(", "),
            self.file.prediction.design_rmse_um
        )
    }
}

/// Designs the board's compensator from records, as `boucwen board design`.
///
/// The board's design identifies its own model from the records (an invertible loop with
/// its input delay, the structure from a broadband record), so it takes records, not a
/// fitted `Model`: `records` is one record or a list, each a Record from `read_record` or a
/// path (read with the defaults, as the command reads its arguments). At least one is a sine
/// at the frequency to track. `freq` (Hz), `amplitude` (µm), `harmonics` ("auto", "none"
/// or a list of orders), `drive_limits = (lo, hi)` (V), `slew` (V/s), `host_timeout_ms`,
/// `fade` (s) and `predict_seconds` as the command's flags.
#[pyfunction]
#[pyo3(signature = (records, *, freq=None, amplitude=None, harmonics=None, drive_limits=(-10.0, 10.0),
    slew=100.0, host_timeout_ms=250, fade=closed_loop::FADE_IN_S, predict_seconds=board_design::PREDICT_SECONDS))]
#[allow(clippy::too_many_arguments)]
pub fn design(
    py: Python<'_>,
    records: &Bound<'_, PyAny>,
    freq: Option<f64>,
    amplitude: Option<f64>,
    harmonics: Option<&Bound<'_, PyAny>>,
    drive_limits: (f64, f64),
    slew: f64,
    host_timeout_ms: u32,
    fade: f64,
    predict_seconds: f64,
) -> PyResult<Design> {
    let harmonics = match harmonics {
        None => HarmonicChoice::Auto,
        Some(h) => match h.extract::<String>() {
            Ok(s) if s == "auto" => HarmonicChoice::Auto,
            Ok(s) if s == "none" => HarmonicChoice::None,
            Ok(s) => {
                return Err(Error::new_err(format!(
                    "harmonics {s:?}: \"auto\", \"none\" or a list of orders"
                )));
            }
            Err(_) => HarmonicChoice::Orders(h.extract::<Vec<u32>>().map_err(|_| {
                Error::new_err("harmonics: \"auto\", \"none\" or a list of orders like [3, 5]")
            })?),
        },
    };
    let (lo, hi) = drive_limits;
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(Error::new_err(format!("drive_limits ({lo}, {hi}): not finite numbers")));
    }
    if !slew.is_finite() {
        return Err(Error::new_err(format!("slew {slew}: not a finite number")));
    }
    let opts = DesignOptions {
        freq_hz: freq,
        amplitude_um: amplitude,
        harmonics,
        safety: SafetyParams {
            u_min: lo as f32,
            u_max: hi as f32,
            slew_v_per_s: slew as f32,
            host_timeout_ms,
        },
        fade_s: fade,
        predict_seconds,
    };
    let items: Vec<Bound<'_, PyAny>> =
        if records.cast::<Record>().is_ok() || records.extract::<PathBuf>().is_ok() {
            vec![records.clone()]
        } else {
            records.try_iter()?.collect::<PyResult<_>>()?
        };
    let mut given = vec![];
    for item in &items {
        given.push(match item.cast::<Record>() {
            Ok(r) => Ok(r.borrow().to_lab(py)?),
            Err(_) => Err(item
                .extract::<PathBuf>()
                .map_err(|_| Error::new_err("records: Records from read_record or paths"))?),
        });
    }
    let file = guarded(py, "design", || {
        let records = given
            .into_iter()
            .map(|g| match g {
                Ok(r) => Ok(r),
                Err(path) => record::Record::read(&path).map_err(|e| e.to_string()),
            })
            .collect::<Result<Vec<_>, String>>()?;
        board_design::design_from_records(&records, &opts).map_err(|e| e.to_string())
    })?;
    Ok(Design { file })
}

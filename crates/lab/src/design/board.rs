//! The board's compensator designed from measured records, and the design file that
//! carries it to the board (`boucwen board design`, `boucwen board load`).
//!
//! ## From records to a design ([`design_from_records`])
//! 1. **The records.** All share one sample interval, which becomes the board's sample
//!    period (a whole number of µs, 100 µs to 100 ms). A record whose drive is a sine
//!    (its fundamental holds at least [`SINE_SHARE`] of the input's power) is a *sine
//!    record* at its frequency (rounded to what the record resolves); any other is *broadband*. The design frequency `f` is the
//!    one asked for, else the first sine record's.
//! 2. **Structure.** With a broadband record, the structure (AR part) is fitted to it first
//!    as a linear model (the actuator is nearly linear at small amplitude) and kept fixed
//!    for what follows, as the sweep does; without one, the sine record alone sets it.
//! 3. **The model.** The extended model with its input delay `τ` (fractional samples, up to
//!    [`crate::model::MAX_DELAY`]) is fitted by output error on the first half of the first sine
//!    record at `f` (an invertible loop required), and its free run is judged on the second half:
//!    `fit_pct = 100·(1 − ‖y − ŷ‖/‖y − ȳ‖)`. Every other record at `f` is a check: the
//!    model's free run on it, the same percentage.
//! 4. **Harmonics found.** The odd harmonics of `f` (3rd to 9th, below 0.45 of the sample
//!    rate) whose amplitude in the fitted part of the output is at least
//!    [`crate::model::MIN_HARMONIC_REL`] of the fundamental, the two largest, get
//!    branches: the enhanced model fitted the same way is the *prediction model*, the best
//!    account of the actuator the records give.
//! 5. **α.** The amplitude asked for, else eq. (25) on the sine record.
//! 6. **The cancelled harmonic.** `u_f` alone (the board's own controller code, `f32`)
//!    tracks `α·sin 2πft` on the prediction model; the odd harmonic that stands out in its
//!    tracking error ([`crate::design::cancelled_harmonic`]) is cancelled, or if none does
//!    the largest odd harmonic found in the record (or the orders asked for, at most
//!    [`MAX_HARMONICS`]), with the extended model's response at `n·f`
//!    (the cancellation phase: [`boucwen_core::compensator::PhaseRule::Model`]).
//! 7. **Refusals.** The design is refused, with the reason, when no invertible loop fits,
//!    when the loop is not invertible over the range the tracking needs (the hysteresis'
//!    range under the `u` that `u_f` demands for `α`, widened as in
//!    [`fit::operating_slope`]), when that `u` leaves the drive limits, and when the
//!    board would refuse the parameters.
//!    The board's compensator previews the reference by `τ`: its inverse works on
//!    `d(k + τ)` ([`ControllerParams::preview_samples`]), so an actuator that applies its
//!    input `τ` samples late follows `d[k]`.
//! 8. **The prediction.** The designed compensator tracks `α` on the prediction model (its
//!    delay included) for
//!    [`PREDICT_SECONDS`]: `design_rmse_um` after the settling time ([`settle_samples`]).
//!
//! ## The design file ([`DesignFile`], JSON)
//! Versioned ([`FORMAT`], [`VERSION`]) and meant to be read: the records it came from (path,
//! samples, interval, drive, role, fit percentage), the model in `f64` with its fit
//! percentage and the range it was checked invertible on, the harmonics found and
//! cancelled with the cancellation's gain and phase, the reference, the prediction, and the
//! `board` section: exactly the `f32` values `boucwen board load` sends (written in the
//! shortest form that reads back to the same bits) and the drive limits. [`DesignFile::read`]
//! checks the format, the version and every value as the board will; a file that fails
//! is refused whole, with the file and the field named.

use crate::design::closed_loop;
use crate::design::{self, ReferenceSpec, controller_params};
use crate::fit::{self, Averaging, DelaySearch, FitError, LoopSearch, OeOptions, Samples, StructureSearch};
use crate::model::{HostModel, ModelSpec};
use crate::record::Record;
use crate::signal::analysis;
use boucwen_core::compensator::{HarmonicSpec, PhaseRule, Saturation};
use boucwen_core::model::{BoucWenParams, EnhancedParams, ExtendedParams, HarmonicBranch, Model};
use boucwen_core::rls::RlsConfig;
use boucwen_core::signal::Oscillator;
use boucwen_link::device::{Controller, check_safety};
use boucwen_link::message::{ControllerParams, MAX_AR, MAX_HARMONICS, SafetyParams};
use nalgebra::Complex;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// The design file's `format`.
pub const FORMAT: &str = "boucwen-board-design";
/// The design file's version this code writes and reads.
/// Version 2 added the preview (`board.preview_samples`, `model.delay_samples`); a version
/// 1 file (designed without the delay) is refused: design again.
pub const VERSION: u32 = 2;
/// Longest design file read, bytes. A design file is a few kilobytes (about 200 bytes more
/// per record it came from); a longer one is refused before it is read.
pub const MAX_FILE_BYTES: u64 = 1 << 20;
/// Most records a design file lists.
pub const MAX_SOURCES: usize = 1000;
/// Share of the input's power the fundamental must hold for a sine record.
pub const SINE_SHARE: f64 = 0.9;
/// Length of the prediction run by default, s.
pub const PREDICT_SECONDS: f64 = 5.0;
/// The enhanced model's structure is trusted on sine records alone when its held-out error
/// is at most this fraction of the extended model's (see [`design_from_records`], step 6).
pub const ENHANCED_EXPLAINS: f64 = 0.1;
/// Highest odd harmonic looked for.
pub const MAX_ORDER: u32 = 9;

/// The tracking RMSE of a run of `samples` samples is taken from this sample on: the first
/// fifth of the run, at least the fade-in of the reference, at most half the run (the rule
/// of `boucwen hil`).
pub fn settle_samples(samples: u32, fade_samples: u32) -> u32 {
    (samples / 5).max(fade_samples).min(samples / 2)
}

/// Which harmonics the compensator cancels.
#[derive(Clone, Debug, PartialEq)]
pub enum HarmonicChoice {
    /// The one that stands out under `u_f` on the prediction model (or none).
    Auto,
    /// None: `u_f` alone.
    None,
    /// These orders (odd or even, at most [`MAX_HARMONICS`]).
    Orders(Vec<u32>),
}

/// Settings of [`design_from_records`].
#[derive(Clone, Debug)]
pub struct DesignOptions {
    /// Design frequency, Hz (`None`: the first sine record's).
    pub freq_hz: Option<f64>,
    /// Reference amplitude α, µm (`None`: eq. 25 on the sine record).
    pub amplitude_um: Option<f64>,
    /// Cancelled harmonics.
    pub harmonics: HarmonicChoice,
    /// The board's drive limits and safe state; the compensator's saturation is the same
    /// range.
    pub safety: SafetyParams,
    /// Fade-in of the reference, s.
    pub fade_s: f64,
    /// Length of the prediction run, s (at least 1000 samples).
    pub predict_seconds: f64,
}

impl Default for DesignOptions {
    fn default() -> Self {
        Self {
            freq_hz: None,
            amplitude_um: None,
            harmonics: HarmonicChoice::Auto,
            safety: SafetyParams::DEFAULT,
            fade_s: closed_loop::FADE_IN_S,
            predict_seconds: PREDICT_SECONDS,
        }
    }
}

/// Why no design was made. Every message names the record or the setting at fault.
#[derive(Debug)]
pub enum BoardDesignError {
    /// No record given.
    NoRecords,
    /// A record cannot be used (its name and why).
    Record(String, String),
    /// The records do not allow a design at the frequency asked for.
    NoSineRecord(String),
    /// A setting is out of range.
    Option(String),
    /// The identification failed.
    Fit(String, FitError),
    /// The model cannot be inverted where the tracking needs it (why).
    NotInvertible(String),
    /// The tracking needs more drive than the limits allow.
    DriveLimits(String),
    /// The board would refuse the parameters.
    Params(boucwen_core::Error),
}

impl fmt::Display for BoardDesignError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BoardDesignError::NoRecords => f.write_str("no record given"),
            BoardDesignError::Record(name, why) => write!(f, "{name}: {why}"),
            BoardDesignError::NoSineRecord(why) => f.write_str(why),
            BoardDesignError::Option(why) => f.write_str(why),
            BoardDesignError::Fit(name, e) => write!(f, "{name}: identification: {e}"),
            BoardDesignError::NotInvertible(why) => write!(f, "the model cannot be inverted: {why}"),
            BoardDesignError::DriveLimits(why) => f.write_str(why),
            BoardDesignError::Params(e) => write!(f, "compensator for the board: {e}"),
        }
    }
}

impl std::error::Error for BoardDesignError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            BoardDesignError::Fit(_, e) => Some(e),
            BoardDesignError::Params(e) => Some(e),
            _ => None,
        }
    }
}

/// A record the design came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SourceRecord {
    /// The file.
    pub path: String,
    /// Samples.
    pub samples: usize,
    /// Sample interval, s.
    pub ts_s: f64,
    /// Its drive: `sine F Hz` or `broadband`.
    pub drive: String,
    /// What the design used it for: `fit` (first half fitted, second held out),
    /// `structure` (the AR part), `check` (the model's free run compared with it), or
    /// `unused` (a sine at another frequency).
    pub role: String,
    /// The model's fit percentage on it (`fit`: the held-out half; `check`: all after the
    /// start-up); absent for the others.
    pub fit_pct: Option<f64>,
}

/// The identified model whose extended part the board inverts, `f64`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelSection {
    /// Which: `extended`, or `the extended part of enhanced(n)` (the enhanced model's
    /// structure and loop, when it carries every cancelled harmonic).
    pub inverted: String,
    /// AR part `[a1, a2]` of the structure (eq. 9's form).
    pub ar: [f64; 2],
    /// `A1`, µm/V.
    pub a1: f64,
    /// `A`.
    pub a: f64,
    /// `A0`.
    pub a0: f64,
    /// `γ`.
    pub gamma: f64,
    /// `β`.
    pub beta: f64,
    /// The input delay `τ`, samples (fitted; the board previews the reference by it).
    pub delay_samples: f64,
    /// Resonance of the structure, Hz (complex poles only).
    pub resonance_hz: Option<f64>,
    /// Fit percentage of the model (with its branches) on the held-out half of the fitted
    /// record.
    pub fit_pct: f64,
    /// RMS of its free-run error there, µm.
    pub held_out_rms_um: f64,
    /// The drive range `[lo, hi]` (V) the tracking needs, over which the loop was checked
    /// invertible.
    pub checked_u_v: [f64; 2],
    /// The smallest slope of `A1·u − h` over that range (widened as in
    /// [`fit::operating_slope`]), relative to `A1` (at least [`fit::MIN_SLOPE`]).
    pub min_slope_rel: f64,
}

/// A harmonic found in the record or cancelled.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HarmonicSection {
    /// Order `n`.
    pub order: u32,
    /// `n·f`, Hz.
    pub freq_hz: f64,
    /// Found in the output: its amplitude relative to the fundamental, %; cancelled: its
    /// amplitude in the tracking error under `u_f` alone on the prediction model, µm.
    pub amplitude: f64,
    /// Cancelled only: the response `Ĝ(n·f)` the cancellation uses, gain µm/V.
    pub gain_um_per_v: Option<f64>,
    /// Cancelled only: its phase, degrees (the cancellation phase).
    pub phase_deg: Option<f64>,
}

/// The prediction model's harmonic branch.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BranchSection {
    /// Order.
    pub order: u32,
    /// Weight of `sin nθ`.
    pub alpha_s: f64,
    /// Weight of `cos nθ`.
    pub alpha_c: f64,
}

/// The reference of the design.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceSection {
    /// Frequency `f`, Hz.
    pub freq_hz: f64,
    /// Amplitude `α`, µm.
    pub amplitude_um: f64,
    /// `eq25` or `requested`.
    pub amplitude_source: String,
    /// Fade-in, s.
    pub fade_s: f64,
}

/// What the design predicts on the prediction model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PredictionSection {
    /// The prediction model: `extended` or `enhanced(n,…)`.
    pub model: String,
    /// Its branches (at most [`MAX_HARMONICS`]).
    #[serde(deserialize_with = "at_most_max_harmonics")]
    pub branches: Vec<BranchSection>,
    /// Its fit percentage on the held-out half.
    pub fit_pct: f64,
    /// Length of the prediction run, s.
    pub seconds: f64,
    /// RMSE taken from this time on, s.
    pub settle_s: f64,
    /// Tracking RMSE of `u_f` alone, µm.
    pub uf_rmse_um: f64,
    /// Tracking RMSE of the designed compensator, µm.
    pub design_rmse_um: f64,
}

/// One cancelled harmonic as the board gets it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoardHarmonic {
    /// Order.
    pub order: u32,
    /// `Re Ĝ(n·f)`, µm/V.
    #[serde(deserialize_with = "f32_exact")]
    pub re: f32,
    /// `Im Ĝ(n·f)`, µm/V.
    #[serde(deserialize_with = "f32_exact")]
    pub im: f32,
}

/// Exactly what `boucwen board load` sends: the compensator's parameters in `f32` and the
/// drive limits.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoardSection {
    /// The board's sample period, µs.
    pub sample_period_us: u32,
    /// The reference frequency, Hz (the board's phase increment is computed from it).
    pub freq_hz: f64,
    /// The reference amplitude, µm.
    #[serde(deserialize_with = "f32_exact")]
    pub amplitude_um: f32,
    /// The fade-in, samples.
    pub fade_samples: u32,
    /// `A1, A, A0, γ, β`.
    #[serde(deserialize_with = "f32s_exact")]
    pub bouc_wen: [f32; 5],
    /// AR part, zero-padded to the board's order.
    #[serde(deserialize_with = "f32s_exact")]
    pub ar: [f32; MAX_AR],
    /// The cancelled harmonics (at most [`MAX_HARMONICS`]).
    #[serde(deserialize_with = "at_most_max_harmonics")]
    pub harmonics: Vec<BoardHarmonic>,
    /// RLS `[λ, P0, P_max]`.
    #[serde(deserialize_with = "f32s_exact")]
    pub rls: [f32; 3],
    /// The compensator's range `[u_min, u_max]`, V.
    #[serde(deserialize_with = "f32s_exact")]
    pub saturation: [f32; 2],
    /// Bound on each cancellation amplitude, V.
    #[serde(deserialize_with = "f32_exact")]
    pub uc_max_v: f32,
    /// The preview `τ` of the reference, samples (the model's input delay).
    #[serde(deserialize_with = "f32_exact")]
    pub preview_samples: f32,
    /// Drive limits `[u_min, u_max]`, V.
    #[serde(deserialize_with = "f32s_exact")]
    pub drive_limits_v: [f32; 2],
    /// Slew of the ramp to 0 V, V/s.
    #[serde(deserialize_with = "f32_exact")]
    pub slew_v_per_s: f32,
    /// The host is lost after this long without a frame, ms.
    pub host_timeout_ms: u32,
}

/// The design file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DesignFile {
    /// [`FORMAT`].
    pub format: String,
    /// [`VERSION`].
    pub version: u32,
    /// The program that wrote it.
    pub created_by: String,
    /// The records (at most [`MAX_SOURCES`]).
    #[serde(deserialize_with = "at_most_max_sources")]
    pub sources: Vec<SourceRecord>,
    /// The extended model.
    pub model: ModelSection,
    /// Odd harmonics standing out in the fitted output (at most [`MAX_HARMONICS`]).
    #[serde(deserialize_with = "at_most_max_harmonics")]
    pub harmonics_found: Vec<HarmonicSection>,
    /// The harmonics the compensator cancels (at most [`MAX_HARMONICS`]).
    #[serde(deserialize_with = "at_most_max_harmonics")]
    pub harmonics_cancelled: Vec<HarmonicSection>,
    /// The reference.
    pub reference: ReferenceSection,
    /// The prediction.
    pub prediction: PredictionSection,
    /// What the board gets.
    pub board: BoardSection,
}

/// Why a design file cannot be used.
#[derive(Debug)]
pub struct DesignFileError {
    /// The file.
    pub path: String,
    /// What is wrong.
    pub what: String,
}

impl fmt::Display for DesignFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path, self.what)
    }
}

impl std::error::Error for DesignFileError {}

impl DesignFile {
    /// The compensator and drive limits the board gets, validated as the board does.
    pub fn board_params(&self) -> Result<(ControllerParams, SafetyParams), boucwen_core::Error> {
        let b = &self.board;
        let ts = b.sample_period_us as f64 * 1e-6;
        let [a1, a, a0, gamma, beta] = b.bouc_wen;
        if b.harmonics.len() > MAX_HARMONICS {
            return Err(boucwen_core::Error::OutOfRange("harmonic count (the board cancels at most 2)"));
        }
        let p = ControllerParams {
            model: ExtendedParams { bw: BoucWenParams { a1, a, a0, gamma, beta }, ar: b.ar },
            drive: Oscillator::new(b.freq_hz, ts)?,
            sample_period_us: b.sample_period_us,
            amplitude_um: b.amplitude_um,
            fade_samples: b.fade_samples,
            harmonics: b
                .harmonics
                .iter()
                .map(|h| HarmonicSpec { order: h.order, response: Complex::new(h.re, h.im) })
                .collect(),
            rls: RlsConfig { lambda: b.rls[0], p0: b.rls[1], p_max: b.rls[2] },
            saturation: Saturation { u_min: b.saturation[0], u_max: b.saturation[1] },
            uc_max: b.uc_max_v,
            preview_samples: b.preview_samples,
        };
        let s = SafetyParams {
            u_min: b.drive_limits_v[0],
            u_max: b.drive_limits_v[1],
            slew_v_per_s: b.slew_v_per_s,
            host_timeout_ms: b.host_timeout_ms,
        };
        p.validate()?;
        if b.harmonics.iter().any(|h| h.order > u8::MAX as u32) {
            return Err(boucwen_core::Error::OutOfRange("harmonic order (at most 255 on the wire)"));
        }
        check_safety(&s)?;
        Ok((p, s))
    }

    /// The file's text: pretty JSON with a final newline.
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).unwrap_or_default();
        s.push('\n');
        s
    }

    /// Writes the file atomically (never half-written).
    pub fn write(&self, path: &Path) -> Result<(), DesignFileError> {
        crate::record::write_atomic(path, self.to_json().as_bytes())
            .map_err(|e| DesignFileError { path: path.display().to_string(), what: e.to_string() })
    }

    /// Reads and checks a design file: format, version, every field, and the board's
    /// parameters as the board checks them. A file longer than [`MAX_FILE_BYTES`] is refused
    /// before it is read.
    pub fn read(path: &Path) -> Result<Self, DesignFileError> {
        use std::io::Read as _;
        let name = path.display().to_string();
        let err = |what: String| DesignFileError { path: name.clone(), what };
        let file = std::fs::File::open(path).map_err(|e| err(format!("cannot read: {e}")))?;
        let mut bytes = Vec::new();
        // At most one byte more than allowed: the length is checked on what was read (the
        // file may be a pipe, or grow).
        file.take(MAX_FILE_BYTES + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| err(format!("cannot read: {e}")))?;
        if bytes.len() as u64 > MAX_FILE_BYTES {
            return Err(err(format!(
                "longer than {} KiB: not a design file (one is a few KiB)",
                MAX_FILE_BYTES / 1024
            )));
        }
        let text = String::from_utf8(bytes).map_err(|e| {
            let line =
                1 + e.as_bytes()[..e.utf8_error().valid_up_to()].iter().filter(|&&b| b == b'\n').count();
            err(format!("line {line}: not UTF-8 text"))
        })?;
        Self::parse(&text).map_err(err)
    }

    /// [`DesignFile::read`] on a text; the error says what is wrong and where (the field,
    /// and the line and column), without the file. A byte-order mark is skipped; a key given
    /// twice, a number the board's `f32` cannot hold and a list longer than a design has are
    /// refused.
    pub fn parse(text: &str) -> Result<Self, String> {
        if text.len() as u64 > MAX_FILE_BYTES {
            return Err(format!(
                "longer than {} KiB: not a design file (one is a few KiB)",
                MAX_FILE_BYTES / 1024
            ));
        }
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        // The format and the version first (the rest is skipped, not stored): a file of
        // another kind or version is named as such, not by the first field it lacks.
        #[derive(Deserialize)]
        #[serde(expecting = "a JSON object (a boucwen board design)")]
        struct Header {
            // `Some(null)` for `"version": null`, `None` when absent.
            #[serde(default, deserialize_with = "present")]
            format: Option<serde_json::Value>,
            #[serde(default, deserialize_with = "present")]
            version: Option<serde_json::Value>,
        }
        fn present<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<serde_json::Value>, D::Error> {
            serde_json::Value::deserialize(d).map(Some)
        }
        let h: Header = serde_json::from_str(text).map_err(|e| {
            if e.is_syntax() || e.is_eof() { format!("not JSON: {e}") } else { format!("{e}") }
        })?;
        if text.trim_start().starts_with('[') {
            // (Which serde would read as the fields in order.)
            return Err("a JSON array, not an object: not a boucwen board design".into());
        }
        match &h.format {
            Some(serde_json::Value::String(f)) if f == FORMAT => {}
            Some(serde_json::Value::String(other)) => {
                let shown: String = other.chars().take(40).collect();
                return Err(format!("format {shown:?}, not a boucwen board design"));
            }
            Some(other) => {
                return Err(format!("format {}, not a boucwen board design ({FORMAT:?})", found(other)));
            }
            None => return Err(format!("no \"format\": not a boucwen board design ({FORMAT})")),
        }
        match &h.version {
            Some(serde_json::Value::Number(x)) => match x.as_u64() {
                Some(x) if x == VERSION as u64 => {}
                Some(1) => {
                    return Err(format!(
                        "version 1: designed without the actuator's input delay, which the board now previews; this boucwen reads version {VERSION}: design again (boucwen board design)"
                    ));
                }
                Some(_) => return Err(format!("version {x}: this boucwen reads version {VERSION}")),
                None if x.is_f64() => {
                    return Err(format!(
                        "version {x}: not a whole number; this boucwen reads version {VERSION}"
                    ));
                }
                None => return Err(format!("version {x}: this boucwen reads version {VERSION}")),
            },
            Some(other) => {
                return Err(format!(
                    "version {}: this boucwen reads version {VERSION} (a number)",
                    found(other)
                ));
            }
            None => return Err(format!("no \"version\": this boucwen reads version {VERSION}")),
        }
        let de = &mut serde_json::Deserializer::from_str(text);
        let d: DesignFile = serde_path_to_error::deserialize(de).map_err(|e| {
            let path = e.path().to_string();
            if path == "." { e.inner().to_string() } else { format!("{path}: {}", e.inner()) }
        })?;
        d.board_params().map_err(|e| format!("board: {e}"))?;
        Ok(d)
    }
}

/// A JSON value as a message shows what was found: a number as written, a string quoted
/// (at most 40 characters), else its kind.
fn found(v: &serde_json::Value) -> String {
    use serde_json::Value;
    match v {
        Value::Number(n) => n.to_string(),
        Value::String(s) => format!("{:?} (a string)", s.chars().take(40).collect::<String>()),
        Value::Bool(b) => format!("{b} (not a number)"),
        Value::Null => "null".into(),
        Value::Array(_) => "an array".into(),
        Value::Object(_) => "an object".into(),
    }
}

/// A number of the board section as the board's `f32`: refused if the `f64` written does
/// not fit (beyond `f32::MAX` in size, which would become infinite, or a non-zero value so
/// small that it would become 0).
fn f32_exact<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f32, D::Error> {
    to_f32(f64::deserialize(d)?)
}

/// [`f32_exact`] for each number of an array.
fn f32s_exact<'de, D: serde::Deserializer<'de>, const N: usize>(d: D) -> Result<[f32; N], D::Error>
where
    [f64; N]: Deserialize<'de>,
{
    let x = <[f64; N]>::deserialize(d)?;
    let mut out = [0.0f32; N];
    for (o, v) in out.iter_mut().zip(x) {
        *o = to_f32(v)?;
    }
    Ok(out)
}

fn to_f32<E: serde::de::Error>(x: f64) -> Result<f32, E> {
    let v = x as f32;
    if v.is_infinite() && x.is_finite() {
        return Err(E::custom(format_args!(
            "{} does not fit the board's f32 (at most {:e} in size)",
            crate::record::for_people(x),
            f32::MAX
        )));
    }
    if v == 0.0 && x != 0.0 {
        return Err(E::custom(format_args!(
            "{} is too small for the board's f32 (it would become 0; the smallest is {:e})",
            crate::record::for_people(x),
            f32::from_bits(1)
        )));
    }
    Ok(v)
}

/// A list of at most `max` items, refused at the first item beyond (nothing more is read or
/// stored).
fn at_most<'de, D: serde::Deserializer<'de>, T: Deserialize<'de>>(
    d: D,
    max: usize,
) -> Result<Vec<T>, D::Error> {
    struct Bounded<T> {
        max: usize,
        item: std::marker::PhantomData<T>,
    }
    impl<'de, T: Deserialize<'de>> serde::de::Visitor<'de> for Bounded<T> {
        type Value = Vec<T>;
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            write!(f, "a list of at most {}", self.max)
        }
        fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
            let mut out = Vec::new();
            while let Some(x) = seq.next_element()? {
                if out.len() == self.max {
                    return Err(serde::de::Error::custom(format_args!(
                        "more than {} items: a design has at most {}",
                        self.max, self.max
                    )));
                }
                out.push(x);
            }
            Ok(out)
        }
    }
    d.deserialize_seq(Bounded { max, item: std::marker::PhantomData })
}

fn at_most_max_harmonics<'de, D: serde::Deserializer<'de>, T: Deserialize<'de>>(
    d: D,
) -> Result<Vec<T>, D::Error> {
    at_most(d, MAX_HARMONICS)
}

fn at_most_max_sources<'de, D: serde::Deserializer<'de>, T: Deserialize<'de>>(
    d: D,
) -> Result<Vec<T>, D::Error> {
    at_most(d, MAX_SOURCES)
}

/// The fit percentage `100·(1 − ‖y − ŷ‖/‖y − ȳ‖)`.
pub fn fit_pct(y: &[f64], y_hat: &[f64]) -> f64 {
    let m = analysis::mean(y);
    let num: f64 = y.iter().zip(y_hat).map(|(a, b)| (a - b).powi(2)).sum();
    let den: f64 = y.iter().map(|a| (a - m).powi(2)).sum();
    if den > 0.0 { 100.0 * (1.0 - (num / den).sqrt()) } else { f64::NAN }
}

/// `Some(f)` if `u`'s fundamental at `f` holds at least [`SINE_SHARE`] of its power; `f`
/// rounded to what the record resolves (a decade below a tenth of a bin: 0.01 Hz for 6 s),
/// so a sine of 23 Hz reads as 23 Hz, not 23.0000000036.
fn sine_frequency(u: &[f64], ts: f64) -> Option<f64> {
    let f = analysis::estimate_drive(u, ts)?;
    let step = 10f64.powf((0.1 / (u.len() as f64 * ts)).log10().floor());
    let f = (f / step).round() * step;
    let n = analysis::whole_periods(u.len(), f, ts);
    if n < u.len() / 2 {
        return None;
    }
    let x = &u[u.len() - n..];
    let m = analysis::mean(x);
    let power: f64 = x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / x.len() as f64;
    let t = analysis::tone(x, f, ts);
    (power > 0.0 && t.amp * t.amp / 2.0 >= SINE_SHARE * power).then_some(f)
}

/// The model as a plant the host steps sample by sample (the extended model with up to
/// [`MAX_HARMONICS`] branches and its input delay, from rest).
struct Stepper {
    model: Branches,
    /// The input delay: whole samples and the fraction (linear interpolation, as
    /// [`crate::model::delayed`]).
    whole: usize,
    frac: f64,
    /// The last `whole + 2` inputs, newest last (zeros before the start).
    past: std::collections::VecDeque<f64>,
}

enum Branches {
    M0(EnhancedParams<f64, 2, 2, 0>, <EnhancedParams<f64, 2, 2, 0> as Model<f64>>::State),
    M1(EnhancedParams<f64, 2, 2, 1>, <EnhancedParams<f64, 2, 2, 1> as Model<f64>>::State),
    M2(EnhancedParams<f64, 2, 2, 2>, <EnhancedParams<f64, 2, 2, 2> as Model<f64>>::State),
}

impl Stepper {
    fn new(m: &HostModel, ts: f64) -> Result<Self, boucwen_core::Error> {
        if !(m.delay >= 0.0 && m.delay <= crate::model::MAX_DELAY) {
            return Err(boucwen_core::Error::OutOfRange("model delay (0 to 3 samples)"));
        }
        let whole = m.delay.floor() as usize;
        let past = std::iter::repeat_n(0.0, whole + 2).collect();
        Ok(Self { model: Branches::new(m, ts)?, whole, frac: m.delay - whole as f64, past })
    }

    fn step(&mut self, u: f64) -> f64 {
        self.past.pop_front();
        self.past.push_back(u);
        let n = self.past.len();
        let u_d =
            (1.0 - self.frac) * self.past[n - 1 - self.whole] + self.frac * self.past[n - 2 - self.whole];
        self.model.step(u_d)
    }
}

impl Branches {
    fn new(m: &HostModel, ts: f64) -> Result<Self, boucwen_core::Error> {
        let drive = Oscillator::new(m.drive_hz, ts)?;
        fn p<const M: usize>(m: &HostModel, drive: Oscillator) -> EnhancedParams<f64, 2, 2, M> {
            EnhancedParams {
                base: m.ext,
                branches: core::array::from_fn(|i| {
                    let b = &m.branches[i];
                    HarmonicBranch { order: b.order, alpha_s: b.alpha_s, alpha_c: b.alpha_c, ar: b.ar }
                }),
                drive,
            }
        }
        Ok(match m.branches.len() {
            0 => {
                let q = p::<0>(m, drive);
                Branches::M0(q, q.initial_state())
            }
            1 => {
                let q = p::<1>(m, drive);
                Branches::M1(q, q.initial_state())
            }
            _ => {
                let q = p::<2>(m, drive);
                Branches::M2(q, q.initial_state())
            }
        })
    }

    fn step(&mut self, u: f64) -> f64 {
        match self {
            Branches::M0(p, s) => p.step(s, u),
            Branches::M1(p, s) => p.step(s, u),
            Branches::M2(p, s) => p.step(s, u),
        }
    }
}

/// A closed-loop run of the board's controller on a model: `(d, u, y, flags)` per sample.
struct Tracked {
    d: Vec<f64>,
    u: Vec<f64>,
    y: Vec<f64>,
    saturated: Vec<bool>,
}

fn track(
    params: &ControllerParams,
    model: &HostModel,
    n: usize,
    ts: f64,
) -> Result<Tracked, boucwen_core::Error> {
    let mut c = Controller::new(params)?;
    let mut plant = Stepper::new(model, ts)?;
    let mut t = Tracked { d: vec![], u: vec![], y: vec![], saturated: vec![] };
    let mut y_prev = None;
    for _ in 0..n {
        let s = c.step(y_prev)?;
        let y = plant.step(s.out.u as f64);
        y_prev = Some(y as f32);
        t.d.push(s.d as f64);
        t.u.push(s.out.u as f64);
        t.y.push(y);
        t.saturated.push(s.out.saturated);
    }
    Ok(t)
}

fn rmse_after(t: &Tracked, from: usize) -> f64 {
    analysis::rms_diff(&t.y[from..], &t.d[from..])
}

/// Designs the board's compensator from measured records (see the module docs).
/// `records` are the records with the names to show for them.
pub fn design_from_records(records: &[Record], opts: &DesignOptions) -> Result<DesignFile, BoardDesignError> {
    let first = records.first().ok_or(BoardDesignError::NoRecords)?;
    let ts = first.ts;
    for r in records {
        if ((r.ts - ts) / ts).abs() > 1e-6 {
            return Err(BoardDesignError::Record(
                r.source.clone(),
                format!(
                    "sampled every {} s, {} every {} s: the records must share one interval",
                    r.ts, first.source, ts
                ),
            ));
        }
        r.validate_for_fit(400).map_err(|e| BoardDesignError::Record(r.source.clone(), e.to_string()))?;
    }
    let period_us = ts * 1e6;
    let (lo, hi) = boucwen_link::limits::SAMPLE_PERIOD_US;
    if !((lo as f64..=hi as f64).contains(&period_us.round()) && (period_us - period_us.round()).abs() < 1e-3)
    {
        return Err(BoardDesignError::Record(
            first.source.clone(),
            format!(
                "sampled every {ts} s: the board's sample period is a whole number of µs from {lo} to {hi}"
            ),
        ));
    }
    check_safety(&opts.safety).map_err(BoardDesignError::Params)?;
    if !(opts.fade_s.is_finite() && opts.fade_s >= 0.0 && opts.fade_s <= 60.0) {
        return Err(BoardDesignError::Option(format!("fade-in {} s: 0 to 60 s", opts.fade_s)));
    }
    // 1. Drives.
    let drives: Vec<Option<f64>> = records.iter().map(|r| sine_frequency(&r.u, ts)).collect();
    let f = match opts.freq_hz {
        Some(f) if f.is_finite() && f > 0.0 && f < 0.25 / ts => f,
        Some(f) => {
            return Err(BoardDesignError::Option(format!(
                "frequency {f} Hz: above 0 and below a quarter of the sample rate ({} Hz)",
                0.25 / ts
            )));
        }
        None => drives.iter().flatten().copied().next().ok_or_else(|| {
            BoardDesignError::NoSineRecord(
                "no record drives a sine: record one at the frequency to track (boucwen board excite --sine F:AMP)"
                    .into(),
            )
        })?,
    };
    // A sine record at f: its frequency within half a bin of the record.
    let at_f = |i: usize| drives[i].is_some_and(|g| (g - f).abs() <= 0.5 / (records[i].len() as f64 * ts));
    let fit_i = (0..records.len()).find(|&i| at_f(i)).ok_or_else(|| {
        BoardDesignError::NoSineRecord(format!(
            "no record drives a sine at {f} Hz (found: {}): record one (boucwen board excite --sine {f}:AMP)",
            drives
                .iter()
                .zip(records)
                .map(|(d, r)| match d {
                    Some(g) => format!("{} sine {g:.3} Hz", r.source),
                    None => format!("{} broadband", r.source),
                })
                .collect::<Vec<_>>()
                .join(", ")
        ))
    })?;
    let rec = &records[fit_i];
    let fit_err = |e| BoardDesignError::Fit(rec.source.clone(), e);
    let (u, y) = (&rec.u[..], &rec.y[..]);
    let split = u.len() / 2;
    // 2. Structure from the first broadband record.
    let structure_i = drives.iter().position(Option::is_none);
    let structure = match structure_i {
        Some(i) => {
            let r = &records[i];
            let opt = OeOptions {
                samples: Samples::First(8000),
                averaging: Averaging::Off,
                hysteresis: LoopSearch::Linear,
                delay: DelaySearch::Fixed(0.0),
                require_invertible: false,
                ..OeOptions::default()
            };
            let fit = fit::fit_oe(&r.u, &r.y, ts, r.len(), &ModelSpec::extended(1.0), &[], &opt)
                .map_err(|e| BoardDesignError::Fit(r.source.clone(), e))?;
            Some(fit.model.ext.ar)
        }
        None => None,
    };
    // The first 4 s of the fitted half, sample by sample: a record from a board starts from
    // rest, with the excitation's fade-in, and is not in periodic steady state early on.
    let oe = OeOptions {
        samples: Samples::First(4000),
        averaging: Averaging::Off,
        structure: structure.map_or(StructureSearch::Grid, StructureSearch::Fixed),
        delay: DelaySearch::Fit,
        require_invertible: true,
        ..OeOptions::default()
    };
    // 3. The extended model.
    let ext_fit = fit::fit_oe(u, y, ts, split, &ModelSpec::extended(f), &[], &oe).map_err(fit_err)?;
    if !ext_fit.invertible {
        return Err(BoardDesignError::NotInvertible(format!(
            "{}: no model with an invertible loop fits (the slope of A1·u − h must stay above {} A1 on both branches)",
            rec.source,
            fit::MIN_SLOPE
        )));
    }
    let ext = ext_fit.model;
    let held_out = |m: &HostModel| -> Result<(f64, f64), BoardDesignError> {
        let sim = m.simulate(u, ts).map_err(|e| fit_err(e.into()))?;
        Ok((fit_pct(&y[split..], &sim[split..]), analysis::rms_diff(&y[split..], &sim[split..])))
    };
    let (ext_pct, ext_rms) = held_out(&ext)?;
    // 4. Harmonics in the fitted output; the prediction model.
    let n_fit = analysis::whole_periods(split, f, ts);
    let tones = analysis::harmonics(&y[split - n_fit..split], f, ts, MAX_ORDER as usize);
    let fundamental = tones.first().map_or(0.0, |t| t.amp);
    let mut found: Vec<(u32, f64)> = tones
        .iter()
        .enumerate()
        .map(|(i, t)| (i as u32 + 1, t.amp))
        .filter(|&(n, amp)| {
            n >= 3
                && n % 2 == 1
                && n as f64 * f < 0.45 / ts
                && amp >= crate::model::MIN_HARMONIC_REL * fundamental
        })
        .collect();
    found.sort_by(|a, b| b.1.total_cmp(&a.1));
    found.truncate(MAX_HARMONICS);
    let orders: Vec<u32> = found.iter().map(|&(n, _)| n).collect();
    let (prediction, pred_pct, pred_invertible, pred_rms) = if orders.is_empty() {
        (ext.clone(), ext_pct, true, ext_rms)
    } else {
        // The delay is the extended model's (the one the board previews by).
        let oe = OeOptions { delay: DelaySearch::Fixed(ext.delay), ..oe.clone() };
        let fit =
            fit::fit_oe(u, y, ts, split, &ModelSpec::enhanced(f, &orders), std::slice::from_ref(&ext), &oe)
                .map_err(fit_err)?;
        let (pct, rms) = held_out(&fit.model)?;
        // A branch that does not improve the held-out fit is not a better account.
        if pct > ext_pct {
            (fit.model, pct, fit.invertible, rms)
        } else {
            (ext.clone(), ext_pct, true, ext_rms)
        }
    };
    // 5. α.
    let (alpha, alpha_source) = match opts.amplitude_um {
        Some(a) if a.is_finite() && a > 0.0 => (a, "requested"),
        Some(a) => return Err(BoardDesignError::Option(format!("amplitude {a} µm: must be above 0"))),
        // A sensor counting the stroke downwards gives a negative α: the reference is a sine
        // of its size all the same (the inverse is odd in the output).
        None => (closed_loop::eq25_amplitude(u, y).abs(), "eq25"),
    };
    if alpha.is_nan() || alpha <= 0.0 {
        return Err(BoardDesignError::Record(
            rec.source.clone(),
            format!("eq. (25) gives α = {alpha} µm: the output does not follow the drive (give --amplitude)"),
        ));
    }
    let (u_min, u_max) = (opts.safety.u_min as f64, opts.safety.u_max as f64);
    let saturation = Saturation { u_min, u_max };
    let settings = closed_loop::CompensationSettings::default();
    let reference =
        ReferenceSpec { freq_hz: f, amplitude_um: alpha, fade_s: opts.fade_s, preview_samples: 0.0 };
    let params = |m: &HostModel, h: &[HarmonicSpec<f64>]| {
        controller_params(
            &m.ext,
            h,
            RlsConfig::with_forgetting(settings.lambda, settings.p0),
            saturation,
            settings.uc_max,
            ReferenceSpec { preview_samples: m.delay, ..reference },
            ts,
        )
        .map_err(BoardDesignError::Params)
    };
    let n = (opts.predict_seconds / ts).round() as usize;
    if !(opts.predict_seconds.is_finite() && (1000..=10_000_000).contains(&n)) {
        return Err(BoardDesignError::Option(format!(
            "prediction of {} s: 1000 samples ({} s) to 1e7",
            opts.predict_seconds,
            1000.0 * ts
        )));
    }
    let uf_params = params(&ext, &[])?;
    let settle = settle_samples(n as u32, uf_params.fade_samples) as usize;
    // 6. u_f alone (from the extended model) on the prediction model: what stands out.
    let uf = track(&uf_params, &prediction, n, ts).map_err(BoardDesignError::Params)?;
    let err: Vec<f64> = uf.y.iter().zip(&uf.d).map(|(a, b)| a - b).collect();
    let tail = &err[settle..];
    let m = analysis::whole_periods(tail.len(), f, ts);
    let cancel: Vec<u32> = match &opts.harmonics {
        // The one that stands out under u_f on the prediction model; if none does, the
        // largest odd harmonic of the record's output. A model fitted on one sine can
        // reproduce the record's harmonic through its own loop and resonance (it places the
        // resonance near n·f), and then its inverse cancels the harmonic on the model, not
        // on the actuator: on the virtual bimorph at 23 Hz (3rd harmonic 20 % of the output,
        // fitted resonance 71.8 Hz) u_f alone was predicted 0.58 µm and ran 4.06 µm. The
        // cancellation adapts its weights online, so a harmonic that turns out small costs
        // little.
        HarmonicChoice::Auto => design::cancelled_harmonic(&tail[..m], f, ts, alpha)
            .or_else(|| orders.first().copied())
            .into_iter()
            .collect(),
        HarmonicChoice::None => vec![],
        HarmonicChoice::Orders(o) => {
            if o.len() > MAX_HARMONICS {
                return Err(BoardDesignError::Option(format!(
                    "{} harmonics: the board cancels at most {MAX_HARMONICS}",
                    o.len()
                )));
            }
            if let Some(&bad) = o.iter().find(|&&n| n < 2 || n as f64 * f >= 0.5 / ts) {
                return Err(BoardDesignError::Option(format!(
                    "harmonic {bad}: orders from 2 with n·f below the Nyquist frequency ({} Hz)",
                    0.5 / ts
                )));
            }
            o.clone()
        }
    };
    // The model the board inverts: as in the sweep, the enhanced model's extended part when
    // it carries every cancelled harmonic (its structure is not bent to imitate them) and its
    // structure is known: set by a broadband record, or the enhanced model explains the record
    // (its held-out error at most [`ENHANCED_EXPLAINS`] of the extended model's). Else the
    // extended model. On one sine record the enhanced model's branches can take the harmonic
    // and leave its structure free to be anything that fits the fundamental (on the virtual
    // bimorph at 23 Hz: held-out 0.039 against 0.126 µm, a "resonance" at 309 Hz, and the
    // cancellation's response at 69 Hz off by 47° and 7×, which tracked 10.2 µm RMS in
    // `tests/board_design.rs`), while the extended model must place its resonance near the
    // harmonic (there 0.52 µm). On the on-chip actuator, an enhanced model itself, the
    // enhanced fit is exact (5·10⁻⁷ against 0.024 µm) and its extended part tracks 0.15 µm
    // where the extended model tracks 1.36 µm.
    let carries =
        !cancel.is_empty() && cancel.iter().all(|n| prediction.branches.iter().any(|b| b.order == *n));
    let structure_known = structure.is_some() || pred_rms <= ENHANCED_EXPLAINS * ext_rms;
    let base_is_ext = !(carries && pred_invertible && structure_known);
    let base = if base_is_ext { &ext } else { &prediction };
    let uf_rmse = rmse_after(&uf, settle);
    let base_uf = if base_is_ext {
        uf
    } else {
        track(&params(base, &[])?, &prediction, n, ts).map_err(BoardDesignError::Params)?
    };
    // 7. The drive the tracking needs: within the limits, and where the loop is invertible?
    let fade = uf_params.fade_samples as usize;
    let (lo_u, hi_u) =
        base_uf.u[fade.min(n)..].iter().fold((0.0f64, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
    // At a bound of the range (the inverse clamps u_f there itself, unflagged) or flagged.
    let saturated = (fade.min(n)..n)
        .filter(|&k| {
            base_uf.saturated[k] || base_uf.u[k] >= u_max as f32 as f64 || base_uf.u[k] <= u_min as f32 as f64
        })
        .count();
    if saturated > 0 {
        return Err(BoardDesignError::DriveLimits(format!(
            "tracking {alpha:.3} µm at {f} Hz needs a drive from {lo_u:.3} to {hi_u:.3} V on the model, beyond the drive limits [{u_min}, {u_max}] V ({saturated} of {} samples saturated): ask for a smaller --amplitude or wider --drive-limits",
            n - fade.min(n)
        )));
    }
    let bw = &base.ext.bw;
    let mut hs = boucwen_core::model::HysteresisState::default();
    let (mut h_lo, mut h_hi) = (0.0f64, 0.0f64);
    for &uk in &base_uf.u {
        let h = hs.step(bw, uk);
        h_lo = h_lo.min(h);
        h_hi = h_hi.max(h);
    }
    let slope_rel = fit::slope_rel(bw, h_lo, h_hi).unwrap_or(f64::NAN);
    if slope_rel.is_nan() || slope_rel < fit::MIN_SLOPE {
        return Err(BoardDesignError::NotInvertible(format!(
            "over the drive {lo_u:.3} to {hi_u:.3} V that tracking {alpha:.3} µm needs, the slope of A1·u − h falls to {slope_rel:.3}·A1 (at least {} needed; A1 = {:.4} µm/V): ask for a smaller --amplitude",
            fit::MIN_SLOPE,
            bw.a1
        )));
    }
    let hspecs = closed_loop::model_harmonics(base, &cancel, f, ts, PhaseRule::Model);
    let final_params = params(base, &hspecs)?;
    // 8. The prediction.
    let designed = track(&final_params, &prediction, n, ts).map_err(BoardDesignError::Params)?;
    let safety = opts.safety;
    let p = &final_params;
    let board = BoardSection {
        sample_period_us: p.sample_period_us,
        freq_hz: f,
        amplitude_um: p.amplitude_um,
        fade_samples: p.fade_samples,
        bouc_wen: [p.model.bw.a1, p.model.bw.a, p.model.bw.a0, p.model.bw.gamma, p.model.bw.beta],
        ar: p.model.ar,
        harmonics: p
            .harmonics
            .iter()
            .map(|h| BoardHarmonic { order: h.order, re: h.response.re, im: h.response.im })
            .collect(),
        rls: [p.rls.lambda, p.rls.p0, p.rls.p_max],
        saturation: [p.saturation.u_min, p.saturation.u_max],
        uc_max_v: p.uc_max,
        preview_samples: p.preview_samples,
        drive_limits_v: [safety.u_min, safety.u_max],
        slew_v_per_s: safety.slew_v_per_s,
        host_timeout_ms: safety.host_timeout_ms,
    };
    let (base_pct, base_rms) = if base_is_ext { (ext_pct, ext_rms) } else { (pred_pct, held_out(base)?.1) };
    let mut sources = Vec::new();
    for (i, r) in records.iter().enumerate() {
        let drive = match drives[i] {
            Some(g) => format!("sine {g:.4} Hz"),
            None => "broadband".into(),
        };
        let (role, pct) = if i == fit_i {
            ("fit", Some(base_pct))
        } else if Some(i) == structure_i {
            ("structure", None)
        } else if at_f(i) {
            let sim =
                ext.simulate(&r.u, ts).map_err(|e| BoardDesignError::Fit(r.source.clone(), e.into()))?;
            let skip = (r.len() / 10).min(2000);
            ("check", Some(fit_pct(&r.y[skip..], &sim[skip..])))
        } else {
            ("unused", None)
        };
        sources.push(SourceRecord {
            path: r.source.clone(),
            samples: r.len(),
            ts_s: r.ts,
            drive,
            role: role.into(),
            fit_pct: pct,
        });
    }
    let bw = &base.ext.bw;
    let cancelled_amp = |order: u32| analysis::tone(&tail[..m], order as f64 * f, ts).amp;
    Ok(DesignFile {
        format: FORMAT.into(),
        version: VERSION,
        created_by: format!("boucwen {}", env!("CARGO_PKG_VERSION")),
        sources,
        model: ModelSection {
            inverted: if base_is_ext {
                "extended".into()
            } else {
                format!("the extended part of {}", base.name())
            },
            ar: base.ext.ar,
            a1: bw.a1,
            a: bw.a,
            a0: bw.a0,
            gamma: bw.gamma,
            beta: bw.beta,
            delay_samples: base.delay,
            resonance_hz: crate::model::poles::resonance_hz(&base.ext.ar, ts),
            fit_pct: base_pct,
            held_out_rms_um: base_rms,
            checked_u_v: [lo_u, hi_u],
            min_slope_rel: slope_rel,
        },
        harmonics_found: found
            .iter()
            .map(|&(order, amp)| HarmonicSection {
                order,
                freq_hz: order as f64 * f,
                amplitude: 100.0 * amp / fundamental,
                gain_um_per_v: None,
                phase_deg: None,
            })
            .collect(),
        harmonics_cancelled: hspecs
            .iter()
            .map(|h| HarmonicSection {
                order: h.order,
                freq_hz: h.order as f64 * f,
                amplitude: cancelled_amp(h.order),
                gain_um_per_v: Some(h.response.norm()),
                phase_deg: Some(h.response.arg().to_degrees()),
            })
            .collect(),
        reference: ReferenceSection {
            freq_hz: f,
            amplitude_um: alpha,
            amplitude_source: alpha_source.into(),
            fade_s: opts.fade_s,
        },
        prediction: PredictionSection {
            model: prediction.name(),
            branches: prediction
                .branches
                .iter()
                .map(|b| BranchSection { order: b.order, alpha_s: b.alpha_s, alpha_c: b.alpha_c })
                .collect(),
            fit_pct: pred_pct,
            seconds: n as f64 * ts,
            settle_s: settle as f64 * ts,
            uf_rmse_um: uf_rmse,
            design_rmse_um: rmse_after(&designed, settle),
        },
        board,
    })
}

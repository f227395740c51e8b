//! Why a diagnosis could not be made. Each is one sentence naming the rule applied and the
//! numbers.

use crate::fit::FitError;
use crate::model::ModelError;
use crate::signal::steady::{NoResponse, WindowError};
use std::fmt;

/// Why a diagnosis could not be made.
#[derive(Debug)]
pub enum DiagnoseError {
    /// The input has no oscillating component to call a drive.
    NoDrive {
        /// Standard deviation of `u` (V).
        std_v: f64,
    },
    /// The drive is not a sine (for the sine analysis).
    NotSine {
        /// The drive, described.
        drive: String,
    },
    /// The drive does not repeat (a chirp, noise): distortion cannot be told from noise.
    Aperiodic {
        /// The drive, described.
        drive: String,
    },
    /// The drive is a sine or none (for the periodic analysis).
    NotPeriodic {
        /// The drive, described.
        drive: String,
    },
    /// The records given as realisations of one drive are not.
    Realisations(String),
    /// No steady window, or `--window` outside the record.
    Window(WindowError),
    /// The output does not respond.
    NoResponse(NoResponse),
    /// Fewer whole drive periods in the steady window than the analysis needs.
    TooFewPeriods {
        /// Drive frequency (Hz).
        drive_hz: f64,
        /// Whole periods in the window.
        periods: usize,
        /// Whole periods needed (`sine.min_periods`, `periodic.min_periods`).
        need: usize,
        /// The window (s).
        window_s: [f64; 2],
    },
    /// Fewer samples in the steady window than the analysis needs.
    TooFewSamples {
        /// Samples in the window.
        samples: usize,
        /// Samples needed (`sine.min_samples`).
        need: usize,
        /// The window (s).
        window_s: [f64; 2],
    },
    /// The drive's harmonics cannot be analysed: its second harmonic is at or above Nyquist.
    DriveTooFast {
        /// Drive frequency found (Hz).
        drive_hz: f64,
        /// Nyquist frequency (Hz).
        nyquist_hz: f64,
    },
    /// The fitted baseline's loop does not close under this drive: its free run's mean
    /// moves from period to period (a Bouc–Wen loop can ratchet under a drive without
    /// half-wave symmetry), so what it gets wrong says nothing about the actuator.
    Ratchets {
        /// How far its mean moves over the held-out part (µm).
        moved_um: f64,
        /// The drive's own harmonic distortion (%).
        thd_pct: f64,
    },
    /// The fit failed.
    Fit(FitError),
}

impl fmt::Display for DiagnoseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let span = |w: &[f64; 2]| format!("{:.3}–{:.3} s", w[0], w[1]);
        match self {
            DiagnoseError::NoDrive { std_v } => write!(
                f,
                "the input u does not vary (standard deviation {std_v:.2e} V): there is no drive to analyse"
            ),
            DiagnoseError::NotSine { drive } => write!(
                f,
                "the drive is {drive}; the sine analysis takes a sine drive (a periodic or multisine drive has its own \
                 analysis, boucwen diagnose chooses it)"
            ),
            DiagnoseError::Aperiodic { drive } => write!(
                f,
                "the drive is {drive}; diagnose needs a drive that repeats (a sine, a triangle or square, a multisine) \
                 to tell distortion from noise over whole periods (boucwen identify fits a model to any drive)"
            ),
            DiagnoseError::NotPeriodic { drive } => write!(
                f,
                "the drive is {drive}; the periodic analysis takes a periodic drive that is not a sine, or a multisine"
            ),
            DiagnoseError::Realisations(why) => write!(f, "{why}"),
            DiagnoseError::Window(e) => write!(f, "{e}"),
            DiagnoseError::NoResponse(e) => write!(f, "{e}"),
            DiagnoseError::TooFewPeriods { drive_hz, periods, need, window_s } => write!(
                f,
                "the steady window {} holds {periods} whole periods of the {drive_hz:.3} Hz drive; diagnose needs at \
                 least {need} (half fitted, half held out): record more periods",
                span(window_s)
            ),
            DiagnoseError::TooFewSamples { samples, need, window_s } => write!(
                f,
                "the steady window {} holds {samples} samples; diagnose needs at least {need}: record longer or \
                 sample faster",
                span(window_s)
            ),
            DiagnoseError::DriveTooFast { drive_hz, nyquist_hz } => write!(
                f,
                "the drive ({drive_hz:.1} Hz) is above half the Nyquist frequency ({nyquist_hz:.1} Hz): \
                 no harmonic of it can be seen"
            ),
            DiagnoseError::Ratchets { moved_um, thd_pct } => write!(
                f,
                "the fitted extended model does not close its loop under this drive: its free run's mean moves by \
                 {moved_um:.3} µm over the held-out part (the Bouc–Wen loop ratchets; the drive's own distortion is \
                 {thd_pct:.2} %), so no diagnosis is made on top of it"
            ),
            DiagnoseError::Fit(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for DiagnoseError {}

impl From<FitError> for DiagnoseError {
    fn from(e: FitError) -> Self {
        DiagnoseError::Fit(e)
    }
}

impl From<ModelError> for DiagnoseError {
    fn from(e: ModelError) -> Self {
        DiagnoseError::Fit(e.into())
    }
}

impl From<WindowError> for DiagnoseError {
    fn from(e: WindowError) -> Self {
        DiagnoseError::Window(e)
    }
}

impl From<NoResponse> for DiagnoseError {
    fn from(e: NoResponse) -> Self {
        DiagnoseError::NoResponse(e)
    }
}

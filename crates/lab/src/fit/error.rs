//! Why a fit failed.

use super::MAX_BRANCHES;
use std::fmt;

/// Why a fit failed.
#[derive(Clone, Debug, PartialEq)]
pub enum FitError {
    /// Fewer samples than the fit needs.
    TooFewSamples {
        /// Samples available for fitting.
        have: usize,
        /// Samples needed.
        need: usize,
    },
    /// A harmonic at or above Nyquist, or an order below 2.
    BadHarmonic(u32),
    /// More branches than supported.
    TooManyBranches(usize),
    /// A core error (parameters, frequencies).
    Core(boucwen_core::Error),
    /// No candidate gave a stable model that could be solved.
    NoStableModel,
}

impl fmt::Display for FitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FitError::TooFewSamples { have, need } => {
                write!(f, "too few samples to fit: {have} available, at least {need} needed")
            }
            FitError::BadHarmonic(n) => write!(f, "harmonic order {n} is below 2 or at/above Nyquist"),
            FitError::TooManyBranches(m) => {
                write!(f, "{m} harmonic branches: at most {MAX_BRANCHES} are supported")
            }
            FitError::Core(e) => write!(f, "{e}"),
            FitError::NoStableModel => write!(f, "no stable model fits the data"),
        }
    }
}

impl std::error::Error for FitError {}

impl From<boucwen_core::Error> for FitError {
    fn from(e: boucwen_core::Error) -> Self {
        FitError::Core(e)
    }
}

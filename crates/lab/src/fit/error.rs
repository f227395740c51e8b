//! Why a fit failed.

use crate::model::ModelError;
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
    /// The model asked for cannot be built or run (a harmonic at or above Nyquist, too many
    /// branches, a core parameter).
    Model(ModelError),
    /// No candidate gave a stable model that could be solved.
    NoStableModel,
}

impl fmt::Display for FitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FitError::TooFewSamples { have, need } => {
                write!(f, "too few samples to fit: {have} available, at least {need} needed")
            }
            FitError::Model(e) => write!(f, "{e}"),
            FitError::NoStableModel => write!(f, "no stable model fits the data"),
        }
    }
}

impl std::error::Error for FitError {}

impl From<ModelError> for FitError {
    fn from(e: ModelError) -> Self {
        FitError::Model(e)
    }
}

impl From<boucwen_core::Error> for FitError {
    fn from(e: boucwen_core::Error) -> Self {
        FitError::Model(ModelError::Core(e))
    }
}

//! Several inputs and outputs at once: the best linear approximation from multisines, a
//! linear state-space model, and one hysteretic model across amplitude levels.
//!
//! Built for records like the CubeSpec Fine Steering Mirror (three piezos, three
//! displacement sensors, orthogonal random-phase multisines at three levels; see
//! [`crate::record::mimo`]). The steps, each its own module:
//!
//! | step | module | what |
//! |---|---|---|
//! | spectra | [`spectra`] | DFT of the period means, per level and realisation; the noise from the periods |
//! | BLA | [`bla`] | `G = Y U⁻¹` per group of `m` realisations, its noise and nonlinear-distortion variances, and per output what a linear model leaves |
//! | linear | [`linear`] | frequency-domain subspace identification (McKelvey et al. 1996) of a modal state-space model, then output-error refinement (Levenberg–Marquardt) |
//! | hysteresis | [`hysteresis`] | the Bouc–Wen hysteresis, integrated exactly between samples |
//! | model | [`model`] | [`MimoModel`]: parameters apart from state, simulation with a periodic warm-up |
//! | fit | [`fit`] | the whole identification across levels, order choice on kept-apart realisations, the benchmark's metric |
//! | file | [`file`] | the model file of family `"mimo"` (`identify --save`, `compare`, `simulate --model`) |
//!
//! ## Steady state and the frequency domain
//! Under a periodic input in steady state, a linear model's output over one period is
//! `Y_k = G(z_k) U_k` on every DFT line `k` (`z_k = e^{i2πk/N}`), exactly: the simulation
//! error over a steady-state period is, by Parseval,
//! ```text
//! Σ_n e[n]² = (1/N) Σ_k |Y_k − G(z_k)U_k|²
//! ```
//! So the output-error fit of the linear part is done on the lines (no simulation, no
//! transient), and the hysteretic channels, which are not linear, are simulated in the time
//! domain once per shape and then taken to the lines.

pub mod bla;
pub mod feedback;
pub mod file;
pub mod fit;
pub mod hysteresis;
pub mod linear;
pub mod model;
pub mod spectra;

pub use file::MimoModelFile;
pub use fit::{FitOptions, MimoFit, Progress, fit_mimo};
pub use model::MimoModel;

use std::fmt;

/// Why a MIMO identification or simulation failed.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum MimoError {
    /// The data do not allow the step: what is missing.
    Data(String),
    /// A shape or size mismatch: what.
    Shape(String),
    /// A numerical failure (a singular system, an eigen-decomposition that did not
    /// converge): where.
    Numerical(&'static str),
    /// A model parameter is not finite or out of range: which.
    Parameter(&'static str),
}

impl fmt::Display for MimoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Data(w) => write!(f, "data: {w}"),
            Self::Shape(w) => write!(f, "shape: {w}"),
            Self::Numerical(w) => write!(f, "numerical failure in {w}"),
            Self::Parameter(w) => write!(f, "parameter {w} is not finite or out of range"),
        }
    }
}

impl std::error::Error for MimoError {}

//! The models the host fits and simulates.
//!
//! | module | what |
//! |---|---|
//! | [`host`] | the paper's actuator as identified on the host: the extended model with branches, a drift polynomial and an input delay |
//! | [`terms`] | terms around and inside it: saturation, delay, creep, stiffening |
//! | [`poles`] | the poles of a linear part: stability, resonance, decay |
//! | [`family`] | the one model structure: [`Model`] of any family, where its hysteresis sits, one simulator |
//! | [`file`] | the model file (`identify --save`, `compare`, `simulate --model`) |
//! | [`linear`] | linear output-error models of any order |
//! | [`oscillator`] | the Bouc–Wen oscillator: hysteresis as a restoring force |

pub mod family;
pub mod file;
pub mod host;
pub mod linear;
pub mod oscillator;
pub mod poles;
pub mod terms;

pub use family::{Family, Model, Placement, Structure};
pub use file::{ModelFile, ModelFileError};
pub use host::{
    Branch, HostModel, LoopShape, MAX_BRANCHES, MAX_DELAY, ModelError, ModelSpec, delayed, delayed_iter,
};
pub use terms::{TermModel, Terms};

/// Smallest amplitude of a harmonic the model gets a branch for, relative to the output's
/// fundamental: below this a term is not worth it. The sweep, `identify` and the board's
/// design propose branches by it.
pub const MIN_HARMONIC_REL: f64 = 0.02;

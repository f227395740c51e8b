//! The host model: the core's enhanced model with any number (up to [`MAX_BRANCHES`]) of
//! branches, a drift polynomial and an input delay, and what to fit ([`ModelSpec`]).

use boucwen_core::model::{EnhancedParams, ExtendedParams, HarmonicBranch, Model};
use boucwen_core::signal::Oscillator;
use std::fmt;

/// A harmonic branch of a host model: the core's branch with an AR part of order 2 (zero
/// except in the paper's RLS procedure).
pub type Branch = HarmonicBranch<f64, 2>;

/// Largest input delay a host model carries (samples).
pub const MAX_DELAY: f64 = 3.0;

/// The most branches a host model may have.
pub const MAX_BRANCHES: usize = 4;

/// A model identified on the host.
#[derive(Clone, Debug, PartialEq)]
pub struct HostModel {
    /// The extended model (`P = 2`).
    pub ext: ExtendedParams<f64, 2>,
    /// Drive frequency `f` of the branches (Hz).
    pub drive_hz: f64,
    /// Harmonic branches.
    pub branches: Vec<Branch>,
    /// Drift: coefficients of `1, t, t², …` (t in s from the record's start) added to the output.
    pub drift: Vec<f64>,
    /// Input delay `τ` (samples, ≥ 0, fractional): the model is driven by `u` delayed by `τ`
    /// (linear interpolation between samples). 0 is the paper's form; a sampled actuator
    /// (zero-order hold, driver, transport) applies its input later than the paper's
    /// instantaneous `A1·u[k]`, and `τ` says by how much. The compensator compensates it by
    /// preview ([`boucwen_core::compensator::Compensator::step_previewed`]).
    pub delay: f64,
}

/// `u` delayed by `delay` samples (linear interpolation, zero before the start).
pub fn delayed(u: &[f64], delay: f64) -> Vec<f64> {
    delayed_iter(u, delay).collect()
}

/// [`delayed`] sample by sample, without a copy of `u`.
pub fn delayed_iter(u: &[f64], delay: f64) -> impl Iterator<Item = f64> + '_ {
    // `delay <= 0` (not `< 0`): no delay, `u` itself bit for bit.
    let (m, frac) =
        if delay <= 0.0 { (0, None) } else { (delay.floor() as usize, Some(delay - delay.floor())) };
    let at = move |i: isize| if i < 0 { 0.0 } else { u.get(i as usize).copied().unwrap_or(0.0) };
    (0..u.len() as isize).map(move |k| match frac {
        None => u[k as usize],
        Some(frac) => (1.0 - frac) * at(k - m as isize) + frac * at(k - m as isize - 1),
    })
}

impl HostModel {
    /// The number of free parameters (AR, hysteresis, branch weights and AR, drift).
    pub fn parameter_count(&self) -> usize {
        7 + self.branches.iter().map(|b| if b.ar == [0.0, 0.0] { 2 } else { 4 }).sum::<usize>()
            + self.drift.len()
    }

    /// A short name: "extended", "enhanced(3)", "extended+offset" (a constant output
    /// offset), "enhanced(3)+drift" (an offset and a trend), ….
    pub fn name(&self) -> String {
        let mut s = if self.branches.is_empty() {
            "extended".to_string()
        } else {
            let orders: Vec<String> = self.branches.iter().map(|b| b.order.to_string()).collect();
            format!("enhanced({})", orders.join(","))
        };
        if self.drift.len() == 1 {
            s.push_str("+offset");
        } else if self.drift.len() > 1 {
            s.push_str("+drift");
        }
        s
    }

    fn enhanced<const M: usize>(&self, ts: f64) -> Result<EnhancedParams<f64, 2, 2, M>, ModelError> {
        let drive = Oscillator::new(self.drive_hz, ts)?;
        let branches = <[Branch; M]>::try_from(self.branches.as_slice())
            .map_err(|_| ModelError::TooManyBranches(self.branches.len()))?;
        Ok(EnhancedParams { base: self.ext, branches, drive })
    }

    /// The model with one branch as a core enhanced model (tests).
    #[cfg(test)]
    pub(crate) fn enhanced_for_test(&self) -> EnhancedParams<f64, 2, 2, 1> {
        self.enhanced::<1>(1e-3).expect("valid test model")
    }

    /// Free-run simulation from rest (`h = 0`, past outputs 0, phase 0) for the input `u`.
    /// An unstable model's output grows without bound; it is returned as computed.
    pub fn simulate(&self, u: &[f64], ts: f64) -> Result<Vec<f64>, ModelError> {
        fn run<const M: usize>(m: &HostModel, u: &[f64], ts: f64) -> Result<Vec<f64>, ModelError> {
            let p = m.enhanced::<M>(ts)?;
            let mut s = p.initial_state();
            Ok(delayed_iter(u, m.delay).map(|uk| p.step(&mut s, uk)).collect())
        }
        let mut y = match self.branches.len() {
            0 => run::<0>(self, u, ts)?,
            1 => run::<1>(self, u, ts)?,
            2 => run::<2>(self, u, ts)?,
            3 => run::<3>(self, u, ts)?,
            4 => run::<4>(self, u, ts)?,
            m => return Err(ModelError::TooManyBranches(m)),
        };
        if !self.drift.is_empty() {
            for (k, v) in y.iter_mut().enumerate() {
                *v += poly(&self.drift, k as f64 * ts);
            }
        }
        Ok(y)
    }

    /// The loop shape of the output-error parametrisation (`None` when `A = 0`).
    pub fn shape(&self) -> Option<LoopShape> {
        let bw = &self.ext.bw;
        (bw.a != 0.0).then(|| LoopShape {
            a0_ratio: bw.a0 / bw.a,
            gamma: bw.a.signum() * bw.gamma,
            beta: bw.beta,
        })
    }
}

/// The shape of the hysteresis loop with the amplitude `A` factored out: by the homogeneity
/// of the Bouc–Wen equation, `h(A, A0, γ, β) = A·h₁` with `h₁` the hysteresis of `A = 1`,
/// `A0/A`, `γ' = sgn(A)·γ` and `β`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopShape {
    /// `A0/A`: the asymmetric term relative to the amplitude.
    pub a0_ratio: f64,
    /// `γ' = sgn(A)·γ`.
    pub gamma: f64,
    /// `β`.
    pub beta: f64,
}

/// `c[0] + c[1]·t + c[2]·t² + …`.
pub(crate) fn poly(c: &[f64], t: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, &ci| acc * t + ci)
}

/// What to fit.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelSpec {
    /// Drive frequency (needed for branches).
    pub drive_hz: f64,
    /// Orders of the harmonic branches (empty: the extended model).
    pub harmonics: Vec<u32>,
    /// Degree of the drift polynomial (`None`: no drift term).
    pub drift_degree: Option<usize>,
}

impl ModelSpec {
    /// The extended model.
    pub fn extended(drive_hz: f64) -> Self {
        Self { drive_hz, harmonics: vec![], drift_degree: None }
    }

    /// The enhanced model with the given branches.
    pub fn enhanced(drive_hz: f64, harmonics: &[u32]) -> Self {
        Self { drive_hz, harmonics: harmonics.to_vec(), drift_degree: None }
    }

    pub(crate) fn check(&self, ts: f64) -> Result<(), ModelError> {
        if self.harmonics.len() > MAX_BRANCHES {
            return Err(ModelError::TooManyBranches(self.harmonics.len()));
        }
        for &n in &self.harmonics {
            if n < 2 || n as f64 * self.drive_hz >= 0.5 / ts {
                return Err(ModelError::BadHarmonic(n));
            }
        }
        Oscillator::new(self.drive_hz, ts)?;
        Ok(())
    }
}

/// Why a host model cannot be built or run.
#[derive(Clone, Debug, PartialEq)]
pub enum ModelError {
    /// A harmonic at or above Nyquist, or an order below 2.
    BadHarmonic(u32),
    /// More branches than supported.
    TooManyBranches(usize),
    /// A core error (parameters, frequencies).
    Core(boucwen_core::Error),
    /// The free run leaves every finite value.
    Diverges,
    /// Too few samples for the model to run (its output filter's length).
    TooFewSamples {
        /// Samples given.
        have: usize,
        /// Samples needed.
        need: usize,
    },
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ModelError::BadHarmonic(n) => write!(f, "harmonic order {n} is below 2 or at/above Nyquist"),
            ModelError::TooManyBranches(m) => {
                write!(f, "{m} harmonic branches: at most {MAX_BRANCHES} are supported")
            }
            ModelError::Core(e) => write!(f, "{e}"),
            ModelError::Diverges => write!(f, "the model's free run diverges"),
            ModelError::TooFewSamples { have, need } => {
                write!(f, "too few samples to run the model: {have} given, at least {need} needed")
            }
        }
    }
}

impl std::error::Error for ModelError {}

impl From<boucwen_core::Error> for ModelError {
    fn from(e: boucwen_core::Error) -> Self {
        ModelError::Core(e)
    }
}

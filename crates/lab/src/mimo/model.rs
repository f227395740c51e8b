//! [`MimoModel`]: a linear modal state-space model with an optional hysteresis branch.
//!
//! ## Structure
//! ```text
//! x_l[k+1] = A x_l[k] + B₀ u[k]                      (the linear model's state, driving the branch)
//! z_j[k]   = u_i[k] / s_j      or   x_l,i[k] / s_j     (channel j: an input, or a modal coordinate)
//! w_j[k]   = h_j(z_j)[k]                               (Bouc–Wen, A = 1, shape j; hysteresis module)
//! x[k+1]   = A x[k] + B u[k] + E w[k]
//! y[k]     = C x[k] + D u[k] + F w[k]
//! ```
//! A channel may instead close the loop ([`Source::Feedback`]): its input is a state of `x`
//! itself and it gives `w_j = h_j(z_j) − z_j` (the loop's nonlinear part), an LFR whose
//! nonlinearity is a Bouc–Wen restoring force on a mode ([`super::feedback`]).
//!
//! Without a branch it is the linear model `(A, B, C, D)`. A channel on an input is the
//! Hammerstein form (`u → h(u)` through its own input matrix); a channel on a modal
//! coordinate (the first state of a mode's block) puts a hysteretic term on that mode's
//! displacement, the first-order effect of a hysteretic stiffness in the structure (the
//! mode's frequency and damping change with amplitude): the Bouc–Wen oscillator family,
//! taken open loop so that the model stays linear in `B, D, E, F`.
//!
//! Parameters are plain data (serde), apart from the simulation state.

use super::MimoError;
use super::hysteresis::Shape;
use super::linear::{ModalSs, Mode};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// Where a hysteresis channel takes its input from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Source {
    /// Input `i`.
    Input(usize),
    /// State `i` of the linear state `x_l`.
    State(usize),
    /// State `i` of the model's own state `x`: the loop is closed (an LFR), and the channel
    /// gives the nonlinear part of its loop only, `w = h(z) − z` (`z = x_i/s`), so that at
    /// small amplitude the model is `(A, B, C, D)`.
    Feedback(usize),
}

/// One hysteresis channel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Channel {
    /// Its input.
    pub source: Source,
    /// `s_j`: the source is divided by it (its RMS on the fitted data).
    pub scale: f64,
    /// The loop's shape.
    pub shape: Shape,
}

/// The hysteresis branch.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Branch {
    /// The channels `w_j`.
    pub channels: Vec<Channel>,
    /// `B₀`, `n × m` row-major (drives `x_l`).
    pub b0: Vec<f64>,
    /// `E`, `n × q` row-major.
    pub e: Vec<f64>,
    /// `F`, `p × q` row-major.
    pub f: Vec<f64>,
}

/// The inputs' envelope, the signal that schedules the modes' stiffness ([`Schedule`]):
/// `ρ[k] = a·ρ[k−1] + (1 − a)·(1/m) Σ_c |u_c[k]| / scale`, from `ρ = 0` at rest.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// `a` (0 ≤ a < 1): `exp(−1/τ)` for a time constant of `τ` samples.
    pub pole: f64,
    /// `scale` (the inputs' mean absolute value on the fitted data).
    pub scale: f64,
}

impl Envelope {
    /// `ρ[k]` from `ρ[k−1]` and the inputs `u[k]`.
    #[inline]
    pub fn step(&self, rho: f64, u: &[f64]) -> f64 {
        let mean = u.iter().map(|v| v.abs()).sum::<f64>() / u.len().max(1) as f64;
        self.pole * rho + (1.0 - self.pole) * mean / self.scale
    }

    /// `ρ` over a warm-up pass and a scored pass of the period `u` (`m × N` channels-major):
    /// `2N` values.
    pub fn rho(&self, u: &[f64], m: usize, len: usize) -> Vec<f64> {
        let mut out = vec![0.0; 2 * len];
        let mut rho = 0.0;
        let mut uk = vec![0.0; m];
        for (k, o) in out.iter_mut().enumerate() {
            for (c, v) in uk.iter_mut().enumerate() {
                *v = u[c * len + k % len];
            }
            rho = self.step(rho, &uk);
            *o = rho;
        }
        out
    }

    /// Checks `0 ≤ a < 1` and `scale > 0`.
    pub fn validate(&self) -> Result<(), MimoError> {
        if !((0.0..1.0).contains(&self.pole) && self.scale.is_finite() && self.scale > 0.0) {
            return Err(MimoError::Parameter("the envelope's pole or scale"));
        }
        Ok(())
    }
}

/// One mode's scheduled stiffness: `x_i, x_{i+1}` get `(k₀ρ + k₂ρ², k₁ρ + k₃ρ²)·x_i`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScheduledMode {
    /// `i`: the first state of the mode's block.
    pub state: usize,
    /// `[k₀, k₁, k₂, k₃]`.
    pub k: [f64; 4],
}

/// The modes' stiffness scheduled by the inputs' envelope: the amplitude-dependent
/// stiffness of the piezos (Rayleigh's law: the compliance grows with the field's amplitude).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Schedule {
    /// The envelope `ρ`.
    pub envelope: Envelope,
    /// Per scheduled mode.
    pub modes: Vec<ScheduledMode>,
}

/// How a simulation starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Warmup {
    /// From rest (state zero, hysteresis zero, previous input zero).
    Rest,
    /// From rest, then the input run this many times before the returned pass: the periodic
    /// steady state of a periodic input.
    Periods(usize),
}

/// A MIMO model (module docs). Matrices are row-major.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MimoModel {
    /// Sample rate the model runs at, Hz.
    pub sample_rate_hz: f64,
    /// Inputs `m`.
    pub inputs: usize,
    /// Outputs `p`.
    pub outputs: usize,
    /// The blocks of `A`.
    pub modes: Vec<Mode>,
    /// `B`, `n × m`.
    pub b: Vec<f64>,
    /// `C`, `p × n`.
    pub c: Vec<f64>,
    /// `D`, `p × m`.
    pub d: Vec<f64>,
    /// The hysteresis branch, if any.
    pub branch: Option<Branch>,
    /// The stiffness scheduled by the inputs' envelope, if any.
    #[serde(default)]
    pub schedule: Option<Schedule>,
}

fn row_major(m: &DMatrix<f64>) -> Vec<f64> {
    m.transpose().as_slice().to_vec()
}

impl MimoModel {
    /// The linear model `ss` at `sample_rate_hz`.
    pub fn linear(ss: &ModalSs, sample_rate_hz: f64) -> Self {
        Self {
            sample_rate_hz,
            inputs: ss.b.ncols(),
            outputs: ss.c.nrows(),
            modes: ss.modes.clone(),
            b: row_major(&ss.b),
            c: row_major(&ss.c),
            d: row_major(&ss.d),
            branch: None,
            schedule: None,
        }
    }

    /// The linear part `(A, B, C, D)`.
    pub fn linear_part(&self) -> ModalSs {
        let n = self.order();
        ModalSs {
            modes: self.modes.clone(),
            b: DMatrix::from_row_slice(n, self.inputs, &self.b),
            c: DMatrix::from_row_slice(self.outputs, n, &self.c),
            d: DMatrix::from_row_slice(self.outputs, self.inputs, &self.d),
        }
    }

    /// States `n` of `A`.
    pub fn order(&self) -> usize {
        self.modes.iter().map(Mode::size).sum()
    }

    /// Checks sizes, finiteness, stability and the shapes.
    pub fn validate(&self) -> Result<(), MimoError> {
        let (n, m, p) = (self.order(), self.inputs, self.outputs);
        if self.b.len() != n * m || self.c.len() != p * n || self.d.len() != p * m {
            return Err(MimoError::Shape("B, C, D do not match the order and channels".into()));
        }
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(MimoError::Parameter("sample rate"));
        }
        self.linear_part().validate()?;
        if self.modes.iter().any(|md| md.radius().is_nan() || md.radius() >= 1.0) {
            return Err(MimoError::Parameter("A (a pole on or outside the unit circle)"));
        }
        if let Some(br) = &self.branch {
            let q = br.channels.len();
            if br.b0.len() != n * m || br.e.len() != n * q || br.f.len() != p * q {
                return Err(MimoError::Shape("B0, E, F do not match the order and channels".into()));
            }
            for ch in &br.channels {
                ch.shape.validate()?;
                let ok = match ch.source {
                    Source::Input(i) => i < m,
                    Source::State(i) | Source::Feedback(i) => i < n,
                };
                if !(ok && ch.scale.is_finite() && ch.scale > 0.0) {
                    return Err(MimoError::Parameter("a hysteresis channel's source or scale"));
                }
            }
            if br.b0.iter().chain(&br.e).chain(&br.f).any(|v| !v.is_finite()) {
                return Err(MimoError::Parameter("B0, E or F"));
            }
        }
        if let Some(sc) = &self.schedule {
            sc.envelope.validate()?;
            if sc.modes.iter().any(|sm| sm.state + 1 >= n || sm.k.iter().any(|v| !v.is_finite())) {
                return Err(MimoError::Parameter("a scheduled mode's state or gains"));
            }
        }
        Ok(())
    }

    /// Simulates the model on `u`, channels-major (`u[c·N + k]`, `N = u.len()/m` samples), and
    /// returns `y` channels-major (`p·N`).
    ///
    /// ```
    /// use boucwen_lab::mimo::linear::{ModalSs, Mode};
    /// use boucwen_lab::mimo::model::{MimoModel, Warmup};
    /// use nalgebra::DMatrix;
    /// // y[k] = 0.5·x[k], x[k+1] = 0.5·x[k] + u[k].
    /// let ss = ModalSs { modes: vec![Mode::Real(0.5)], b: DMatrix::from_element(1, 1, 1.0),
    ///     c: DMatrix::from_element(1, 1, 0.5), d: DMatrix::zeros(1, 1) };
    /// let m = MimoModel::linear(&ss, 1000.0);
    /// assert_eq!(m.simulate(&[1.0, 0.0, 0.0], Warmup::Rest)?, vec![0.0, 0.5, 0.25]);
    /// # Ok::<(), boucwen_lab::mimo::MimoError>(())
    /// ```
    #[allow(clippy::needless_range_loop, reason = "the indices are those of the matrix products in the docs")]
    pub fn simulate(&self, u: &[f64], warmup: Warmup) -> Result<Vec<f64>, MimoError> {
        self.validate()?;
        let (n, m, p) = (self.order(), self.inputs, self.outputs);
        if m == 0 || u.len() % m != 0 {
            return Err(MimoError::Shape(format!("{} input samples for {m} inputs", u.len())));
        }
        let len = u.len() / m;
        let passes = match warmup {
            Warmup::Rest => 1,
            Warmup::Periods(w) => w + 1,
        };
        let empty: Vec<Channel> = Vec::new();
        let (channels, b0, e, f) = match &self.branch {
            Some(br) => (&br.channels, br.b0.as_slice(), br.e.as_slice(), br.f.as_slice()),
            None => (&empty, &[][..], &[][..], &[][..]),
        };
        let q = channels.len();
        let uses_xl = channels.iter().any(|c| matches!(c.source, Source::State(_)));
        let mut x = vec![0.0; n];
        let mut xl = vec![0.0; n];
        let mut nx = vec![0.0; n];
        let mut h = vec![0.0; q];
        let mut zprev = vec![0.0; q];
        let mut w = vec![0.0; q];
        let mut uk = vec![0.0; m];
        let mut y = vec![0.0; p * len];
        let mut rho = 0.0;
        for pass in 0..passes {
            for k in 0..len {
                for (c, v) in uk.iter_mut().enumerate() {
                    *v = u[c * len + k];
                }
                if let Some(sc) = &self.schedule {
                    rho = sc.envelope.step(rho, &uk);
                }
                for (j, ch) in channels.iter().enumerate() {
                    let src = match ch.source {
                        Source::Input(i) => uk[i],
                        Source::State(i) => xl[i],
                        Source::Feedback(i) => x[i],
                    };
                    let z = src / ch.scale;
                    h[j] = ch.shape.step(h[j], z - zprev[j]);
                    zprev[j] = z;
                    w[j] = match ch.source {
                        Source::Feedback(_) => h[j] - z,
                        _ => h[j],
                    };
                }
                if pass + 1 == passes {
                    for o in 0..p {
                        let mut v = 0.0;
                        for i in 0..n {
                            v += self.c[o * n + i] * x[i];
                        }
                        for c in 0..m {
                            v += self.d[o * m + c] * uk[c];
                        }
                        for j in 0..q {
                            v += f[o * q + j] * w[j];
                        }
                        y[o * len + k] = v;
                    }
                }
                advance(&self.modes, &x, &mut nx);
                for i in 0..n {
                    let mut v = nx[i];
                    for c in 0..m {
                        v += self.b[i * m + c] * uk[c];
                    }
                    for j in 0..q {
                        v += e[i * q + j] * w[j];
                    }
                    nx[i] = v;
                }
                if let Some(sc) = &self.schedule {
                    for sm in &sc.modes {
                        let xi = x[sm.state];
                        nx[sm.state] += (sm.k[0] * rho + sm.k[2] * rho * rho) * xi;
                        nx[sm.state + 1] += (sm.k[1] * rho + sm.k[3] * rho * rho) * xi;
                    }
                }
                x.copy_from_slice(&nx);
                if uses_xl {
                    advance(&self.modes, &xl, &mut nx);
                    for i in 0..n {
                        let mut v = nx[i];
                        for c in 0..m {
                            v += b0[i * m + c] * uk[c];
                        }
                        xl[i] = v;
                    }
                }
            }
        }
        if y.iter().any(|v| !v.is_finite()) {
            return Err(MimoError::Numerical("simulation (the output is not finite)"));
        }
        Ok(y)
    }
}

/// `out = A x` for a modal `A`.
#[inline]
pub(crate) fn advance(modes: &[Mode], x: &[f64], out: &mut [f64]) {
    let mut i = 0;
    for md in modes {
        match *md {
            Mode::Real(l) => {
                out[i] = l * x[i];
                i += 1;
            }
            Mode::Pair { sigma, omega } => {
                let (a, b) = (x[i], x[i + 1]);
                out[i] = sigma * a + omega * b;
                out[i + 1] = -omega * a + sigma * b;
                i += 2;
            }
        }
    }
}

//! What the output-error fit searches, on which data, and when it stops.

use crate::model::{HostModel, LoopShape, delayed_iter};
use boucwen_core::model::BoucWenParams;

/// The structure (the AR part `G`) of the fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StructureSearch {
    /// Rank resonances on a grid (16 frequencies from 5 Hz to 0.9·Nyquist, damping 0.01 to
    /// 3), then refine the best.
    Grid,
    /// Refine from this AR part (e.g. one measured on a broadband record). A record at one
    /// drive frequency pins only one complex gain of the structure, so without it the
    /// structure of a single-sine fit is whatever reproduces that record best, physical or
    /// not.
    From([f64; 2]),
    /// Keep this AR part fixed (fit only the loop, gains, branches and drift). A single-sine
    /// record lets a free structure bend to absorb harmonics it does not cause (moving its
    /// resonance far away), which helps that record's fit and ruins the model's inverse; a
    /// model meant for compensation keeps the measured structure.
    Fixed([f64; 2]),
}

impl StructureSearch {
    /// The given AR part, if any.
    pub fn ar(&self) -> Option<[f64; 2]> {
        match *self {
            StructureSearch::Grid => None,
            StructureSearch::From(ar) | StructureSearch::Fixed(ar) => Some(ar),
        }
    }
}

/// The input delay `τ` (samples).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DelaySearch {
    /// Use this delay (0 is the paper's form).
    Fixed(f64),
    /// Fit it: start from 0, ½, 1 and 1½ samples, then refine with the other outer
    /// parameters. A record at one frequency cannot tell a delay from the structure's phase;
    /// a broadband one can.
    Fit,
}

/// The hysteresis loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LoopSearch {
    /// Rank loop shapes on a grid (saturation and asymmetry), then refine the best.
    Grid,
    /// A known loop shape (e.g. from a quasi-static record). With a fixed structure and delay
    /// too, nothing nonlinear is left and the fit is one linear least-squares solve for the
    /// gains `A1`, `A`, the branch weights and the drift.
    Fixed(LoopShape),
    /// No hysteresis (`A = 0`): a linear model, e.g. of a small-amplitude broadband record
    /// that characterises the structure and the delay.
    Linear,
}

/// Which samples of the fitted part enter the criterion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Samples {
    /// All of `[skip, fit_end)`.
    All,
    /// At most this many samples from the record's start (`[skip, min(n, fit_end))`): the
    /// fit simulates from sample 0 to the end of that window.
    First(usize),
}

/// Whether whole periods of a periodic drive are averaged before fitting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Averaging {
    /// Fit sample by sample.
    Off,
    /// When the drive is periodic at the spec's drive frequency over the fitted part (after
    /// the start-up) and the output is in steady state, fit the model's periodic steady state
    /// to the average period of the output (see the module docs); otherwise fit sample by
    /// sample. The output counts as steady when its linear trend (beyond the spec's drift
    /// degree) has an RMS below that of its noise: a model without a drift term can follow a
    /// trend in part through its dynamics (a slow pole, a creeping loop), which a fit on the
    /// samples rewards and a fit on the average period cannot see.
    Periods,
    /// As [`Averaging::Periods`], but a trend of the spec's drift degree (at least a line) is
    /// always separated from the periodic part by least squares first: the model explains
    /// the periodic part, and a trend only through its drift term. For a diagnosis, which
    /// tries a drift term of its own.
    PeriodsAndTrend,
}

/// When Levenberg–Marquardt stops. The iteration limit is a safety net: a fit that hits it
/// says so ([`Stop::IterationLimit`](super::Stop::IterationLimit)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tolerances {
    /// Stop when an accepted step lowers the cost by less than this fraction of it.
    pub cost: f64,
    /// Stop when the step (scaled by the Jacobian's column norms) is below this fraction of
    /// the parameters' scaled norm.
    pub step: f64,
    /// Stop when the largest cosine between the residual and a Jacobian column is below this.
    pub gradient: f64,
    /// Most iterations per start.
    pub max_iter: usize,
}

impl Default for Tolerances {
    fn default() -> Self {
        Self { cost: 1e-10, step: 1e-10, gradient: 1e-8, max_iter: 200 }
    }
}

/// Options of the output-error fit.
#[derive(Clone, Debug, PartialEq)]
pub struct OeOptions {
    /// Which samples of the fitted part enter the criterion.
    pub samples: Samples,
    /// Samples at the start left out of the criterion (start-up transient). With
    /// [`Averaging::Periods`] the periods are averaged from here.
    pub skip: usize,
    /// Whether whole periods are averaged first.
    pub averaging: Averaging,
    /// When Levenberg–Marquardt stops.
    pub tolerances: Tolerances,
    /// Levenberg–Marquardt starts: the best this many (at least 1) of the grid's candidates
    /// and the given start models, run in parallel.
    pub lm_starts: usize,
    /// The structure.
    pub structure: StructureSearch,
    /// The input delay. With [`StructureSearch::Fixed`] the delay counts as part of the
    /// structure: [`DelaySearch::Fit`] is then taken as 0.
    pub delay: DelaySearch,
    /// The loop.
    pub hysteresis: LoopSearch,
    /// Accept only models whose loop is invertible: on both branches and over the operating
    /// range of `h` (see [`operating_slope`]), the slope of `A1·u - h` stays above
    /// [`MIN_SLOPE`]·`A1` > 0 (a bimorph's deflection rises with voltage on each branch). The
    /// direct inverse (eqs. 16/17) needs it, and it drives the model along paths near but not
    /// on the fitted one; a free fit may reach a locally decreasing loop that reproduces a
    /// record as well.
    pub require_invertible: bool,
    /// The output's sign, `1.0` for an output counted upwards (`A ≥ 0`), `-1.0` downwards
    /// (`A ≤ 0`; [`upwards`]). `None`: the start models', else decided by
    /// [`super::fit_oe_on`].
    pub output_sign: Option<f64>,
}

impl Default for OeOptions {
    fn default() -> Self {
        Self {
            samples: Samples::All,
            skip: 200,
            averaging: Averaging::Periods,
            tolerances: Tolerances::default(),
            lm_starts: 3,
            structure: StructureSearch::Grid,
            delay: DelaySearch::Fixed(0.0),
            hysteresis: LoopSearch::Grid,
            require_invertible: true,
            output_sign: None,
        }
    }
}

/// The smallest slope of `A1·u - h` over the operating range of `h`: the range `[lo, hi]` a
/// record reached, widened by half its width on each side (room for the compensator's
/// excursions) and capped at the loop's saturation range. `None` when `h` is unbounded.
pub fn operating_slope(bw: &BoucWenParams<f64>, lo: f64, hi: f64) -> Option<f64> {
    let (sat_lo, sat_hi) = bw.h_range()?;
    let margin = 0.5 * (hi - lo);
    Some(bw.min_output_slope_over((lo - margin).max(sat_lo), (hi + margin).min(sat_hi)))
}

/// Whether `model` is invertible on the operating range its hysteresis reaches for the
/// input `u` (see [`operating_slope`]), with the margin [`MIN_SLOPE`].
pub fn invertible_for(model: &HostModel, u: &[f64]) -> bool {
    let bw = &model.ext.bw;
    let mut s = boucwen_core::model::HysteresisState::default();
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for uk in delayed_iter(u, model.delay) {
        let h = s.step(bw, uk);
        lo = lo.min(h);
        hi = hi.max(h);
    }
    slope_rel(bw, lo, hi).is_some_and(|r| r >= MIN_SLOPE)
}

/// The model of the output counted upwards, and the output's sign: `bw` itself and `1` if
/// `A1 ≥ 0`, else its mirror `−A1, −A, −A0, −γ` (the hysteresis `h → −h`) and `−1`. The
/// models are odd in the output, and so is their inverse (a sensor may count the stroke
/// either way).
pub fn upwards(bw: &BoucWenParams<f64>) -> (BoucWenParams<f64>, f64) {
    if bw.a1 < 0.0 {
        let m = BoucWenParams { a1: -bw.a1, a: -bw.a, a0: -bw.a0, gamma: -bw.gamma, beta: bw.beta };
        (m, -1.0)
    } else {
        (*bw, 1.0)
    }
}

/// [`operating_slope`] relative to `A1` over `bw`'s hysteresis range `[lo, hi]`, for an
/// output counted either way ([`upwards`]); `None` without a loop's range, or with `A1 = 0`.
pub fn slope_rel(bw: &BoucWenParams<f64>, lo: f64, hi: f64) -> Option<f64> {
    let (up, sign) = upwards(bw);
    let (lo, hi) = if sign < 0.0 { (-hi, -lo) } else { (lo, hi) };
    if up.a1 > 0.0 { operating_slope(&up, lo, hi).map(|m| m / up.a1) } else { None }
}

/// Smallest branch slope of `A1·u - h`, relative to `A1`, of an invertible model.
pub const MIN_SLOPE: f64 = 0.05;

/// The outer (nonlinear) parameters of the output-error fit: for fixed outer parameters
/// the model's output is linear in the gains, branch weights and drift.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outer {
    /// The AR part `(a1, a2)` of `G = 1/(1 - a1 z⁻¹ - a2 z⁻²)`.
    pub ar: [f64; 2],
    /// The loop's shape.
    pub shape: LoopShape,
    /// The input delay `τ` (samples).
    pub delay: f64,
}

/// One outer parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Param {
    /// `a1`.
    Ar1,
    /// `a2`.
    Ar2,
    /// `A0/A`.
    A0Ratio,
    /// `γ'`.
    Gamma,
    /// `β`.
    Beta,
    /// `τ`.
    Delay,
}

impl Outer {
    /// The value of `p`.
    pub fn get(&self, p: Param) -> f64 {
        match p {
            Param::Ar1 => self.ar[0],
            Param::Ar2 => self.ar[1],
            Param::A0Ratio => self.shape.a0_ratio,
            Param::Gamma => self.shape.gamma,
            Param::Beta => self.shape.beta,
            Param::Delay => self.delay,
        }
    }

    /// Sets `p` to `v`.
    pub fn set(&mut self, p: Param, v: f64) {
        match p {
            Param::Ar1 => self.ar[0] = v,
            Param::Ar2 => self.ar[1] = v,
            Param::A0Ratio => self.shape.a0_ratio = v,
            Param::Gamma => self.shape.gamma = v,
            Param::Beta => self.shape.beta = v,
            Param::Delay => self.delay = v,
        }
    }

    /// The outer parameters of `m` (`None` when it has no loop).
    pub fn of(m: &HostModel) -> Option<Outer> {
        Some(Outer { ar: m.ext.ar, shape: m.shape()?, delay: m.delay })
    }
}

//! The compensator of section 4: the direct inverse `u_f` (eqs. 15–17), the online
//! odd-harmonic cancellation (eqs. 18–21) and output saturation.
//!
//! ## Direct inverse (eqs. 15–17, for the AR form of this crate)
//! Setting the model output to the reference, `y = d`, in
//! `y[k] = Σ a_j y[k-j] + A1 u[k] - h[k]` and writing `h[k] = h[k-1] + m_s·Δ` with the
//! branch slope `m_s = A + s·A0 - γ|h[k-1]| - s·β·h[k-1]` (`s = ±1` the sign of
//! `Δ = u_f[k] - u_f[k-1]`) gives, for each sign case,
//! ```text
//! r[k] = d[k] - Σ_{j=1..P} a_j d[k-j]
//! Δ_s  = (r[k] - A1·u_f[k-1] + h[k-1]) / (A1 - m_s)
//! ```
//! which, with `a = [1, c1, c2]`, is exactly eq. (16) for `s = +1` and eq. (17) for `s = -1`
//! (`u_f[k] = u_f[k-1] + Δ_s`; the paper's `q1` is the numerator of the sum).
//! Case `s` is *consistent* when its `Δ_s` has sign `s` (`Δ_+ ≥ 0`, `Δ_- < 0`). When the
//! model is locally increasing on both branches (`A1 - m_± > 0`, the normal case) exactly
//! one case is consistent. Otherwise this crate defines:
//! * **both consistent** → the smaller step `|Δ|` (the output reaches `d` with the least move);
//! * **neither consistent** → hold, `Δ = 0`: every move in either direction takes the model
//!   output further from `d`, so holding is the least-squares choice.
//!
//! **Denominator guard.** Where `|A1 - m_s| < d_min` the model is nearly flat on that
//! branch and the step would blow up; the denominator is replaced by `±d_min` (its sign
//! kept) and the step flagged. The default `d_min` is 10⁻³ of the small-signal gain `|A1 - A|`.
//!
//! **Saturation.** `u_f` is clamped to the driver's range and the inverse's own hysteresis
//! state is advanced with the clamped value, so it stays the state of the input applied.
//!
//! ## Harmonic cancellation (eqs. 18–21), with model-derived sign and phase
//! `u[k] = u_f[k] - Σ_n û_n[k]`, `û_n[k] = α̂_{n,s} sin(nθ_k) + α̂_{n,c} cos(nθ_k)`,
//! `θ_k = 2π f k Ts`. If the plant's response at `n·f` is `Ĝ_n = g e^{iφ}`, an input
//! `a sin + b cos` shows at the output as `g (a sin(nθ+φ) + b cos(nθ+φ))`, i.e. `αᵀ x̃`
//! with the *filtered regressor*
//! ```text
//! x̃_n[k] = [ Re Ĝ·sin(nθ_k) + Im Ĝ·cos(nθ_k),  Re Ĝ·cos(nθ_k) - Im Ĝ·sin(nθ_k) ]
//! ```
//! The output the plant would show without cancellation is then
//! `y - d + Σ α̂ᵀ x̃ = z`, and each branch's RLS fits `z[k] ≈ α_nᵀ x̃_n[k]` (the regressors of
//! different orders are orthogonal over a period). At the fixed point the harmonic in `y - d`
//! vanishes whatever the error in `|Ĝ|`, and the iteration converges while the phase error
//! of `Ĝ` stays under 90° (the usual filtered-x argument). This replaces the paper's table
//! (eqs. 22/23: `e = d - y` below about 66 Hz, `y - d` above): [`PhaseRule::Model`] takes `Ĝ`
//! from the identified model's frequency response at `n·f`; [`PhaseRule::Table`] keeps the
//! table's content, a rotation by 0 below the flip frequency and by π above it (with the
//! model's `|Ĝ|`). Adaptation pauses for a sample after the output saturated (the applied
//! input was not the computed one), and each `|α̂_n|` is bounded by `uc_max`.
//!
//! As in the paper, `û_n` is subtracted at the input and `u_f`'s hysteresis state follows
//! `u_f` alone. The cancellation input therefore passes through the plant's hysteresis,
//! whose slope varies along the loop; that modulation puts a little of `û_n` at other
//! frequencies (`n·f ± f`, …), which the canceller of order `n` does not see. It is small
//! when `|Ĝ_n|` is large (a harmonic near the resonance needs only a small `û_n`).
//!
//! ## Timing
//! [`Compensator::step`] at sample `k` takes `d[k]` and the measurement `y[k-1]` (the
//! response to the previous output, `None` if it was lost), adapts, and returns `u[k]`.
//!
//! ## Preview of a delayed plant
//! A sampled actuator answers later than the model's instantaneous `A1·u[k]` (the zero-order
//! hold, the driver, transport delay): in effect it applies the input `τ` samples late. The
//! exact sampled model has a zero near `z = -1`, whose inverse is unusable, so the model
//! keeps the paper's form and the delay is compensated by preview instead: with a
//! reference known ahead (a planned trajectory, a sine), [`Compensator::step_previewed`]
//! inverts for `d` at `k + τ` and measures the tracking error against `d[k]`.

use crate::controllers::{ControlOutput, Controller};
use crate::error::finite;
use crate::model::{BoucWenParams, ExtendedParams, push_front};
use crate::rls::{Rls, RlsConfig};
use crate::signal::{Oscillator, sin_cos};
use crate::{Error, Real};
use nalgebra::{Complex, ComplexField, SVector, Vector2};

/// The driver's input range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Saturation<T> {
    /// Lowest output.
    pub u_min: T,
    /// Highest output.
    pub u_max: T,
}

impl<T: Real> Saturation<T> {
    /// A symmetric range `±limit`.
    ///
    /// ```
    /// use boucwen_core::compensator::Saturation;
    /// let s = Saturation::symmetric(10.0_f64);
    /// assert_eq!((s.u_min, s.u_max), (-10.0, 10.0));
    /// assert_eq!(s.clamp(12.0), (10.0, true));
    /// ```
    pub fn symmetric(limit: T) -> Self {
        Self { u_min: -limit, u_max: limit }
    }

    /// Checks `u_min < u_max`, both finite.
    pub fn validate(&self) -> Result<(), Error> {
        finite(self.u_min, "saturation u_min")?;
        finite(self.u_max, "saturation u_max")?;
        if self.u_min >= self.u_max {
            return Err(Error::OutOfRange("saturation (u_min must be < u_max)"));
        }
        Ok(())
    }

    /// `u` clamped to the range, and whether it was clamped.
    #[inline(always)]
    pub fn clamp(&self, u: T) -> (T, bool) {
        if u > self.u_max {
            (self.u_max, true)
        } else if u < self.u_min {
            (self.u_min, true)
        } else {
            (u, false)
        }
    }
}

/// Which case of eqs. (16)/(17) gave `u_f`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InverseCase {
    /// Only the rising case (16) was consistent.
    Rising,
    /// Only the falling case (17) was consistent.
    Falling,
    /// Both were: the smaller step was taken.
    Both,
    /// Neither was: the input was held.
    Neither,
}

/// State of the direct inverse.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverseState<T, const P: usize> {
    /// `h[k-1]` of the model driven by `u_f`.
    pub h: T,
    /// `u_f[k-1]`.
    pub u_prev: T,
    /// `d_past[j] = d[k-1-j]`.
    pub d_past: [T; P],
}

impl<T: Real, const P: usize> Default for InverseState<T, P> {
    fn default() -> Self {
        Self { h: T::zero(), u_prev: T::zero(), d_past: [T::zero(); P] }
    }
}

/// One step of the direct inverse.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverseStep<T> {
    /// `u_f[k]` (after saturation).
    pub u_f: T,
    /// Which case applied.
    pub case: InverseCase,
    /// The denominator guard acted.
    pub guarded: bool,
    /// `u_f` was clamped.
    pub saturated: bool,
}

/// The direct inverse of eqs. (15)–(17) for the extended model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectInverse<T, const P: usize> {
    /// The model inverted.
    pub model: ExtendedParams<T, P>,
    /// Smallest denominator magnitude `|A1 - m_s|` used.
    pub d_min: T,
}

impl<T: Real, const P: usize> DirectInverse<T, P> {
    /// The inverse of `model`, with `d_min` = 10⁻³·|A1 - A| (or the smallest normal number if
    /// that is zero).
    ///
    /// ```
    /// use boucwen_core::compensator::{DirectInverse, InverseState, Saturation};
    /// use boucwen_core::model::{BoucWenParams, ExtendedParams};
    /// let model = ExtendedParams { bw: BoucWenParams { a1: 20.0_f64, a: 6.0, a0: 0.0, gamma: 2.0, beta: 3.0 },
    ///                              ar: [0.5] };
    /// let inv = DirectInverse::new(model)?;
    /// assert!((inv.d_min - 0.014).abs() < 1e-12);
    /// let mut st = InverseState::default();
    /// let step = inv.step(&mut st, 7.0, &Saturation::symmetric(10.0));
    /// assert!((step.u_f - 0.5).abs() < 1e-12); // y = A1·u - A·u = 14·0.5 from rest
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn new(model: ExtendedParams<T, P>) -> Result<Self, Error> {
        use crate::model::Model;
        model.validate()?;
        let d_min = (T::lit(1e-3) * (model.bw.a1 - model.bw.a).abs()).max(T::MIN_POSITIVE);
        Ok(Self { model, d_min })
    }

    /// `u_f[k]` for the reference `d[k]`.
    #[inline]
    pub fn step(&self, st: &mut InverseState<T, P>, d: T, sat: &Saturation<T>) -> InverseStep<T> {
        let bw: &BoucWenParams<T> = &self.model.bw;
        let mut r = d;
        for j in 0..P {
            r -= self.model.ar[j] * st.d_past[j];
        }
        let num = r - bw.a1 * st.u_prev + st.h;
        let mut guarded = false;
        let mut guard = |den: T| {
            if den.abs() < self.d_min {
                guarded = true;
                if den < T::zero() { -self.d_min } else { self.d_min }
            } else {
                den
            }
        };
        let up = num / guard(bw.a1 - bw.slope(st.h, true));
        let down = num / guard(bw.a1 - bw.slope(st.h, false));
        let (rising_ok, falling_ok) = (up >= T::zero(), down < T::zero());
        let (delta, case) = match (rising_ok, falling_ok) {
            (true, false) => (up, InverseCase::Rising),
            (false, true) => (down, InverseCase::Falling),
            (true, true) => (if up.abs() <= down.abs() { up } else { down }, InverseCase::Both),
            (false, false) => (T::zero(), InverseCase::Neither),
        };
        let (u_f, saturated) = sat.clamp(st.u_prev + delta);
        st.h = bw.h_next(st.h, u_f - st.u_prev);
        st.u_prev = u_f;
        push_front(&mut st.d_past, d);
        InverseStep { u_f, case, guarded, saturated }
    }
}

/// How the plant's response at `n·f` is obtained for the harmonic cancellation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PhaseRule<T> {
    /// From the identified model's frequency response at `n·f`.
    Model,
    /// The paper's table (eqs. 22/23): phase 0 below `flip_hz`, π at or above; the gain is
    /// the model's.
    Table {
        /// The frequency where the structure's phase flips (about 66 Hz in the paper).
        flip_hz: T,
    },
}

/// The plant response `Ĝ` at the `order`-th harmonic of `drive_hz` under `rule`.
pub fn harmonic_response<T: Real, const P: usize>(
    model: &ExtendedParams<T, P>,
    order: u32,
    drive_hz: T,
    ts_s: T,
    rule: PhaseRule<T>,
) -> Complex<T> {
    let f = drive_hz * T::lit(order as f64);
    let g = model.frequency_response(f, ts_s);
    match rule {
        PhaseRule::Model => g,
        PhaseRule::Table { flip_hz } => {
            let mag = g.modulus();
            Complex::new(if f < flip_hz { mag } else { -mag }, T::zero())
        }
    }
}

/// One cancelled harmonic: its order and the plant's response `Ĝ` at `n·f`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HarmonicSpec<T> {
    /// Harmonic order `n ≥ 2`.
    pub order: u32,
    /// The plant's response at `n·f` (see [`harmonic_response`]).
    pub response: Complex<T>,
}

/// Everything the compensator needs (what the firmware receives from the host).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompensatorConfig<T, const P: usize, const M: usize> {
    /// The identified model whose first two equations are inverted.
    pub model: ExtendedParams<T, P>,
    /// The reference frequency `f` (the harmonics are its multiples).
    pub drive: Oscillator,
    /// The cancelled harmonics (`M = 0`: `u_f` alone).
    pub harmonics: [HarmonicSpec<T>; M],
    /// RLS of the cancellation weights.
    pub rls: RlsConfig<T>,
    /// The driver's range.
    pub saturation: Saturation<T>,
    /// Bound on each `|α̂_n|` (input units).
    pub uc_max: T,
}

impl<T: Real, const P: usize, const M: usize> CompensatorConfig<T, P, M> {
    /// Checks every part.
    #[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x > 0)` does")]
    pub fn validate(&self) -> Result<(), Error> {
        use crate::model::Model;
        self.model.validate()?;
        self.rls.validate()?;
        self.saturation.validate()?;
        if !(self.uc_max > T::zero()) {
            return Err(Error::OutOfRange("uc_max (must be > 0)"));
        }
        for h in &self.harmonics {
            if h.order < 2 {
                return Err(Error::OutOfRange("harmonic order (must be >= 2)"));
            }
            finite(h.response.re, "harmonic response")?;
            finite(h.response.im, "harmonic response")?;
            if h.response.re == T::zero() && h.response.im == T::zero() {
                return Err(Error::OutOfRange("harmonic response (must be non-zero)"));
            }
        }
        Ok(())
    }
}

/// One step's output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompensatorOutput<T> {
    /// `u[k]`, what to apply.
    pub u: T,
    /// The direct-inverse part `u_f[k]`.
    pub u_f: T,
    /// The cancellation `Σ û_n[k]` (subtracted).
    pub u_c: T,
    /// Which case of the inverse applied.
    pub case: InverseCase,
    /// The denominator guard acted.
    pub guarded: bool,
    /// `u` was clamped.
    pub saturated: bool,
}

/// The proposed compensator: `u = sat(u_f - Σ û_n)` with `α̂_n` adapted online.
#[derive(Clone, Debug)]
pub struct Compensator<T: Real, const P: usize, const M: usize> {
    cfg: CompensatorConfig<T, P, M>,
    inverse: DirectInverse<T, P>,
    state: InverseState<T, P>,
    rls: [Rls<T, 2>; M],
    x_prev: [Vector2<T>; M],
    d_prev: T,
    started: bool,
    saturated_prev: bool,
    phase: u64,
}

impl<T: Real, const P: usize, const M: usize> Compensator<T, P, M> {
    /// A compensator from a validated configuration.
    ///
    /// ```
    /// use boucwen_core::compensator::{Compensator, CompensatorConfig, HarmonicSpec, Saturation};
    /// use boucwen_core::model::{BoucWenParams, ExtendedParams};
    /// use boucwen_core::rls::RlsConfig;
    /// use boucwen_core::signal::Oscillator;
    /// use nalgebra::Complex;
    /// let mut cfg = CompensatorConfig {
    ///     model: ExtendedParams { bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
    ///                             ar: [1.5, -0.6] },
    ///     drive: Oscillator::new(23.0, 1e-3)?,
    ///     harmonics: [HarmonicSpec { order: 3, response: Complex::new(0.5, -2.0) }],
    ///     rls: RlsConfig::with_forgetting(0.999, 1e-2),
    ///     saturation: Saturation::symmetric(10.0),
    ///     uc_max: 2.0,
    /// };
    /// let mut c = Compensator::new(cfg)?;
    /// assert_eq!(c.step(0.0, None)?.u, 0.0);
    /// cfg.harmonics[0].order = 1; // the fundamental is u_f's job
    /// assert!(Compensator::new(cfg).is_err());
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn new(cfg: CompensatorConfig<T, P, M>) -> Result<Self, Error> {
        cfg.validate()?;
        let inverse = DirectInverse::new(cfg.model)?;
        let rls = Rls::new(cfg.rls, SVector::zeros())?;
        Ok(Self {
            cfg,
            inverse,
            state: InverseState::default(),
            rls: [(); M].map(|_| rls.clone()),
            x_prev: [Vector2::zeros(); M],
            d_prev: T::zero(),
            started: false,
            saturated_prev: false,
            phase: 0,
        })
    }

    /// One sample: reference `d[k]`, measurement `y[k-1]` (`None` if lost); returns `u[k]`.
    /// On `Err` (non-finite `d` or `y`) nothing changed.
    #[inline]
    pub fn step(&mut self, d: T, y_prev: Option<T>) -> Result<CompensatorOutput<T>, Error> {
        self.step_previewed(d, d, y_prev)
    }

    /// One sample with preview: the inverse works on `d_ahead` (the reference `τ` samples
    /// ahead, for a plant that applies its input `τ` samples late), the tracking error on `d`.
    /// On `Err` (non-finite input) nothing changed.
    #[inline]
    pub fn step_previewed(
        &mut self,
        d: T,
        d_ahead: T,
        y_prev: Option<T>,
    ) -> Result<CompensatorOutput<T>, Error> {
        finite(d, "d")?;
        finite(d_ahead, "d_ahead")?;
        if let Some(y) = y_prev {
            finite(y, "y")?;
        }
        // Adapt on the previous sample's error, reconstructed without the cancellation.
        if let (Some(y), true, false) = (y_prev, self.started, self.saturated_prev) {
            let mut z = y - self.d_prev;
            for m in 0..M {
                z += self.rls[m].theta().dot(&self.x_prev[m]);
            }
            for m in 0..M {
                // x_prev and z are finite here, so the update cannot fail.
                let _ = self.rls[m].update(&self.x_prev[m], z);
                let th = *self.rls[m].theta();
                let norm = th.norm();
                if norm > self.cfg.uc_max {
                    let _ = self.rls[m].set_theta(th * (self.cfg.uc_max / norm));
                }
            }
        }

        let inv = self.inverse.step(&mut self.state, d_ahead, &self.cfg.saturation);
        let mut u_c = T::zero();
        for m in 0..M {
            let h = &self.cfg.harmonics[m];
            let (s, c) = sin_cos::<T>(self.phase.wrapping_mul(h.order as u64));
            let th = self.rls[m].theta();
            u_c += th[0] * s + th[1] * c;
            let (gr, gi) = (h.response.re, h.response.im);
            self.x_prev[m] = Vector2::new(gr * s + gi * c, gr * c - gi * s);
        }
        let (u, saturated) = self.cfg.saturation.clamp(inv.u_f - u_c);
        self.d_prev = d;
        self.started = true;
        self.saturated_prev = saturated;
        self.phase = self.phase.wrapping_add(self.cfg.drive.increment());
        Ok(CompensatorOutput { u, u_f: inv.u_f, u_c, case: inv.case, guarded: inv.guarded, saturated })
    }

    /// The cancellation weights `(α̂_s, α̂_c)` of branch `m`.
    pub fn weights(&self, m: usize) -> Option<(T, T)> {
        self.rls.get(m).map(|r| (r.theta()[0], r.theta()[1]))
    }

    /// The configuration.
    pub fn config(&self) -> &CompensatorConfig<T, P, M> {
        &self.cfg
    }

    /// Back to `k = 0` with the same configuration (weights and covariances reset).
    pub fn reset(&mut self) {
        if let Ok(fresh) = Self::new(self.cfg) {
            *self = fresh;
        }
    }
}

impl<T: Real, const P: usize, const M: usize> Controller<T> for Compensator<T, P, M> {
    /// [`Compensator::step`] in the shared form: `u_ff` is the direct inverse `u_f`, `u_rc`
    /// the cancellation as applied (`-Σ û_n`), no feedback part.
    #[inline]
    fn step(&mut self, d: T, y_prev: Option<T>) -> Result<ControlOutput<T>, Error> {
        let o = Compensator::step(self, d, y_prev)?;
        Ok(o.into())
    }

    fn reset(&mut self) {
        Compensator::reset(self);
    }
}

impl<T: Real> From<CompensatorOutput<T>> for ControlOutput<T> {
    fn from(o: CompensatorOutput<T>) -> Self {
        ControlOutput { u: o.u, u_ff: o.u_f, u_fb: T::zero(), u_rc: -o.u_c, saturated: o.saturated }
    }
}

/// The most harmonics an [`AnyCompensator`] cancels at once.
pub const MAX_CANCELLED: usize = 2;

/// A compensator whose number of cancelled harmonics (0 to [`MAX_CANCELLED`]) is known only
/// at run time: the one place where that count becomes the const generic `M` of
/// [`Compensator`]. No allocation; it is as large as the two-harmonic compensator.
///
/// ```
/// use boucwen_core::compensator::{AnyCompensator, CompensatorConfig, HarmonicSpec, Saturation};
/// use boucwen_core::model::{BoucWenParams, ExtendedParams};
/// use boucwen_core::rls::RlsConfig;
/// use boucwen_core::signal::Oscillator;
/// use nalgebra::Complex;
/// let base = CompensatorConfig {
///     model: ExtendedParams { bw: BoucWenParams { a1: 20.0_f64, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
///                             ar: [1.5, -0.6] },
///     drive: Oscillator::new(23.0, 1e-3)?,
///     harmonics: [],
///     rls: RlsConfig::with_forgetting(0.999, 1e-2),
///     saturation: Saturation::symmetric(10.0),
///     uc_max: 2.0,
/// };
/// let third = HarmonicSpec { order: 3, response: Complex::new(0.5, -2.0) };
/// let mut c = AnyCompensator::new(base, &[third])?;
/// assert_eq!(c.harmonic_count(), 1);
/// let out = c.step_previewed(1.0, 1.0, None)?;
/// assert!(out.u.is_finite());
/// assert!(AnyCompensator::new(base, &[third; 3]).is_err());
/// # Ok::<(), boucwen_core::Error>(())
/// ```
#[derive(Clone, Debug)]
pub enum AnyCompensator<T: Real, const P: usize> {
    /// `u_f` alone.
    Zero(Compensator<T, P, 0>),
    /// One cancelled harmonic.
    One(Compensator<T, P, 1>),
    /// Two cancelled harmonics.
    Two(Compensator<T, P, 2>),
}

/// Calls `$body` with `$c` bound to the compensator inside any variant.
macro_rules! each {
    ($any:expr, $c:ident => $body:expr) => {
        match $any {
            AnyCompensator::Zero($c) => $body,
            AnyCompensator::One($c) => $body,
            AnyCompensator::Two($c) => $body,
        }
    };
}

impl<T: Real, const P: usize> AnyCompensator<T, P> {
    /// The compensator of `base` (everything but the harmonics) cancelling `harmonics`
    /// (at most [`MAX_CANCELLED`]), validated.
    ///
    /// See the type's example; more than [`MAX_CANCELLED`] harmonics is an error:
    /// ```
    /// use boucwen_core::compensator::{AnyCompensator, CompensatorConfig, HarmonicSpec, Saturation};
    /// use boucwen_core::model::ExtendedParams;
    /// use boucwen_core::rls::RlsConfig;
    /// use boucwen_core::signal::Oscillator;
    /// let mut model = ExtendedParams::<f64, 1>::default();
    /// model.bw.a1 = 1.0;
    /// let base = CompensatorConfig { model, drive: Oscillator::new(10.0, 1e-3)?, harmonics: [],
    ///     rls: RlsConfig::paper(), saturation: Saturation::symmetric(1.0), uc_max: 1.0 };
    /// assert_eq!(AnyCompensator::new(base, &[])?.harmonic_count(), 0);
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn new(base: CompensatorConfig<T, P, 0>, harmonics: &[HarmonicSpec<T>]) -> Result<Self, Error> {
        fn with<T: Real, const P: usize, const M: usize>(
            base: CompensatorConfig<T, P, 0>,
            harmonics: &[HarmonicSpec<T>],
        ) -> Result<Compensator<T, P, M>, Error> {
            let CompensatorConfig { model, drive, rls, saturation, uc_max, .. } = base;
            let harmonics = core::array::from_fn(|m| harmonics[m]);
            Compensator::new(CompensatorConfig { model, drive, harmonics, rls, saturation, uc_max })
        }
        Ok(match harmonics.len() {
            0 => Self::Zero(with(base, harmonics)?),
            1 => Self::One(with(base, harmonics)?),
            2 => Self::Two(with(base, harmonics)?),
            _ => return Err(Error::OutOfRange("harmonic count (at most 2 are cancelled at once)")),
        })
    }

    /// The number of cancelled harmonics.
    pub fn harmonic_count(&self) -> usize {
        match self {
            Self::Zero(_) => 0,
            Self::One(_) => 1,
            Self::Two(_) => 2,
        }
    }

    /// [`Compensator::step`].
    #[inline]
    pub fn step(&mut self, d: T, y_prev: Option<T>) -> Result<CompensatorOutput<T>, Error> {
        each!(self, c => c.step(d, y_prev))
    }

    /// [`Compensator::step_previewed`].
    #[inline]
    pub fn step_previewed(
        &mut self,
        d: T,
        d_ahead: T,
        y_prev: Option<T>,
    ) -> Result<CompensatorOutput<T>, Error> {
        each!(self, c => c.step_previewed(d, d_ahead, y_prev))
    }

    /// [`Compensator::weights`].
    pub fn weights(&self, m: usize) -> Option<(T, T)> {
        each!(self, c => c.weights(m))
    }

    /// [`Compensator::reset`].
    pub fn reset(&mut self) {
        each!(self, c => c.reset())
    }
}

impl<T: Real, const P: usize> Controller<T> for AnyCompensator<T, P> {
    #[inline]
    fn step(&mut self, d: T, y_prev: Option<T>) -> Result<ControlOutput<T>, Error> {
        Ok(AnyCompensator::step(self, d, y_prev)?.into())
    }

    fn reset(&mut self) {
        AnyCompensator::reset(self);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{EnhancedParams, HarmonicBranch, Model};
    use crate::signal::Sine;
    use std::boxed::Box;

    const TS: f64 = 1e-3;

    /// A plant in µm per volt with a resonance near 70 Hz and a saturating loop.
    fn plant() -> ExtendedParams<f64, 2> {
        let w0 = core::f64::consts::TAU * 70.0 * TS;
        ExtendedParams {
            bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
            ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
        }
    }

    fn config<const M: usize>(
        model: ExtendedParams<f64, 2>,
        f: f64,
        harmonics: [HarmonicSpec<f64>; M],
    ) -> CompensatorConfig<f64, 2, M> {
        CompensatorConfig {
            model,
            drive: Oscillator::new(f, TS).unwrap(),
            harmonics,
            rls: RlsConfig::with_forgetting(0.999, 1e-2),
            saturation: Saturation::symmetric(10.0),
            uc_max: 5.0,
        }
    }

    fn rms(v: &[f64]) -> f64 {
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    }

    /// Runs `n` samples of the compensator on an enhanced plant; returns the tracking errors.
    fn track<const M: usize, const MP: usize>(
        comp: &mut Compensator<f64, 2, M>,
        plant: &EnhancedParams<f64, 2, 0, MP>,
        amplitude: f64,
        n: usize,
    ) -> Vec<f64> {
        let mut s = plant.initial_state();
        let mut d = Sine::new(amplitude, comp.config().drive);
        let mut y_prev = None;
        (0..n)
            .map(|_| {
                let dk = d.next_sample();
                let out = comp.step(dk, y_prev).unwrap();
                let y = plant.step(&mut s, out.u);
                y_prev = Some(y);
                y - dk
            })
            .collect()
    }

    #[test]
    fn direct_inverse_is_eqs_16_and_17_of_the_paper() {
        // Eq. (3) form: a = [1, c1, c2].
        let bw = BoucWenParams { a1: 2.0, a: 1.0, a0: 0.1, gamma: 0.5, beta: 0.25 };
        let (c1, c2) = (-0.5, 0.2);
        let inv = DirectInverse::new(ExtendedParams::from_eq3(bw, c1, c2)).unwrap();
        let sat = Saturation::symmetric(1e9);
        let mut st = InverseState::default();
        // The paper's formulas, written out independently.
        let (mut h, mut uf_prev, mut d1, mut d2, mut d3) = (0.0f64, 0.0f64, 0.0, 0.0, 0.0);
        for k in 0..400 {
            let t = k as f64 * TS;
            let d = 0.8 * (core::f64::consts::TAU * 3.0 * t).sin()
                + 0.3 * (core::f64::consts::TAU * 11.0 * t).sin();
            let base = d - d1 - c1 * d2 - c2 * d3 + h;
            let q_up = base - bw.a * uf_prev - bw.a0 * uf_prev
                + bw.gamma * h.abs() * uf_prev
                + bw.beta * uf_prev * h;
            let u_up = q_up / (bw.a1 - bw.a - bw.a0 + bw.gamma * h.abs() + bw.beta * h);
            let q_dn = base - bw.a * uf_prev + bw.a0 * uf_prev + bw.gamma * h.abs() * uf_prev
                - bw.beta * uf_prev * h;
            let u_dn = q_dn / (bw.a1 - bw.a + bw.a0 + bw.gamma * h.abs() - bw.beta * h);
            let want = if u_up - uf_prev >= 0.0 { u_up } else { u_dn };
            assert!(u_dn - uf_prev < 0.0 || u_up - uf_prev >= 0.0, "k={k}: both inconsistent");
            let got = inv.step(&mut st, d, &sat);
            assert!((got.u_f - want).abs() < 1e-12 * (1.0 + want.abs()), "k={k}: {} vs {want}", got.u_f);
            h = h + bw.a * (want - uf_prev) + bw.a0 * (want - uf_prev).abs()
                - bw.gamma * h.abs() * (want - uf_prev)
                - bw.beta * (want - uf_prev).abs() * h;
            (uf_prev, d3, d2, d1) = (want, d2, d1, d);
        }
    }

    #[test]
    fn the_exact_model_tracks_a_23_hz_sine() {
        let p = plant();
        let enh = EnhancedParams::<f64, 2, 0, 0> {
            base: p,
            branches: [],
            drive: Oscillator::new(23.0, TS).unwrap(),
        };
        let mut comp = Compensator::new(config(p, 23.0, [])).unwrap();
        let amplitude = 20.0;
        let err = track(&mut comp, &enh, amplitude, 20_000);
        let r = rms(&err) / amplitude;
        assert!(r < 0.01, "RMS error {r} of the amplitude");
        // The inverse is exact for the model it was built from: only rounding remains.
        assert!(r < 1e-9, "RMS error {r} of the amplitude");
    }

    #[test]
    fn the_controller_trait_and_any_compensator_step_as_the_compensator_does() {
        let p = plant();
        let plant3 = EnhancedParams::<f64, 2, 0, 1> {
            base: p,
            branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }],
            drive: Oscillator::new(23.0, TS).unwrap(),
        };
        let g3 = harmonic_response(&p, 3, 23.0, TS, PhaseRule::Model);
        let specs = [HarmonicSpec { order: 3, response: g3 }];
        let base = config(p, 23.0, []);
        for count in 0..=MAX_CANCELLED {
            let harmonics = [specs[0], HarmonicSpec { order: 5, ..specs[0] }];
            let chosen = &harmonics[..count];
            let mut any = AnyCompensator::new(base, chosen).unwrap();
            assert_eq!(any.harmonic_count(), count);
            let mut dynamic: Box<dyn Controller<f64>> = Box::new(AnyCompensator::new(base, chosen).unwrap());
            let mut reference: Box<dyn FnMut(f64, Option<f64>) -> CompensatorOutput<f64>> = match count {
                0 => {
                    let mut c = Compensator::new(base).unwrap();
                    Box::new(move |d, y| c.step(d, y).unwrap())
                }
                1 => {
                    let mut c = Compensator::new(config(p, 23.0, [harmonics[0]])).unwrap();
                    Box::new(move |d, y| c.step(d, y).unwrap())
                }
                _ => {
                    let mut c = Compensator::new(config(p, 23.0, harmonics)).unwrap();
                    Box::new(move |d, y| c.step(d, y).unwrap())
                }
            };
            let mut s = plant3.initial_state();
            let mut d = Sine::new(20.0, base.drive);
            let mut y_prev = None;
            let mut moved = 0.0f64;
            for _ in 0..3000 {
                let dk = d.next_sample();
                let want = reference(dk, y_prev);
                let got = any.step(dk, y_prev).unwrap();
                let shared = dynamic.step(dk, y_prev).unwrap();
                assert_eq!(got, want);
                assert_eq!(shared, ControlOutput::from(want));
                if !shared.saturated {
                    // u = u_f - Σ û_n: the parts add up to the output.
                    assert!((shared.u - (shared.u_ff + shared.u_rc)).abs() < 1e-12, "{shared:?}");
                }
                moved = moved.max(want.u_c.abs());
                let y = plant3.step(&mut s, want.u);
                y_prev = Some(y);
            }
            assert_eq!(moved > 0.0, count > 0, "{count} harmonics: cancellation reached {moved}");
            if count > 0 {
                assert!(any.weights(count - 1).is_some() && any.weights(count).is_none());
            }
        }
        assert!(AnyCompensator::new(base, &[specs[0]; 3]).is_err());
    }

    #[test]
    fn cancels_the_odd_harmonic_of_an_enhanced_plant() {
        let p = plant();
        let drive = Oscillator::new(23.0, TS).unwrap();
        // A third harmonic at 69 Hz, about 15 % of the 20 µm reference.
        let enh = EnhancedParams::<f64, 2, 0, 1> {
            base: p,
            branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }],
            drive,
        };
        let amplitude = 20.0;
        let mut uf_only = Compensator::new(config(p, 23.0, [])).unwrap();
        let err_uf = track(&mut uf_only, &enh, amplitude, 20_000);
        let response = harmonic_response(&p, 3, 23.0, TS, PhaseRule::Model);
        let mut proposed = Compensator::new(config(p, 23.0, [HarmonicSpec { order: 3, response }])).unwrap();
        let err = track(&mut proposed, &enh, amplitude, 20_000);
        let (r_uf, r) = (rms(&err_uf[10_000..]) / amplitude, rms(&err[10_000..]) / amplitude);
        assert!(r_uf > 0.05, "u_f alone leaves {r_uf}");
        assert!(r < 0.01, "proposed leaves {r} of the amplitude");
    }

    /// Amplitude of the component at `freq_hz` (least squares on sin/cos over whole periods).
    fn tone_amplitude(x: &[f64], freq_hz: f64) -> f64 {
        let w = core::f64::consts::TAU * freq_hz * TS;
        let (mut s, mut c) = (0.0, 0.0);
        for (k, v) in x.iter().enumerate() {
            s += v * (w * k as f64).sin();
            c += v * (w * k as f64).cos();
        }
        2.0 * (s * s + c * c).sqrt() / x.len() as f64
    }

    #[test]
    fn both_phase_rules_cancel_a_harmonic_far_below_the_flip() {
        let p = plant();
        let drive = Oscillator::new(7.0, TS).unwrap();
        let enh = EnhancedParams::<f64, 2, 0, 1> {
            base: p,
            branches: [HarmonicBranch { order: 3, alpha_s: 0.3, alpha_c: 0.2, ar: [] }],
            drive,
        };
        let table = PhaseRule::Table { flip_hz: 66.0 };
        let g_table = harmonic_response(&p, 3, 7.0, TS, table);
        assert!(g_table.re > 0.0 && g_table.im == 0.0);
        assert!(harmonic_response(&p, 3, 23.0, TS, table).re < 0.0, "above the flip: rotated by π");
        let mut uf_only = Compensator::new(config(p, 7.0, [])).unwrap();
        let before = tone_amplitude(&track(&mut uf_only, &enh, 20.0, 30_000)[20_000..], 21.0);
        for rule in [PhaseRule::Model, table] {
            let response = harmonic_response(&p, 3, 7.0, TS, rule);
            let mut comp = Compensator::new(config(p, 7.0, [HarmonicSpec { order: 3, response }])).unwrap();
            let after = tone_amplitude(&track(&mut comp, &enh, 20.0, 30_000)[20_000..], 21.0);
            assert!(after < before / 50.0, "{rule:?}: 21 Hz error {before} µm -> {after} µm");
        }
    }

    #[test]
    fn both_and_neither_cases_follow_the_documented_rule() {
        // A1 - m_+ = -0.1 < 0 < A1 - m_- = 1.1 at h = 0: a locally non-monotone model.
        let model =
            ExtendedParams { bw: BoucWenParams { a1: 1.0, a: 0.5, a0: 0.6, gamma: 0.0, beta: 0.0 }, ar: [] };
        let inv = DirectInverse::new(model).unwrap();
        let sat = Saturation::symmetric(100.0);
        // d > 0: Δ_+ = d/(-0.1) < 0 and Δ_- = d/1.1 > 0: neither is consistent → hold.
        let mut st = InverseState::default();
        let out = inv.step(&mut st, 0.5, &sat);
        assert_eq!((out.case, out.u_f), (InverseCase::Neither, 0.0));
        // d < 0: Δ_+ = 5 ≥ 0 and Δ_- = -0.4545 < 0: both → the smaller step.
        let mut st = InverseState::default();
        let out = inv.step(&mut st, -0.5, &sat);
        assert_eq!(out.case, InverseCase::Both);
        assert!((out.u_f + 0.5 / 1.1).abs() < 1e-15);
    }

    #[test]
    fn the_guard_bounds_a_vanishing_denominator() {
        // A1 - m_+ = A1 - A - A0 = 0 exactly: the rising branch is flat.
        let model =
            ExtendedParams { bw: BoucWenParams { a1: 1.0, a: 0.5, a0: 0.5, gamma: 0.0, beta: 0.0 }, ar: [] };
        let inv = DirectInverse::new(model).unwrap();
        let mut st = InverseState::default();
        let out = inv.step(&mut st, 1e-6, &Saturation::symmetric(1e12));
        assert!(out.guarded);
        assert!(out.u_f.is_finite());
        assert!((out.u_f - 1e-6 / inv.d_min).abs() < 1e-6);
    }

    #[test]
    fn saturation_clamps_and_the_state_follows_the_applied_input() {
        let p = plant();
        let inv = DirectInverse::new(p).unwrap();
        let sat = Saturation::symmetric(0.1);
        let mut st = InverseState::default();
        let mut h = crate::model::HysteresisState::default();
        for k in 0..200 {
            let d = 30.0 * (k as f64 * 0.05).sin();
            let out = inv.step(&mut st, d, &sat);
            assert!(out.u_f.abs() <= 0.1);
            h.step(&p.bw, out.u_f);
            assert_eq!(st.h, h.h);
        }
    }

    #[test]
    fn non_finite_inputs_are_rejected_without_change() {
        let p = plant();
        let mut comp =
            Compensator::new(config(p, 23.0, [HarmonicSpec { order: 3, response: Complex::new(1.0, 0.0) }]))
                .unwrap();
        comp.step(1.0, None).unwrap();
        let before = comp.clone();
        assert_eq!(comp.step(f64::NAN, Some(0.0)), Err(Error::NonFinite("d")));
        assert_eq!(comp.step(1.0, Some(f64::INFINITY)), Err(Error::NonFinite("y")));
        assert_eq!(comp.state, before.state);
        assert_eq!(comp.phase, before.phase);
        assert_eq!(comp.weights(0), before.weights(0));
        // A lost measurement still produces an output and skips adaptation.
        let out = comp.step(1.0, None).unwrap();
        assert!(out.u.is_finite());
        assert_eq!(comp.weights(0), before.weights(0));
    }

    #[test]
    fn invalid_configurations_are_named() {
        let p = plant();
        let mut cfg = config(p, 23.0, [HarmonicSpec { order: 1, response: Complex::new(1.0, 0.0) }]);
        assert_eq!(Compensator::new(cfg).err(), Some(Error::OutOfRange("harmonic order (must be >= 2)")));
        cfg.harmonics[0].order = 3;
        cfg.saturation = Saturation { u_min: 1.0, u_max: -1.0 };
        assert!(Compensator::new(cfg).is_err());
        cfg.saturation = Saturation::symmetric(1.0);
        cfg.model.bw.beta = f64::NAN;
        assert_eq!(Compensator::new(cfg).err(), Some(Error::NonFinite("beta")));
    }

    #[test]
    fn f32_stays_close_to_f64_over_a_million_samples() {
        let p = plant();
        let cast = |m: &ExtendedParams<f64, 2>| ExtendedParams {
            bw: BoucWenParams {
                a1: m.bw.a1 as f32,
                a: m.bw.a as f32,
                a0: m.bw.a0 as f32,
                gamma: m.bw.gamma as f32,
                beta: m.bw.beta as f32,
            },
            ar: m.ar.map(|a| a as f32),
        };
        let drive = Oscillator::new(23.0, TS).unwrap();
        let branch = HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] };
        let plant64 = EnhancedParams::<f64, 2, 0, 1> { base: p, branches: [branch], drive };
        let plant32 = EnhancedParams::<f32, 2, 0, 1> {
            base: cast(&p),
            branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }],
            drive,
        };
        let g = harmonic_response(&p, 3, 23.0, TS, PhaseRule::Model);
        let mut c64 = Compensator::new(config(p, 23.0, [HarmonicSpec { order: 3, response: g }])).unwrap();
        let mut c32 = Compensator::<f32, 2, 1>::new(CompensatorConfig {
            model: cast(&p),
            drive,
            harmonics: [HarmonicSpec { order: 3, response: Complex::new(g.re as f32, g.im as f32) }],
            rls: RlsConfig::with_forgetting(0.999, 1e-2),
            saturation: Saturation::symmetric(10.0),
            uc_max: 5.0,
        })
        .unwrap();
        let (mut s64, mut s32) = (plant64.initial_state(), plant32.initial_state());
        let (mut d64, mut d32) = (Sine::new(20.0f64, drive), Sine::new(20.0f32, drive));
        let (mut y64, mut y32) = (None, None);
        let (mut worst_u, mut worst_e): (f64, f64) = (0.0, 0.0);
        for _ in 0..1_000_000 {
            let (a, b) = (d64.next_sample(), d32.next_sample());
            let (o64, o32) = (c64.step(a, y64).unwrap(), c32.step(b, y32).unwrap());
            let (ya, yb) = (plant64.step(&mut s64, o64.u), plant32.step(&mut s32, o32.u));
            worst_u = worst_u.max((o64.u - o32.u as f64).abs());
            worst_e = worst_e.max(((ya - a) - (yb - b) as f64).abs());
            (y64, y32) = (Some(ya), Some(yb));
        }
        // Input and tracking error agree to a small fraction of a 0.27 V drive and 20 µm.
        assert!(worst_u < 1e-3, "largest u gap {worst_u} V");
        assert!(worst_e < 0.05, "largest tracking-error gap {worst_e} µm");
    }
}

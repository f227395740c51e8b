//! The Bouc–Wen model family: classic (eq. 2), extended (eq. 3) and enhanced (eqs. 6/7).
//!
//! Each model is a parameter set (`*Params`, what the firmware receives and what RLS
//! estimates) apart from its running state (`*State`). [`Model::step`] takes `u[k]` and
//! returns `y[k]`; one parameter set can drive several states.
//!
//! ## Hysteresis (first line of eqs. 2, 3, 6, 7)
//! ```text
//! h[k] = h[k-1] + A·Δu + A0·|Δu| - γ·|h[k-1]|·Δu - β·|Δu|·h[k-1],   Δu = u[k] - u[k-1]
//! ```
//! `A0 = 0` gives the classic model (2); `A0 ≠ 0` is the extended model's velocity-sign
//! sensitivity (`A` replaced by `A + A0·sgn(Δu)`), which moves the loop off-centre.
//! Initial state `h[0] = 0`, `u[0] = 0` (the paper's section 3).
//!
//! ## Output
//! * classic (2): `y[k] = A1·u[k] - h[k]`
//! * extended (3): `y[k] = Σ_{j=1..P} a_j·y[k-j] + A1·u[k] - h[k]`
//! * enhanced (6)/(7): the extended output plus `M` harmonic branches
//!   ```text
//!   y_n[k] = Σ_{j=1..Q} c_{n,j}·y_n[k-j] + α_s·sin(2π n f k Ts) + α_c·cos(2π n f k Ts)
//!   y[k]   = Σ_{j=1..P} a_j·y[k-j] + A1·u[k] - h[k] + Σ_n y_n[k]
//!   ```
//!   The structural recursion runs on the total output `y`, as in eq. (6), whose `y_1`
//!   uses `y[k-1]`, not `y_1[k-1]`.
//!
//! The free AR part (`P`, `Q`) is this crate's one consistent form of the paper's two
//! (eq. 3 vs regression 9–12); see the crate docs. [`ExtendedParams::from_eq3`] builds
//! eq. (3) exactly. A non-finite `u` makes the output and state non-finite: validate
//! inputs upstream (the compensator and the identifier do).

use crate::error::finite;
use crate::signal::{Oscillator, sin_cos};
use crate::{Error, Real};
use nalgebra::Complex;

/// A model: parameters that advance a separate state by one sample.
pub trait Model<T: Real> {
    /// The running state.
    type State: Clone;
    /// The state at `k = 0`: all past inputs, outputs and `h` zero, phase zero.
    fn initial_state(&self) -> Self::State;
    /// One sample: `u[k]` in, `y[k]` out.
    fn step(&self, state: &mut Self::State, u: T) -> T;
    /// Checks the parameters (finite, allowed ranges).
    fn validate(&self) -> Result<(), Error>;
}

/// Bouc–Wen hysteresis parameters and the output gain `A1`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BoucWenParams<T> {
    /// `A1`: gain from input to output.
    pub a1: T,
    /// `A`: amplitude of the hysteresis term.
    pub a: T,
    /// `A0`: asymmetric (velocity-sign) term of the extended model; 0 in the classic model.
    pub a0: T,
    /// `γ`: shape.
    pub gamma: T,
    /// `β`: shape.
    pub beta: T,
}

impl<T: Real> BoucWenParams<T> {
    /// Checks that every parameter is finite.
    pub fn validate(&self) -> Result<(), Error> {
        finite(self.a1, "A1")?;
        finite(self.a, "A")?;
        finite(self.a0, "A0")?;
        finite(self.gamma, "gamma")?;
        finite(self.beta, "beta")?;
        Ok(())
    }

    /// `h[k]` from `h[k-1]` and `Δu = u[k] - u[k-1]` (first line of eq. 3).
    #[inline(always)]
    pub fn h_next(&self, h_prev: T, du: T) -> T {
        h_prev + (self.a - self.gamma * h_prev.abs()) * du + (self.a0 - self.beta * h_prev) * du.abs()
    }

    /// The slope `dh/du` of the hysteresis at `h` on the rising (`Δu ≥ 0`) or falling branch:
    /// `A + A0 - γ|h| - βh` or `A - A0 - γ|h| + βh`, so that `h[k] = h[k-1] + slope·Δu`.
    #[inline(always)]
    pub fn slope(&self, h: T, rising: bool) -> T {
        let common = self.a - self.gamma * h.abs();
        if rising { common + self.a0 - self.beta * h } else { common - self.a0 + self.beta * h }
    }
}

impl<T: Real> BoucWenParams<T> {
    /// The range `[h_lo, h_hi]` where each branch saturates (its slope vanishes):
    /// `h_hi = (A + A0)/(γ + β)` rising and `h_lo = -(A - A0)/(γ + β)` falling, 0 inside.
    /// `None` when `γ + β ≤ 0` (`h` is unbounded).
    ///
    /// `h` cannot leave the range once inside when `A ≥ |A0|`, `γ, β ≥ 0`, either `A0 = 0`
    /// or `β ≥ γ`, and each step of the input is at most `1/(γ + β)` (then every update is
    /// a convex combination of `h` and an end of the range; the property tests check it).
    /// With `γ > β` and `A0 ≠ 0` one branch's slope turns negative inside the range and an
    /// input moving along that branch carries `h` out of it without bound.
    #[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the check, as `!(s > 0)` does")]
    pub fn h_range(&self) -> Option<(T, T)> {
        let s = self.gamma + self.beta;
        if !(s > T::zero()) {
            return None;
        }
        Some(((-(self.a - self.a0) / s).min(T::zero()), ((self.a + self.a0) / s).max(T::zero())))
    }

    /// The smallest slope of the static part `A1·u - h` over both branches and every `h`
    /// in [`Self::h_range`]: `min (A1 - slope)`. The direct inverse (eqs. 16/17) is well posed
    /// when it is positive (the output rises with the input on each branch). The slopes
    /// are piecewise linear in `h` with a kink at 0, so the minimum is at `h_lo`, 0 or
    /// `h_hi`. `None` when `h` is unbounded.
    pub fn min_output_slope(&self) -> Option<T> {
        let (lo, hi) = self.h_range()?;
        Some(self.min_output_slope_over(lo, hi))
    }

    /// [`Self::min_output_slope`] over `h ∈ [lo, hi]` only (an operating range, e.g. the
    /// range a loop of known amplitude reaches, with a margin: a thin loop's saturation range
    /// can be many times what it ever reaches).
    pub fn min_output_slope_over(&self, lo: T, hi: T) -> T {
        let (lo, hi) = (lo.min(T::zero()), hi.max(T::zero()));
        let mut worst = T::zero();
        let mut first = true;
        for h in [lo, T::zero(), hi] {
            for rising in [true, false] {
                let d = self.a1 - self.slope(h, rising);
                if first || d < worst {
                    worst = d;
                    first = false;
                }
            }
        }
        worst
    }
}

/// The hysteresis state: `h[k-1]` and `u[k-1]`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HysteresisState<T> {
    /// `h[k-1]`.
    pub h: T,
    /// `u[k-1]`.
    pub u_prev: T,
}

impl<T: Real> HysteresisState<T> {
    /// Advances to `u[k]` and returns `h[k]`.
    #[inline(always)]
    pub fn step(&mut self, p: &BoucWenParams<T>, u: T) -> T {
        self.h = p.h_next(self.h, u - self.u_prev);
        self.u_prev = u;
        self.h
    }
}

/// The classic discrete Bouc–Wen model, eq. (2): `y[k] = A1·u[k] - h[k]`.
///
/// ```
/// use boucwen_core::model::{BoucWenParams, Classic, Model};
/// let m = Classic(BoucWenParams { a1: 2.0, a: 1.0, a0: 0.0, gamma: 0.5, beta: 0.25 });
/// let mut s = m.initial_state();
/// assert_eq!(m.step(&mut s, 1.0), 1.0); // h = 1, y = 2·1 - 1
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Classic<T>(pub BoucWenParams<T>);

impl<T: Real> Model<T> for Classic<T> {
    type State = HysteresisState<T>;
    fn initial_state(&self) -> Self::State {
        HysteresisState::default()
    }
    #[inline]
    fn step(&self, state: &mut Self::State, u: T) -> T {
        let h = state.step(&self.0, u);
        self.0.a1 * u - h
    }
    fn validate(&self) -> Result<(), Error> {
        self.0.validate()?;
        if self.0.a0 != T::zero() {
            return Err(Error::OutOfRange("A0 (the classic model (2) has none; use Extended)"));
        }
        Ok(())
    }
}

/// Parameters of the extended model, eq. (3), with an AR part of order `P`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtendedParams<T, const P: usize> {
    /// Hysteresis and gain.
    pub bw: BoucWenParams<T>,
    /// `a_1..a_P`: coefficients of `y[k-1]..y[k-P]`.
    pub ar: [T; P],
}

impl<T: Real, const P: usize> Default for ExtendedParams<T, P> {
    fn default() -> Self {
        Self { bw: BoucWenParams::default(), ar: [T::zero(); P] }
    }
}

impl<T: Real> ExtendedParams<T, 3> {
    /// Eq. (3) as printed: `y[k] = y[k-1] + c1·y[k-2] + c2·y[k-3] + A1·u[k] - h[k]`.
    ///
    /// ```
    /// use boucwen_core::model::{BoucWenParams, ExtendedParams};
    /// let m = ExtendedParams::from_eq3(BoucWenParams::<f64>::default(), 0.2, -0.3);
    /// assert_eq!(m.ar, [1.0, 0.2, -0.3]);
    /// ```
    pub fn from_eq3(bw: BoucWenParams<T>, c1: T, c2: T) -> Self {
        Self { bw, ar: [T::one(), c1, c2] }
    }
}

impl<T: Real, const P: usize> ExtendedParams<T, P> {
    /// `Σ a_j·y[k-j]` over a history `past[j] = y[k-1-j]`.
    #[inline(always)]
    pub fn ar_sum(&self, past: &[T; P]) -> T {
        let mut acc = T::zero();
        for (&a, &y) in self.ar.iter().zip(past) {
            acc += a * y;
        }
        acc
    }

    /// Whether the AR part is stable (all roots of `z^P - a_1 z^{P-1} - … - a_P` strictly
    /// inside the unit circle), by the Schur–Cohn step-down recursion.
    pub fn is_stable(&self) -> bool {
        ar_is_stable(&self.ar)
    }

    /// The frequency response of the linearised model at `freq_hz`:
    /// `(A1 - A) / (1 - Σ a_j e^{-iωj})`, `ω = 2π f Ts`. `A1 - A` is the small-signal gain
    /// of `A1·u - h` at `h = 0` (the asymmetric term averages out over a cycle).
    pub fn frequency_response(&self, freq_hz: T, ts_s: T) -> Complex<T> {
        let b = self.bw.a1 - self.bw.a;
        let w = T::two_pi() * freq_hz * ts_s;
        let mut den = Complex::new(T::one(), T::zero());
        for (j, &a) in self.ar.iter().enumerate() {
            let phi = w * T::lit((j + 1) as f64);
            den -= Complex::new(a * phi.cos(), -a * phi.sin());
        }
        Complex::new(b, T::zero()) / den
    }

    /// The static gain `(A1 - A) / (1 - Σ a_j)` of the linearised model.
    pub fn static_gain(&self) -> T {
        let mut s = T::one();
        for &a in &self.ar {
            s -= a;
        }
        (self.bw.a1 - self.bw.a) / s
    }
}

/// Stability of `1 - Σ a_j z^-j` by the step-down (reflection coefficient) recursion.
pub fn ar_is_stable<T: Real, const P: usize>(ar: &[T; P]) -> bool {
    // Work on alpha_j = -a_j, the coefficients of 1 + Σ alpha_j z^-j.
    let mut alpha = [T::zero(); P];
    for j in 0..P {
        alpha[j] = -ar[j];
        if !ar[j].is_finite() {
            return false;
        }
    }
    let mut m = P;
    while m > 0 {
        let k = alpha[m - 1];
        if k.abs() >= T::one() {
            return false;
        }
        let den = T::one() - k * k;
        let prev = alpha;
        for i in 0..m - 1 {
            alpha[i] = (prev[i] - k * prev[m - 2 - i]) / den;
        }
        m -= 1;
    }
    true
}

/// State of the extended model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExtendedState<T, const P: usize> {
    /// Hysteresis state.
    pub hyst: HysteresisState<T>,
    /// `past[j] = y[k-1-j]`.
    pub y_past: [T; P],
}

impl<T: Real, const P: usize> Default for ExtendedState<T, P> {
    fn default() -> Self {
        Self { hyst: HysteresisState::default(), y_past: [T::zero(); P] }
    }
}

/// Pushes `v` to the front of a history, dropping the oldest value.
#[inline(always)]
pub(crate) fn push_front<T: Copy, const N: usize>(past: &mut [T; N], v: T) {
    if N > 0 {
        past.copy_within(0..N.saturating_sub(1), 1);
        if let Some(first) = past.first_mut() {
            *first = v;
        }
    }
}

impl<T: Real, const P: usize> Model<T> for ExtendedParams<T, P> {
    type State = ExtendedState<T, P>;
    fn initial_state(&self) -> Self::State {
        ExtendedState::default()
    }
    #[inline]
    fn step(&self, state: &mut Self::State, u: T) -> T {
        let h = state.hyst.step(&self.bw, u);
        let y = self.ar_sum(&state.y_past) + self.bw.a1 * u - h;
        push_front(&mut state.y_past, y);
        y
    }
    fn validate(&self) -> Result<(), Error> {
        self.bw.validate()?;
        for &a in &self.ar {
            finite(a, "AR coefficient a_j")?;
        }
        Ok(())
    }
}

/// One harmonic branch of the enhanced model: order `n`, weights `α_s, α_c` of
/// `sin, cos(2π n f k Ts)` (the paper's `α1, α2` for `n = 3`, `α3, α4` for `n = 5`) and an
/// AR part of order `Q` on the branch's own past.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HarmonicBranch<T, const Q: usize> {
    /// Harmonic order `n ≥ 2` (odd in the paper; even orders use the same structure).
    pub order: u32,
    /// Weight of `sin(2π n f k Ts)`.
    pub alpha_s: T,
    /// Weight of `cos(2π n f k Ts)`.
    pub alpha_c: T,
    /// `c_1..c_Q`: coefficients of `y_n[k-1]..y_n[k-Q]`.
    pub ar: [T; Q],
}

impl<T: Real, const Q: usize> HarmonicBranch<T, Q> {
    /// A branch of order `n` with zero weights.
    ///
    /// ```
    /// use boucwen_core::model::HarmonicBranch;
    /// let b = HarmonicBranch::<f64, 2>::new(3);
    /// assert_eq!((b.order, b.alpha_s, b.alpha_c, b.ar), (3, 0.0, 0.0, [0.0; 2]));
    /// ```
    pub fn new(order: u32) -> Self {
        Self { order, alpha_s: T::zero(), alpha_c: T::zero(), ar: [T::zero(); Q] }
    }
}

/// Parameters of the enhanced model, eqs. (6)/(7): the extended model plus `M` harmonic
/// branches of the drive frequency `f` (held as an [`Oscillator`], which fixes `f·Ts`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnhancedParams<T, const P: usize, const Q: usize, const M: usize> {
    /// The extended model.
    pub base: ExtendedParams<T, P>,
    /// The harmonic branches.
    pub branches: [HarmonicBranch<T, Q>; M],
    /// The drive frequency `f` at the sample interval `Ts`.
    pub drive: Oscillator,
}

/// State of the enhanced model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnhancedState<T, const P: usize, const Q: usize, const M: usize> {
    /// State of the extended part (its `y_past` holds the total output).
    pub base: ExtendedState<T, P>,
    /// `branch_past[m][j] = y_n[k-1-j]` of branch `m`.
    pub branch_past: [[T; Q]; M],
    /// The last output of each branch.
    pub branch_out: [T; M],
    /// Phase of the drive at the next sample, in 2⁻⁶⁴ turn.
    pub phase: u64,
}

impl<T: Real, const P: usize, const Q: usize, const M: usize> Model<T> for EnhancedParams<T, P, Q, M> {
    type State = EnhancedState<T, P, Q, M>;
    fn initial_state(&self) -> Self::State {
        EnhancedState {
            base: ExtendedState::default(),
            branch_past: [[T::zero(); Q]; M],
            branch_out: [T::zero(); M],
            phase: 0,
        }
    }
    #[inline]
    fn step(&self, state: &mut Self::State, u: T) -> T {
        let mut harmonics = T::zero();
        for m in 0..M {
            let br = &self.branches[m];
            let (s, c) = sin_cos::<T>(state.phase.wrapping_mul(br.order as u64));
            let past = &mut state.branch_past[m];
            let mut yn = br.alpha_s * s + br.alpha_c * c;
            for (&c, &p) in br.ar.iter().zip(past.iter()) {
                yn += c * p;
            }
            push_front(past, yn);
            state.branch_out[m] = yn;
            harmonics += yn;
        }
        let h = state.base.hyst.step(&self.base.bw, u);
        let y = self.base.ar_sum(&state.base.y_past) + self.base.bw.a1 * u - h + harmonics;
        push_front(&mut state.base.y_past, y);
        state.phase = state.phase.wrapping_add(self.drive.increment());
        y
    }
    fn validate(&self) -> Result<(), Error> {
        self.base.validate()?;
        for br in &self.branches {
            if br.order < 2 {
                return Err(Error::OutOfRange("harmonic order (must be >= 2)"));
            }
            finite(br.alpha_s, "alpha_s")?;
            finite(br.alpha_c, "alpha_c")?;
            for &c in &br.ar {
                finite(c, "branch AR coefficient")?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::assert_close;
    use core::f64::consts::FRAC_1_SQRT_2 as R2;

    fn bw() -> BoucWenParams<f64> {
        BoucWenParams { a1: 2.0, a: 1.0, a0: 0.1, gamma: 0.5, beta: 0.25 }
    }

    #[test]
    fn classic_reproduces_hand_computed_steps() {
        let m = Classic(BoucWenParams { a0: 0.0, ..bw() });
        m.validate().unwrap();
        let mut s = m.initial_state();
        // k=1: Δu = 1, h = 0 + 1·1 = 1, y = 2·1 - 1 = 1
        assert_close(m.step(&mut s, 1.0), 1.0, 1e-15);
        // k=2: Δu = -0.5, h = 1 + 1(-0.5) - 0.5·|1|·(-0.5) - 0.25·0.5·1 = 0.625; y = 1 - 0.625
        assert_close(m.step(&mut s, 0.5), 0.375, 1e-15);
        assert_close(s.h, 0.625, 1e-15);
        // Classic rejects A0.
        assert!(Classic(bw()).validate().is_err());
    }

    #[test]
    fn extended_eq3_reproduces_hand_computed_steps() {
        let m = ExtendedParams::from_eq3(bw(), -0.5, 0.2);
        let mut s = m.initial_state();
        // k=1: h = 1·1 + 0.1·1 = 1.1; y = 2 - 1.1
        assert_close(m.step(&mut s, 1.0), 0.9, 1e-15);
        // k=2: h = 1.1 + (1 - 0.55)(-0.5) + (0.1 - 0.275)(0.5) = 0.7875; y = 0.9 + 1 - 0.7875
        assert_close(m.step(&mut s, 0.5), 1.1125, 1e-15);
        // k=3: Δu = 0, h unchanged; y = 1.1125 - 0.5·0.9 + 1 - 0.7875
        assert_close(m.step(&mut s, 0.5), 0.875, 1e-15);
        // k=4: h = 0.7875 - 1.5 + 0.15 + 0.590625 - 0.2953125 = -0.2671875
        //      y = 0.875 - 0.5·1.1125 + 0.2·0.9 - 2 + 0.2671875
        assert_close(m.step(&mut s, -1.0), -1.234_062_5, 1e-15);
        assert_close(s.hyst.h, -0.267_187_5, 1e-15);
    }

    #[test]
    fn enhanced_reproduces_hand_computed_steps() {
        // Drive at 1/8 turn per sample, 3rd-harmonic branch (3/8 turn per sample).
        let m = EnhancedParams {
            base: ExtendedParams::from_eq3(bw(), -0.5, 0.2),
            branches: [HarmonicBranch { order: 3, alpha_s: 0.5, alpha_c: 0.25, ar: [0.5] }],
            drive: Oscillator::from_increment(1 << 61),
        };
        m.validate().unwrap();
        let mut s = m.initial_state();
        // k=0: sin 0 = 0, cos 0 = 1: y3 = 0.25; y = 0.9 + 0.25
        assert_close(m.step(&mut s, 1.0), 1.15, 1e-15);
        // k=1: 135°: y3 = 0.5·0.25 + 0.5·R2 - 0.25·R2; y = 1.15 + 1 - 0.7875 + y3
        let y3 = 0.125 + 0.25 * R2;
        assert_close(m.step(&mut s, 0.5), 1.3625 + y3, 1e-15);
        // k=2: 270°: sin = -1, cos = 0: y3' = 0.5·y3 - 0.5
        //      y = y[1] - 0.5·y[0] + 0.2·0 + 1 - 0.7875 + y3'
        let y1 = 1.3625 + y3;
        let y3b = 0.5 * y3 - 0.5;
        assert_close(m.step(&mut s, 0.5), y1 - 0.575 + 0.2125 + y3b, 1e-15);
        assert_close(s.branch_out[0], y3b, 1e-15);
    }

    #[test]
    fn enhanced_without_branches_is_the_extended_model() {
        let ext = ExtendedParams { bw: bw(), ar: [1.2, -0.5] };
        let enh = EnhancedParams::<f64, 2, 0, 0> {
            base: ext,
            branches: [],
            drive: Oscillator::new(23.0, 1e-3).unwrap(),
        };
        let (mut a, mut b) = (ext.initial_state(), enh.initial_state());
        for k in 0..1000 {
            let u = ((k as f64) * 0.1).sin();
            assert_eq!(ext.step(&mut a, u), enh.step(&mut b, u));
        }
    }

    #[test]
    fn h_stays_in_its_range_and_the_slope_bound_holds_along_the_way() {
        let p = bw();
        let (lo, hi) = p.h_range().unwrap();
        // (A ± A0)/(γ + β) = 1.1/0.75 and 0.9/0.75
        assert_close(hi, 1.1 / 0.75, 1e-15);
        assert_close(lo, -0.9 / 0.75, 1e-15);
        let min_slope = p.min_output_slope().unwrap();
        let mut s = HysteresisState::default();
        for k in 0..20_000 {
            let u = 3.0 * (k as f64 * 0.003).sin() * (k as f64 * 0.0007).cos();
            let h_prev = s.h;
            let h = s.step(&p, u);
            assert!(h <= hi + 1e-12 && h >= lo - 1e-12, "h = {h} outside [{lo}, {hi}]");
            // Observed output slope on the branch taken, never below the bound.
            let du = u - s.u_prev;
            let _ = du;
            assert!(p.a1 - p.slope(h_prev, true) >= min_slope - 1e-12);
            assert!(p.a1 - p.slope(h_prev, false) >= min_slope - 1e-12);
        }
        // Unbounded h: no range, no bound.
        assert_eq!(BoucWenParams { gamma: -0.5, beta: 0.25, ..p }.min_output_slope(), None);
    }

    #[test]
    fn stability_matches_known_polynomials() {
        // y = 1.6 y1 - 0.8 y2: roots 0.8 ± 0.4i, |z| = 0.894: stable.
        assert!(ar_is_stable(&[1.6, -0.8]));
        // roots 1.0 and 0.5: marginal -> unstable.
        assert!(!ar_is_stable(&[1.5, -0.5]));
        // single root at 1.1
        assert!(!ar_is_stable(&[1.1]));
        // eq. (3) with a_1 = 1 and small c: z^3 - z^2 + 0.5 z - 0.2 has roots ~0.5 and |z|~0.63
        assert!(ar_is_stable(&[1.0, -0.5, 0.2]));
        assert!(ar_is_stable::<f64, 0>(&[]));
    }

    #[test]
    fn frequency_response_of_a_resonance() {
        // A lightly damped resonance at 70 Hz sampled at 1 kHz.
        let (r, f0, ts) = (0.98_f64, 70.0, 1e-3);
        let w0 = core::f64::consts::TAU * f0 * ts;
        let m = ExtendedParams {
            bw: BoucWenParams { a1: 1.0, ..Default::default() },
            ar: [2.0 * r * w0.cos(), -r * r],
        };
        use nalgebra::ComplexField;
        let polar = |r: f64, a: f64| Complex::new(r * a.cos(), r * a.sin());
        let g_dc = m.frequency_response(0.0, ts).modulus();
        assert_close(g_dc, m.static_gain(), 1e-12);
        assert!(m.frequency_response(70.0, ts).modulus() > 10.0 * g_dc);
        // Independent form: H(z) = z^2 / ((z - p)(z - p*)), p = r e^{iw0}.
        let p = polar(r, w0);
        for f in [1.0, 20.0, 66.0, 70.0, 75.0, 140.0, 400.0] {
            let z = polar(1.0, core::f64::consts::TAU * f * ts);
            let want = z * z / ((z - p) * (z - p.conj()));
            let got = m.frequency_response(f, ts);
            assert!((got - want).modulus() < 1e-9 * want.modulus(), "{f} Hz: {got} vs {want}");
        }
    }
}

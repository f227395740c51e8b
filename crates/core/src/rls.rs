//! Recursive least squares in Bierman's U-D factorised form.
//!
//! Estimates `θ` in `y[k] = θᵀ x[k] + e[k]` (eq. 8). The covariance is kept as
//! `P = U D Uᵀ` (`U` unit upper triangular, `D` diagonal and positive), which is what keeps
//! `f32` close to `f64` over long runs: `P` stays symmetric and positive definite by
//! construction, where the textbook update `P ← (P - P x xᵀ P / α) / λ` loses both in
//! single precision.
//!
//! ## One update (Bierman 1977, with exponential forgetting λ)
//! Forgetting is a time update `P ← P/λ` (on the factors: `D_j ← D_j/λ`), followed by
//! Bierman's measurement update:
//! ```text
//! e = y - θᵀx,  f = Uᵀx,  v = D f,  α_0 = 1
//! for j = 1..N:  α_j = α_{j-1} + f_j v_j
//!                D_j ← D_j α_{j-1} / α_j,   k_j = v_j,   μ = -f_j / α_{j-1}
//!                for i < j:  U_ij ← U_ij + k_i μ,   k_i ← k_i + U_ij(old) v_j
//! θ ← θ + k e / α_N
//! ```
//! which equals `K = P x / (λ + xᵀ P x)`, `P ← (P - K xᵀ P) / λ` of the covariance form.
//!
//! ## Guards for a microcontroller
//! * **Non-finite input** (`x` or `y` NaN/∞, or a prediction error that overflows) is
//!   rejected with [`Error::NonFinite`] before anything is touched.
//! * **Windup.** With `λ < 1` and poor excitation, `P` grows as `λ^-k` along unexcited
//!   directions (the paper's collinear `A1`/`A` pair is one). Forgetting is selective: a
//!   factor `D_j` at or above [`RlsConfig::p_max`] is not inflated. A measurement update
//!   never increases a factor, so `D_j ≤ max(p0, p_max) / λ` for ever, while the
//!   well-excited directions (small `D_j`) keep forgetting and stay adaptive. (Suspending
//!   forgetting for all directions at once, the simpler guard, freezes those too: their
//!   prior bias then decays only as `1/k`.)
//! * **Breakdown.** If the factors become non-finite or `D` non-positive (only possible by
//!   overflow), the covariance is reset to `P(0)` and the event counted in [`RlsStats`];
//!   `θ` is kept.

use crate::{Error, Real};
use nalgebra::{SMatrix, SVector};

/// Settings of an [`Rls`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RlsConfig<T> {
    /// Forgetting factor `λ ∈ (0, 1]`; 1 means no forgetting (the paper's choice).
    pub lambda: T,
    /// Initial covariance `P(0) = p0·I`, `p0 > 0` (the paper uses 1).
    pub p0: T,
    /// Ceiling on the U-D factors `D_j` of `P`: a factor at or above it is not inflated by
    /// forgetting (`> 0`; infinite disables the guard).
    pub p_max: T,
}

impl<T: Real> RlsConfig<T> {
    /// The paper's setting: `λ = 1`, `P(0) = I`.
    ///
    /// ```
    /// use boucwen_core::rls::RlsConfig;
    /// let c = RlsConfig::<f64>::paper();
    /// assert_eq!((c.lambda, c.p0), (1.0, 1.0));
    /// assert!(c.validate().is_ok());
    /// ```
    pub fn paper() -> Self {
        Self { lambda: T::one(), p0: T::one(), p_max: T::lit(1e3) }
    }

    /// Forgetting factor `lambda`, `P(0) = p0·I`, windup ceiling `p_max = 10³·p0`.
    ///
    /// ```
    /// use boucwen_core::rls::RlsConfig;
    /// let c = RlsConfig::with_forgetting(0.999_f64, 1e-2);
    /// assert_eq!((c.lambda, c.p0, c.p_max), (0.999, 1e-2, 10.0));
    /// assert!(RlsConfig::with_forgetting(1.5_f64, 1.0).validate().is_err());
    /// ```
    pub fn with_forgetting(lambda: T, p0: T) -> Self {
        Self { lambda, p0, p_max: T::lit(1e3) * p0 }
    }

    /// Checks the ranges.
    #[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x > 0)` does")]
    pub fn validate(&self) -> Result<(), Error> {
        if !self.lambda.is_finite() {
            return Err(Error::NonFinite("forgetting factor"));
        }
        if !(self.lambda > T::zero() && self.lambda <= T::one()) {
            return Err(Error::OutOfRange("forgetting factor (must be in (0, 1])"));
        }
        if !self.p0.is_finite() {
            return Err(Error::NonFinite("initial covariance"));
        }
        if self.p0 <= T::zero() {
            return Err(Error::OutOfRange("initial covariance (must be > 0)"));
        }
        if !(self.p_max > T::zero()) {
            return Err(Error::OutOfRange("covariance ceiling p_max (must be > 0)"));
        }
        Ok(())
    }
}

/// Counters of what the guards did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RlsStats {
    /// Accepted updates.
    pub updates: u32,
    /// Updates rejected for non-finite input.
    pub rejected: u32,
    /// Updates in which the windup guard held at least one factor back from forgetting.
    pub forgetting_suspended: u32,
    /// Covariance resets after numerical breakdown or on request.
    pub resets: u32,
}

/// Recursive least squares for `N` parameters.
#[derive(Clone, Debug)]
pub struct Rls<T: Real, const N: usize> {
    theta: SVector<T, N>,
    u: SMatrix<T, N, N>,
    d: SVector<T, N>,
    cfg: RlsConfig<T>,
    stats: RlsStats,
}

impl<T: Real, const N: usize> Rls<T, N> {
    /// A new estimator starting at `theta0` with `P(0) = p0·I`.
    ///
    /// ```
    /// use boucwen_core::rls::{Rls, RlsConfig};
    /// use nalgebra::Vector2;
    /// let mut rls = Rls::new(RlsConfig::with_forgetting(1.0, 1e6), Vector2::zeros()).unwrap();
    /// for k in 0..50 {
    ///     let x = Vector2::new(1.0, k as f64);
    ///     rls.update(&x, 3.0 - 0.5 * k as f64).unwrap();
    /// }
    /// assert!((rls.theta()[0] - 3.0).abs() < 1e-6 && (rls.theta()[1] + 0.5).abs() < 1e-6);
    /// ```
    pub fn new(cfg: RlsConfig<T>, theta0: SVector<T, N>) -> Result<Self, Error> {
        cfg.validate()?;
        if theta0.iter().any(|t| !t.is_finite()) {
            return Err(Error::NonFinite("initial parameters"));
        }
        Ok(Self {
            theta: theta0,
            u: SMatrix::identity(),
            d: SVector::repeat(cfg.p0),
            cfg,
            stats: RlsStats::default(),
        })
    }

    /// The current estimate `θ`.
    pub fn theta(&self) -> &SVector<T, N> {
        &self.theta
    }

    /// Replaces the estimate, keeping the covariance (e.g. to swap in parameters from the host).
    pub fn set_theta(&mut self, theta: SVector<T, N>) -> Result<(), Error> {
        if theta.iter().any(|t| !t.is_finite()) {
            return Err(Error::NonFinite("parameters"));
        }
        self.theta = theta;
        Ok(())
    }

    /// The settings.
    pub fn config(&self) -> &RlsConfig<T> {
        &self.cfg
    }

    /// What the guards did so far.
    pub fn stats(&self) -> RlsStats {
        self.stats
    }

    /// The prediction `θᵀx`.
    #[inline]
    pub fn predict(&self, x: &SVector<T, N>) -> T {
        self.theta.dot(x)
    }

    /// The covariance `P = U D Uᵀ` (computed; for inspection, not per sample).
    pub fn covariance(&self) -> SMatrix<T, N, N> {
        let mut ud = self.u;
        for j in 0..N {
            for i in 0..N {
                ud[(i, j)] *= self.d[j];
            }
        }
        ud * self.u.transpose()
    }

    /// The largest U-D factor `max_j D_j` (what the windup guard bounds).
    pub fn max_factor(&self) -> T {
        self.d.iter().fold(T::zero(), |m, &dj| m.max(dj))
    }

    /// `tr P = Σ_j D_j (1 + Σ_{i<j} U_ij²)`.
    #[inline]
    pub fn trace(&self) -> T {
        let mut tr = T::zero();
        for j in 0..N {
            let mut col = T::one();
            for i in 0..j {
                col += self.u[(i, j)] * self.u[(i, j)];
            }
            tr += self.d[j] * col;
        }
        tr
    }

    /// Resets the covariance to `P(0)`, keeping `θ`.
    pub fn reset_covariance(&mut self) {
        self.u = SMatrix::identity();
        self.d = SVector::repeat(self.cfg.p0);
        self.stats.resets = self.stats.resets.saturating_add(1);
    }

    /// One update with regressor `x` and measurement `y`; returns the a-priori error
    /// `y - θᵀx`. On `Err` nothing changed.
    #[inline]
    pub fn update(&mut self, x: &SVector<T, N>, y: T) -> Result<T, Error> {
        if !y.is_finite() {
            self.stats.rejected = self.stats.rejected.saturating_add(1);
            return Err(Error::NonFinite("measurement"));
        }
        let e = y - self.theta.dot(x);
        self.update_with_error(x, e)?;
        Ok(e)
    }

    /// One update of a recursive prediction-error method: `ψ` is the gradient of the
    /// prediction with respect to `θ` and `e` the prediction error computed by the caller
    /// (for a model linear in `θ`, `ψ = x` and `e = y - θᵀx`, which is [`Rls::update`]).
    /// On `Err` nothing changed.
    ///
    /// The loops work on the fixed-size arrays behind the matrices (columns of `U`, which
    /// nalgebra stores column-major), so they carry no bounds checks and vectorise; the
    /// divisions, which do not depend on the gain `k`, are done in one pass before the
    /// `O(N²)` loop. Every value is computed by the same operations in the same order as in
    /// the recursion written out in the module docs.
    #[inline]
    pub fn update_with_error(&mut self, psi: &SVector<T, N>, e: T) -> Result<(), Error> {
        let x: &[T; N] = &psi.data.0[0];
        if !all_finite(x) {
            self.stats.rejected = self.stats.rejected.saturating_add(1);
            return Err(Error::NonFinite("regressor"));
        }
        // Time update (selective forgetting) on a copy: nothing changes before the checks.
        // (Computed for every factor and selected, which keeps the loop branch-free.)
        let (lambda, p_max) = (self.cfg.lambda, self.cfg.p_max);
        let mut d = self.d.data.0[0];
        let mut capped = false;
        for dj in d.iter_mut() {
            let inflate = *dj < p_max;
            capped |= !inflate;
            let inflated = *dj / lambda;
            *dj = if inflate { inflated } else { *dj };
        }
        // f = Uᵀ x (column j of U holds U_0j..U_Nj), v = D f, and the running sums
        // α_j = α_{j-1} + f_j v_j (alpha[j] = α_{j+1}).
        let cols: &[[T; N]; N] = &self.u.data.0;
        let mut f = [T::zero(); N];
        let mut v = [T::zero(); N];
        let mut alpha = [T::zero(); N];
        let mut acc_alpha = T::one();
        for j in 0..N {
            let mut acc = x[j];
            for (uij, xi) in cols[j][..j].iter().zip(&x[..j]) {
                acc += *uij * *xi;
            }
            f[j] = acc;
            v[j] = d[j] * acc;
            acc_alpha += acc * v[j];
            alpha[j] = acc_alpha;
        }
        if !e.is_finite() || !acc_alpha.is_finite() {
            self.stats.rejected = self.stats.rejected.saturating_add(1);
            return Err(Error::NonFinite("prediction error"));
        }
        if capped {
            self.stats.forgetting_suspended = self.stats.forgetting_suspended.saturating_add(1);
        }

        // D_j ← D_j α_{j-1} / α_j and μ_j = -f_j / α_{j-1}, all independent of k.
        let mut mu = [T::zero(); N];
        let mut alpha_prev = T::one();
        for j in 0..N {
            d[j] = d[j] * alpha_prev / alpha[j];
            mu[j] = -f[j] / alpha_prev;
            alpha_prev = alpha[j];
        }
        // U_ij ← U_ij + k_i μ_j,  k_i ← k_i + U_ij(old) v_j  (i < j),  k_j = v_j.
        let mut k = [T::zero(); N];
        let cols: &mut [[T; N]; N] = &mut self.u.data.0;
        for j in 0..N {
            let (mu_j, v_j) = (mu[j], v[j]);
            for (uij, ki) in cols[j][..j].iter_mut().zip(&mut k[..j]) {
                let old = *uij;
                *uij = old + *ki * mu_j;
                *ki += old * v_j;
            }
            k[j] = v_j;
        }
        // θ ← θ + k e / α_N
        let gain = e / alpha_prev;
        let mut theta = self.theta.data.0[0];
        for (t, kj) in theta.iter_mut().zip(&k) {
            *t += *kj * gain;
        }
        self.d.data.0[0] = d;
        let mut d_min = T::lit(f64::INFINITY);
        for &dj in &d {
            // (A NaN is not taken here but fails `all_finite`.)
            d_min = if dj < d_min { dj } else { d_min };
        }
        let healthy = all_finite(&theta) & all_finite(&d) & (d_min > T::zero());
        if healthy {
            self.theta.data.0[0] = theta;
        } else {
            self.reset_covariance();
        }
        self.stats.updates = self.stats.updates.saturating_add(1);
        Ok(())
    }
}

/// Whether every entry is finite: `t·0` is 0 for a finite `t` and NaN otherwise, so the
/// sum is 0 exactly when all are finite (arithmetic without branches, which vectorises).
#[inline(always)]
fn all_finite<T: Real, const N: usize>(v: &[T; N]) -> bool {
    let mut acc = T::zero();
    for &t in v {
        acc += t * T::zero();
    }
    acc == T::zero()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{Noise, assert_close};

    /// Textbook covariance-form RLS on plain arrays, written independently of the U-D code.
    struct Textbook<const N: usize> {
        theta: [f64; N],
        p: [[f64; N]; N],
        lambda: f64,
    }
    impl<const N: usize> Textbook<N> {
        fn new(p0: f64, lambda: f64) -> Self {
            let mut p = [[0.0; N]; N];
            for (i, row) in p.iter_mut().enumerate() {
                row[i] = p0;
            }
            Self { theta: [0.0; N], p, lambda }
        }
        fn update(&mut self, x: &[f64; N], y: f64) {
            let mut px = [0.0; N];
            for (pxi, row) in px.iter_mut().zip(&self.p) {
                for (pij, xj) in row.iter().zip(x) {
                    *pxi += pij * xj;
                }
            }
            let denom = self.lambda + (0..N).map(|i| x[i] * px[i]).sum::<f64>();
            let e = y - (0..N).map(|i| self.theta[i] * x[i]).sum::<f64>();
            for (th, pxi) in self.theta.iter_mut().zip(&px) {
                *th += pxi / denom * e;
            }
            for (row, pxi) in self.p.iter_mut().zip(&px) {
                for (pij, pxj) in row.iter_mut().zip(&px) {
                    *pij = (*pij - pxi * pxj / denom) / self.lambda;
                }
            }
        }
    }

    #[test]
    fn recovers_linear_regression_parameters_to_1e_9() {
        let truth = SVector::<f64, 7>::from_column_slice(&[1.3, -0.7, 25.0, 0.004, -3.5, 0.0, 2.0]);
        let mut rls = Rls::new(RlsConfig::with_forgetting(1.0, 1e8), SVector::zeros()).unwrap();
        let mut g = Noise::new(1);
        for _ in 0..2000 {
            let x = SVector::<f64, 7>::from_fn(|_, _| g.next_f64());
            rls.update(&x, truth.dot(&x)).unwrap();
        }
        for i in 0..7 {
            assert_close(rls.theta()[i], truth[i], 1e-9);
        }
    }

    #[test]
    fn agrees_with_the_textbook_covariance_form() {
        const N: usize = 5;
        let mut rls = Rls::new(RlsConfig::with_forgetting(0.98, 10.0), SVector::zeros()).unwrap();
        let mut tb = Textbook::<N>::new(10.0, 0.98);
        let mut g = Noise::new(7);
        for k in 0..3000 {
            let xa: [f64; N] = core::array::from_fn(|_| g.next_f64());
            let y = 2.0 * xa[0] - xa[1] + 0.5 * xa[4] + 0.1 * g.next_f64();
            rls.update(&SVector::from(xa), y).unwrap();
            tb.update(&xa, y);
            if k % 500 == 0 || k == 2999 {
                let p = rls.covariance();
                for i in 0..N {
                    assert_close(rls.theta()[i], tb.theta[i], 1e-9);
                    for j in 0..N {
                        assert_close(p[(i, j)], tb.p[i][j], 1e-9 * (1.0 + tb.p[i][j].abs()));
                    }
                }
            }
        }
    }

    #[test]
    fn non_finite_input_leaves_the_state_untouched() {
        let mut rls = Rls::new(RlsConfig::with_forgetting(0.99, 1.0), SVector::zeros()).unwrap();
        let x = SVector::<f64, 3>::new(1.0, 2.0, 3.0);
        rls.update(&x, 1.0).unwrap();
        let (theta, p) = (*rls.theta(), rls.covariance());
        assert_eq!(rls.update(&x, f64::NAN), Err(Error::NonFinite("measurement")));
        assert_eq!(
            rls.update(&SVector::<f64, 3>::new(1.0, f64::INFINITY, 0.0), 1.0),
            Err(Error::NonFinite("regressor"))
        );
        assert_eq!(
            rls.update(&SVector::<f64, 3>::new(1e300, 1e300, 1e300), 1e300),
            Err(Error::NonFinite("prediction error"))
        );
        assert_eq!(*rls.theta(), theta);
        assert_eq!(rls.covariance(), p);
        assert_eq!(rls.stats().rejected, 3);
    }

    #[test]
    fn windup_is_bounded_under_poor_excitation() {
        // Two collinear regressors (like the paper's u[k] and -Σ Δu) with forgetting:
        // without the guard P grows as λ^-k along (1, 1).
        let cfg = RlsConfig { lambda: 0.99, p0: 1.0, p_max: 100.0 };
        let mut rls = Rls::new(cfg, SVector::<f64, 2>::zeros()).unwrap();
        let mut g = Noise::new(3);
        for _ in 0..100_000 {
            let u = g.next_f64();
            rls.update(&SVector::<f64, 2>::new(u, -u), 2.0 * u).unwrap();
        }
        assert!(rls.max_factor() <= 100.0 / 0.99, "largest factor {}", rls.max_factor());
        let p = rls.covariance();
        assert!(p[(0, 0)] < 300.0 && p[(1, 1)] < 300.0, "P = {p}");
        assert!(rls.stats().forgetting_suspended > 0);
        // The identifiable combination θ1 - θ2 is still found.
        assert_close(rls.theta()[0] - rls.theta()[1], 2.0, 1e-9);
        // A textbook update without the guard does wind up on the same data.
        let mut tb = Textbook::<2>::new(1.0, 0.99);
        let mut g = Noise::new(3);
        for _ in 0..3000 {
            let u = g.next_f64();
            tb.update(&[u, -u], 2.0 * u);
        }
        assert!(tb.p[0][0] + tb.p[1][1] > 1e10);
    }

    #[test]
    fn rejects_bad_configuration() {
        let bad = |lambda, p0, p_max| {
            Rls::<f64, 2>::new(RlsConfig { lambda, p0, p_max }, SVector::zeros()).is_err()
        };
        assert!(bad(0.0, 1.0, 10.0));
        assert!(bad(1.5, 1.0, 10.0));
        assert!(bad(f64::NAN, 1.0, 10.0));
        assert!(bad(1.0, -1.0, 10.0));
        assert!(bad(1.0, 1.0, 0.0));
        assert!(!bad(1.0, 1.0, f64::INFINITY));
    }

    #[test]
    fn f32_stays_close_to_f64_over_a_million_samples() {
        // A resonant ARX regression with noise and forgetting: the worst case for
        // single-precision covariance updates.
        const N: usize = 5;
        let cfg64 = RlsConfig::with_forgetting(0.999, 100.0);
        let cfg32 = RlsConfig { lambda: 0.999f32, p0: 100.0, p_max: cfg64.p_max as f32 };
        let mut r64 = Rls::<f64, N>::new(cfg64, SVector::zeros()).unwrap();
        let mut r32 = Rls::<f32, N>::new(cfg32, SVector::zeros()).unwrap();
        let truth = [1.6, -0.8, 0.5, 0.2, -0.1];
        let mut g = Noise::new(11);
        let (mut y1, mut y2, mut u1, mut u2) = (0.0, 0.0, 0.0, 0.0);
        let mut worst: f64 = 0.0;
        for k in 0..1_000_000 {
            let u = g.next_f64();
            let x = [y1, y2, u, u1, u2];
            let y: f64 = truth.iter().zip(&x).map(|(a, b)| a * b).sum::<f64>() + 1e-3 * g.next_f64();
            r64.update(&SVector::from(x), y).unwrap();
            r32.update(&SVector::from(x.map(|v| v as f32)), y as f32).unwrap();
            (y2, y1, u2, u1) = (y1, y, u1, u);
            if k > 10_000 {
                for i in 0..N {
                    worst = worst.max((r64.theta()[i] - r32.theta()[i] as f64).abs());
                }
            }
        }
        assert!(worst < 1e-3, "largest f32/f64 parameter gap {worst}");
        for (est, want) in r64.theta().iter().zip(&truth) {
            assert_close(*est, *want, 2e-3);
        }
        assert_eq!(r32.stats().resets, 0);
    }
}

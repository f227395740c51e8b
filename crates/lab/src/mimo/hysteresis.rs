//! The Bouc–Wen hysteresis of the paper, integrated exactly between samples.
//!
//! The paper's hysteresis (first line of eq. 3, [`boucwen_core::model::BoucWenParams::h_next`])
//! ```text
//! h[k] = h[k−1] + (A − γ|h[k−1]|)·Δz + (A0 − β·h[k−1])·|Δz|
//! ```
//! is the explicit Euler step of the rate-independent equation
//! ```text
//! dh/dz = A + A0·s − (γ·sgn h + β·s)·h,      s = sgn(dz/dt)
//! ```
//! Under a broadband multisine the input moves by a large part of the loop between two
//! samples, where the Euler step overshoots and diverges once `(γ + β)|Δz| > 1`. Here the
//! input is taken to move linearly between samples and the equation is solved exactly on
//! each step: with `s` fixed and `sgn h` fixed the equation is linear, `dh/dz = a − c·h`
//! (`a = A + A0·s`, `c = γ·sgn h + β·s`), so after a move `x`
//! ```text
//! h(x) = h₀ + (a − c·h₀)·(1 − e^{−c·x})/c         (h₀ + a·x when c·x → 0)
//! ```
//! and a step on which `h` reaches 0 is split there (it crosses at most once). For small
//! steps it agrees with the Euler step (a test checks it against the core's `h_next`).
//!
//! The amplitude `A` is 1 here ([`Shape`]): a model multiplies `h` by its own gains (the
//! columns of `E` and `F`) and divides `z` by a scale, which together cover any `A` (the
//! equation is homogeneous: `h(A, A0, γ, β) = A·h(1, A0/A, γ, β)` for `A > 0`).

use super::MimoError;
use serde::{Deserialize, Serialize};

/// The shape of a Bouc–Wen loop with `A = 1`: `h` saturates at `(1 ± A0)/(γ + β)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Shape {
    /// `A0`: asymmetry (|A0| < 1).
    pub a0: f64,
    /// `γ`.
    pub gamma: f64,
    /// `β`.
    pub beta: f64,
}

impl Shape {
    /// A symmetric loop (`A0 = 0`) with `γ = β = s`.
    pub fn symmetric(s: f64) -> Self {
        Self { a0: 0.0, gamma: s, beta: s }
    }

    /// Checks `|A0| < 1`, `γ + β > 0` and finiteness.
    pub fn validate(&self) -> Result<(), MimoError> {
        if self.a0.is_nan() || self.a0.abs() >= 1.0 {
            return Err(MimoError::Parameter("A0 of a hysteresis shape"));
        }
        if !(self.gamma.is_finite() && self.beta.is_finite() && self.gamma + self.beta > 0.0) {
            return Err(MimoError::Parameter("gamma, beta of a hysteresis shape"));
        }
        Ok(())
    }

    /// `h` after the input moves by `dz` from state `h` (module docs).
    #[inline]
    pub fn step(&self, h: f64, dz: f64) -> f64 {
        if dz == 0.0 {
            return h;
        }
        let s = dz.signum();
        let a = 1.0 + self.a0 * s;
        let sh = if h != 0.0 { h.signum() } else { (a * dz).signum() };
        let c = self.gamma * sh + self.beta * s;
        let go = |h0: f64, c: f64, x: f64| -> f64 {
            let cx = c * x;
            let f = if cx.abs() < 1e-9 { x * (1.0 - 0.5 * cx) } else { -(-cx).exp_m1() / c };
            h0 + (a - c * h0) * f
        };
        let h1 = go(h, c, dz);
        if h1 * sh >= 0.0 || h == 0.0 {
            return h1;
        }
        // h reaches 0 inside the step: where, then on with the other sign.
        let x0 = if (c * h).abs() < 1e-12 * a.abs() {
            -h / a
        } else {
            let ratio = a / (a - c * h);
            if ratio <= 0.0 {
                return h1;
            }
            -ratio.ln() / c
        };
        if !(x0.is_finite() && x0 * dz >= 0.0 && x0.abs() <= dz.abs()) {
            return h1;
        }
        let c2 = -self.gamma * sh + self.beta * s;
        go(0.0, c2, dz - x0)
    }

    /// As [`Self::step`], with the derivatives of the new `h` with respect to the old `h` and
    /// to `dz` (`(h₁, ∂h₁/∂h, ∂h₁/∂dz)`): on a step without a zero crossing
    /// `∂h₁/∂h = e^{−c·x}`, `∂h₁/∂x = (a − c·h)·e^{−c·x}`; across a crossing at `x₀`
    /// (`∂x₀/∂h = −1/(a − c·h)`) the second part's `∂/∂x = a·e^{−c₂(x − x₀)}` carries both.
    /// At `dz = 0` the derivative is that of a rising step.
    #[inline]
    pub fn step_grad(&self, h: f64, dz: f64) -> (f64, f64, f64) {
        let s = if dz < 0.0 { -1.0 } else { 1.0 };
        let a = 1.0 + self.a0 * s;
        if dz == 0.0 {
            let sh = if h != 0.0 { h.signum() } else { 1.0 };
            return (h, 1.0, a - (self.gamma * sh + self.beta) * h);
        }
        let sh = if h != 0.0 { h.signum() } else { (a * dz).signum() };
        let c = self.gamma * sh + self.beta * s;
        let go = |h0: f64, c: f64, x: f64| -> (f64, f64, f64) {
            let cx = c * x;
            let f = if cx.abs() < 1e-9 { x * (1.0 - 0.5 * cx) } else { -(-cx).exp_m1() / c };
            let e = (-cx).exp();
            (h0 + (a - c * h0) * f, e, (a - c * h0) * e)
        };
        let plain = go(h, c, dz);
        if plain.0 * sh >= 0.0 || h == 0.0 {
            return plain;
        }
        let (x0, dx0_dh) = if (c * h).abs() < 1e-12 * a.abs() {
            (-h / a, -1.0 / a)
        } else {
            let ratio = a / (a - c * h);
            if ratio <= 0.0 {
                return plain;
            }
            (-ratio.ln() / c, -1.0 / (a - c * h))
        };
        if !(x0.is_finite() && x0 * dz >= 0.0 && x0.abs() <= dz.abs()) {
            return plain;
        }
        let c2 = -self.gamma * sh + self.beta * s;
        let (h1, _, dx) = go(0.0, c2, dz - x0);
        (h1, -dx * dx0_dh, dx)
    }

    /// The steady-state loop of a periodic `z` (one period): `h` over the last of
    /// `1 + warmup` passes, starting at `h = 0`, `z[−1] = z[N−1]`.
    pub fn periodic(&self, z: &[f64], warmup: usize) -> Vec<f64> {
        let mut h = 0.0;
        let mut prev = z.last().copied().unwrap_or(0.0);
        let mut out = vec![0.0; z.len()];
        for pass in 0..=warmup {
            for (k, &zk) in z.iter().enumerate() {
                h = self.step(h, zk - prev);
                prev = zk;
                if pass == warmup {
                    out[k] = h;
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use boucwen_core::model::BoucWenParams;

    #[test]
    fn small_steps_agree_with_the_papers_recursion() {
        let sh = Shape { a0: 0.2, gamma: 0.7, beta: 1.1 };
        let p = BoucWenParams { a1: 0.0, a: 1.0, a0: 0.2, gamma: 0.7, beta: 1.1 };
        let (mut he, mut hx, mut prev) = (0.0f64, 0.0f64, 0.0f64);
        for k in 0..200_000 {
            let z = 1.5 * (k as f64 * 1e-4).sin();
            he = p.h_next(he, z - prev);
            hx = sh.step(hx, z - prev);
            prev = z;
        }
        assert!((he - hx).abs() < 1e-3, "{he} {hx}");
    }

    #[test]
    fn mimo_step_gradient_matches_finite_differences() {
        let shapes = [
            Shape { a0: 0.2, gamma: 0.7, beta: 1.1 },
            Shape::symmetric(0.5),
            Shape { a0: -0.3, gamma: -0.2, beta: 0.9 },
        ];
        for sh in shapes {
            for &(h, dz) in &[
                (0.3, 0.2),
                (0.3, -0.9),
                (-0.4, 1.5),
                (0.05, -0.3),
                (-0.2, 0.01),
                (0.6, -2.0),
                (0.0, 0.4),
                (0.2, 1e-12),
            ] {
                let (h1, dh, ddz) = sh.step_grad(h, dz);
                assert!((h1 - sh.step(h, dz)).abs() < 1e-14, "{h1}");
                let e = 1e-7;
                let fdh = (sh.step(h + e, dz) - sh.step(h - e, dz)) / (2.0 * e);
                let fdz = (sh.step(h, dz + e) - sh.step(h, dz - e)) / (2.0 * e);
                if h != 0.0 {
                    assert!((fdh - dh).abs() < 1e-5 * (1.0 + dh.abs()), "{sh:?} {h} {dz}: dh {dh} vs {fdh}");
                }
                if dz.abs() > 1e-6 {
                    assert!(
                        (fdz - ddz).abs() < 1e-5 * (1.0 + ddz.abs()),
                        "{sh:?} {h} {dz}: ddz {ddz} vs {fdz}"
                    );
                }
            }
        }
    }

    #[test]
    fn large_steps_stay_bounded() {
        let sh = Shape { a0: 0.0, gamma: 5.0, beta: 5.0 };
        let mut h = 0.0;
        for k in 0..1000 {
            h = sh.step(h, if k % 2 == 0 { 3.0 } else { -3.0 });
            assert!(h.abs() <= 0.1 + 1e-12);
        }
    }
}

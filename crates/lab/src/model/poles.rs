//! The poles of a linear part `1/(1 − a1 z⁻¹ − … − an z⁻ⁿ)`: one routine for its
//! stability, its largest pole's modulus and its resonance, whatever its order.
//!
//! The poles are the roots of `zⁿ − a1 zⁿ⁻¹ − … − an`. For the order 2 of the paper's
//! structure they are taken in closed form; for other orders, as the eigenvalues of the
//! companion matrix.

use nalgebra::{Complex, DMatrix};
use std::f64::consts::TAU;

/// The poles of `ar` (any order; empty for order 0, `NaN`s for non-finite coefficients).
pub fn poles(ar: &[f64]) -> Vec<Complex<f64>> {
    let n = ar.len();
    if ar.iter().any(|a| !a.is_finite()) {
        return vec![Complex::new(f64::NAN, f64::NAN); n];
    }
    match n {
        0 => vec![],
        1 => vec![Complex::new(ar[0], 0.0)],
        2 => {
            let (a1, a2) = (ar[0], ar[1]);
            let disc = a1 * a1 + 4.0 * a2;
            if disc >= 0.0 {
                let s = disc.sqrt();
                vec![Complex::new(0.5 * (a1 + s), 0.0), Complex::new(0.5 * (a1 - s), 0.0)]
            } else {
                let im = 0.5 * (-disc).sqrt();
                vec![Complex::new(0.5 * a1, im), Complex::new(0.5 * a1, -im)]
            }
        }
        _ => {
            let mut c = DMatrix::<f64>::zeros(n, n);
            for (j, &a) in ar.iter().enumerate() {
                c[(0, j)] = a;
            }
            for i in 1..n {
                c[(i, i - 1)] = 1.0;
            }
            c.complex_eigenvalues().iter().copied().collect()
        }
    }
}

/// The largest modulus of the poles of `ar` (0 for order 0; `NaN` if not finite). For
/// order 2 in closed form: `(|a1| + √(a1² + 4a2))/2` for real poles, `√(−a2)` for complex
/// ones.
pub fn largest_modulus(ar: &[f64]) -> f64 {
    if let [a1, a2] = *ar {
        let disc = a1 * a1 + 4.0 * a2;
        return if disc >= 0.0 { (a1.abs() + disc.sqrt()) / 2.0 } else { (-a2).sqrt() };
    }
    poles(ar).iter().map(|p| p.norm()).fold(0.0, |m: f64, r| if r.is_nan() { f64::NAN } else { m.max(r) })
}

/// Whether every pole lies inside the unit circle.
pub fn stable(ar: &[f64]) -> bool {
    largest_modulus(ar) < 1.0
}

/// The resonance (Hz) of the complex pole pair of `ar` with the largest modulus, at sample
/// interval `ts`: the pole's angle. `None` when every pole is real.
pub fn resonance_hz(ar: &[f64], ts: f64) -> Option<f64> {
    if let [a1, a2] = *ar {
        // z² − a1 z − a2 = 0: complex when a1² + 4 a2 < 0.
        let disc = a1 * a1 + 4.0 * a2;
        if disc >= 0.0 || a2 >= 0.0 {
            return None;
        }
        let r = (-a2).sqrt();
        let c = (a1 / (2.0 * r)).clamp(-1.0, 1.0);
        return Some(c.acos() / (TAU * ts));
    }
    poles(ar)
        .into_iter()
        .filter(|p| p.im > 0.0 && p.norm().is_finite())
        .max_by(|a, b| a.norm().total_cmp(&b.norm()))
        .map(|p| p.arg() / (TAU * ts))
}

/// Samples for the transient of `ar` to decay to `to` (its largest pole's modulus);
/// `usize::MAX` if it does not decay.
pub fn decay_samples(ar: &[f64], to: f64) -> usize {
    let r = largest_modulus(ar);
    if r.is_nan() || r <= 0.0 {
        return 0;
    }
    if r >= 1.0 {
        return usize::MAX;
    }
    (to.ln() / r.ln()).ceil().min(1e9) as usize
}

/// The AR(2) part of a resonance at `f_hz` with damping ratio `zeta` at interval `ts`
/// (two real poles for `zeta ≥ 1`).
pub fn ar2_of(f_hz: f64, zeta: f64, ts: f64) -> [f64; 2] {
    let w = TAU * f_hz * ts;
    if zeta < 1.0 {
        let r = (-zeta * w).exp();
        [2.0 * r * (w * (1.0 - zeta * zeta).sqrt()).cos(), -r * r]
    } else {
        let s = (zeta * zeta - 1.0).sqrt();
        let (r1, r2) = ((-(zeta - s) * w).exp(), (-(zeta + s) * w).exp());
        [r1 + r2, -r1 * r2]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resonance_of_an_ar2_and_of_a_higher_order() {
        let w = TAU * 70.0 * 1e-3;
        let ar = [2.0 * 0.97 * w.cos(), -0.97 * 0.97];
        let r = resonance_hz(&ar, 1e-3).unwrap();
        assert!((r - 70.0).abs() < 1e-9);
        assert_eq!(resonance_hz(&[1.5, -0.5], 1e-3), None); // real poles
        assert!((largest_modulus(&ar) - 0.97).abs() < 1e-12);
        // The same resonance times a real pole at 0.5: order 3.
        let ar3 = [ar[0] + 0.5, ar[1] - 0.5 * ar[0], -0.5 * ar[1]];
        assert!((resonance_hz(&ar3, 1e-3).unwrap() - 70.0).abs() < 1e-6);
        assert!((largest_modulus(&ar3) - 0.97).abs() < 1e-9);
        assert!(stable(&ar3) && !stable(&[1.5, -0.5, 0.1]));
    }

    #[test]
    fn the_closed_form_and_the_companion_matrix_agree() {
        for ar in [[1.6, -0.8], [1.5, -0.5], [0.2, 0.3], [-1.9, -0.95]] {
            let mut m = poles(&[ar[0], ar[1], 0.0]).iter().map(|p| p.norm()).fold(0.0, f64::max);
            m = m.max(0.0);
            assert!((m - largest_modulus(&ar)).abs() < 1e-9, "{ar:?}: {m}");
        }
        assert_eq!(ar2_of(70.0, 0.02, 1e-3)[1], -(-0.02 * TAU * 70.0 * 1e-3f64).exp().powi(2));
    }
}

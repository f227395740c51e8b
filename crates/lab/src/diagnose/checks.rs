//! What a fitted model must pass before its errors say anything: a stable free run
//! ([`instability`], [`runaway`]), a loop that closes under the drive ([`ratchet_um`]), and a
//! fit that holds beyond the record's amplitude ([`narrow`]).

use super::evidence::{Instability, Narrow};
use crate::model::poles;
use crate::record::Y_LIMIT_UM;
use crate::rules::CheckRules;
use crate::signal::analysis;
use boucwen_core::model::BoucWenParams;

/// A model's measure on the held-out part: its fit and whether its free run stays stable.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelCheck {
    /// `100·(1 − ‖y − ŷ‖/‖y − mean(y)‖)` on the held-out part; `None` if not stable.
    pub fit_pct: Option<f64>,
    /// Why the model is not stable (`None`: stable).
    pub unstable: Option<Instability>,
    /// Why the model may hold this record's amplitude only ([`narrow`]; `None`: not checked,
    /// or it holds at the others too).
    pub narrow: Option<Narrow>,
}

impl ModelCheck {
    /// Checks a free run `sim` against the held-out output `y` (both over the held-out part)
    /// and the linear part `ar`: a pole on or outside the unit circle, a non-finite value or
    /// one beyond [`Y_LIMIT_UM`], or a free run that leaves the output's range by
    /// `checks.runaway_spans` times its span make it unstable.
    pub fn of(ar: &[f64], sim: &[f64], y: &[f64], ts: f64, r: &CheckRules) -> ModelCheck {
        let unstable = instability(ar, sim, ts).or_else(|| runaway(sim, y, ts, r));
        let fit_pct = unstable.is_none().then(|| analysis::fit_pct(y, sim));
        ModelCheck { fit_pct, unstable, narrow: None }
    }

    /// Sets [`Self::narrow`] for a stable model of loop `bw` and structure `ar`: its free run
    /// under the record's drive `u` at `checks.other_amplitudes` ([`narrow`]).
    pub fn check_amplitudes(
        &mut self,
        bw: &BoucWenParams<f64>,
        ar: &[f64],
        u: &[f64],
        ts: f64,
        r: &CheckRules,
        simulate: impl Fn(&[f64]) -> Option<Vec<f64>>,
    ) {
        if self.unstable.is_none() {
            self.narrow = narrow(bw, ar, ts, r, |k| simulate(&scaled_about_mean(u, k)));
        }
    }
}

/// Whether a model fitted at one amplitude holds at others. The Bouc–Wen loop of eq. (3) is
/// bounded for every input only when `γ + β > 0` ([`BoucWenParams::h_range`]); with
/// `γ + β ≤ 0` the state `h` grows by a factor `e^{|γ+β|·ΔU}` over a swing `ΔU` on one
/// branch, and the loop closes at the amplitude it was fitted at only. `simulate_at(k)` is the
/// model's free run under the record's drive scaled by `k` about its mean; each of
/// `checks.other_amplitudes` is checked by [`instability`]. `None` when the loop is bounded
/// and every run stays in range.
pub fn narrow(
    bw: &BoucWenParams<f64>,
    ar: &[f64],
    ts: f64,
    r: &CheckRules,
    simulate_at: impl Fn(f64) -> Option<Vec<f64>>,
) -> Option<Narrow> {
    let diverges_at: Vec<f64> = r
        .other_amplitudes
        .iter()
        .copied()
        .filter(|&k| simulate_at(k).is_none_or(|sim| instability(ar, &sim, ts).is_some()))
        .collect();
    let unbounded = bw.h_range().is_none();
    (unbounded || !diverges_at.is_empty()).then(|| Narrow {
        gamma_plus_beta: bw.gamma + bw.beta,
        unbounded,
        diverges_at,
        scales: r.other_amplitudes.to_vec(),
    })
}

/// `u` scaled by `k` about its mean.
fn scaled_about_mean(u: &[f64], k: f64) -> Vec<f64> {
    let m = analysis::mean(u);
    u.iter().map(|v| m + k * (v - m)).collect()
}

/// Why a model with linear part `ar` and free run `sim` is not stable, if it is not: a pole
/// on or outside the unit circle, or a free run that leaves the physical range.
pub fn instability(ar: &[f64], sim: &[f64], ts: f64) -> Option<Instability> {
    let modulus = poles::largest_modulus(ar);
    if modulus.is_nan() || modulus >= 1.0 {
        let mut a = [f64::NAN; 2];
        for (d, s) in a.iter_mut().zip(ar) {
            *d = *s;
        }
        return Some(Instability::Pole { modulus, ar: a });
    }
    let k = sim.iter().position(|v| !v.is_finite() || v.abs() > Y_LIMIT_UM)?;
    Some(Instability::LeavesRange { limit_um: Y_LIMIT_UM, after_s: k as f64 * ts })
}

/// Why a free run `sim` has run away from the output `y` it models, if it has: it leaves
/// `y`'s range by `checks.runaway_spans` times `y`'s span. A model that does so is not a
/// model of the record, even inside the physical range: its held-out error would be a number
/// that means nothing.
pub fn runaway(sim: &[f64], y: &[f64], ts: f64, r: &CheckRules) -> Option<Instability> {
    let (lo, hi) = analysis::extent(y);
    let span = hi - lo;
    if span.is_nan() || span <= 0.0 {
        return None;
    }
    let (a, b) = (lo - r.runaway_spans * span, hi + r.runaway_spans * span);
    let k = sim.iter().position(|v| *v < a || *v > b)?;
    Some(Instability::RunsAway { spans: r.runaway_spans, range_um: [lo, hi], after_s: k as f64 * ts })
}

/// How far (µm, signed) the mean of a signal moves from its first to its last whole period
/// of `period` samples; `None` with fewer than two periods. Under a periodic drive a model
/// whose loop closes repeats itself.
pub fn ratchet_um(sim: &[f64], period: Option<f64>) -> Option<f64> {
    let p = period.filter(|p| *p >= 1.0)?;
    let n = sim.len();
    if (n as f64) < 2.0 * p {
        return None;
    }
    let pw = p.round() as usize;
    Some(analysis::mean(&sim[n - pw..]) - analysis::mean(&sim[..pw]))
}

/// Whether a free run that moves by `moves_um` ratchets rather than follows the output
/// (which moves by `y_moves_um`), against the output's fundamental `amp_um`: it moves by more
/// than `checks.ratchet_rel` of it, and the output does not move with it to within
/// `checks.ratchet_follow` of the move.
pub fn ratchets(moves_um: f64, y_moves_um: f64, amp_um: f64, r: &CheckRules) -> bool {
    moves_um.abs() > r.ratchet_rel * amp_um
        && (moves_um - y_moves_um).abs() > r.ratchet_follow * moves_um.abs()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_loop_outside_the_bounded_class_or_a_run_that_diverges_is_noted() {
        let ar = [0.5, -0.2];
        let ts = 1e-3;
        let r = CheckRules::default();
        let bounded = BoucWenParams { a1: 10.0, a: 3.0, a0: 0.1, gamma: 0.01, beta: 0.15 };
        let unbounded = BoucWenParams { gamma: -0.2, ..bounded };
        let fine = |_: f64| Some(vec![1.0; 100]);
        // In range at 0.5×, beyond Y_LIMIT_UM at 1.5×.
        let blows_up = |k: f64| Some(vec![if k > 1.0 { 2.0 * Y_LIMIT_UM } else { 1.0 }; 100]);
        assert_eq!(narrow(&bounded, &ar, ts, &r, fine), None);
        let shape = narrow(&unbounded, &ar, ts, &r, fine).expect("an unbounded loop is noted");
        assert!(
            shape.unbounded && shape.diverges_at.is_empty() && (shape.gamma_plus_beta + 0.05).abs() < 1e-12
        );
        let runs = narrow(&bounded, &ar, ts, &r, blows_up).expect("a diverging run is noted");
        assert_eq!(runs.diverges_at, vec![1.5]);
        assert!(!runs.unbounded);
        assert_eq!(narrow(&bounded, &ar, ts, &r, |_| None).map(|n| n.diverges_at), Some(vec![0.5, 1.5]));
    }

    #[test]
    fn a_pole_outside_or_a_run_out_of_range_is_unstable() {
        assert!(matches!(instability(&[1.5, -0.5], &[0.0], 1e-3), Some(Instability::Pole { .. })));
        let far = [0.0, 0.0, 2.0 * Y_LIMIT_UM];
        assert_eq!(
            instability(&[0.5, -0.2], &far, 1e-3),
            Some(Instability::LeavesRange { limit_um: Y_LIMIT_UM, after_s: 2e-3 })
        );
        let r = CheckRules::default();
        assert!(runaway(&[0.0, 50.0], &[0.0, 1.0], 1e-3, &r).is_some());
        assert!(runaway(&[0.0, 5.0], &[0.0, 1.0], 1e-3, &r).is_none());
    }
}

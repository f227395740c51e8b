//! Records with a hidden effect: randomized, seeded scenarios of the virtual bimorph for
//! testing and benchmarking [`crate::diagnose`].
//!
//! Each [`Case`] switches one effect on (or none) without telling the diagnosis, and
//! records a sine drive of random frequency and amplitude. All cases share the paper's
//! actuator (Bouc–Wen hysteresis with its off-centre loop, creep, driver, 16-bit DAC, sensor
//! noise 10 nm and resolution 10 nm) with the first bending mode moved, its damping drawn
//! and its stiffening replaced:
//!
//! | effect | what is switched on |
//! |---|---|
//! | [`Effect::Clean`] | nothing: linear stiffness, the resonance at least `f/3` away from every harmonic `k·f`, no sensor drift |
//! | [`Effect::OddHarmonic`]`(n)` | a stiffening that forces the `n`th harmonic, the resonance within ±2 % of `n·f` |
//! | [`Effect::EvenHarmonic`]`(n)` | an asymmetric stiffening (even powers) that forces the `n`th harmonic, the resonance near `n·f` |
//! | [`Effect::Drift`] | sensor drift: a linear trend (±0.05 to ±0.3 µm/s) and a random walk (0.005 to 0.03 µm/√s) |
//!
//! ## The hidden harmonic
//! A harmonic `n·f` that the extended model cannot explain needs a nonlinearity outside the
//! Bouc–Wen loop that forces `n·f`, and a resonance that amplifies it (the loop's own
//! harmonics through a resonance are inside the extended model's family). A stiffening
//! polynomial `N(q)` of the first mode forces, for `q = q0 + X·q_ref·sin θ`, the harmonics of
//! `N`; a single power `p` forces `p, p−2, …` with the lower ones the larger (`sin⁷θ` has 21
//! times more 3rd than 7th harmonic), so a pure 7th power gives mostly a 3rd harmonic unless
//! the resonance at `7f` is very sharp. To hide one effect of order `n`, the stiffening is
//! shaped so that at the operating point it forces the `n`th harmonic only:
//! ```text
//! N(q) = κ·q_ref·P_n((q − q0)/(X·q_ref)),   P_n(sin θ) = sin nθ (n odd), cos nθ (n even)
//! ```
//! `P_n = ±T_n` is the Chebyshev polynomial (`sin 3θ = 3s − 4s³`, `sin 5θ = 5s − 20s³ + 16s⁵`,
//! …), `q0` and `X` the mean and fundamental amplitude of the deflection measured on the
//! same scenario with linear stiffness, and its terms of power 2 to `n` are the stiffening
//! terms. The constant is an offset and is left out, and so is the linear term: a small
//! motion at `n·f` on top of the operating cycle sees the stiffness `1 + ⟨N'⟩`, and the mean
//! slope of `P_n` over the cycle is exactly its linear coefficient, so without it the `n`th
//! harmonic sees the drawn resonance (the fundamental sees a slightly harder or softer
//! mode, far below it).
//! Odd `n` with `q0 = 0` are symmetric hardening/softening of the bending (the terms are
//! centred on the off-centre operating point, else the odd powers would force even
//! harmonics too); even `n` are an asymmetric bimorph. With damping `ζ` and the resonance on
//! `n·f`, the `n`th harmonic of the deflection relative to the fundamental is about
//! `r = |κ|/(2ζ·X)`; [`Case::generate`] draws `r` from 6 % to 25 % and sets `κ` from it.
//! The response to the big `n`th harmonic adds smaller harmonics of second order.

use crate::analysis;
use crate::experiment;
use crate::record::{Record, RecordError};
use boucwen_sim::scenario::{Mode, StiffeningTerm};
use boucwen_sim::{Bimorph, Scenario, SimError};
use std::f64::consts::TAU;

/// The effect hidden in a record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effect {
    /// None.
    Clean,
    /// An odd harmonic oscillation of order `n` (`3..=9`).
    OddHarmonic(u32),
    /// An even harmonic of order `n` (`2..=8`).
    EvenHarmonic(u32),
    /// Sensor drift.
    Drift,
}

impl Effect {
    /// A short name: "clean", "odd3", "even2", "drift".
    pub fn name(&self) -> String {
        match self {
            Effect::Clean => "clean".into(),
            Effect::OddHarmonic(n) => format!("odd{n}"),
            Effect::EvenHarmonic(n) => format!("even{n}"),
            Effect::Drift => "drift".into(),
        }
    }
}

/// A drawn case: the scenario and the drive.
#[derive(Clone, Debug)]
pub struct Case {
    /// The hidden effect.
    pub effect: Effect,
    /// The seed it was drawn from.
    pub seed: u64,
    /// The virtual bimorph.
    pub scenario: Scenario,
    /// Drive frequency (Hz).
    pub drive_hz: f64,
    /// Drive amplitude (V).
    pub amplitude_v: f64,
    /// Record length (s).
    pub seconds: f64,
    /// The drawn relative amplitude `r` of the hidden harmonic (0 for other effects).
    pub target_rel: f64,
    /// The first mode's resonance at the operating point (Hz).
    pub resonance_hz: f64,
}

/// Why a case could not be drawn or recorded.
#[derive(Debug)]
pub enum CaseError {
    /// The order is outside `3..=9` (odd) or `2..=8` (even).
    Order(Effect),
    /// The virtual bimorph failed.
    Sim(SimError),
    /// The record is out of range.
    Record(RecordError),
}

impl std::fmt::Display for CaseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CaseError::Order(e) => {
                write!(f, "no case for {}: odd orders 3..=9 and even 2..=8 only", e.name())
            }
            CaseError::Sim(e) => write!(f, "virtual bimorph: {e}"),
            CaseError::Record(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for CaseError {}

impl From<SimError> for CaseError {
    fn from(e: SimError) -> Self {
        CaseError::Sim(e)
    }
}

/// SplitMix64: a small seeded source for drawing scenarios.
struct Draw(u64);

impl Draw {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform on `[lo, hi)`.
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Log-uniform on `[lo, hi)`.
    fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (self.uniform(lo.ln(), hi.ln())).exp()
    }
    fn sign(&mut self) -> f64 {
        if self.next() & 1 == 0 { 1.0 } else { -1.0 }
    }
}

/// Lowest and highest first-mode resonance drawn (Hz).
pub const RESONANCE_RANGE_HZ: (f64, f64) = (40.0, 200.0);
/// Lowest and highest drive frequency drawn (Hz).
pub const DRIVE_RANGE_HZ: (f64, f64) = (5.0, 60.0);
/// Drive amplitudes drawn (V).
pub const AMPLITUDE_RANGE_V: (f64, f64) = (0.6, 1.4);
/// Damping ratios of the first mode drawn (log-uniform).
pub const DAMPING_RANGE: (f64, f64) = (0.02, 0.06);
/// Relative amplitudes `r` of a hidden harmonic drawn (log-uniform).
pub const HARMONIC_RANGE: (f64, f64) = (0.06, 0.25);
/// Record length (s).
pub const SECONDS: f64 = 10.0;

impl Case {
    /// Draws a case with `effect` from `seed` (same seed, same case).
    pub fn generate(effect: Effect, seed: u64) -> Result<Case, CaseError> {
        let class = match effect {
            Effect::Clean => 1,
            Effect::OddHarmonic(n) if n % 2 == 1 && (3..=9).contains(&n) => 10 + u64::from(n),
            Effect::EvenHarmonic(n) if n % 2 == 0 && (2..=8).contains(&n) => 100 + u64::from(n),
            Effect::Drift => 1000,
            _ => return Err(CaseError::Order(effect)),
        };
        let mut d = Draw(seed ^ class.wrapping_mul(0x5E_ED0F_B0C5));
        let mut s = Scenario::default().with_seed(seed & (i64::MAX as u64)).without_drift();
        let amplitude_v = d.uniform(AMPLITUDE_RANGE_V.0, AMPLITUDE_RANGE_V.1);
        let zeta = d.log_uniform(DAMPING_RANGE.0, DAMPING_RANGE.1);
        let (f_r, drive_hz) = match effect {
            Effect::OddHarmonic(n) | Effect::EvenHarmonic(n) => {
                let n = f64::from(n);
                let lo = RESONANCE_RANGE_HZ.0.max(DRIVE_RANGE_HZ.0 * n);
                let hi = RESONANCE_RANGE_HZ.1.min(DRIVE_RANGE_HZ.1 * n);
                let f_r = d.uniform(lo, hi);
                (f_r, f_r / n * (1.0 + d.uniform(-0.02, 0.02)))
            }
            Effect::Clean | Effect::Drift => {
                let drive_hz = d.uniform(DRIVE_RANGE_HZ.0, 40.0);
                // The resonance between two harmonics, at least f/3 from both.
                let lo = (RESONANCE_RANGE_HZ.0 / drive_hz).ceil().max(2.0);
                let hi = (RESONANCE_RANGE_HZ.1 / drive_hz).floor().max(lo + 1.0);
                let k = d.uniform(lo, hi).floor();
                (drive_hz * (k + d.uniform(1.0 / 3.0, 2.0 / 3.0)), drive_hz)
            }
        };
        let m1 = &mut s.structure.modes[0];
        *m1 = Mode {
            freq_hz: f_r,
            damping: zeta,
            participation: m1.participation,
            stiffening: vec![],
            damping_nl: vec![],
        };
        s.structure.modes[1].freq_hz = (6.27 * f_r).min(1200.0);
        let mut target_rel = 0.0;
        if let Effect::OddHarmonic(n) | Effect::EvenHarmonic(n) = effect {
            target_rel = d.log_uniform(HARMONIC_RANGE.0, HARMONIC_RANGE.1);
            let (q0, amp) = operating_point(&s, drive_hz, amplitude_v)?;
            let q_ref = s.structure.q_ref_um;
            let (x0, x) = (q0 / q_ref, amp / q_ref);
            // Hardening for the fundamental for odd orders (the dropped linear part of P_n is +n).
            let kappa = if n % 2 == 1 { -1.0 } else { 1.0 } * target_rel * 2.0 * zeta * x;
            let c = shaped_stiffening(n, kappa, x0, x);
            let m1 = &mut s.structure.modes[0];
            m1.stiffening = (2..=n as usize)
                .filter(|&p| c[p] != 0.0)
                .map(|p| StiffeningTerm { power: p as u32, coeff: c[p] })
                .collect();
        }
        s.structure.modes[1].freq_hz = (6.27 * s.structure.modes[0].freq_hz).min(1200.0);
        if effect == Effect::Drift {
            s.sensor.drift_um_per_s = d.sign() * d.log_uniform(0.05, 0.3);
            s.sensor.random_walk_um_per_sqrt_s = d.log_uniform(0.005, 0.03);
        }
        s.validate()?;
        Ok(Case {
            effect,
            seed,
            scenario: s,
            drive_hz,
            amplitude_v,
            seconds: SECONDS,
            target_rel,
            resonance_hz: f_r,
        })
    }

    /// Runs the virtual bimorph from rest with the case's sine drive; the record starts
    /// at `t = 0` and is named after the case ("odd5-17").
    pub fn record(&self) -> Result<Record, CaseError> {
        let ts = self.scenario.sampling.ts_s;
        let n = (self.seconds / ts).round() as usize;
        let u = drive(self.amplitude_v, self.drive_hz, ts, n);
        let y = Bimorph::new(&self.scenario)?.run(&u)?;
        let name = format!("{}-{}", self.effect.name(), self.seed);
        Record::new(&name, 0.0, ts, u, y, None).map_err(CaseError::Record)
    }
}

fn drive(amplitude_v: f64, drive_hz: f64, ts: f64, n: usize) -> Vec<f64> {
    experiment::sine(amplitude_v, drive_hz, ts, n)
        .unwrap_or_else(|_| (0..n).map(|k| amplitude_v * (TAU * drive_hz * k as f64 * ts).sin()).collect())
}

/// Coefficients `c[0..=n]` of `N(q)/q_ref` in powers of `q/q_ref` for
/// `κ·P_n((q/q_ref − x0)/x)` (see the module docs).
fn shaped_stiffening(n: u32, kappa: f64, x0: f64, x: f64) -> Vec<f64> {
    let n = n as usize;
    // Chebyshev T_n by T_{k+1} = 2ξ·T_k − T_{k−1}.
    let (mut t0, mut t1) = (vec![1.0], vec![0.0, 1.0]);
    for _ in 1..n {
        let mut t2 = vec![0.0; t1.len() + 1];
        for (i, &c) in t1.iter().enumerate() {
            t2[i + 1] += 2.0 * c;
        }
        for (i, &c) in t0.iter().enumerate() {
            t2[i] -= c;
        }
        (t0, t1) = (t1, t2);
    }
    let tn = if n == 0 { t0 } else { t1 };
    // sin nθ = (−1)^((n−1)/2)·T_n(sin θ) for odd n, cos nθ = (−1)^(n/2)·T_n(sin θ) for even n.
    let sign = if (n / 2) % 2 == 0 { 1.0 } else { -1.0 };
    // Expand κ·Σ_j p_j·((ξ − x0)/x)^j in powers of ξ.
    let mut c = vec![0.0; n + 1];
    for (j, &p) in tn.iter().enumerate() {
        let pj = kappa * sign * p / x.powi(j as i32);
        for (i, ci) in c.iter_mut().enumerate().take(j + 1) {
            *ci += pj * binomial(j, i) * (-x0).powi((j - i) as i32);
        }
    }
    c
}

fn binomial(n: usize, k: usize) -> f64 {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
}

/// The mean and fundamental amplitude (µm) of the true deflection of the scenario with
/// linear stiffness under the drive, over whole periods after 2 s of settling.
fn operating_point(s: &Scenario, drive_hz: f64, amplitude_v: f64) -> Result<(f64, f64), SimError> {
    let lin = s.clone().without_stiffening().without_noise().without_drift().without_quantisation();
    let mut plant = Bimorph::new(&lin)?;
    let ts = lin.sampling.ts_s;
    let settle = (2.0 / ts) as usize;
    let u = drive(amplitude_v, drive_hz, ts, settle + (1.0 / ts) as usize);
    let mut y = Vec::with_capacity(u.len());
    for &uk in &u {
        y.push(plant.step_detail(uk)?.y_true_um);
    }
    let y = &y[settle..];
    let n = analysis::whole_periods(y.len(), drive_hz, ts);
    let amp = analysis::harmonics(&y[..n], drive_hz, ts, 1).first().map_or(0.0, |t| t.amp);
    Ok((analysis::mean(&y[..n]), amp))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shaped_stiffening_forces_only_its_harmonic() {
        // κ·P_n(sin θ) must be κ·sin nθ (odd) or κ·cos nθ (even) at x0 = 0, x = 1.
        for n in 2..=9u32 {
            let c = shaped_stiffening(n, 0.5, 0.0, 1.0);
            for k in 0..50 {
                let th = k as f64 * 0.13;
                let s = th.sin();
                let v: f64 = c.iter().enumerate().map(|(i, ci)| ci * s.powi(i as i32)).sum();
                let want = 0.5 * if n % 2 == 1 { (n as f64 * th).sin() } else { (n as f64 * th).cos() };
                assert!((v - want).abs() < 1e-9, "n {n}: {v} vs {want}");
            }
        }
        // Centred on x0 with amplitude x: the same at ξ = x0 + x·sin θ.
        let c = shaped_stiffening(5, 0.3, -0.06, 0.8);
        let th: f64 = 0.7;
        let xi = -0.06 + 0.8 * th.sin();
        let v: f64 = c.iter().enumerate().map(|(i, ci)| ci * xi.powi(i as i32)).sum();
        assert!((v - 0.3 * (5.0 * th).sin()).abs() < 1e-9);
    }

    #[test]
    fn cases_are_reproducible_and_valid() {
        for e in [Effect::Clean, Effect::OddHarmonic(7), Effect::EvenHarmonic(2), Effect::Drift] {
            let a = Case::generate(e, 3).unwrap();
            let b = Case::generate(e, 3).unwrap();
            assert_eq!(a.scenario, b.scenario);
            assert_eq!(a.drive_hz, b.drive_hz);
            assert!(a.scenario.validate().is_ok());
        }
        assert!(matches!(Case::generate(Effect::OddHarmonic(4), 1), Err(CaseError::Order(_))));
    }
}

//! The tuning rule: PI by maximum integral gain under a sensitivity bound, the ORC by
//! Li et al.'s stability condition (see the module docs of [`super`]).

use super::{OpenLoopConfig, OrcConfig, OrcPlacement, PiConfig, half_period};
use crate::compensator::Saturation;
use crate::error::finite;
use crate::model::{ExtendedParams, Model};
use crate::signal::{Oscillator, sin_cos};
use crate::{Error, Real};
use nalgebra::Complex;

/// Number of frequencies on which [`tune`] evaluates the model (`0 < ω < π`).
pub const TUNE_GRID: usize = 4096;

/// The largest phase lead [`tune`] considers, in samples.
pub const TUNE_MAX_LEAD: usize = 32;

/// The `Q` coefficients [`tune`] considers, strongest low-pass first.
pub const TUNE_Q_COEFFS: [f64; 5] = [0.25, 0.1, 0.05, 0.025, 0.01];

/// The largest learning gain [`tune`] chooses.
pub const TUNE_MAX_LEARNING_GAIN: f64 = 1.0;
/// Options of [`tune`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TuneOptions<T> {
    /// The sensitivity bound `Ms > 1` of the PI design (1.5: gain margin ≥ 3, phase
    /// margin ≥ 38.9°).
    pub max_sensitivity: T,
    /// Give the PI (and so the ORC) the static feedforward `k_ff = 1/G0`; otherwise plain
    /// feedback, `k_ff = 0`. The feedforward does not change the loop, so the rest of the
    /// design is the same.
    pub static_feedforward: bool,
    /// The model's input delay `τ ≥ 0` in samples (fractional; the host fits carry one):
    /// the plant is taken as `z^{-⌊τ⌋}·(1 - φ + φ z⁻¹)·P`, `φ = τ - ⌊τ⌋` (the host
    /// model's linear interpolation).
    pub input_delay_samples: T,
    /// Where the ORC's output enters the loop (default: the PI's input, Li et al.'s form).
    pub orc_placement: OrcPlacement,
}

impl<T: Real> Default for TuneOptions<T> {
    fn default() -> Self {
        Self {
            max_sensitivity: T::lit(1.5),
            static_feedforward: false,
            input_delay_samples: T::zero(),
            orc_placement: OrcPlacement::PiInput,
        }
    }
}

/// The PI design and the numbers behind it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PiDesign<T> {
    /// The PI.
    pub pi: PiConfig<T>,
    /// `G0`, the model's static gain.
    pub static_gain: T,
    /// `[κ_lo, κ_hi]`: the incremental gain range relative to the small-signal gain.
    pub gain_factors: (T, T),
    /// The nominal loop's gain crossover (Hz): the lowest grid frequency with `|L_fb| ≤ 1`.
    pub crossover_hz: T,
    /// The largest `|S|` on the grid over the gain range (≤ `Ms` up to the grid).
    pub sensitivity_peak: T,
}

/// The ORC design and the numbers behind it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrcDesign<T> {
    /// The internal model's parameters.
    pub orc: OrcConfig<T>,
    /// The normalised learning gain `k_r` (`orc.learning_gain·G0`).
    pub normalised_learning_gain: T,
    /// The largest normalised learning gain with `ρ ≤ 1` for the chosen `Q` and lead (`k_r`
    /// is half of it, at most [`TUNE_MAX_LEARNING_GAIN`]).
    pub max_learning_gain: T,
    /// Predicted steady-state error ratio ORC/PI `η_n` at the harmonics 1, 3, 5 (1 where
    /// the harmonic is at or above Nyquist).
    pub predicted_error_ratio: [T; 3],
}

/// Everything [`tune`] designs from one model, for one reference frequency.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tuning<T> {
    /// Open loop `u = d/G0`.
    pub open_loop: OpenLoopConfig<T>,
    /// The PI design (also the ORC's stabilising feedback).
    pub pi: PiDesign<T>,
    /// The ORC design.
    pub orc: OrcDesign<T>,
}

/// The identified model normalised to unit static gain, with its input delay, evaluated on
/// the unit circle.
struct Normalised<'a, T, const P: usize> {
    ar: &'a [T; P],
    dc: T,
    /// `⌊τ⌋` and `φ`.
    delay: (T, T),
}

impl<'a, T: Real, const P: usize> Normalised<'a, T, P> {
    fn new(model: &'a ExtendedParams<T, P>, opts: &TuneOptions<T>) -> Result<Self, Error> {
        let tau = finite(opts.input_delay_samples, "input delay")?;
        if tau < T::zero() {
            return Err(Error::OutOfRange("input delay (must be >= 0)"));
        }
        let mut dc = T::one();
        for &a in &model.ar {
            dc -= a;
        }
        Ok(Self { ar: &model.ar, dc, delay: (tau.floor(), tau - tau.floor()) })
    }

    /// `P_n(ω) = z^{-⌊τ⌋}(1 - φ + φ z⁻¹)·(1 - Σ a_j)/(1 - Σ a_j e^{-iωj})` at
    /// `z⁻¹ = e^{-iω}`.
    fn at(&self, z_inv: Complex<T>, w: T) -> Complex<T> {
        let mut den = Complex::new(T::one(), T::zero());
        let mut zp = z_inv;
        for &a in self.ar {
            den -= zp * a;
            zp *= z_inv;
        }
        let (whole, frac) = self.delay;
        let wd = w * whole;
        let delay =
            Complex::new(wd.cos(), -wd.sin()) * (z_inv * frac + Complex::new(T::one() - frac, T::zero()));
        delay * Complex::new(self.dc, T::zero()) / den
    }
}

/// `e^{-iω}` for the grid point `i`, and `ω`.
fn grid_point<T: Real>(i: usize) -> (Complex<T>, T) {
    let w = T::pi() * T::lit((i as f64 + 0.5) / TUNE_GRID as f64);
    (Complex::new(w.cos(), -w.sin()), w)
}

/// The smallest `x ≥ 0` with `|c + x·b|² < r2`, given `|c|² ≥ r2` (`None`: there is none).
#[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x > 0)` does")]
fn first_violation<T: Real>(c: Complex<T>, b: Complex<T>, r2: T) -> Option<T> {
    let bb = b.norm_sqr();
    if !(bb > T::zero()) {
        return None;
    }
    let p = (c * b.conj()).re;
    let cc = c.norm_sqr() - r2;
    if p >= T::zero() {
        return None;
    }
    let disc = p * p - bb * cc;
    if !(disc > T::zero()) {
        return None;
    }
    Some(cc.max(T::zero()) / (disc.sqrt() - p))
}

/// The incremental gain range of `A1·u - h` relative to `A1 - A`, as `(κ_lo, κ_hi)` with
/// `0.1 ≤ κ_lo ≤ 1 ≤ κ_hi`.
fn gain_factors<T: Real, const P: usize>(model: &ExtendedParams<T, P>) -> (T, T) {
    let bw = &model.bw;
    let b = bw.a1 - bw.a;
    let (mut lo, mut hi) = (T::one(), T::one());
    if let Some((h_lo, h_hi)) = bw.h_range() {
        for h in [h_lo, T::zero(), h_hi] {
            for rising in [true, false] {
                let k = (bw.a1 - bw.slope(h, rising)) / b;
                lo = lo.min(k);
                hi = hi.max(k);
            }
        }
    }
    (lo.max(T::lit(0.1)), hi)
}

/// Number of proportional gains tried by the PI rule.
const KP_STEPS: usize = 16;

/// The PI of the module docs' tuning rule, from the identified model alone.
#[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x > 0)` does")]
pub fn tune_pi<T: Real, const P: usize>(
    model: &ExtendedParams<T, P>,
    ts_s: T,
    saturation: Saturation<T>,
    opts: &TuneOptions<T>,
) -> Result<PiDesign<T>, Error> {
    model.validate()?;
    saturation.validate()?;
    finite(ts_s, "sample interval")?;
    finite(opts.max_sensitivity, "Ms")?;
    if !(ts_s > T::zero()) {
        return Err(Error::OutOfRange("sample interval (must be > 0)"));
    }
    if !(opts.max_sensitivity > T::one()) {
        return Err(Error::OutOfRange("Ms (must be > 1)"));
    }
    if !model.is_stable() {
        return Err(Error::OutOfRange("model (its AR part is unstable: nothing to tune on)"));
    }
    let g0 = finite(model.static_gain(), "static gain G0")?;
    if g0.abs() < T::MIN_POSITIVE || (model.bw.a1 - model.bw.a) == T::zero() {
        return Err(Error::OutOfRange("static gain G0 (must be non-zero)"));
    }
    let plant = Normalised::new(model, opts)?;
    let (k_lo, k_hi) = gain_factors(model);
    let kappas = [k_lo, T::one(), k_hi];
    let r2 = T::one() / (opts.max_sensitivity * opts.max_sensitivity);
    let one = Complex::new(T::one(), T::zero());

    // kp_lim: the largest kp meeting the bound with ki = 0.
    let mut kp_lim = T::lit(2.0);
    for i in 0..TUNE_GRID {
        let (z_inv, w) = grid_point::<T>(i);
        let pz = plant.at(z_inv, w) * z_inv;
        for &k in &kappas {
            if let Some(x) = first_violation(one, pz * k, r2) {
                kp_lim = kp_lim.min(x);
            }
        }
    }
    // For each kp, the largest ki whose path from 0 meets the bound.
    let mut ki_max = [T::one(); KP_STEPS];
    for i in 0..TUNE_GRID {
        let (z_inv, w) = grid_point::<T>(i);
        let pz = plant.at(z_inv, w) * z_inv;
        let integ = one / (one - z_inv);
        for &k in &kappas {
            let a1 = pz * k;
            let b = a1 * integ;
            for (j, ki) in ki_max.iter_mut().enumerate() {
                let kp = kp_lim * T::lit(j as f64 / KP_STEPS as f64);
                let c = one + a1 * kp;
                if c.norm_sqr() < r2 {
                    *ki = T::zero();
                } else if let Some(x) = first_violation(c, b, r2) {
                    *ki = (*ki).min(x);
                }
            }
        }
    }
    let mut best = 0;
    for j in 1..KP_STEPS {
        if ki_max[j] > ki_max[best] {
            best = j;
        }
    }
    let ki_n = ki_max[best];
    if !(ki_n > T::zero()) {
        return Err(Error::OutOfRange("PI tuning (no gains meet the sensitivity bound)"));
    }
    let kp_n = kp_lim * T::lit(best as f64 / KP_STEPS as f64);

    // Crossover and sensitivity peak of the design.
    let mut crossover_hz = T::zero();
    let mut found = false;
    let mut peak = T::zero();
    for i in 0..TUNE_GRID {
        let (z_inv, w) = grid_point::<T>(i);
        let c = (one * kp_n + one / (one - z_inv) * ki_n) * z_inv * plant.at(z_inv, w);
        if !found && c.norm_sqr() <= T::one() {
            crossover_hz = w / (T::two_pi() * ts_s);
            found = true;
        }
        for &k in &kappas {
            peak = peak.max(T::one() / (one + c * k).norm_sqr().sqrt());
        }
    }
    let pi = PiConfig {
        kp: kp_n / g0,
        ki_per_s: ki_n / (g0 * ts_s),
        ts_s,
        feedforward_gain: if opts.static_feedforward { T::one() / g0 } else { T::zero() },
        saturation,
    };
    pi.validate()?;
    Ok(PiDesign { pi, static_gain: g0, gain_factors: (k_lo, k_hi), crossover_hz, sensitivity_peak: peak })
}

/// The ORC of the module docs' tuning rule on the PI `pi` (from [`tune_pi`] or the
/// caller's), for the reference `drive`.
#[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x > 0)` does")]
pub fn tune_orc<T: Real, const P: usize>(
    model: &ExtendedParams<T, P>,
    pi: &PiConfig<T>,
    drive: Oscillator,
    opts: &TuneOptions<T>,
) -> Result<OrcDesign<T>, Error> {
    const NA: usize = TUNE_Q_COEFFS.len();
    const NM: usize = TUNE_MAX_LEAD + 1;
    model.validate()?;
    pi.validate()?;
    if !model.is_stable() {
        return Err(Error::OutOfRange("model (its AR part is unstable: nothing to tune on)"));
    }
    let g0 = finite(model.static_gain(), "static gain G0")?;
    if g0.abs() < T::MIN_POSITIVE {
        return Err(Error::OutOfRange("static gain G0 (must be non-zero)"));
    }
    let (l0, mu) = half_period(drive)?;
    if l0 < 2 {
        return Err(Error::OutOfRange("ORC reference frequency (N/2 must be at least 2 samples)"));
    }
    let n_lead = TUNE_MAX_LEAD.min(l0 - 2) + 1;
    let mu_t = T::lit(mu);
    let plant = Normalised::new(model, opts)?;
    let (k_lo, k_hi) = gain_factors(model);
    let kappas = [k_lo, T::one(), k_hi];
    let one = Complex::new(T::one(), T::zero());
    // The PI in normalised units.
    let (kp_n, ki_n) = (pi.kp * g0, pi.ki_per_s * g0 * pi.ts_s);
    let loop_gain =
        |z_inv: Complex<T>, w: T| (one * kp_n + one / (one - z_inv) * ki_n) * z_inv * plant.at(z_inv, w);
    // What the ORC learns through: κ·P_n·S_κ at the plant input, T_κ = κL/(1 + κL) at the
    // PI's (in normalised units).
    let path = |pn: Complex<T>, l: Complex<T>, k: T| match opts.orc_placement {
        OrcPlacement::PlantInput => pn * k / (one + l * k),
        OrcPlacement::PiInput => l * k / (one + l * k),
    };
    let qf = |a: T, z_inv: Complex<T>| {
        let q = T::one() - (a + a) * (T::one() - z_inv.re);
        (one * (T::one() - mu_t) + z_inv * mu_t) * q
    };

    let mut k_max = [[T::max_value().unwrap_or(T::lit(1e30)); NM]; NA];
    for i in 0..TUNE_GRID {
        let (z_inv, w) = grid_point::<T>(i);
        let z = z_inv.conj();
        let l = loop_gain(z_inv, w);
        let pn = plant.at(z_inv, w);
        for &k in &kappas {
            let t = path(pn, l, k);
            for (ia, &a) in TUNE_Q_COEFFS.iter().enumerate() {
                let g2 = qf(T::lit(a), z_inv).norm_sqr();
                if !(g2 > T::zero()) {
                    continue;
                }
                let g2inv = (T::one() / g2 - T::one()).max(T::zero());
                let mut w = t;
                for k_am in k_max[ia].iter_mut().take(n_lead) {
                    let ww = w.norm_sqr();
                    if ww > T::zero() {
                        let p = w.re;
                        let disc = (p * p + ww * g2inv).sqrt();
                        let x = if p >= T::zero() { (p + disc) / ww } else { g2inv / (disc - p) };
                        *k_am = k_am.min(x);
                    }
                    w *= z;
                }
            }
        }
    }

    // Score the candidates at the odd harmonics.
    // Phases as exact 2⁻⁶⁴-turn integers (no libm on f64 in no_std, and no precision lost
    // on long delays in f32).
    let inc = drive.increment();
    let at = |phase: u64| {
        let (s, c) = sin_cos::<T>(phase);
        Complex::new(c, s)
    };
    let mut best: Option<(T, usize, usize, T, [T; 3])> = None;
    for (ia, &a) in TUNE_Q_COEFFS.iter().enumerate() {
        for (m, &km) in k_max[ia].iter().enumerate().take(n_lead) {
            if !(km > T::zero()) {
                continue;
            }
            let kr = (km * T::lit(0.5)).min(T::lit(TUNE_MAX_LEARNING_GAIN));
            let mut eta = [T::one(); 3];
            let mut score = T::zero();
            for (h, n) in [1u32, 3, 5].into_iter().enumerate() {
                // n·f below Nyquist: n·inc < 2⁶³ (inc < 2⁶³ for any valid oscillator).
                let Some(pn) = inc.checked_mul(n as u64).filter(|&p| p < 1 << 63) else {
                    continue;
                };
                let z_inv = at(pn).conj();
                let wn = T::lit(pn as f64 / 18_446_744_073_709_551_616.0) * T::two_pi();
                let t = path(plant.at(z_inv, wn), loop_gain(z_inv, wn), T::one());
                let x = qf(T::lit(a), z_inv) * at(pn.wrapping_mul(l0 as u64)).conj();
                let lead = at(pn.wrapping_mul(m as u64));
                let num = (one + x).norm_sqr().sqrt();
                let den = (one + x * (one - lead * t * kr)).norm_sqr().sqrt();
                eta[h] = num / den;
                score += eta[h] / T::lit(n as f64);
            }
            if best.as_ref().is_none_or(|b| score < b.0) {
                best = Some((score, ia, m, km, eta));
            }
        }
    }
    let Some((_, ia, m, km, eta)) = best else {
        return Err(Error::OutOfRange("ORC tuning (no Q and lead give a positive stable learning gain)"));
    };
    let kr = (km * T::lit(0.5)).min(T::lit(TUNE_MAX_LEARNING_GAIN));
    let u_range = pi.saturation.u_min.abs().max(pi.saturation.u_max.abs());
    let (learning_gain, limit) = match opts.orc_placement {
        OrcPlacement::PlantInput => (kr / g0, u_range),
        OrcPlacement::PiInput => {
            // The ε at which the PI alone would ask for the driver's range at f.
            let z_inv = at(inc).conj();
            let c = (one * pi.kp + one / (one - z_inv) * (pi.ki_per_s * pi.ts_s)).norm_sqr().sqrt();
            (kr, u_range / c)
        }
    };
    let orc = OrcConfig {
        drive,
        q_coeff: T::lit(TUNE_Q_COEFFS[ia]),
        learning_gain,
        lead_samples: m as u32,
        limit,
        placement: opts.orc_placement,
    };
    orc.validate(usize::MAX)?;
    Ok(OrcDesign { orc, normalised_learning_gain: kr, max_learning_gain: km, predicted_error_ratio: eta })
}

/// Open loop, PI and ORC for the reference `drive`, all from the identified `model` by the
/// rule of the module docs.
///
/// ```
/// use boucwen_core::compensator::Saturation;
/// use boucwen_core::controllers::{tune, Controller, OrcController, TuneOptions, ORC_CAPACITY};
/// use boucwen_core::model::{BoucWenParams, ExtendedParams};
/// use boucwen_core::signal::Oscillator;
/// let model = ExtendedParams { bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
///                              ar: [1.6, -0.8] };
/// let drive = Oscillator::new(10.0, 1e-3)?;
/// let t = tune(&model, drive, 1e-3, Saturation::symmetric(10.0), &TuneOptions::default())?;
/// assert!(t.pi.sensitivity_peak <= 1.51);
/// let mut orc = OrcController::<f64, ORC_CAPACITY>::new(t.pi.pi, t.orc.orc)?;
/// orc.step(0.0, None)?;
/// # Ok::<(), boucwen_core::Error>(())
/// ```
pub fn tune<T: Real, const P: usize>(
    model: &ExtendedParams<T, P>,
    drive: Oscillator,
    ts_s: T,
    saturation: Saturation<T>,
    opts: &TuneOptions<T>,
) -> Result<Tuning<T>, Error> {
    let pi = tune_pi(model, ts_s, saturation, opts)?;
    let orc = tune_orc(model, &pi.pi, drive, opts)?;
    let open_loop = OpenLoopConfig { static_gain: pi.static_gain, saturation };
    open_loop.validate()?;
    Ok(Tuning { open_loop, pi, orc })
}

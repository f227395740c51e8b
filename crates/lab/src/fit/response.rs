//! The structure from sine records: the extended model's linear part (`a1`, `a2` and the
//! input delay `d`) fitted to the fundamentals' complex gains measured at a few drive
//! frequencies, when no broadband record is at hand (the paper's own Fig. 10 comes from sine
//! records alone).
//!
//! At one drive amplitude the Bouc–Wen loop is rate-independent: it turns the drive's
//! fundamental into a fundamental of another amplitude and phase that do not depend on the
//! frequency. So the measured gain at `ω` (rad/sample) is
//!
//! ```text
//! G(ω) = c · e^{−jωd} / (1 − a1 e^{−jω} − a2 e^{−2jω})
//! ```
//!
//! with one complex constant `c` (the structure's gain times the loop's describing function)
//! shared by every frequency. The fit is Levy's linearisation `G·A = c·e^{−jωd}`, solved by
//! weighted least squares and iterated as Sanathanan and Koerner did (weights
//! `|U|/|A_prev(e^{jω})|`), so that at convergence it minimises the error of the output's
//! fundamental, `Σ |U_i|²·|G_i − Ĝ_i|²`, in the output's units; the delay is searched on a
//! grid of quarter samples and the one with the smallest error kept.
//!
//! Where this departs from a broadband fit: the records are taken at the drive amplitude, so
//! the loop's describing function is in `c` (the loop shape is fitted afterwards, with the
//! structure fixed, as for a broadband record); the resonance is pinned only by the
//! frequencies the sines cover (the nearer one comes to it, the better), and records of
//! different drive amplitudes would put different `c` into one fit.

use super::FitError;
use nalgebra::{SMatrix, SVector};
use rustfft::num_complex::Complex;
use std::f64::consts::TAU;

/// The largest input delay searched (samples).
pub const MAX_DELAY_SAMPLES: f64 = 8.0;
/// The delay grid's step (samples).
pub const DELAY_STEP_SAMPLES: f64 = 0.25;
/// The fewest distinct frequencies the fit takes: four real unknowns and a delay need more
/// than the four equations two frequencies give.
pub const MIN_FREQUENCIES: usize = 3;
/// Sanathanan–Koerner iterations per delay.
const ITERATIONS: usize = 12;

/// One sine record's fundamentals: the drive's and the output's amplitude and phase
/// (`amp·sin(2π f t + phase)`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fundamental {
    /// Drive frequency (Hz).
    pub freq_hz: f64,
    /// The drive's fundamental `(amplitude, phase)` (V, rad).
    pub u: (f64, f64),
    /// The output's fundamental `(amplitude, phase)` (output unit, rad).
    pub y: (f64, f64),
}

impl Fundamental {
    /// The complex gain `Y/U`.
    fn gain(&self) -> Complex<f64> {
        Complex::from_polar(self.y.0 / self.u.0, self.y.1 - self.u.1)
    }
}

/// The linear part fitted to the fundamentals.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResponseFit {
    /// `[a1, a2]` of `y[k] = a1·y[k−1] + a2·y[k−2] + …`.
    pub ar: [f64; 2],
    /// The input delay (samples).
    pub delay: f64,
    /// The shared complex gain `c`.
    pub gain: Complex<f64>,
    /// RMS over the records of the output fundamental's error, as the RMS of a sine
    /// (`|Y − Ĝ·U|/√2`, output unit).
    pub rms: f64,
}

impl ResponseFit {
    /// The model's gain at `freq_hz`.
    pub fn at(&self, freq_hz: f64, ts: f64) -> Complex<f64> {
        let w = TAU * freq_hz * ts;
        let z = Complex::from_polar(1.0, -w);
        let a = Complex::new(1.0, 0.0) - self.ar[0] * z - self.ar[1] * z * z;
        self.gain * Complex::from_polar(1.0, -w * self.delay) / a
    }
}

/// Fits `a1`, `a2`, `d` and `c` to `points` sampled every `ts` seconds (see the module
/// docs). Errors when fewer than [`MIN_FREQUENCIES`] distinct frequencies with a drive are
/// given, or when no delay gives a stable linear part.
pub fn fit_response(points: &[Fundamental], ts: f64) -> Result<ResponseFit, FitError> {
    let pts: Vec<&Fundamental> = points
        .iter()
        .filter(|p| p.u.0 > 0.0 && [p.u.0, p.u.1, p.y.0, p.y.1, p.freq_hz].iter().all(|v| v.is_finite()))
        .collect();
    let mut freqs: Vec<f64> = pts.iter().map(|p| p.freq_hz).collect();
    freqs.sort_by(f64::total_cmp);
    freqs.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * b.abs());
    if freqs.len() < MIN_FREQUENCIES {
        return Err(FitError::TooFewSamples { have: freqs.len(), need: MIN_FREQUENCIES });
    }
    let steps = (MAX_DELAY_SAMPLES / DELAY_STEP_SAMPLES).round() as usize;
    let mut best: Option<(f64, ResponseFit)> = None;
    for i in 0..=steps {
        let d = i as f64 * DELAY_STEP_SAMPLES;
        let Some(fit) = fit_at_delay(&pts, ts, d) else { continue };
        let cost = cost(&pts, ts, &fit);
        if cost.is_finite() && best.as_ref().is_none_or(|(c, _)| cost < *c) {
            best = Some((cost, fit));
        }
    }
    let (cost, mut fit) = best.ok_or(FitError::NoStableModel)?;
    fit.rms = (cost / (2.0 * pts.len() as f64)).sqrt();
    Ok(fit)
}

/// `Σ |U_i|²·|G_i − Ĝ_i|²`.
fn cost(pts: &[&Fundamental], ts: f64, fit: &ResponseFit) -> f64 {
    pts.iter().map(|p| p.u.0 * p.u.0 * (p.gain() - fit.at(p.freq_hz, ts)).norm_sqr()).sum()
}

/// The Sanathanan–Koerner iteration at delay `d`; `None` when the system is singular or the
/// linear part comes out unstable.
fn fit_at_delay(pts: &[&Fundamental], ts: f64, d: f64) -> Option<ResponseFit> {
    let mut ar = [0.0; 2];
    let mut gain = Complex::new(0.0, 0.0);
    for _ in 0..ITERATIONS {
        let mut n = SMatrix::<f64, 4, 4>::zeros();
        let mut b = SVector::<f64, 4>::zeros();
        for p in pts {
            let w = TAU * p.freq_hz * ts;
            let z = Complex::from_polar(1.0, -w);
            let a_prev = Complex::new(1.0, 0.0) - ar[0] * z - ar[1] * z * z;
            let weight = p.u.0 / a_prev.norm().max(1e-12);
            let g = p.gain();
            let e = Complex::from_polar(1.0, -w * d);
            // G = a1·G·z + a2·G·z² + c_r·e + c_i·j·e, real and imaginary parts.
            let phi = [g * z, g * z * z, e, Complex::new(0.0, 1.0) * e];
            for part in [|c: Complex<f64>| c.re, |c: Complex<f64>| c.im] {
                let row = SVector::<f64, 4>::from_fn(|k, _| weight * part(phi[k]));
                n += row * row.transpose();
                b += row * (weight * part(g));
            }
        }
        let theta = n.lu().solve(&b)?;
        if theta.iter().any(|v| !v.is_finite()) {
            return None;
        }
        ar = [theta[0], theta[1]];
        gain = Complex::new(theta[2], theta[3]);
    }
    crate::model::poles::stable(&ar).then_some(ResponseFit { ar, delay: d, gain, rms: f64::NAN })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fundamentals of a known linear part at `freqs`, with a loop's constant gain and lag.
    fn points(truth: &ResponseFit, freqs: &[f64], ts: f64) -> Vec<Fundamental> {
        freqs
            .iter()
            .map(|&f| {
                let g = truth.at(f, ts);
                Fundamental { freq_hz: f, u: (2.0, 0.3), y: (2.0 * g.norm(), 0.3 + g.arg()) }
            })
            .collect()
    }

    #[test]
    fn a_second_order_part_with_delay_is_recovered_from_four_sines() {
        // A 70 Hz resonance at 1 kHz sampling, damping 0.05, 2 samples of delay, and a loop
        // that scales the fundamental by 0.8 and delays it by 0.2 rad at every frequency.
        let ts = 1e-3;
        let (r, th) = ((-0.05 * TAU * 70.0 * ts).exp(), TAU * 70.0 * ts);
        let ar = [2.0 * r * th.cos(), -r * r];
        let gain = Complex::from_polar(0.8 * (1.0 - ar[0] - ar[1]), -0.2);
        let truth = ResponseFit { ar, delay: 2.0, gain, rms: 0.0 };
        let fit = fit_response(&points(&truth, &[1.0, 14.0, 23.0, 40.0], ts), ts).unwrap();
        assert!((fit.ar[0] - ar[0]).abs() < 1e-6 && (fit.ar[1] - ar[1]).abs() < 1e-6, "{fit:?}");
        assert_eq!(fit.delay, 2.0);
        assert!((fit.gain - gain).norm() < 1e-6 * gain.norm(), "{fit:?}");
        assert!(fit.rms < 1e-9, "{fit:?}");
        let f_res = crate::model::poles::resonance_hz(&fit.ar, ts).unwrap();
        assert!((f_res - 70.0).abs() < 4.0, "{f_res}");
    }

    #[test]
    fn two_frequencies_are_too_few() {
        let ts = 1e-3;
        let truth = ResponseFit { ar: [1.5, -0.6], delay: 1.0, gain: Complex::new(0.1, 0.0), rms: 0.0 };
        let e = fit_response(&points(&truth, &[1.0, 23.0, 23.0], ts), ts).unwrap_err();
        assert_eq!(e, FitError::TooFewSamples { have: 2, need: MIN_FREQUENCIES });
    }
}

//! What a model gets wrong, split: the held-out residual's harmonics of the drive, a slow
//! trend, what repeats above the harmonics, and noise ([`decompose`]).

use crate::rules::Rules;
use crate::signal::analysis::{self, Tone};
use std::f64::consts::TAU;

/// The residual decomposition of a model's held-out error.
#[derive(Clone, Debug, PartialEq)]
pub struct Residual {
    /// Held-out residual RMS (µm).
    pub rms_um: f64,
    /// Harmonics `1..` of the residual (µm), over whole drive periods.
    pub harmonics: Vec<Tone>,
    /// RMS of the slow trend, its mean included (µm).
    pub trend_rms_um: f64,
    /// Mean of the trend (µm).
    pub trend_mean_um: f64,
    /// Trend slope (µm/s, from the linear term).
    pub trend_slope_um_per_s: f64,
    /// RMS of what is neither periodic nor trend (µm).
    pub noise_rms_um: f64,
    /// RMS of the part periodic with the drive above the harmonics analysed (µm): what the
    /// average period holds beyond them when a period is a whole number of samples (a
    /// converter's steps, sharp corners); else 0.
    pub above_um: f64,
}

impl Residual {
    /// RMS of the part periodic with the drive (all harmonics measured, and what repeats
    /// above them).
    pub fn periodic_rms_um(&self) -> f64 {
        (self.harmonics.iter().map(|h| h.amp * h.amp / 2.0).sum::<f64>() + self.above_um * self.above_um)
            .sqrt()
    }

    /// The share of its power a part of `rms_um` RMS holds.
    pub fn share(&self, rms_um: f64) -> f64 {
        rms_um * rms_um / (self.rms_um * self.rms_um).max(1e-300)
    }
}

/// A phasor advanced by rotation is re-anchored every this many samples.
const REANCHOR: usize = 1024;

/// Splits a held-out residual into harmonics of `f` (up to `sine.max_order`), a slow trend
/// (a polynomial of `sine.trend_degree` in time, fitted to what the harmonics leave) and
/// noise; over whole-sample periods, what still repeats is periodic too, above the
/// harmonics (it counts when the average period holds twice the noise's share).
pub fn decompose(r: &[f64], f: f64, ts: f64, rules: &Rules) -> Residual {
    let n = analysis::whole_periods(r.len(), f, ts);
    let r = &r[..n];
    let kmax = ((0.5 / ts) / f).ceil() as usize;
    let harmonics = analysis::harmonics(r, f, ts, kmax.clamp(1, rules.sine.max_order));
    // Remove the harmonics, then fit the trend to what is left.
    let mut rest: Vec<f64> = r.to_vec();
    for h in &harmonics {
        // amp·sin(wk + phase) by a rotating phasor, re-anchored now and then.
        let w = TAU * h.freq_hz * ts;
        let (dw_s, dw_c) = w.sin_cos();
        let (mut s, mut c) = (0.0f64, 1.0f64);
        for (k, v) in rest.iter_mut().enumerate() {
            if k % REANCHOR == 0 {
                (s, c) = (w * k as f64 + h.phase).sin_cos();
            }
            *v -= h.amp * s;
            (s, c) = (s * dw_c + c * dw_s, c * dw_c - s * dw_s);
        }
    }
    let (trend, slope) = poly_fit(&rest, ts, rules.sine.trend_degree);
    let mut noise: Vec<f64> = rest.iter().zip(&trend).map(|(a, b)| a - b).collect();
    let mut above_um = 0.0;
    if let Some(p) = analysis::whole_sample_period(f, ts, n) {
        let (avg, m) = analysis::average_period(&noise, p);
        // The average of m periods holds 1/m of the noise's power: it counts when it holds
        // twice that.
        let (avg_power, noise_share) =
            (analysis::rms(&avg).powi(2), analysis::rms(&noise).powi(2) / m as f64);
        if avg_power > 2.0 * noise_share {
            above_um = (avg_power - noise_share).sqrt();
            for (k, v) in noise.iter_mut().enumerate().take(m * p) {
                *v -= avg[k % p];
            }
            // The deviation from a mean of m periods underestimates by √((m−1)/m).
            let scale = (m as f64 / (m as f64 - 1.0)).sqrt();
            noise.iter_mut().for_each(|v| *v *= scale);
        }
    }
    Residual {
        rms_um: analysis::rms(r),
        harmonics,
        trend_rms_um: analysis::rms(&trend),
        trend_mean_um: analysis::mean(&trend),
        trend_slope_um_per_s: slope,
        noise_rms_um: analysis::rms(&noise),
        above_um,
    }
}

/// Least-squares polynomial of `degree` in time (scaled to [-1, 1]); returns the fitted
/// values and the slope of the linear part in units per second.
fn poly_fit(x: &[f64], ts: f64, degree: usize) -> (Vec<f64>, f64) {
    let n = x.len();
    if n < degree + 2 {
        return (vec![analysis::mean(x); n], 0.0);
    }
    let half = (n - 1) as f64 / 2.0;
    let tau = |k: usize| (k as f64 - half) / half.max(1.0);
    let m = degree + 1;
    let mut ata = nalgebra::DMatrix::<f64>::zeros(m, m);
    let mut atb = nalgebra::DVector::<f64>::zeros(m);
    let mut p = vec![1.0; m];
    for (k, &v) in x.iter().enumerate() {
        let t = tau(k);
        for i in 1..m {
            p[i] = p[i - 1] * t;
        }
        for i in 0..m {
            atb[i] += p[i] * v;
            for j in 0..m {
                ata[(i, j)] += p[i] * p[j];
            }
        }
    }
    let Some(c) = ata.cholesky().map(|ch| ch.solve(&atb)) else {
        return (vec![analysis::mean(x); n], 0.0);
    };
    let fitted = (0..n).map(|k| (0..m).rev().fold(0.0, |acc, i| acc * tau(k) + c[i])).collect();
    (fitted, if m > 1 { c[1] / (half * ts) } else { 0.0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_core::{RngCore, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn decomposition_separates_harmonic_trend_and_noise() {
        let ts = 1e-3;
        let mut g = Xoshiro256PlusPlus::seed_from_u64(1);
        let r: Vec<f64> = (0..10_000)
            .map(|k| {
                let t = k as f64 * ts;
                let noise = (g.next_u64() >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                0.5 * (TAU * 69.0 * t + 0.2).sin() + 0.05 * t + 0.01 * noise
            })
            .collect();
        let d = decompose(&r, 23.0, ts, &Rules::default());
        assert!((d.harmonics[2].amp - 0.5).abs() < 1e-3, "{:?}", d.harmonics[2]);
        assert!((d.trend_slope_um_per_s - 0.05).abs() < 2e-3, "{}", d.trend_slope_um_per_s);
        assert!((d.trend_mean_um - 0.25).abs() < 2e-3, "{}", d.trend_mean_um);
        assert!(d.noise_rms_um < 0.01);
    }
}

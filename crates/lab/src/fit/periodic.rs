//! The average period of a record under a periodic drive.
//!
//! In steady state under a drive of frequency `f`, the output is a periodic function of
//! the drive's phase `θ[n] = 2π f Ts n` plus a slow trend and noise:
//! ```text
//! y[n] = c₀ + Σ_{j≥1} c_j t^j + Σ_{k=1..K} (a_k sin kθ[n] + b_k cos kθ[n]) + e[n]
//! ```
//! The coefficients are found by least squares over every whole period of the fitted part
//! (the harmonics up to `K =` [`MAX_TEMPLATE_ORDER`] or Nyquist, the trend of the fit's
//! drift degree). This is the average of the periods, also when a period is not a whole
//! number of samples (the phase of each sample is exact), with the noise reduced by the
//! square root of the number of periods. It costs one pass over the data (one rotating
//! phasor per harmonic, the harmonics in parallel); the Gram matrix of the harmonics is
//! summed in closed form.

use rayon::prelude::*;
use std::f64::consts::TAU;

/// Highest harmonic of the drive in the average period.
pub const MAX_TEMPLATE_ORDER: usize = 50;

/// Fewest whole periods to average.
pub const MIN_PERIODS: f64 = 8.0;

/// The drive counts as periodic when what its harmonics (and mean) leave of it has an RMS
/// below this fraction of its RMS.
pub const MAX_DRIVE_APERIODIC: f64 = 1e-2;

/// The average period of an output.
#[derive(Clone, Debug)]
pub(crate) struct Template {
    /// Drive frequency in cycles per sample.
    cycles: f64,
    /// `(a_k, b_k)` for `k = 1..=K`.
    harmonics: Vec<(f64, f64)>,
    /// Trend: coefficients of `1, t, t², …` (t in s from sample 0).
    pub trend: Vec<f64>,
    /// Whole periods averaged.
    pub periods: f64,
    /// RMS of what the harmonics and the trend leave of the output (noise).
    pub noise_rms: f64,
    /// RMS over the averaged samples of each trend term `c_j t^j`, `j ≥ 1`, centred.
    pub trend_rms: Vec<f64>,
    /// Mean over the averaged samples of each trend term `c_j t^j`, `j ≥ 0`.
    trend_mean: Vec<f64>,
    /// Samples averaged: `[from, to)`.
    pub from: usize,
    /// End of the averaged samples.
    pub to: usize,
}

/// `Σ_{n=n0}^{n0+len-1} e^{i2πcn}` as `(re, im)`.
fn geometric(c: f64, n0: usize, len: usize) -> (f64, f64) {
    let frac = |x: f64| x - x.floor();
    let (s0, c0) = (TAU * frac(c * n0 as f64)).sin_cos();
    let (sw, cw) = (TAU * frac(c)).sin_cos();
    let (sn, cn) = (TAU * frac(c * len as f64)).sin_cos();
    // (1 - e^{iwN}) / (1 - e^{iw})
    let (dr, di) = (1.0 - cw, -sw);
    let den = dr * dr + di * di;
    let (qr, qi) = if den < 1e-20 {
        (len as f64, 0.0)
    } else {
        let (nr, ni) = (1.0 - cn, -sn);
        ((nr * dr + ni * di) / den, (ni * dr - nr * di) / den)
    };
    (c0 * qr - s0 * qi, c0 * qi + s0 * qr)
}

impl Template {
    /// The average period of `y[from..to]` (trimmed to whole periods) under a drive at
    /// `freq_hz`, with a trend of `degree`; `None` when `u` is not periodic at `freq_hz`
    /// there or fewer than [`MIN_PERIODS`] periods are available.
    pub fn new(
        u: &[f64],
        y: &[f64],
        from: usize,
        to: usize,
        freq_hz: f64,
        ts: f64,
        degree: usize,
    ) -> Option<Self> {
        let cycles = freq_hz * ts;
        if !(cycles > 0.0 && cycles < 0.25) || to <= from {
            return None;
        }
        let per = 1.0 / cycles;
        let periods = (((to - from) as f64 + 0.49) / per).floor();
        if periods < MIN_PERIODS {
            return None;
        }
        let to = from + ((periods * per).round() as usize).min(to - from);
        let len = to - from;
        let kmax = MAX_TEMPLATE_ORDER.min(((0.5 - 1e-9) / cycles).floor() as usize).max(1);
        let npoly = degree + 1;
        let t_scale = to as f64;
        // Per harmonic: Σ y·sin, Σ y·cos, Σ u·sin, Σ u·cos, Σ τ^j·sin, Σ τ^j·cos.
        let sums: Vec<Vec<f64>> = (1..=kmax)
            .into_par_iter()
            .map(|k| {
                let ck = k as f64 * cycles;
                let (ds, dc) = (TAU * (ck - ck.floor())).sin_cos();
                let mut acc = vec![0.0; 4 + 2 * npoly];
                let (mut s, mut c) = (0.0, 1.0);
                for n in from..to {
                    if (n - from) % 512 == 0 {
                        let x = ck * n as f64;
                        (s, c) = (TAU * (x - x.floor())).sin_cos();
                    }
                    let (yn, un) = (y[n], u[n]);
                    acc[0] += yn * s;
                    acc[1] += yn * c;
                    acc[2] += un * s;
                    acc[3] += un * c;
                    let tau = n as f64 / t_scale;
                    let mut p = 1.0;
                    for j in 0..npoly {
                        acc[4 + 2 * j] += p * s;
                        acc[5 + 2 * j] += p * c;
                        p *= tau;
                    }
                    (s, c) = (s * dc + c * ds, c * dc - s * ds);
                }
                acc
            })
            .collect();
        // Poly columns against themselves and the data.
        let mut pp = nalgebra::DMatrix::<f64>::zeros(npoly, npoly);
        let mut py = nalgebra::DVector::<f64>::zeros(npoly);
        let mut pu = nalgebra::DVector::<f64>::zeros(npoly);
        let (mut uu, mut yy) = (0.0, 0.0);
        // Per trend term: Σ τ^j and Σ τ^2j, for its centred RMS.
        let mut tm = vec![(0.0, 0.0); npoly];
        for n in from..to {
            let tau = n as f64 / t_scale;
            let mut p = vec![1.0; npoly];
            for j in 1..npoly {
                p[j] = p[j - 1] * tau;
            }
            for i in 0..npoly {
                py[i] += p[i] * y[n];
                pu[i] += p[i] * u[n];
                for j in 0..npoly {
                    pp[(i, j)] += p[i] * p[j];
                }
            }
            uu += u[n] * u[n];
            yy += y[n] * y[n];
            for (j, t) in tm.iter_mut().enumerate() {
                t.0 += p[j];
                t.1 += p[j] * p[j];
            }
        }
        // Normal equations: [poly, sin_1, cos_1, …].
        let m = npoly + 2 * kmax;
        let mut g = nalgebra::DMatrix::<f64>::zeros(m, m);
        let mut rhs = nalgebra::DVector::<f64>::zeros(m);
        let mut rhs_u = nalgebra::DVector::<f64>::zeros(m);
        g.view_mut((0, 0), (npoly, npoly)).copy_from(&pp);
        rhs.rows_mut(0, npoly).copy_from(&py);
        rhs_u.rows_mut(0, npoly).copy_from(&pu);
        for (a, acc) in sums.iter().enumerate() {
            let ia = npoly + 2 * a;
            rhs[ia] = acc[0];
            rhs[ia + 1] = acc[1];
            rhs_u[ia] = acc[2];
            rhs_u[ia + 1] = acc[3];
            for j in 0..npoly {
                g[(j, ia)] = acc[4 + 2 * j];
                g[(ia, j)] = acc[4 + 2 * j];
                g[(j, ia + 1)] = acc[5 + 2 * j];
                g[(ia + 1, j)] = acc[5 + 2 * j];
            }
            for b in 0..=a {
                let ib = npoly + 2 * b;
                let (ca, cb) = ((a + 1) as f64 * cycles, (b + 1) as f64 * cycles);
                let (dr, di) = geometric(ca - cb, from, len);
                let (sr, si) = geometric(ca + cb, from, len);
                let ss = 0.5 * (dr - sr);
                let cc = 0.5 * (dr + sr);
                let sc = 0.5 * (si + di); // Σ sin_a cos_b
                let cs = 0.5 * (si - di); // Σ cos_a sin_b
                g[(ia, ib)] = ss;
                g[(ib, ia)] = ss;
                g[(ia + 1, ib + 1)] = cc;
                g[(ib + 1, ia + 1)] = cc;
                g[(ia, ib + 1)] = sc;
                g[(ib + 1, ia)] = sc;
                g[(ia + 1, ib)] = cs;
                g[(ib, ia + 1)] = cs;
            }
        }
        let scale = (0..m).map(|i| g[(i, i)]).fold(0.0, f64::max);
        for i in 0..m {
            g[(i, i)] += 1e-13 * scale;
        }
        let chol = g.cholesky()?;
        // Is the drive periodic? What the harmonics and the trend leave of it.
        let left = uu - chol.solve(&rhs_u).dot(&rhs_u);
        if uu.is_nan() || uu <= 0.0 || left > MAX_DRIVE_APERIODIC.powi(2) * uu {
            return None;
        }
        let coef = chol.solve(&rhs);
        let noise_rms = ((yy - coef.dot(&rhs)).max(0.0) / len as f64).sqrt();
        let trend_rms = (1..npoly)
            .map(|j| {
                let (m1, m2) = (tm[j].0 / len as f64, tm[j].1 / len as f64);
                coef[j].abs() * (m2 - m1 * m1).max(0.0).sqrt()
            })
            .collect();
        let trend_mean = (0..npoly).map(|j| coef[j] * tm[j].0 / len as f64).collect();
        let trend = (0..npoly).map(|j| coef[j] / (t_scale * ts).powi(j as i32)).collect();
        let harmonics = (0..kmax).map(|a| (coef[npoly + 2 * a], coef[npoly + 2 * a + 1])).collect();
        Some(Self { cycles, harmonics, trend, periods, noise_rms, trend_rms, trend_mean, from, to })
    }

    /// The period's value at samples `from..to`, plus the level of a model whose drift has
    /// `degree`: the trend's constant, and the mean of the trend terms above `degree` (what a
    /// fit on the samples would give a model that cannot follow them).
    pub fn values(&self, from: usize, to: usize, degree: usize) -> Vec<f64> {
        let level = self.trend[0] + self.trend_mean.iter().skip(degree + 1).sum::<f64>();
        let mut v = vec![level; to.saturating_sub(from)];
        for (k, &(a, b)) in self.harmonics.iter().enumerate() {
            let ck = (k + 1) as f64 * self.cycles;
            let (ds, dc) = (TAU * (ck - ck.floor())).sin_cos();
            let (mut s, mut c) = (0.0, 1.0);
            for (i, out) in v.iter_mut().enumerate() {
                if i % 512 == 0 {
                    let x = ck * (from + i) as f64;
                    (s, c) = (TAU * (x - x.floor())).sin_cos();
                }
                *out += a * s + b * c;
                (s, c) = (s * dc + c * ds, c * dc - s * ds);
            }
        }
        v
    }

    /// RMS over samples `from..to` (interval `ts`) of the trend terms above `degree`, less
    /// their mean over the averaged samples: what a model of that drift degree, at the
    /// level [`Template::values`] gives it, cannot follow there.
    pub fn unmodelled_trend_rms(&self, degree: usize, from: usize, to: usize, ts: f64) -> f64 {
        let mean: f64 = self.trend_mean.iter().skip(degree + 1).sum();
        let ss: f64 = (from..to)
            .map(|n| {
                let t = n as f64 * ts;
                let v: f64 = (degree + 1..self.trend.len()).map(|j| self.trend[j] * t.powi(j as i32)).sum();
                (v - mean).powi(2)
            })
            .sum();
        (ss / (to - from).max(1) as f64).sqrt()
    }

    /// Samples per period.
    pub fn period(&self) -> f64 {
        1.0 / self.cycles
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_average_period_of_a_periodic_signal_with_trend_and_noise_is_recovered() {
        // 17.3 Hz at 1 kHz: 57.8 samples per period, not a whole number.
        let (f, ts) = (17.3, 1e-3);
        let n = 20_000;
        let th = |k: usize| TAU * f * ts * k as f64;
        let u: Vec<f64> = (0..n).map(|k| th(k).sin()).collect();
        let clean = |k: usize| 0.3 + 2.0 * th(k).sin() - 0.7 * th(k).cos() + 0.2 * (3.0 * th(k)).sin();
        let mut s = 1u64;
        let mut noise = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.1
        };
        let y: Vec<f64> = (0..n).map(|k| clean(k) + 0.05 * k as f64 * ts + noise()).collect();
        let t = Template::new(&u, &y, 1000, n, f, ts, 1).unwrap();
        assert!((t.trend[1] - 0.05).abs() < 2e-3, "{:?}", t.trend);
        // Uniform noise of ±0.05: RMS 0.029; the trend over 19 s: 0.05·19/√12 = 0.27.
        assert!((t.noise_rms - 0.0289).abs() < 1e-3, "{}", t.noise_rms);
        assert!((t.trend_rms[0] - 0.274).abs() < 0.01, "{:?}", t.trend_rms);
        let v = t.values(5000, 5100, 1);
        for (i, vi) in v.iter().enumerate() {
            let want = clean(5000 + i);
            assert!((vi - want).abs() < 5e-3, "{i}: {vi} vs {want}");
        }
        // A drive that is not periodic at f is refused.
        let chirp: Vec<f64> = (0..n).map(|k| (th(k) * (1.0 + 1e-4 * k as f64)).sin()).collect();
        assert!(Template::new(&chirp, &y, 1000, n, f, ts, 0).is_none());
        // Periods that are not whole numbers of samples, and a frequency slightly off.
        for (to, f_est) in [(4990, f), (n, f * (1.0 + 1e-9))] {
            assert!(Template::new(&u, &y, 1000, to, f_est, ts, 0).is_some(), "{to} {f_est}");
        }
    }
}

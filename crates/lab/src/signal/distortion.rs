//! Nonlinear distortion under periodic drives: the lines of whole periods, the best linear
//! approximation (BLA) with its noise and distortion levels, and the output at the lines the
//! drive does not excite.
//!
//! The method is the standard one of frequency-domain system identification (Pintelon and
//! Schoukens, *System Identification: A Frequency Domain Approach*, 2nd ed., chs. 2–4):
//!
//! - **Whole periods in steady state.** The steady window (start-up transient left out,
//!   [`crate::signal::steady`]) is cut into `M` periods of `N` samples; line `k` is the frequency
//!   `k·f0`, `f0 = 1/(N·Ts)`. With a whole number of samples per period each period's DFT
//!   gives the lines exactly; otherwise the lines are fitted jointly by least squares over
//!   all the periods (no leakage between them) and each period's departure from that fit
//!   gives the noise.
//! - **Noise.** The mean over the periods is the line's value; the sample variance over the
//!   periods divided by `M` is the noise variance of that mean ([`Line::noise_var`]).
//! - **Excited lines** are those where the drive's line reaches `periodic.excited_rel` of its
//!   largest and stands `periodic.excited_snr_db` above the drive's own noise. The others are
//!   **non-excited**: at an even line, output there comes from an even nonlinearity (an
//!   asymmetry); at an odd line (an odd multisine's lines left out), from an odd one (a
//!   stiffening, a symmetric hysteresis loop).
//! - **Level** of a set of lines: `10·log10(Σ|Y(k)|² / Σσ²(k))`, the power at those lines
//!   over the power the noise alone would put there, in dB (0 dB: noise only, since the
//!   mean's power holds its noise variance). A level of `periodic.detect_db` or more over at
//!   least `periodic.min_lines` lines is distortion; the **band** is where single lines stand
//!   `periodic.line_db` above their noise.
//! - **BLA.** `G(k) = Y(k)/U(k)` at the excited lines, averaged over realisations; its noise
//!   variance from the period-to-period variation, and with two or more realisations its
//!   total variance from the realisation-to-realisation variation; their difference is the
//!   variance of the stochastic nonlinear distortion ([`BlaLine::distortion_var`]). With one
//!   realisation the distortion at an excited line is estimated from the non-excited lines
//!   around it.

use crate::rules::{PeriodicRules, Rules};
use crate::signal::analysis;
use crate::signal::steady::whole_periods_in;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

/// One line of a record: the drive's and the output's complex amplitudes (mean over the
/// periods; `amp·e^{jφ}` of `amp·cos(2π k f0 t + φ)` from the first analysed sample) and
/// their noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Line {
    /// The line (multiple of `f0`).
    pub k: u32,
    /// Its frequency (Hz).
    pub freq_hz: f64,
    /// The drive's mean (V).
    pub u: Complex<f64>,
    /// The output's mean (µm).
    pub y: Complex<f64>,
    /// Noise variance of the drive's mean (V²).
    pub u_noise_var: f64,
    /// Noise variance of the output's mean (µm²).
    pub noise_var: f64,
    /// Whether the drive excites it.
    pub excited: bool,
}

/// The lines of one record (one realisation).
#[derive(Clone, Debug, PartialEq)]
pub struct Lines {
    /// Line spacing `f0` (Hz).
    pub f0_hz: f64,
    /// Samples per period.
    pub period: f64,
    /// Whole periods used.
    pub periods: usize,
    /// Lines `1..=kmax`.
    pub lines: Vec<Line>,
}

/// A period within this fraction of a whole number of samples is one.
const WHOLE_SAMPLES: f64 = 1e-9;

/// Complex amplitudes of the lines `1..=kmax` of each period of `x` (whole periods of
/// `period` samples from sample 0): the mean over the periods and the noise variance of the
/// mean. `None` with fewer than two periods.
fn period_lines(x: &[f64], period: f64, kmax: u32, r: &Rules) -> Option<(Vec<Complex<f64>>, Vec<f64>)> {
    let m = whole_periods_in(x.len(), period, r.drive.period_slack_samples);
    if m < 2 || kmax == 0 {
        return None;
    }
    let n_int = period.round() as usize;
    let kmax = kmax as usize;
    let mut per: Vec<Vec<Complex<f64>>> = Vec::with_capacity(m);
    if (period - n_int as f64).abs() < WHOLE_SAMPLES * period {
        // Whole samples per period: each period's DFT.
        let fft = FftPlanner::new().plan_fft_forward(n_int);
        for p in 0..m {
            let mut buf: Vec<Complex<f64>> =
                x[p * n_int..(p + 1) * n_int].iter().map(|&v| Complex::new(v, 0.0)).collect();
            fft.process(&mut buf);
            // x = Σ amp cos(θ + φ) ⇒ X[k] = (N/2)·amp·e^{jφ}.
            per.push((1..=kmax.min(n_int / 2)).map(|k| buf[k] * (2.0 / n_int as f64)).collect());
        }
    } else {
        // A period between samples: the lines fitted jointly over all the periods, then each
        // period's departure from that fit projected on the lines.
        let kmax = kmax.min(r.periodic.max_fitted_lines as usize).min((period / 2.0).floor() as usize - 1);
        let len = (m as f64 * period).round() as usize;
        let w = std::f64::consts::TAU / period;
        let mean = joint_fit(&x[..len], w, kmax)?;
        let fitted: Vec<f64> = (0..len)
            .map(|i| {
                mean.iter()
                    .enumerate()
                    .map(|(j, c)| (c * Complex::from_polar(1.0, w * ((j + 1) * i) as f64)).re)
                    .sum()
            })
            .collect();
        let constant = analysis::mean(&x[..len]) - analysis::mean(&fitted);
        for p in 0..m {
            let (a, b) = ((p as f64 * period).round() as usize, ((p + 1) as f64 * period).round() as usize);
            let e: Vec<f64> = (a..b).map(|i| x[i] - fitted[i] - constant).collect();
            let row = (1..=kmax)
                .map(|k| {
                    let s: Complex<f64> = e
                        .iter()
                        .enumerate()
                        .map(|(i, &v)| v * Complex::from_polar(1.0, -w * (k * (a + i)) as f64))
                        .sum();
                    mean[k - 1] + s * (2.0 / e.len() as f64)
                })
                .collect();
            per.push(row);
        }
    }
    let kk = per[0].len();
    let mut mean = vec![Complex::new(0.0, 0.0); kk];
    for row in &per {
        for (a, b) in mean.iter_mut().zip(row) {
            *a += b / m as f64;
        }
    }
    let var = (0..kk)
        .map(|k| per.iter().map(|row| (row[k] - mean[k]).norm_sqr()).sum::<f64>() / ((m - 1) * m) as f64)
        .collect();
    Some((mean, var))
}

/// Least squares of `x` on a constant and `cos/sin(w·k·i)`, `k = 1..=kmax`: the complex
/// amplitudes `a_k − j·b_k` of `a_k cos + b_k sin`.
fn joint_fit(x: &[f64], w: f64, kmax: usize) -> Option<Vec<Complex<f64>>> {
    let cols = 2 * kmax + 1;
    let mut ata = nalgebra::DMatrix::<f64>::zeros(cols, cols);
    let mut atb = nalgebra::DVector::<f64>::zeros(cols);
    let mut row = vec![0.0; cols];
    for (i, &v) in x.iter().enumerate() {
        row[0] = 1.0;
        for k in 1..=kmax {
            let (s, c) = (w * (k * i) as f64).sin_cos();
            row[2 * k - 1] = c;
            row[2 * k] = s;
        }
        for a in 0..cols {
            atb[a] += row[a] * v;
            for b in 0..=a {
                ata[(a, b)] += row[a] * row[b];
            }
        }
    }
    for a in 0..cols {
        for b in 0..a {
            ata[(b, a)] = ata[(a, b)];
        }
    }
    let c = ata.cholesky()?.solve(&atb);
    Some((1..=kmax).map(|k| Complex::new(c[2 * k - 1], -c[2 * k])).collect())
}

/// The lines `1..=kmax` of the drive `u` and the output `y` (whole periods of `period`
/// samples from sample 0, at interval `ts`), with the excited lines marked. `None` with
/// fewer than two periods.
pub fn lines(u: &[f64], y: &[f64], period: f64, ts: f64, kmax: u32, r: &Rules) -> Option<Lines> {
    let n = u.len().min(y.len());
    let (um, uv) = period_lines(&u[..n], period, kmax, r)?;
    let (ym, yv) = period_lines(&y[..n], period, kmax, r)?;
    let top = um.iter().map(|c| c.norm()).fold(0.0, f64::max);
    let f0 = 1.0 / (period * ts);
    let lines = (0..um.len().min(ym.len()))
        .map(|i| {
            let a = um[i].norm();
            let excited =
                a >= r.periodic.excited_rel * top && a * a >= db_ratio(r.periodic.excited_snr_db) * uv[i];
            Line {
                k: i as u32 + 1,
                freq_hz: (i + 1) as f64 * f0,
                u: um[i],
                y: ym[i],
                u_noise_var: uv[i],
                noise_var: yv[i],
                excited,
            }
        })
        .collect();
    Some(Lines {
        f0_hz: f0,
        period,
        periods: whole_periods_in(n, period, r.drive.period_slack_samples),
        lines,
    })
}

fn db_ratio(db: f64) -> f64 {
    10f64.powf(db / 10.0)
}

fn to_db(ratio: f64) -> f64 {
    10.0 * ratio.max(1e-30).log10()
}

/// Odd or even lines.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Parity {
    /// Odd multiples of `f0`.
    Odd,
    /// Even multiples of `f0`.
    Even,
}

impl Parity {
    /// Whether line `k` has this parity.
    pub fn has(self, k: u32) -> bool {
        (k % 2 == 1) == (self == Parity::Odd)
    }

    /// "odd", "even".
    pub fn as_str(self) -> &'static str {
        match self {
            Parity::Odd => "odd",
            Parity::Even => "even",
        }
    }
}

/// The level of a set of lines over their noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Level {
    /// `10·log10(Σ|Y|²/Σσ²)` (dB above the noise; about 0 for noise alone).
    pub db: f64,
    /// Lines counted.
    pub lines: usize,
    /// RMS of the lines (µm): `√(Σ|Y|²/2)`.
    pub rms_um: f64,
    /// The band `[lo, hi]` (Hz) of the lines that stand `periodic.line_db` above their
    /// noise, if any.
    pub band_hz: Option<[f64; 2]>,
    /// Whether the lines hold distortion: `periodic.detect_db` over at least
    /// `periodic.min_lines` lines.
    pub detected: bool,
}

/// Lines of realisations within this many Hz are one line.
const SAME_LINE_HZ: f64 = 1e-9;

/// The level of `lines` (their output `y` against their noise), pooled over realisations:
/// `sets` holds each realisation's lines.
pub fn level(sets: &[&[Line]], r: &PeriodicRules) -> Level {
    let (mut p, mut v, mut count) = (0.0, 0.0, 0usize);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut per_line: Vec<(f64, f64, f64)> = vec![];
    for set in sets {
        for l in set.iter() {
            p += l.y.norm_sqr();
            v += l.noise_var;
            count += 1;
            per_line.push((l.freq_hz, l.y.norm_sqr(), l.noise_var));
        }
    }
    // A line's band membership from its power summed over realisations.
    per_line.sort_by(|a, b| a.0.total_cmp(&b.0));
    for chunk in per_line.chunk_by(|a, b| (a.0 - b.0).abs() < SAME_LINE_HZ) {
        let (pp, vv) = chunk.iter().fold((0.0, 0.0), |(a, b), l| (a + l.1, b + l.2));
        if pp >= db_ratio(r.line_db) * vv.max(1e-300) {
            lo = lo.min(chunk[0].0);
            hi = hi.max(chunk[0].0);
        }
    }
    let realisations = sets.len().max(1) as f64;
    let db = if count > 0 { to_db(p / v.max(1e-300)) } else { f64::NAN };
    let lines = count / sets.len().max(1);
    Level {
        db,
        lines,
        rms_um: (p / realisations / 2.0).sqrt(),
        band_hz: (lo <= hi).then_some([lo, hi]),
        detected: lines >= r.min_lines && db >= r.detect_db,
    }
}

/// The non-excited lines of `parity` from line 1 up to `k_top`.
pub fn non_excited(l: &Lines, parity: Parity, k_top: u32) -> Vec<Line> {
    l.lines.iter().filter(|x| !x.excited && parity.has(x.k) && x.k <= k_top).copied().collect()
}

/// The lines where odd and even distortion are looked for: up to three times the highest
/// excited line (`periodic.distortion_top_factor`: a cubic term's reach) and below
/// `drive.nyquist_fraction` of the sample rate.
pub fn distortion_top(l: &Lines, ts: f64, r: &Rules) -> u32 {
    let top = l.lines.iter().filter(|x| x.excited).map(|x| x.k).max().unwrap_or(1);
    let nyq = (r.drive.nyquist_fraction / ts / l.f0_hz).floor() as u32;
    (r.periodic.distortion_top_factor * top).min(nyq).min(l.lines.len() as u32)
}

/// The drive excites only odd lines (a symmetric triangle, an odd multisine): its even
/// lines are free to show even distortion and its odd lines left out, odd distortion.
pub fn odd_drive(l: &Lines) -> bool {
    l.lines.iter().filter(|x| x.excited).all(|x| x.k % 2 == 1)
}

/// One line of the best linear approximation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlaLine {
    /// The line.
    pub k: u32,
    /// Frequency (Hz).
    pub freq_hz: f64,
    /// `G = Y/U` (µm/V), averaged over realisations.
    pub g: Complex<f64>,
    /// Noise variance of `G` (from the period-to-period variation).
    pub noise_var: f64,
    /// Total variance of `G` (from the realisation-to-realisation variation; `None` with one
    /// realisation).
    pub total_var: Option<f64>,
    /// Variance of the stochastic nonlinear distortion of `G` (total − noise, at least 0;
    /// with one realisation, from the non-excited lines nearby).
    pub distortion_var: f64,
}

/// The BLA at the excited lines common to every realisation (see the module docs). With
/// one realisation the distortion variance at a line is the mean output power of the
/// non-excited lines (both parities) within `periodic.bla_neighbour_lines` of it, over
/// `|U|²`.
pub fn bla(sets: &[Lines], r: &PeriodicRules) -> Vec<BlaLine> {
    let Some(first) = sets.first() else { return vec![] };
    let n_sets = sets.len();
    let mut out = vec![];
    for (i, l0) in first.lines.iter().enumerate() {
        if !sets.iter().all(|s| s.lines.get(i).is_some_and(|l| l.excited)) {
            continue;
        }
        let gs: Vec<Complex<f64>> = sets.iter().map(|s| s.lines[i].y / s.lines[i].u).collect();
        let g = gs.iter().sum::<Complex<f64>>() / n_sets as f64;
        let noise_var = sets
            .iter()
            .map(|s| {
                let l = &s.lines[i];
                let u2 = l.u.norm_sqr().max(1e-300);
                l.noise_var / u2 + l.y.norm_sqr() * l.u_noise_var / (u2 * u2)
            })
            .sum::<f64>()
            / (n_sets * n_sets) as f64;
        let total_var = (n_sets >= 2)
            .then(|| gs.iter().map(|x| (x - g).norm_sqr()).sum::<f64>() / ((n_sets - 1) * n_sets) as f64);
        let distortion_var = match total_var {
            Some(t) => (t - noise_var).max(0.0) * n_sets as f64,
            None => {
                let near: Vec<&Line> = first
                    .lines
                    .iter()
                    .filter(|x| !x.excited && x.k.abs_diff(l0.k) <= r.bla_neighbour_lines)
                    .collect();
                if near.is_empty() {
                    0.0
                } else {
                    let p = near.iter().map(|x| (x.y.norm_sqr() - x.noise_var).max(0.0)).sum::<f64>()
                        / near.len() as f64;
                    p / l0.u.norm_sqr().max(1e-300)
                }
            }
        };
        out.push(BlaLine { k: l0.k, freq_hz: l0.freq_hz, g, noise_var, total_var, distortion_var });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::LazyLock;

    static R: LazyLock<Rules> = LazyLock::new(Rules::default);
    use crate::signal::excitation::{Multisine, triangle};

    fn noise(seed: &mut u64) -> f64 {
        // Sum of uniforms: roughly normal, unit variance.
        (0..12)
            .map(|_| {
                *seed ^= *seed << 13;
                *seed ^= *seed >> 7;
                *seed ^= *seed << 17;
                (*seed >> 11) as f64 / (1u64 << 53) as f64
            })
            .sum::<f64>()
            - 6.0
    }

    /// `y = u + a2·u² + a3·u³ + noise` through a one-pole filter.
    fn system(u: &[f64], a2: f64, a3: f64, sigma: f64, seed: u64) -> Vec<f64> {
        let mut s = seed | 1;
        let mut z = 0.0;
        u.iter()
            .map(|&v| {
                z = 0.7 * z + 0.3 * (v + a2 * v * v + a3 * v * v * v);
                z + sigma * noise(&mut s)
            })
            .collect()
    }

    #[test]
    fn odd_and_even_distortion_land_on_their_lines() {
        let ms = Multisine::odd_random_phase(512, 1, 60, 4, 5);
        let u = ms.signal(1.0, 8);
        let ts = 1e-3;
        for (a2, a3, odd, even) in
            [(0.0, 0.0, false, false), (0.0, 0.1, true, false), (0.1, 0.0, false, true)]
        {
            let y = system(&u, a2, a3, 1e-3, 3);
            let l = lines(&u[512..], &y[512..], 512.0, ts, 200, &R).unwrap();
            assert!(odd_drive(&l));
            assert_eq!(l.lines.iter().filter(|x| x.excited).count(), ms.lines.len());
            let top = distortion_top(&l, ts, &R);
            let lo = level(&[&non_excited(&l, Parity::Odd, top)], &R.periodic);
            let le = level(&[&non_excited(&l, Parity::Even, top)], &R.periodic);
            assert_eq!((lo.detected, le.detected), (odd, even), "a2 {a2} a3 {a3}: odd {lo:?} even {le:?}");
            if !odd {
                assert!(lo.db.abs() < 3.0, "{lo:?}");
            }
        }
    }

    #[test]
    fn the_bla_of_a_linear_system_is_its_response_and_noise_is_measured() {
        let ms = Multisine::odd_random_phase(400, 1, 40, 4, 2);
        let ts = 1e-3;
        let sets: Vec<Lines> = (0..3)
            .map(|r| {
                let u = ms.realisation(100 + r).signal(1.0, 10);
                let y = system(&u, 0.0, 0.0, 1e-2, 7 + r);
                lines(&u[400..], &y[400..], 400.0, ts, 100, &R).unwrap()
            })
            .collect();
        let g = bla(&sets, &R.periodic);
        assert_eq!(g.len(), ms.lines.len());
        for b in &g {
            let z = Complex::from_polar(1.0, -std::f64::consts::TAU * f64::from(b.k) / 400.0);
            let truth = Complex::new(0.3, 0.0) / (Complex::new(1.0, 0.0) - 0.7 * z);
            let err = (b.g - truth).norm_sqr();
            assert!(err < 25.0 * b.noise_var, "line {}: {} vs {truth}, noise var {}", b.k, b.g, b.noise_var);
            assert!(b.total_var.is_some());
        }
        // Noise: σ² per sample gives E|Y|² = 4σ²/(N·M) at a line of the mean.
        let l = &sets[0];
        let expected = 4.0 * 1e-4 / (400.0 * 9.0);
        let mean_var = l.lines.iter().map(|x| x.noise_var).sum::<f64>() / l.lines.len() as f64;
        assert!((mean_var / expected - 1.0).abs() < 0.2, "{mean_var} vs {expected}");
    }

    #[test]
    fn a_period_between_samples_is_fitted_without_leakage() {
        // A triangle of 137.4 samples per period: its even lines stay at the noise.
        let period = 137.4;
        let ts = 1e-3;
        let n = (30.0 * period) as usize;
        let u: Vec<f64> = (0..n)
            .map(|k| {
                let x = (k as f64 / period + 0.25).fract();
                if x < 0.5 { 4.0 * x - 1.0 } else { 3.0 - 4.0 * x }
            })
            .collect();
        let y = system(&u, 0.0, 0.05, 1e-3, 11);
        let l = lines(&u, &y, period, ts, 40, &R).unwrap();
        assert!(odd_drive(&l), "{:?}", l.lines.iter().filter(|x| x.excited).map(|x| x.k).collect::<Vec<_>>());
        let le = level(&[&non_excited(&l, Parity::Even, 40)], &R.periodic);
        assert!(!le.detected, "{le:?}");
        let y2 = system(&u, 0.05, 0.05, 1e-3, 11);
        let l2 = lines(&u, &y2, period, ts, 40, &R).unwrap();
        assert!(level(&[&non_excited(&l2, Parity::Even, 40)], &R.periodic).detected);
        // The integer-period path agrees with the triangle generator.
        let t = triangle(1.0, 100, 1000);
        let lt = lines(&t, &t, 100.0, ts, 10, &R).unwrap();
        // (The sampled triangle's line 1 holds its aliased harmonics 99, 101, …: 1e-4 of it.)
        assert!((lt.lines[0].u.norm() - 8.0 / std::f64::consts::PI.powi(2)).abs() < 1e-3);
    }
}

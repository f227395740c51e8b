//! Signal analysis for records: drive frequency, harmonic decomposition, spectra, RMS.
//!
//! Harmonics are measured by least-squares projection on `sin`/`cos` at `k·f` over a
//! window holding a whole number of drive periods, where those functions are (nearly)
//! orthogonal, so each harmonic is measured without leakage from the others.

use rayon::prelude::*;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;
use std::f64::consts::TAU;

/// One sinusoidal component `amp·sin(2π f t + phase)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tone {
    /// Frequency (Hz).
    pub freq_hz: f64,
    /// Peak amplitude.
    pub amp: f64,
    /// Phase (rad) of the sine at `t = 0` (sample 0 of the analysed slice).
    pub phase: f64,
}

/// Root mean square.
pub fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

/// RMS of `a - b`.
pub fn rms_diff(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n == 0 {
        return 0.0;
    }
    (a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / n as f64).sqrt()
}

/// The smallest and the largest value of `x` (`(∞, −∞)` when empty; NaN values skipped).
pub fn extent(x: &[f64]) -> (f64, f64) {
    x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)))
}

/// The fit percentage `100·(1 − ‖y − ŷ‖/‖y − ȳ‖)`: 100 % a perfect model, 0 % no better
/// than the mean, negative worse; `NaN` for a constant `y`.
pub fn fit_pct(y: &[f64], yhat: &[f64]) -> f64 {
    let m = mean(y);
    let den = y.iter().map(|v| (v - m) * (v - m)).sum::<f64>().sqrt();
    let num = y.iter().zip(yhat).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
    if den > 0.0 { 100.0 * (1.0 - num / den) } else { f64::NAN }
}

/// Mean.
pub fn mean(x: &[f64]) -> f64 {
    if x.is_empty() { 0.0 } else { x.iter().sum::<f64>() / x.len() as f64 }
}

/// The longest prefix of `n` samples holding a whole number of periods of `freq_hz`
/// (at least one period; `n` itself if the record is shorter than one period).
pub fn whole_periods(n: usize, freq_hz: f64, ts: f64) -> usize {
    if freq_hz <= 0.0 {
        return n;
    }
    let per = 1.0 / (freq_hz * ts);
    // Half a sample of slack: a period estimated a hair long must not lose the last period.
    let periods = ((n as f64 + 0.49) / per).floor();
    if periods < 1.0 { n } else { ((periods * per).round() as usize).min(n) }
}

/// The period of `freq_hz` in samples when it is a whole number of them (as a drive
/// generated on the sampling clock has: the periods of `n` samples, cut at whole samples,
/// drift by at most a quarter of a sample from the drive's) and `n` samples hold two.
pub fn whole_sample_period(freq_hz: f64, ts: f64, n: usize) -> Option<usize> {
    let p = 1.0 / (freq_hz * ts);
    let whole = p.round();
    let periods = n as f64 / p;
    (p.is_finite() && whole >= 2.0 && periods >= 2.0 && (p - whole).abs() * periods <= 0.25)
        .then_some(whole as usize)
}

/// The average over the whole periods of `p` samples in `x`, and how many there are.
pub fn average_period(x: &[f64], p: usize) -> (Vec<f64>, usize) {
    let m = x.len() / p.max(1);
    let mut avg = vec![0.0; p];
    for k in 0..m * p {
        avg[k % p] += x[k] / m.max(1) as f64;
    }
    (avg, m)
}

/// What of `x` (its whole periods of `p` samples) neither repeats from period to period nor
/// follows a slow cubic in time: `x` less the least-squares fit of a periodic part (any
/// waveform of `p` samples) plus `t, t², t³`, fitted jointly (the polynomial's own periodic
/// part taken out first; detrending first would pass a fast periodic part's projection on the
/// polynomial into the result as "noise"). Its RMS, times `√(m/(m−1))` for `m` periods, is the
/// noise of one period.
pub fn periodic_residual(x: &[f64], p: usize) -> Vec<f64> {
    let m = x.len() / p.max(1);
    let len = m * p;
    let x = &x[..len];
    let without_period = |v: &[f64]| -> Vec<f64> {
        let (avg, _) = average_period(v, p);
        v.iter().enumerate().map(|(k, a)| a - avg[k % p]).collect()
    };
    let e0 = without_period(x);
    if m < 2 {
        return e0;
    }
    let half = (len.max(2) - 1) as f64 / 2.0;
    let basis: Vec<Vec<f64>> = (1..=3)
        .map(|j| without_period(&(0..len).map(|k| ((k as f64 - half) / half).powi(j)).collect::<Vec<_>>()))
        .collect();
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atb = nalgebra::Vector3::<f64>::zeros();
    for i in 0..3 {
        for j in 0..3 {
            ata[(i, j)] = basis[i].iter().zip(&basis[j]).map(|(a, b)| a * b).sum();
        }
        atb[i] = basis[i].iter().zip(&e0).map(|(a, b)| a * b).sum();
    }
    let Some(c) = ata.lu().solve(&atb) else { return e0 };
    (0..len).map(|k| e0[k] - (0..3).map(|j| c[j] * basis[j][k]).sum::<f64>()).collect()
}

/// The component of `x` at `freq_hz` (sample 0 is `t = 0`), by least squares on
/// `sin`, `cos` and a constant (exact also off whole periods, and under an offset: a
/// unipolar drive's mean leaks into a tone fitted without one).
pub fn tone(x: &[f64], freq_hz: f64, ts: f64) -> Tone {
    let (a, b, _) = tone_fit(x, freq_hz, ts);
    // a sin + b cos = amp sin(θ + phase)
    Tone { freq_hz, amp: (a * a + b * b).sqrt(), phase: b.atan2(a) }
}

/// Least-squares `a sin + b cos + m` at `freq_hz`, and the energy the tone explains beyond the
/// constant (`a·Σx̃ sin + b·Σx̃ cos` with `x̃` the data less its mean; unlike the amplitude,
/// it is largest exactly at a pure tone's frequency).
fn tone_fit(x: &[f64], freq_hz: f64, ts: f64) -> (f64, f64, f64) {
    let w = TAU * freq_hz * ts;
    // Four rotating phasors, one per sample of a group of four (independent chains the CPU
    // runs side by side), each turned by 4ω per group and re-anchored every 1024 samples.
    const L: usize = 4;
    let (dw_s, dw_c) = (L as f64 * w).sin_cos();
    let [mut ss, mut cc, mut sc, mut xs, mut xc, mut s1, mut c1] = [[0.0; L]; 7];
    let (mut s, mut c) = ([0.0f64; L], [1.0f64; L]);
    let groups = x.len() / L;
    for (g, chunk) in x.chunks_exact(L).enumerate() {
        if (g * L) % 1024 == 0 {
            for j in 0..L {
                (s[j], c[j]) = (w * (g * L + j) as f64).sin_cos();
            }
        }
        for j in 0..L {
            let v = chunk[j];
            ss[j] += s[j] * s[j];
            cc[j] += c[j] * c[j];
            sc[j] += s[j] * c[j];
            xs[j] += v * s[j];
            xc[j] += v * c[j];
            s1[j] += s[j];
            c1[j] += c[j];
            (s[j], c[j]) = (s[j] * dw_c + c[j] * dw_s, c[j] * dw_c - s[j] * dw_s);
        }
    }
    let sum = |a: [f64; L]| a.iter().sum::<f64>();
    let (mut ss, mut cc, mut sc, mut xs, mut xc, mut s1, mut c1) =
        (sum(ss), sum(cc), sum(sc), sum(xs), sum(xc), sum(s1), sum(c1));
    for (k, &v) in x.iter().enumerate().skip(groups * L) {
        let (s, c) = (w * k as f64).sin_cos();
        ss += s * s;
        cc += c * c;
        sc += s * c;
        xs += v * s;
        xc += v * c;
        s1 += s;
        c1 += c;
    }
    let n = x.len() as f64;
    if n == 0.0 {
        return (0.0, 0.0, 0.0);
    }
    // The constant eliminated: the 2×2 normal equations of the tone on the data less its mean.
    let x1 = x.iter().sum::<f64>();
    let (ss, cc, sc) = (ss - s1 * s1 / n, cc - c1 * c1 / n, sc - s1 * c1 / n);
    let (xs, xc) = (xs - s1 * x1 / n, xc - c1 * x1 / n);
    let det = ss * cc - sc * sc;
    let (a, b) = if det.abs() > 1e-12 * (ss * cc).max(1e-300) {
        ((xs * cc - xc * sc) / det, (xc * ss - xs * sc) / det)
    } else if ss + cc > 0.0 {
        (2.0 * xs / n, 2.0 * xc / n)
    } else {
        (0.0, 0.0)
    };
    (a, b, a * xs + b * xc)
}

/// Adds `tone` to `x`, its sample `k` at time `(k - k0)·ts`: `x[k] += amp·sin(ω(k - k0)ts +
/// phase)`, by a rotating phasor re-anchored every 1024 samples (one `sin_cos` per 1024
/// samples instead of one `sin` per sample).
pub fn add_tone(x: &mut [f64], tone: &Tone, ts: f64, k0: f64) {
    let w = TAU * tone.freq_hz * ts;
    let (dw_s, dw_c) = w.sin_cos();
    let (mut s, mut c) = (0.0f64, 1.0f64);
    for (k, v) in x.iter_mut().enumerate() {
        if k % 1024 == 0 {
            (s, c) = (w * (k as f64 - k0) + tone.phase).sin_cos();
        }
        *v += tone.amp * s;
        (s, c) = (s * dw_c + c * dw_s, c * dw_c - s * dw_s);
    }
}

/// Harmonics `1..=kmax` of `freq_hz` in `x`, measured over whole periods from the start of
/// `x`; harmonics within a bin of Nyquist or above are left out.
pub fn harmonics(x: &[f64], freq_hz: f64, ts: f64, kmax: usize) -> Vec<Tone> {
    let n = whole_periods(x.len(), freq_hz, ts);
    let xs = &x[..n];
    let m = mean(xs);
    let centred: Vec<f64> = xs.iter().map(|v| v - m).collect();
    // One pass over the record per harmonic, the harmonics in parallel; a harmonic within a
    // bin of Nyquist has almost no sine component over the record, and its fit is ill-posed.
    let top = 0.5 / ts - 1.0 / (n.max(1) as f64 * ts);
    let freqs: Vec<f64> = (1..=kmax).map(|k| k as f64 * freq_hz).take_while(|&f| f < top).collect();
    freqs.par_iter().map(|&f| tone(&centred, f, ts)).collect()
}

/// One-sided amplitude spectrum of `x` (Hann window, amplitude-corrected so a sine of
/// amplitude `a` on a bin shows `a`): `(freqs, amplitudes)`.
pub fn spectrum(x: &[f64], ts: f64) -> (Vec<f64>, Vec<f64>) {
    let n = x.len();
    if n < 4 {
        return (vec![], vec![]);
    }
    let m = mean(x);
    let mut buf: Vec<Complex<f64>> = x
        .iter()
        .enumerate()
        .map(|(k, &v)| {
            let w = 0.5 - 0.5 * (TAU * k as f64 / n as f64).cos();
            Complex::new((v - m) * w, 0.0)
        })
        .collect();
    FftPlanner::new().plan_fft_forward(n).process(&mut buf);
    let half = n / 2 + 1;
    let scale = 4.0 / n as f64; // 2/n one-sided, ×2 for the Hann window's coherent gain
    let freqs = (0..half).map(|i| i as f64 / (n as f64 * ts)).collect();
    let amps = buf[..half].iter().map(|c| c.norm() * scale).collect();
    (freqs, amps)
}

/// The bin (from 1) of [`spectrum`]'s largest amplitude, and that amplitude (the last of
/// equal ones); `None` below 4 samples. For an even length, from the FFT of half the length
/// whose real and imaginary parts are the even and odd samples (`X_k = E_k + e^{−2πik/n} O_k`),
/// so a record of 10⁷ samples needs 160 MB for it (the half-length input and output) where
/// the full spectrum took 900.
fn spectrum_peak(x: &[f64]) -> Option<(usize, f64)> {
    let n = x.len();
    if n < 4 || n % 2 == 1 {
        let (_, amps) = spectrum(x, 1.0);
        return amps.iter().copied().enumerate().skip(1).max_by(|a, b| a.1.total_cmp(&b.1));
    }
    let m = mean(x);
    let windowed = |k: usize| (x[k] - m) * (0.5 - 0.5 * (TAU * k as f64 / n as f64).cos());
    let h = n / 2;
    let mut z: Vec<Complex<f64>> =
        (0..h).map(|j| Complex::new(windowed(2 * j), windowed(2 * j + 1))).collect();
    // For lengths like 5·10⁶ = 2⁶·5⁷ the planners choose Bluestein's algorithm, whose tables
    // of 2²⁴ points took 800 MB: a power of two times an odd factor is planned as Good and
    // Thomas' algorithm on the two (no tables of the whole length).
    let mut planner = FftPlanner::new();
    let twos = 1usize << h.trailing_zeros();
    let fft = if twos > 1 && twos < h {
        std::sync::Arc::new(rustfft::algorithm::GoodThomasAlgorithm::new(
            planner.plan_fft_forward(twos),
            planner.plan_fft_forward(h / twos),
        ))
    } else {
        planner.plan_fft_forward(h)
    };
    let mut scratch = vec![Complex::new(0.0, 0.0); fft.get_outofplace_scratch_len()];
    let mut spectrum = vec![Complex::new(0.0, 0.0); h];
    fft.process_outofplace_with_scratch(&mut z, &mut spectrum, &mut scratch);
    drop((scratch, std::mem::take(&mut z)));
    let z = spectrum;
    let scale = 4.0 / n as f64;
    let mut best: Option<(usize, f64)> = None;
    for k in 1..=h {
        let (zk, zc) = (z[k % h], z[h - k].conj());
        let even = 0.5 * (zk + zc);
        let odd = Complex::new(0.0, -0.5) * (zk - zc);
        let a = (even + Complex::from_polar(1.0, -TAU * k as f64 / n as f64) * odd).norm() * scale;
        if best.is_none_or(|(_, b)| a.total_cmp(&b).is_ge()) {
            best = Some((k, a));
        }
    }
    best
}

/// The dominant frequency of `u` (its drive), refined to a small fraction of a bin by
/// maximising the energy a least-squares tone explains around the FFT peak. `None` if `u` has no
/// oscillating component.
pub fn estimate_drive(u: &[f64], ts: f64) -> Option<f64> {
    let (peak, a) = spectrum_peak(u)?;
    if a.is_nan() || a <= 0.0 {
        return None;
    }
    let n = u.len() as f64;
    let df = 1.0 / (n * ts);
    let freqs = |i: usize| i as f64 / (n * ts);
    if let Some(f) = parabolic_peak(u, ts, freqs(peak), df) {
        return Some(f);
    }
    let amp = |f: f64| tone_fit(u, f, ts).2;
    // Golden-section search of the explained energy on [f - df, f + df].
    let (mut lo, mut hi) = ((freqs(peak) - df).max(df * 0.5), freqs(peak) + df);
    let g = 0.618_033_988_749_894_9;
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (amp(x1), amp(x2));
    // Down to GOLDEN_TOL of a bin: the phase this leaves over the whole record is below
    // 2π·GOLDEN_TOL, and the explained energy is flat to rounding closer to its peak.
    while hi - lo > GOLDEN_TOL * df {
        if f1 > f2 {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - g * (hi - lo);
            f1 = amp(x1);
        } else {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + g * (hi - lo);
            f2 = amp(x2);
        }
    }
    Some(0.5 * (lo + hi))
}

/// Most parabolic steps of [`estimate_drive`] before its golden-section search.
pub const PARABOLIC_STEPS: usize = 12;
/// A parabolic step of [`estimate_drive`] this small (in FFT bins) ends it: the phase it leaves
/// over the whole record is below 2π times this.
pub const PARABOLIC_TOL: f64 = 1e-7;

/// [`estimate_drive`] from a frequency known to within a bin of `u`'s (e.g. measured on
/// part of the same drive): the FFT is skipped. Falls back to [`estimate_drive`].
pub fn estimate_drive_near(u: &[f64], ts: f64, near_hz: f64) -> Option<f64> {
    let df = 1.0 / (u.len() as f64 * ts);
    parabolic_peak(u, ts, near_hz, df).or_else(|| estimate_drive(u, ts))
}

/// Parabolic steps on the energy a tone explains (smooth and concave within a bin of a
/// tone's frequency), from `f` with the record's bin `df`: a few passes over the record
/// instead of a golden-section search's dozens. `None` if they do not settle.
fn parabolic_peak(u: &[f64], ts: f64, f: f64, df: f64) -> Option<f64> {
    let amp = |f: f64| tone_fit(u, f, ts).2;
    let mut f = f;
    let mut d = 0.25 * df;
    for _ in 0..PARABOLIC_STEPS {
        if f - d <= 0.0 || !f.is_finite() {
            return None;
        }
        let (a, b, c) = (amp(f - d), amp(f), amp(f + d));
        let curvature = a - 2.0 * b + c;
        // Concave (and not NaN) or no step.
        if curvature.is_nan() || curvature >= 0.0 {
            return None;
        }
        let step = 0.5 * d * (a - c) / curvature;
        if step.abs() > d {
            // Not bracketed yet: walk one spacing uphill.
            f += d * step.signum();
            continue;
        }
        f += step;
        if step.abs() <= PARABOLIC_TOL * df {
            return Some(f);
        }
        d = (2.0 * step.abs()).clamp(PARABOLIC_TOL * df, d);
    }
    None
}

/// Width (in FFT bins) at which [`estimate_drive`]'s golden-section search stops.
pub const GOLDEN_TOL: f64 = 1e-8;

/// The dominant odd harmonic (order ≥ 3, below Nyquist) of `x`, if it holds at least
/// `min_share` of `x`'s power and has an amplitude of at least `min_amp`.
pub fn dominant_odd_harmonic(x: &[f64], f: f64, ts: f64, min_share: f64, min_amp: f64) -> Option<(u32, f64)> {
    let power = rms(x).powi(2);
    let kmax = ((0.5 / ts) / f).floor() as usize;
    harmonics(x, f, ts, kmax.min(40))
        .iter()
        .enumerate()
        .map(|(i, t)| ((i + 1) as u32, t.amp))
        .filter(|(n, _)| n % 2 == 1 && *n >= 3)
        .map(|(n, amp)| (n, amp * amp / 2.0 / power.max(1e-300), amp))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .filter(|&(_, share, amp)| share >= min_share && amp >= min_amp)
        .map(|(n, share, _)| (n, share))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The peak from half the FFT is the full spectrum's: its bin and its amplitude.
    #[test]
    fn spectrum_peak_is_the_spectrums_largest_bin() {
        let mut r = 0x2545_F491_4F6C_DD1Du64;
        let mut noise = || {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            (r >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for (n, f) in [(1000, 23.0), (4096, 7.3), (6000, 23.0), (999, 11.0), (10_000, 0.5), (5, 100.0)] {
            let x: Vec<f64> =
                (0..n).map(|k| (TAU * f * k as f64 * 1e-3).sin() + 0.1 * noise() + 3.0).collect();
            let (_, amps) = spectrum(&x, 1e-3);
            let (k, a) = spectrum_peak(&x).unwrap();
            let (k0, a0) =
                amps.iter().copied().enumerate().skip(1).max_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
            assert_eq!(k, k0, "n {n}, f {f}");
            assert!((a - a0).abs() <= 1e-12 * a0, "n {n}, f {f}: {a} against {a0}");
        }
        assert_eq!(spectrum_peak(&[1.0, 2.0, 3.0]), None);
    }

    fn signal(n: usize, ts: f64, parts: &[(f64, f64, f64)]) -> Vec<f64> {
        (0..n).map(|k| parts.iter().map(|&(f, a, p)| a * (TAU * f * k as f64 * ts + p).sin()).sum()).collect()
    }

    #[test]
    fn harmonics_are_measured_without_leakage() {
        let ts = 1e-3;
        let x = signal(10_000, ts, &[(23.0, 20.0, 0.3), (69.0, 4.0, -1.0), (115.0, 0.5, 2.0)]);
        let h = harmonics(&x, 23.0, ts, 5);
        assert!((h[0].amp - 20.0).abs() < 1e-9 && (h[0].phase - 0.3).abs() < 1e-9);
        assert!((h[2].amp - 4.0).abs() < 1e-9 && (h[2].phase + 1.0).abs() < 1e-9);
        assert!((h[4].amp - 0.5).abs() < 1e-9);
        assert!(h[1].amp < 1e-9 && h[3].amp < 1e-9);
    }

    #[test]
    fn drive_frequency_is_found_between_bins() {
        let ts = 1e-3;
        // A pure drive is found to a tiny fraction of the 0.14 Hz bin…
        let x = signal(7_000, ts, &[(23.37, 1.0, 0.0)]);
        let f = estimate_drive(&x, ts).unwrap();
        assert!((f - 23.37).abs() < 1e-7, "{f}");
        // …and a second tone biases it only slightly.
        let x = signal(7_000, ts, &[(23.37, 1.0, 0.0), (70.11, 0.2, 1.0)]);
        let f = estimate_drive(&x, ts).unwrap();
        assert!((f - 23.37).abs() < 2e-4, "{f}");
        assert_eq!(estimate_drive(&vec![1.0; 1000], ts), None);
    }

    #[test]
    fn spectrum_shows_amplitudes() {
        let ts = 1e-3;
        let x = signal(4_000, ts, &[(50.0, 3.0, 0.0)]);
        let (f, a) = spectrum(&x, ts);
        let i = a.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).unwrap().0;
        assert!((f[i] - 50.0).abs() < 1e-9);
        assert!((a[i] - 3.0).abs() < 0.01, "{}", a[i]);
    }
}

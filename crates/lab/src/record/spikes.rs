//! Isolated spikes in a measured output, and their repair.
//!
//! A laser triangulation or a capacitive sensor that loses its target for a sample or two
//! reads far from its neighbours (often at its rail), and so does a serial logger that drops
//! a byte. Fifteen such samples of 20–60 µm in a 10 s record at 1 kHz weigh 1.5 µm RMS: more
//! than the 3rd harmonic of a bimorph at 14 Hz, which the diagnosis then missed, calling
//! the spikes the record's noise floor.
//!
//! A sample `y[k]` is a spike when it departs by more than the threshold both from
//! - the cubic through its neighbours `y[k−2], y[k−1], y[k+1], y[k+2]`,
//!   `(−y[k−2] + 4y[k−1] + 4y[k+1] − y[k+2])/6`, which follows a smooth output to within
//!   10⁻⁴ of its amplitude at 40 samples per period (a median would cut its peaks), and
//! - the median of the five samples `y[k−2..=k+2]`, which ignores up to two spikes among
//!   them and does not move at a step (the output of a stiff actuator under a square drive
//!   jumps between two samples: the cubic departs there, the median does not).
//!
//! The output must be smooth about it: the cubic's departures 3 to 8 samples away are
//! [`LOCAL_FACTOR`] times smaller. The threshold is the larger of [`SPIKE_SIGMAS`] times
//! the robust spread of the cubic's departures (1.4826 times their median absolute value:
//! the noise, quantisation included) and [`SPIKE_SPAN_REL`] of the output's span (a dropout
//! reads far off; the output's own kink where the drive steps off departs by about 1 %, and
//! is left alone). The largest departures first, a spike is a run of
//! one or two samples (at most [`MAX_RUN`]) whose replacement leaves its neighbourhood
//! smooth: the samples beside it within the threshold of their own neighbours' cubic. A run
//! no such replacement smooths (three samples or more, a ringing that alternates from
//! sample to sample) is something the output does. The four samples a run is filled from
//! must be clean: their cubic reaches the sample just beyond them on each side to within
//! [`EXTRAPOLATION_FACTOR`] thresholds. More than [`MAX_SHARE`] of the samples is not
//! a few dropouts, and nothing is repaired. A spike is replaced by the cubic through the
//! two clean samples on each side of its run.

/// A spike departs by this many times the robust spread of the cubic's departures.
pub const SPIKE_SIGMAS: f64 = 10.0;
/// …and by at least this fraction of the output's span (0.1 % to 99.9 % quantiles): a dropout
/// reads far off; a kink where the drive steps off departs from the cubic by about 1 %.
pub const SPIKE_SPAN_REL: f64 = 0.03;
/// A spike departs by this many times the median departure 3 to 8 samples about it (a
/// ringing mode near Nyquist after a step departs as much all about it).
pub const LOCAL_FACTOR: f64 = 4.0;
/// The cubic a spike is filled from reaches the samples just beyond its four to within this
/// many thresholds.
pub const EXTRAPOLATION_FACTOR: f64 = 4.0;
/// Longest run of consecutive samples taken as one spike.
pub const MAX_RUN: usize = 2;
/// Largest share of the samples that may be spikes for them to be repaired.
pub const MAX_SHARE: f64 = 0.01;

/// Spikes found in a signal and repaired.
#[derive(Clone, Debug, PartialEq)]
pub struct Spikes {
    /// The samples replaced.
    pub indices: Vec<usize>,
    /// The largest departure of a replaced sample from its replacement.
    pub max_departure: f64,
    /// The smallest.
    pub min_departure: f64,
}

/// Finds the isolated spikes of `y` (see the module docs) and replaces them in place.
/// `None` when there are none, or too many to be dropouts (then `y` is unchanged).
pub fn repair(y: &mut [f64]) -> Option<Spikes> {
    let n = y.len();
    if n < 16 {
        return None;
    }
    let cubic = |y: &[f64], k: usize| (-y[k - 2] + 4.0 * y[k - 1] + 4.0 * y[k + 1] - y[k + 2]) / 6.0;
    // The median of the departures and the quantiles of y, without a copy of either (a
    // record of 10⁷ samples is 80 MB a copy).
    let spread = 1.4826 * super::select::nth(n - 4, (n - 4) / 2, |i| (y[i + 2] - cubic(y, i + 2)).abs());
    let span = {
        let q = |p: f64| super::select::nth(n, ((p * (n - 1) as f64).round() as usize).min(n - 1), |i| y[i]);
        q(0.999) - q(0.001)
    };
    let threshold = (SPIKE_SIGMAS * spread).max(SPIKE_SPAN_REL * span);
    if threshold.is_nan() || threshold <= 0.0 {
        return None;
    }
    // Off both its neighbours' cubic and their median, where the output is smooth about it:
    // the departure from the median (a dropout's neighbour departs from the cubic, which the
    // dropout pulls, by more than the dropout itself when it is a pair; from the median, by
    // a step of the output at most).
    let off = |y: &[f64], k: usize| -> Option<f64> {
        let d = (y[k] - cubic(y, k)).abs();
        if d.is_nan() || d <= threshold {
            return None;
        }
        let dm = (y[k] - median(y[k - 2..=k + 2].to_vec())).abs();
        if dm.is_nan() || dm <= threshold {
            return None;
        }
        // The cubic's departures 3 to 8 samples away do not involve `y[k]`.
        let around: Vec<f64> = (k.saturating_sub(8)..=k + 8)
            .filter(|&j| j.abs_diff(k) >= 3 && j >= 2 && j + 2 < n)
            .map(|j| (y[j] - cubic(y, j)).abs())
            .collect();
        (d > LOCAL_FACTOR * median(around)).then_some(dm)
    };
    let mut flagged: Vec<(usize, f64)> = (2..n - 2).filter_map(|k| off(y, k).map(|d| (k, d))).collect();
    // A spike flags its neighbours too (on a steep slope, by about one step): three per spike.
    if flagged.is_empty() || flagged.len() as f64 > 3.0 * MAX_SHARE * n as f64 {
        return None;
    }
    // The value each replaced sample had before its first replacement.
    let mut original: std::collections::HashMap<usize, f64> = Default::default();
    flagged.sort_by(|a, b| b.1.total_cmp(&a.1));
    let mut indices = vec![];
    let (mut lo_dep, mut hi_dep) = (f64::INFINITY, 0.0f64);
    for (k, _) in flagged {
        if off(y, k).is_none() {
            continue;
        }
        // The run `[a, b]` through `k` (one sample or a pair) whose replacement by the cubic
        // through the two samples on each side leaves its neighbourhood smooth: the samples
        // beside it within the threshold of their own neighbours' cubic. None does: a run
        // of three or more, a ringing, something the output does.
        let smooth_without = |a: usize, b: usize| -> Option<(f64, Vec<f64>)> {
            if a < 4 || b + 4 >= n {
                return None;
            }
            let xs = [a as f64 - 2.0, a as f64 - 1.0, b as f64 + 1.0, b as f64 + 2.0];
            let ys = [y[a - 2], y[a - 1], y[b + 1], y[b + 2]];
            // The samples it is filled from must be clean: their cubic reaches the samples
            // just beyond them (a dropout among them throws it far off; without this, a
            // dropout pair's neighbours, filled from the pair, looked smooth with it).
            let reach = EXTRAPOLATION_FACTOR * threshold;
            if [a - 3, b + 3].iter().any(|&j| (y[j] - lagrange(&xs, &ys, j as f64)).abs() > reach) {
                return None;
            }
            let fill: Vec<f64> = (a..=b).map(|i| lagrange(&xs, &ys, i as f64)).collect();
            let at = |i: usize| if (a..=b).contains(&i) { fill[i - a] } else { y[i] };
            // The samples on either side (not two away: another dropout 4 samples off would
            // keep both from being repaired).
            let worst = [a - 1, b + 1]
                .into_iter()
                .map(|j| {
                    let c = (-at(j - 2) + 4.0 * at(j - 1) + 4.0 * at(j + 1) - at(j + 2)) / 6.0;
                    (at(j) - c).abs()
                })
                .fold(0.0, f64::max);
            (worst <= threshold).then_some((worst, fill))
        };
        // The sample alone if that smooths it, else the pair that smooths it most.
        let Some((a, (_, fill))) = smooth_without(k, k).map(|f| (k, f)).or_else(|| {
            [(k - 1, k), (k, k + 1)]
                .into_iter()
                .filter_map(|(a, b)| smooth_without(a, b).map(|f| (a, f)))
                .min_by(|x, y| x.1.0.total_cmp(&y.1.0))
        }) else {
            continue;
        };
        for (i, v) in fill.into_iter().enumerate() {
            let d = (*original.entry(a + i).or_insert(y[a + i]) - v).abs();
            lo_dep = lo_dep.min(d);
            hi_dep = hi_dep.max(d);
            y[a + i] = v;
            indices.push(a + i);
        }
    }
    if indices.is_empty() || indices.len() as f64 > MAX_SHARE * n as f64 {
        for (k, v) in original {
            y[k] = v;
        }
        return None;
    }
    indices.sort_unstable();
    indices.dedup();
    Some(Spikes { indices, max_departure: hi_dep, min_departure: lo_dep })
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The polynomial through the four points `(xs, ys)`, at `x`.
fn lagrange(xs: &[f64; 4], ys: &[f64; 4], x: f64) -> f64 {
    (0..4)
        .map(|i| {
            let w: f64 = (0..4).filter(|&j| j != i).map(|j| (x - xs[j]) / (xs[i] - xs[j])).product();
            w * ys[i]
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    /// A 23 Hz sine of 28 µm at 1 kHz with 10 nm of deterministic "noise".
    fn bimorph_like(n: usize) -> Vec<f64> {
        (0..n)
            .map(|k| {
                28.0 * (TAU * 23.0 * k as f64 * 1e-3).sin() + 0.01 * ((k * 7919 % 101) as f64 / 50.0 - 1.0)
            })
            .collect()
    }

    #[test]
    fn dropouts_of_one_and_two_samples_are_repaired() {
        let clean = bimorph_like(10_000);
        let mut y = clean.clone();
        // Two of them four samples apart.
        for (k, h) in [
            (1000, 40.0),
            (2345, -25.0),
            (5000, 60.0),
            (7001, 30.0),
            (7002, 31.0),
            (8000, 20.0),
            (8004, -30.0),
        ] {
            y[k] += h;
        }
        let s = repair(&mut y).expect("spikes found");
        assert_eq!(s.indices, vec![1000, 2345, 5000, 7001, 7002, 8000, 8004]);
        // Repaired to within the noise of the clean output.
        let worst = y.iter().zip(&clean).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(worst < 0.05, "{worst}");
        assert!(s.max_departure > 59.0 && s.min_departure > 19.0, "{s:?}");
    }

    #[test]
    fn smooth_outputs_steps_and_ringing_are_left_alone() {
        let mut y = bimorph_like(10_000);
        assert_eq!(repair(&mut y), None);
        // A stiff actuator under a square drive: jumps between two samples, and a ringing
        // 70 Hz mode after each.
        let mut sq: Vec<f64> = (0..10_000)
            .map(|k| {
                let p = k % 1000;
                let level = if p < 500 { 10.0 } else { -10.0 };
                let since = (p % 500) as f64 * 1e-3;
                level + 3.0 * (-since * 30.0).exp() * (TAU * 70.0 * since).cos()
            })
            .collect();
        let before = sq.clone();
        assert_eq!(repair(&mut sq), None);
        assert_eq!(sq, before);
        // A second mode near Nyquist (0.4 of the sampling rate) rung by a step and decaying:
        // it departs from the cubic all about, not at one sample.
        let mut ring: Vec<f64> = (0..4000)
            .map(|k| {
                let t = k as f64;
                20.0 * (TAU * 0.002 * t).sin() + 0.4 * (-t / 60.0).exp() * (TAU * 0.4 * t).sin()
            })
            .collect();
        assert_eq!(repair(&mut ring), None);
        // Noise everywhere is not spikes; nor is a record too short to judge.
        let mut g = 1u64;
        let mut noise: Vec<f64> = (0..4000)
            .map(|_| {
                g ^= g << 13;
                g ^= g >> 7;
                g ^= g << 17;
                (g >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            })
            .collect();
        assert_eq!(repair(&mut noise), None);
        assert_eq!(repair(&mut [0.0, 100.0, 0.0]), None);
    }

    #[test]
    fn too_many_departures_are_not_dropouts() {
        let mut y = bimorph_like(2000);
        for k in (10..2000).step_by(50) {
            y[k] += 50.0; // 40 of 2000 samples: 2 %
        }
        let before = y.clone();
        assert_eq!(repair(&mut y), None);
        assert_eq!(y, before);
    }
}

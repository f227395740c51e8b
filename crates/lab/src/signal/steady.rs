//! What drives a record, and where it is steady: drive classification ([`classify`]) and
//! the steady window ([`steady_window`]).
//!
//! A record measured on a bench rarely starts with its drive: it may start idle, step onto
//! the drive, change amplitude or offset, end idle, and the actuator rings after each step.
//! Analysis is made on the part where the drive is steady and the output has settled.
//!
//! ## The drive ([`classify`])
//! On the steady part of `u` (mean removed):
//! - [`DriveKind::None`]: its standard deviation is below
//!   `drive.min_std_v`, or it has no oscillating
//!   component;
//! - [`DriveKind::Sine`]: the dominant line `f` holds at least half of the variance, `f` and
//!   its harmonics at least `drive.harmonic_share`, and the harmonic distortion
//!   `√(Σ_{k≥2} A_k²)/A_1` is at most `drive.sine_max_thd` (a sine with some distortion of its
//!   own: an amplifier's);
//! - [`DriveKind::Periodic`]: the same with more distortion (a triangle, a square), or a
//!   repeating waveform whose lowest line holds at least half of the variance;
//! - [`DriveKind::Multisine`]: `u` repeats with a period found by its autocorrelation (at
//!   least `drive.periodic_correlation` at one period), the average period holds at least
//!   `drive.harmonic_share` of the variance, and at least three lines are excited (amplitude at
//!   least `drive.excited_line_rel` of the largest), none holding half of the variance;
//! - [`DriveKind::Aperiodic`]: none of these (a chirp, noise).
//!
//! ## The steady window ([`steady_window`])
//! 1. **Steady drive.** `u` is cut into blocks of the smallest length (from a ladder of
//!    lengths growing by 20 %) over which the peak-to-peak value of the busy blocks is the
//!    same within `window.level_tolerance` for nine tenths of them, and between the first busy
//!    block and the last `window.min_busy_inside` are busy (a square wave's blocks shorter than
//!    its half period sit idle between busy ones); for a periodic drive that is about one
//!    period. Consecutive blocks whose peak-to-peak value and
//!    mid-level agree within `window.level_tolerance` (of the peak-to-peak value) form runs;
//!    idle parts, steps and amplitude changes end a run, and a gradual fade is trimmed off
//!    against the run's median. The longest run is the steady drive. If no block length
//!    gives stable peaks (noise), blocks of 1/32 of the record are compared by their
//!    standard deviation and mean within `window.noise_level_tolerance`.
//! 2. **Edges.** For a periodic drive the run's start is moved back, sample by sample, as
//!    long as one period from there still has the run's level: the start is then within a
//!    fraction of a period of the step onto the drive. The model's free run starts there
//!    ([`Window::drive_on`]).
//! 3. **Start-up transient.** For a periodic drive, the output's periodic part is measured
//!    on the second half of the steady drive and subtracted; each period of what is left,
//!    its own mean and slope removed (slow creep or drift is not a start-up transient), has
//!    an RMS; the output has settled from the first period whose RMS and the next one's are
//!    within `window.settled_factor` times the median of the second half.
//! 4. **Whole periods.** For a periodic drive the window ends after a whole number of
//!    periods from its start.
//!
//! `--window START:END` ([`Window::given`]) replaces 1–3; the end is still cut to whole
//! periods.
//!
//! Every threshold named here is a field of the rules table ([`crate::rules`]), in its
//! `drive` and `window` sections.

use crate::rules::{DriveRules, Rules, WindowRules};
use crate::signal::analysis::{self, Tone};
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;
use std::fmt::Write as _;

/// What kind of drive a record has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveKind {
    /// One sine (with at most `drive.sine_max_thd` distortion of its own).
    Sine,
    /// A periodic waveform that is not a sine (triangle, square, …).
    Periodic,
    /// A sum of sines on the lines of one period (a multisine).
    Multisine,
    /// Not periodic: a chirp, noise.
    Aperiodic,
    /// No drive: `u` is constant.
    None,
}

impl DriveKind {
    /// The JSON name.
    pub fn as_str(self) -> &'static str {
        match self {
            DriveKind::Sine => "sine",
            DriveKind::Periodic => "periodic",
            DriveKind::Multisine => "multisine",
            DriveKind::Aperiodic => "aperiodic",
            DriveKind::None => "none",
        }
    }
}

/// A record's drive, as found in `u`.
#[derive(Clone, Debug, PartialEq)]
pub struct Drive {
    /// The kind.
    pub kind: DriveKind,
    /// Sine and periodic: the fundamental (Hz); multisine: the line spacing `1/period`;
    /// aperiodic: the dominant frequency; none: 0.
    pub freq_hz: f64,
    /// One period in samples (sine, periodic, multisine).
    pub period_samples: Option<f64>,
    /// Sine and periodic: harmonics `1..` of `u` (V), over whole periods.
    pub harmonics: Vec<Tone>,
    /// Sine and periodic: `√(Σ_{k≥2} A_k²)/A_1`.
    pub thd: f64,
    /// Multisine: the excited lines (multiples of `freq_hz`) and their amplitudes (V).
    pub lines: Vec<(u32, f64)>,
    /// Share of `u`'s variance on the lines of the period (0 for aperiodic drives).
    pub periodic_share: f64,
    /// Standard deviation of `u` (V).
    pub std_v: f64,
}

impl Drive {
    /// Whether the drive repeats (sine, periodic, multisine).
    pub fn is_periodic(&self) -> bool {
        matches!(self.kind, DriveKind::Sine | DriveKind::Periodic | DriveKind::Multisine)
    }

    /// The harmonic `k` of a sine or periodic drive relative to its fundamental (0 if not measured).
    pub fn harmonic_rel(&self, k: usize) -> f64 {
        match (self.harmonics.first(), self.harmonics.get(k.wrapping_sub(1))) {
            (Some(h1), Some(hk)) if h1.amp > 0.0 => hk.amp / h1.amp,
            _ => 0.0,
        }
    }

    /// One phrase: "sine 23.000 Hz (own harmonic distortion 0.01 %)", "multisine, period
    /// 1.024 s, 40 excited lines from 0.98 to 48.8 Hz", ….
    pub fn describe(&self) -> String {
        match self.kind {
            DriveKind::Sine => {
                format!("sine {:.3} Hz (own harmonic distortion {:.2} %)", self.freq_hz, 100.0 * self.thd)
            }
            DriveKind::Periodic => format!(
                "periodic, not a sine: fundamental {:.3} Hz, harmonic distortion {:.1} %",
                self.freq_hz,
                100.0 * self.thd
            ),
            DriveKind::Multisine => {
                let (lo, hi) = (
                    self.lines.first().map_or(0, |l| l.0) as f64 * self.freq_hz,
                    self.lines.last().map_or(0, |l| l.0) as f64 * self.freq_hz,
                );
                format!(
                    "multisine: period {:.4} s, {} excited lines from {lo:.3} to {hi:.3} Hz",
                    1.0 / self.freq_hz,
                    self.lines.len()
                )
            }
            DriveKind::Aperiodic => {
                format!("aperiodic (no period found; dominant frequency {:.3} Hz)", self.freq_hz)
            }
            DriveKind::None => format!("none: u is constant (standard deviation {:.2e} V)", self.std_v),
        }
    }
}

/// Harmonics of `f_hz` measured: up to `drive.harmonics`, below `drive.nyquist_fraction` of the sample rate
/// (a tone at Nyquist has no sine component to fit).
pub fn harmonic_count(f_hz: f64, ts: f64, r: &DriveRules) -> usize {
    ((r.nyquist_fraction / ts / f_hz).floor() as usize).clamp(1, r.harmonics)
}

fn variance(x: &[f64]) -> f64 {
    let m = analysis::mean(x);
    x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / x.len().max(1) as f64
}

/// Classifies the drive `u` (sampled at `ts`); see the module docs.
pub fn classify(u: &[f64], ts: f64, r: &Rules) -> Drive {
    classify_near(u, ts, None, &r.drive)
}

/// [`classify`], with the dominant frequency known to within a bin (`near_hz`, e.g. from
/// part of the same drive).
fn classify_near(u: &[f64], ts: f64, near_hz: Option<f64>, r: &DriveRules) -> Drive {
    let var = variance(u);
    let std_v = var.sqrt();
    let none = Drive {
        kind: DriveKind::None,
        freq_hz: 0.0,
        period_samples: None,
        harmonics: vec![],
        thd: 0.0,
        lines: vec![],
        periodic_share: 0.0,
        std_v,
    };
    if std_v < r.min_std_v || u.len() < r.min_samples {
        return none;
    }
    let f_dom = match near_hz {
        Some(f) => analysis::estimate_drive_near(u, ts, f),
        None => analysis::estimate_drive(u, ts),
    };
    let Some(f_dom) = f_dom else { return none };
    // A sine or a periodic waveform whose dominant line is its fundamental.
    let n = analysis::whole_periods(u.len(), f_dom, ts);
    let harmonics = analysis::harmonics(&u[..n], f_dom, ts, harmonic_count(f_dom, ts, r));
    let var_n = variance(&u[..n]).max(1e-300);
    let power = |t: &Tone| t.amp * t.amp / 2.0;
    let fund = harmonics.first().map_or(0.0, power) / var_n;
    let share = harmonics.iter().map(power).sum::<f64>() / var_n;
    let thd = match harmonics.first() {
        Some(h1) if h1.amp > 0.0 => {
            harmonics.iter().skip(1).map(|t| t.amp * t.amp).sum::<f64>().sqrt() / h1.amp
        }
        _ => 0.0,
    };
    if fund >= r.fundamental_share && share >= r.harmonic_share {
        if thd <= r.sine_max_thd {
            return Drive {
                kind: DriveKind::Sine,
                freq_hz: f_dom,
                period_samples: Some(1.0 / (f_dom * ts)),
                harmonics,
                thd,
                lines: vec![],
                periodic_share: share.min(1.0),
                std_v,
            };
        }
        // A triangle's or a square's own harmonics pull the fundamental's tone off its
        // frequency over few periods (a 1 Hz square over 8 s read as 0.998 Hz, and its
        // periods, compared edge against edge, as noise): the period where the drive
        // matches itself best.
        let p = matched_period(u, 1.0 / (f_dom * ts), r).unwrap_or(1.0 / (f_dom * ts));
        let f = 1.0 / (p * ts);
        let n = analysis::whole_periods(u.len(), f, ts);
        let harmonics = analysis::harmonics(&u[..n], f, ts, harmonic_count(f, ts, r));
        let thd = match harmonics.first() {
            Some(h1) if h1.amp > 0.0 => {
                harmonics.iter().skip(1).map(|t| t.amp * t.amp).sum::<f64>().sqrt() / h1.amp
            }
            _ => thd,
        };
        let var_n = variance(&u[..n]).max(1e-300);
        let share = harmonics.iter().map(power).sum::<f64>() / var_n;
        return Drive {
            kind: DriveKind::Periodic,
            freq_hz: f,
            period_samples: Some(p),
            harmonics,
            thd,
            lines: vec![],
            periodic_share: share.min(1.0),
            std_v,
        };
    }
    // A repeating waveform whose dominant line is not its fundamental: a multisine.
    let aperiodic = Drive { kind: DriveKind::Aperiodic, freq_hz: f_dom, ..none.clone() };
    // The first lag whose average period holds the drive: a near-repeat comes first where
    // the lines almost line up (10 and 17 Hz at 0.294 s, the period being 1 s).
    let mean = analysis::mean(u);
    // A lag `p`: whole periods in the record, the average period, the share of the
    // variance it holds.
    struct Average {
        p: usize,
        periods: usize,
        avg: Vec<f64>,
        share: f64,
    }
    let average = |p: usize| -> Option<Average> {
        let periods = u.len() / p.max(1);
        if p < r.min_period_samples || periods < r.min_average_periods {
            return None;
        }
        let mut avg = vec![0.0; p];
        for k in 0..periods * p {
            avg[k % p] += (u[k] - mean) / periods as f64;
        }
        let share = (variance(&avg) / variance(&u[..periods * p]).max(1e-300)).min(1.0);
        (share >= r.harmonic_share).then_some(Average { p, periods, avg, share })
    };
    // Of the lags that hold it, the first as good as the best (a lag a little short of a
    // slow period, as 1.95 s of an amplitude modulation's 2 s, holds most of it too).
    let held: Vec<Average> = autocorrelation_periods(u, r)
        .into_iter()
        .take(r.max_period_candidates)
        .filter_map(|period| average(period.round() as usize))
        .collect();
    let top = held.iter().map(|a| a.share).fold(0.0, f64::max);
    let Some(Average { p, periods, avg, share: periodic_share }) =
        held.into_iter().find(|a| a.share >= top - r.period_share_tie)
    else {
        return aperiodic;
    };
    let mut buf: Vec<Complex<f64>> = avg.iter().map(|&v| Complex::new(v, 0.0)).collect();
    FftPlanner::new().plan_fft_forward(p).process(&mut buf);
    let amps: Vec<f64> = buf[..p / 2 + 1].iter().map(|c| 2.0 * c.norm() / p as f64).collect();
    let max = amps.iter().skip(1).copied().fold(0.0, f64::max);
    let lines: Vec<(u32, f64)> = amps
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(_, a)| **a >= r.excited_line_rel * max)
        .map(|(k, a)| (k as u32, *a))
        .collect();
    let f_base = 1.0 / (p as f64 * ts);
    let first_share = amps.get(1).map_or(0.0, |a| a * a / 2.0) / variance(&avg).max(1e-300);
    // Two tones or more whose common period's own line is weak: a multisine.
    let kind = if lines.len() >= 2 && first_share < r.fundamental_share {
        DriveKind::Multisine
    } else {
        DriveKind::Periodic
    };
    let harmonics = if kind == DriveKind::Periodic {
        analysis::harmonics(&u[..periods * p], f_base, ts, (p / 2).clamp(1, r.harmonics))
    } else {
        vec![]
    };
    let thd = match harmonics.first() {
        Some(h1) if h1.amp > 0.0 => {
            harmonics.iter().skip(1).map(|t| t.amp * t.amp).sum::<f64>().sqrt() / h1.amp
        }
        _ => 0.0,
    };
    Drive {
        kind,
        freq_hz: f_base,
        period_samples: Some(p as f64),
        harmonics,
        thd,
        lines: if kind == DriveKind::Multisine { lines } else { vec![] },
        periodic_share,
        std_v,
    }
}

/// `Σ_k (x[k] − x̄)(x[k + lag] − x̄)` for every lag `0..n`, by one FFT of the record padded
/// to twice its length (no wrap-around).
fn lagged_products(x: &[f64]) -> Vec<f64> {
    let n = x.len();
    let m = analysis::mean(x);
    let len = (2 * n).next_power_of_two();
    let mut buf: Vec<Complex<f64>> = x
        .iter()
        .map(|&v| Complex::new(v - m, 0.0))
        .chain(std::iter::repeat(Complex::new(0.0, 0.0)))
        .take(len)
        .collect();
    let mut planner = FftPlanner::new();
    planner.plan_fft_forward(len).process(&mut buf);
    for c in buf.iter_mut() {
        *c = Complex::new(c.norm_sqr(), 0.0);
    }
    planner.plan_fft_inverse(len).process(&mut buf);
    buf[..n].iter().map(|c| c.re / len as f64).collect()
}

/// The least overlap (periods) of the record with itself at the first period searched.
const MATCH_MIN_OVERLAP: f64 = 0.9;
/// The least overlap (periods) at the multiple of the period searched next.
const MULTIPLE_OVERLAP: f64 = 1.5;
/// Fewer multiples than the period has samples, less this margin: the search within half a
/// sample per period never reaches the next multiple.
const MULTIPLE_MARGIN: f64 = 3.0;

/// The period (samples, to a fraction of a sample) near `p0` at which `x` best matches itself:
/// the lag of least mean squared difference `x[k + P] − x[k]` within
/// ±`drive.period_search_rel` of `p0`, then the same at the largest multiple of it the record
/// holds (its error divided by the multiple), refined between samples by a parabola through
/// the three lags about the least. All lags from one FFT of the record. `None` if the
/// record holds fewer than two periods.
pub fn matched_period(x: &[f64], p0: f64, r: &DriveRules) -> Option<f64> {
    let rel = r.period_search_rel;
    let n = x.len();
    if p0.is_nan() || p0 < 2.0 || (n as f64) < 2.0 * p0 * (1.0 - rel) {
        return None;
    }
    let m = analysis::mean(x);
    let lagged = lagged_products(x);
    // Energies of the first and the last n − lag samples, by prefix sums.
    let mut prefix = Vec::with_capacity(n + 1);
    prefix.push(0.0);
    for &v in x {
        let v = v - m;
        prefix.push(prefix.last().copied().unwrap_or(0.0) + v * v);
    }
    // Mean squared difference at an integer lag (the overlap is at least a period).
    let msd = |lag: usize| -> f64 {
        let over = n - lag;
        let head = prefix[over];
        let tail = prefix[n] - prefix[lag];
        (head + tail - 2.0 * lagged[lag]) / over as f64
    };
    let least = |lo: f64, hi: f64| -> Option<f64> {
        let (lo, hi) = ((lo.floor() as usize).max(1), (hi.ceil() as usize).min(n.saturating_sub(2)));
        let k = (lo..=hi).min_by(|&a, &b| msd(a).total_cmp(&msd(b)))?;
        if k <= 1 || k + 1 >= n {
            return Some(k as f64);
        }
        let (a, b, c) = (msd(k - 1), msd(k), msd(k + 1));
        let curv = a - 2.0 * b + c;
        let shift = if curv > 0.0 { (0.5 * (a - c) / curv).clamp(-0.5, 0.5) } else { 0.0 };
        Some(k as f64 + shift)
    };
    let p1 = least(p0 * (1.0 - rel), (p0 * (1.0 + rel)).min(n as f64 - MATCH_MIN_OVERLAP * p0))?;
    // The largest multiple whose overlap keeps a period and a half, searched within half a
    // sample per period of it (p1 is within half a sample): fewer multiples than the period
    // has samples, so the search never reaches the next multiple.
    let mult = ((n as f64 - MULTIPLE_OVERLAP * p1) / p1).floor().min((p1 - MULTIPLE_MARGIN).floor());
    if mult < 2.0 {
        return Some(p1);
    }
    let at = mult * p1;
    let half = 0.5 * mult + 1.0;
    let pm = least(at - half, at + half)?;
    Some(pm / mult)
}

/// The period (samples, refined between samples) of a repeating signal: the first peak of
/// its normalised autocorrelation, after it has fallen below `drive.correlation_dip`, that
/// reaches `drive.periodic_correlation` and is at least `drive.correlation_peak` of the
/// highest peak up to half the length.
pub fn autocorrelation_period(x: &[f64], r: &DriveRules) -> Option<f64> {
    autocorrelation_periods(x, r).first().copied()
}

/// Every such peak, in order of lag (the candidates for [`autocorrelation_period`]).
pub fn autocorrelation_periods(x: &[f64], r: &DriveRules) -> Vec<f64> {
    let n = x.len();
    if n < r.min_autocorrelation_samples {
        return vec![];
    }
    let lagged = lagged_products(x);
    let c0 = lagged[0];
    if c0.is_nan() || c0 <= 0.0 {
        return vec![];
    }
    let half = n / 2;
    let rho: Vec<f64> = (0..=half).map(|k| lagged[k] / c0 * n as f64 / (n - k) as f64).collect();
    let Some(dip) = rho.iter().position(|&v| v < r.correlation_dip) else { return vec![] };
    let best = rho[dip..].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if best < r.periodic_correlation {
        return vec![];
    }
    (dip.max(1)..half)
        .filter(|&k| rho[k] >= r.correlation_peak * best && rho[k] >= rho[k - 1] && rho[k] >= rho[k + 1])
        .map(|k| {
            // Parabolic refinement of the peak.
            let (a, b, c) = (rho[k - 1], rho[k], rho[k + 1]);
            let denom = a - 2.0 * b + c;
            let shift = if denom.abs() > 1e-300 { (0.5 * (a - c) / denom).clamp(-0.5, 0.5) } else { 0.0 };
            k as f64 + shift
        })
        .collect()
}

/// The part of a record analysed.
#[derive(Clone, Debug, PartialEq)]
pub struct Window {
    /// First sample of the steady drive: the model's free run starts here.
    pub drive_on: usize,
    /// First sample analysed (the output has settled).
    pub start: usize,
    /// One past the last sample analysed.
    pub end: usize,
    /// Whether `--window` gave it.
    pub given: bool,
    /// Why: what was left out at each end.
    pub why: String,
}

impl Window {
    /// `[start, end]` in the record's time (s).
    pub fn seconds(&self, t0: f64, ts: f64) -> [f64; 2] {
        [t0 + self.start as f64 * ts, t0 + self.end as f64 * ts]
    }
}

/// Why a window cannot be used.
#[derive(Clone, Debug, PartialEq)]
pub enum WindowError {
    /// `--window` is outside the record or empty.
    Given {
        /// Start asked (s).
        start_s: f64,
        /// End asked (s).
        end_s: f64,
        /// The record's first time (s).
        t0: f64,
        /// The record's end (s).
        t_end: f64,
    },
    /// No part of the record has a steady drive.
    NoSteadyDrive,
}

impl std::fmt::Display for WindowError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WindowError::Given { start_s, end_s, t0, t_end } => write!(
                f,
                "--window {start_s}:{end_s} is not a part of the record, which runs from {t0} to {t_end} s"
            ),
            WindowError::NoSteadyDrive => {
                write!(f, "no part of the record has a steady drive (u idle throughout)")
            }
        }
    }
}

impl std::error::Error for WindowError {}

/// Peak-to-peak value, mid-level and standard deviation of one block.
#[derive(Clone, Copy, Debug)]
struct Level {
    p2p: f64,
    mid: f64,
    std: f64,
}

fn level(x: &[f64]) -> Level {
    let (lo, hi) = analysis::extent(x);
    Level { p2p: hi - lo, mid: 0.5 * (hi + lo), std: variance(x).sqrt() }
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// How blocks are compared: by peak-to-peak value (periodic drives, blocks of about a
/// period) or by standard deviation (noise).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Compare {
    Peaks,
    Spread,
}

impl Compare {
    fn agree(self, a: Level, b: Level, r: &WindowRules) -> bool {
        match self {
            Compare::Peaks => {
                let s = a.p2p.max(b.p2p);
                (a.p2p - b.p2p).abs() <= r.level_tolerance * s
                    && (a.mid - b.mid).abs() <= r.level_tolerance * s
            }
            Compare::Spread => {
                let s = a.std.max(b.std);
                (a.std - b.std).abs() <= r.noise_level_tolerance * s
                    && (a.mid - b.mid).abs() <= r.noise_level_tolerance * s
            }
        }
    }
    fn size(self, l: &Level) -> f64 {
        match self {
            Compare::Peaks => l.p2p,
            Compare::Spread => l.std,
        }
    }
}

/// The block length and levels of the steady-drive search (step 1 of the module docs): the
/// smallest length at which nine tenths of the neighbouring busy blocks have the same
/// peak-to-peak value and mid-level, and `window.min_busy_inside` of the blocks between the first
/// busy one and the last are busy.
///
/// A block length is tried while the record holds this many blocks of it.
const MIN_BLOCKS: usize = 4;

fn blocks(u: &[f64], r: &WindowRules) -> (usize, Vec<Level>, Compare) {
    let n = u.len();
    let mut w = r.first_block_samples;
    while w <= n / MIN_BLOCKS {
        let levels: Vec<Level> = u.chunks_exact(w).map(level).collect();
        let big = levels.iter().map(|l| l.p2p).fold(0.0, f64::max);
        let busy = |l: &Level| l.p2p >= r.busy_rel * big;
        // Blocks shorter than the drive's flat parts (a square wave's half period) are idle
        // between busy ones: only the busy blocks would be compared, and they agree.
        let busy_inside = match (levels.iter().position(busy), levels.iter().rposition(busy)) {
            (Some(first), Some(last)) => {
                let inside = &levels[first..=last];
                inside.iter().filter(|l| busy(l)).count() as f64 >= r.min_busy_inside * inside.len() as f64
            }
            _ => false,
        };
        let pairs: Vec<bool> = levels
            .windows(2)
            .filter(|p| busy(&p[0]) && busy(&p[1]))
            .map(|p| {
                let s = p[0].p2p.max(p[1].p2p);
                (p[0].p2p - p[1].p2p).abs() <= r.level_tolerance * s
                    && (p[0].mid - p[1].mid).abs() <= r.level_tolerance * s
            })
            .collect();
        if busy_inside
            && pairs.len() >= 2
            && big > 0.0
            && pairs.iter().filter(|&&b| b).count() as f64 >= r.agreeing_pairs * pairs.len() as f64
        {
            return (w, levels, Compare::Peaks);
        }
        w = (w as f64 * r.block_growth).ceil() as usize;
    }
    let w = (n / r.spread_blocks).max(1);
    (w, u.chunks_exact(w).map(level).collect(), Compare::Spread)
}

/// The longest run of steady blocks `[first, last]` and its median level.
fn longest_run(levels: &[Level], cmp: Compare, r: &WindowRules) -> Option<(usize, usize, Level)> {
    let big = levels.iter().map(|l| cmp.size(l)).fold(0.0, f64::max);
    if big.is_nan() || big <= 0.0 {
        return None;
    }
    let busy = |l: &Level| cmp.size(l) >= r.busy_rel * big;
    let mut best: Option<(usize, usize, Level)> = None;
    let mut i = 0;
    while i < levels.len() {
        if !busy(&levels[i]) {
            i += 1;
            continue;
        }
        let mut j = i;
        while j + 1 < levels.len() && busy(&levels[j + 1]) && cmp.agree(levels[j], levels[j + 1], r) {
            j += 1;
        }
        // Trim blocks that depart from the run's median (a gradual fade).
        let (mut a, mut b) = (i, j);
        let mut med = levels[a];
        for _ in 0..64 {
            med = Level {
                p2p: median(levels[a..=b].iter().map(|l| l.p2p).collect()),
                mid: median(levels[a..=b].iter().map(|l| l.mid).collect()),
                std: median(levels[a..=b].iter().map(|l| l.std).collect()),
            };
            let before = (a, b);
            while a < b && !cmp.agree(levels[a], med, r) {
                a += 1;
            }
            while b > a && !cmp.agree(levels[b], med, r) {
                b -= 1;
            }
            if (a, b) == before {
                break;
            }
        }
        if cmp.agree(levels[a], med, r) && best.is_none_or(|(x, y, _)| b - a > y - x) {
            best = Some((a, b, med));
        }
        i = j + 1;
    }
    best
}

/// Levels of the windows `[s, s + w)` for `s` in `from..to` (monotonic deques for the
/// extremes, running sums for the standard deviation).
fn sliding_levels(x: &[f64], w: usize, from: usize, to: usize) -> Vec<Level> {
    use std::collections::VecDeque;
    let end = (to + w - 1).min(x.len());
    if to <= from || end < from + w {
        return vec![];
    }
    let mut maxq: VecDeque<usize> = VecDeque::new();
    let mut minq: VecDeque<usize> = VecDeque::new();
    let mut out = Vec::with_capacity(to - from);
    let shift = x[from];
    let (mut sum, mut sum2) = (0.0, 0.0);
    for k in from..end {
        while maxq.back().is_some_and(|&i| x[i] <= x[k]) {
            maxq.pop_back();
        }
        maxq.push_back(k);
        while minq.back().is_some_and(|&i| x[i] >= x[k]) {
            minq.pop_back();
        }
        minq.push_back(k);
        let v = x[k] - shift;
        sum += v;
        sum2 += v * v;
        if k >= from + w {
            let old = x[k - w] - shift;
            sum -= old;
            sum2 -= old * old;
        }
        if k + 1 >= from + w {
            let s = k + 1 - w;
            while maxq.front().is_some_and(|&i| i < s) {
                maxq.pop_front();
            }
            while minq.front().is_some_and(|&i| i < s) {
                minq.pop_front();
            }
            let (hi, lo) = (x[*maxq.front().unwrap_or(&k)], x[*minq.front().unwrap_or(&k)]);
            let mean = sum / w as f64;
            let var = (sum2 / w as f64 - mean * mean).max(0.0);
            out.push(Level { p2p: hi - lo, mid: 0.5 * (hi + lo), std: var.sqrt() });
        }
    }
    out
}

/// One period from `s` has the steady level: peak-to-peak value, mid-level and standard
/// deviation (over exactly one period, a standard deviation does not depend on the phase).
fn period_agrees(l: Level, steady: Level, r: &WindowRules) -> bool {
    let s = l.p2p.max(steady.p2p);
    (l.p2p - steady.p2p).abs() <= r.level_tolerance * s
        && (l.mid - steady.mid).abs() <= r.level_tolerance * s
        && (l.std - steady.std).abs() <= r.level_tolerance * l.std.max(steady.std)
}

/// The steady window of a record (see the module docs). `given` is `--window` in samples.
pub fn steady_window(
    u: &[f64],
    y: &[f64],
    ts: f64,
    given: Option<(usize, usize)>,
    r: &Rules,
) -> Result<(Window, Drive), WindowError> {
    let n = u.len().min(y.len());
    let slack = r.drive.period_slack_samples;
    if let Some((start, end)) = given {
        let drive = classify(&u[start..end], ts, r);
        let end2 = whole_period_end(start, end, &drive, slack);
        let mut why = String::from("given by --window");
        if end2 < end {
            let _ = write!(why, "; cut to whole periods of the drive at {} s", fmt_s(end2 as f64 * ts));
        }
        return Ok((Window { drive_on: start, start, end: end2, given: true, why }, drive));
    }
    let (mut w, mut levels, cmp) = blocks(&u[..n], &r.window);
    let (mut a, mut b, _) = longest_run(&levels, cmp, &r.window).ok_or(WindowError::NoSteadyDrive)?;
    // The drive, from the run's inner blocks (the outer ones may hold part of a step).
    let inner_of =
        |a: usize, b: usize, w: usize| if b >= a + 2 { ((a + 1) * w, b * w) } else { (a * w, (b + 1) * w) };
    let mut inner = inner_of(a, b, w);
    let mut first = classify(&u[inner.0..inner.1], ts, r);
    if let (true, Some(p), Compare::Peaks) = (first.is_periodic(), first.period_samples, cmp) {
        // Blocks shorter than a period may miss a peak: again with blocks of one period.
        if (w as f64) < p && (p.ceil() as usize) <= n / MIN_BLOCKS {
            w = p.ceil() as usize;
            levels = u[..n].chunks_exact(w).map(level).collect();
            (a, b, _) = longest_run(&levels, cmp, &r.window).ok_or(WindowError::NoSteadyDrive)?;
            inner = inner_of(a, b, w);
            first = classify(&u[inner.0..inner.1], ts, r);
        }
    }
    let (mut on, mut off) = (a * w, (b + 1) * w);
    if b + 1 == levels.len() && cmp == Compare::Spread {
        off = n;
    }
    if let (true, Some(p), Compare::Peaks) = (first.is_periodic(), first.period_samples, cmp) {
        // Edges to within a fraction of a period: one period from there must keep the level.
        let pw = (p.ceil() as usize).max(2);
        let steady = level(&u[inner.0..inner.0 + pw.min(inner.1 - inner.0)]);
        let steady = Level {
            std: median(
                sliding_levels(&u[..n], pw, inner.0, inner.1.saturating_sub(pw).max(inner.0 + 1))
                    .iter()
                    .map(|l| l.std)
                    .collect(),
            ),
            ..steady
        };
        let from = inner.0.saturating_sub(2 * w);
        let lv = sliding_levels(&u[..n], pw, from, inner.0 + 1);
        let mut s = inner.0;
        while s > from && s - 1 - from < lv.len() && period_agrees(lv[s - 1 - from], steady, &r.window) {
            s -= 1;
        }
        on = s;
        let to = (inner.1 + 2 * w).min(n);
        if inner.1 >= pw && to > inner.1 {
            let from_s = inner.1 + 1 - pw;
            let lv = sliding_levels(&u[..n], pw, from_s, to + 1 - pw);
            let mut e = inner.1;
            while e < to && e - inner.1 < lv.len() && period_agrees(lv[e - inner.1], steady, &r.window) {
                e += 1;
            }
            off = e;
        } else {
            off = inner.1;
        }
    }
    let mut why = String::new();
    if on > 0 {
        let _ =
            write!(why, "drive steady from {} s (before: idle or a different drive)", fmt_s(on as f64 * ts));
    } else {
        why.push_str("drive steady from the start");
    }
    if off < n {
        let _ = write!(why, " to {} s (after: idle or a different drive)", fmt_s(off as f64 * ts));
    } else {
        why.push_str(" to the end");
    }
    // Start-up transient of the output.
    let mut start = on;
    // The inner blocks' drive: its frequency is not biased by a partial period at an edge.
    let drive = first;
    if let (true, Some(p)) = (drive.is_periodic(), drive.period_samples) {
        let settled = settling(&y[on..off], ts, &drive, p, r);
        if settled > 0 {
            start = on + settled;
            let _ = write!(
                why,
                "; output settled {} s after that (start-up transient left out)",
                fmt_s(settled as f64 * ts)
            );
        }
    }
    let end = whole_period_end(start, off, &drive, slack);
    if end < off && drive.is_periodic() {
        why.push_str("; whole periods of the drive");
    }
    // The inner blocks' dominant line is within a bin of the window's (a sine's or a periodic
    // drive's fundamental).
    let near = matches!(drive.kind, DriveKind::Sine | DriveKind::Periodic).then_some(drive.freq_hz);
    let drive = classify_near(&u[start..end], ts, near, &r.drive);
    if let (true, Some(p)) = (drive.is_periodic(), drive.period_samples) {
        // A "period" the window does not hold twice is a piece of a drive that does not
        // repeat (a random staircase's one step): the whole record says what it is.
        // A slow drive's record of fewer periods than the blocks need (four of about a
        // period) gives such a piece too: if the whole record repeats, it is the window.
        if ((end - start) as f64) < 2.0 * p {
            let whole = classify(&u[..n], ts, r);
            let why = if whole.is_periodic() {
                "the whole record: its drive repeats over the record only (too few periods to look for a steady part)"
            } else {
                "the whole record: no part of it repeats over two periods"
            };
            let end = whole_period_end(0, n, &whole, slack);
            return Ok((Window { drive_on: 0, start: 0, end, given: false, why: why.to_string() }, whole));
        }
    }
    Ok((Window { drive_on: on, start, end, given: false, why }, drive))
}

/// The end of the longest run of whole periods from `start` (for periodic drives).
/// `slack` samples are allowed (`drive.period_slack_samples`): a period estimated a hair
/// long keeps the last period.
fn whole_period_end(start: usize, end: usize, drive: &Drive, slack: f64) -> usize {
    match (drive.is_periodic(), drive.period_samples) {
        (true, Some(p)) if p > 0.0 => {
            let periods = whole_periods_in(end - start, p, slack) as f64;
            if periods >= 1.0 { (start + (periods * p).round() as usize).min(end) } else { end }
        }
        _ => end,
    }
}

/// Whole periods of `p` samples in `n` samples, with `slack` samples allowed
/// (`drive.period_slack_samples`).
pub fn whole_periods_in(n: usize, p: f64, slack: f64) -> usize {
    ((n as f64 + slack) / p).floor() as usize
}

/// Samples from the start of the steady drive until the output has settled (step 3).
fn settling(y: &[f64], ts: f64, drive: &Drive, p: f64, r: &Rules) -> usize {
    let n = y.len();
    let periods = whole_periods_in(n, p, r.drive.period_slack_samples);
    if periods < r.window.min_settling_periods {
        return 0;
    }
    let at = |i: usize| (i as f64 * p).round() as usize;
    let half = at(periods / 2);
    let tail = &y[half..at(periods)];
    // The periodic part, measured on the second half and extended over the whole run.
    // Over whole-sample periods, the average period: every harmonic, a square's edges too.
    let whole = match drive.kind {
        DriveKind::Multisine => Some(p.round() as usize),
        _ => analysis::whole_sample_period(drive.freq_hz, ts, tail.len()),
    };
    let template: Vec<f64> = match whole {
        Some(pp) => {
            let (avg, _) = analysis::average_period(tail, pp);
            // Align the template's phase: the tail starts at sample `half`.
            (0..n).map(|k| avg[(k + pp - half % pp) % pp]).collect()
        }
        None => {
            let kmax = harmonic_count(drive.freq_hz, ts, &r.drive);
            let mean = analysis::mean(tail);
            let h = analysis::harmonics(tail, drive.freq_hz, ts, kmax);
            let mut t = vec![mean; n];
            for tone in &h {
                analysis::add_tone(&mut t, tone, ts, half as f64);
            }
            t
        }
    };
    let rms: Vec<f64> = (0..periods)
        .map(|i| {
            let (a, b) = (at(i), at(i + 1).min(n));
            let e: Vec<f64> = (a..b).map(|k| y[k] - template[k]).collect();
            analysis::rms(&detrend(&e))
        })
        .collect();
    let reference = median(rms[periods / 2..].to_vec());
    // A floor of part of the output's RMS: a record without noise settles too.
    let floor = r.window.settled_floor_rel * analysis::rms(&detrend(tail));
    let limit = (r.window.settled_factor * reference).max(floor);
    let first = (0..periods.saturating_sub(1)).find(|&i| rms[i] <= limit && rms[i + 1] <= limit).unwrap_or(0);
    at(first)
}

/// Why a record has no response worth analysing.
#[derive(Clone, Debug, PartialEq)]
pub enum NoResponse {
    /// The output does not change.
    Constant {
        /// Its value (µm).
        value_um: f64,
    },
    /// The output takes only a few values: it moves less than the sensor resolves.
    BelowResolution {
        /// Distinct values in the window.
        levels: usize,
        /// The smallest step between them (µm).
        step_um: f64,
    },
    /// The output does not follow the drive.
    Uncorrelated {
        /// Share of the output's variance on the drive's lines (periodic drives) or the
        /// largest correlation between drive and output over the lags tried (others).
        share: f64,
        /// Whether `share` is the variance share (periodic drive).
        periodic: bool,
        /// The least it had to be (`window.min_driven_share` or `window.min_correlation`).
        least: f64,
        /// The longest lag tried (s; aperiodic drives).
        max_lag_s: f64,
    },
}

impl std::fmt::Display for NoResponse {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NoResponse::Constant { value_um } => write!(
                f,
                "no response to analyse: the output is constant ({value_um} µm throughout the window); \
                 is the sensor connected?"
            ),
            NoResponse::BelowResolution { levels, step_um } => write!(
                f,
                "no response to analyse: the output takes only {levels} values {step_um:.3e} µm apart, below what \
                 the sensor resolves"
            ),
            NoResponse::Uncorrelated { share, periodic: true, least, .. } => write!(
                f,
                "no response to analyse: the output does not follow the drive (the drive's frequencies hold {:.1} % \
                 of its variance, less than {:.0} %)",
                100.0 * share,
                100.0 * least
            ),
            NoResponse::Uncorrelated { share, periodic: false, least, max_lag_s } => write!(
                f,
                "no response to analyse: the output does not follow the drive (largest correlation {share:.3} \
                 over lags up to {max_lag_s} s, less than {least})"
            ),
        }
    }
}

impl std::error::Error for NoResponse {}

/// Checks that the output responds to the drive in the window (see [`NoResponse`]).
pub fn check_response(u: &[f64], y: &[f64], ts: f64, drive: &Drive, r: &Rules) -> Result<(), NoResponse> {
    let w = &r.window;
    let (lo, hi) = analysis::extent(y);
    if hi.is_nan() || lo.is_nan() || hi <= lo {
        return Err(NoResponse::Constant { value_um: if lo.is_finite() { lo } else { 0.0 } });
    }
    let mut sorted = y.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted.dedup();
    if sorted.len() < w.min_levels {
        let step_um = sorted.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
        return Err(NoResponse::BelowResolution { levels: sorted.len(), step_um });
    }
    match drive.kind {
        DriveKind::Sine | DriveKind::Periodic => {
            let n = analysis::whole_periods(y.len(), drive.freq_hz, ts);
            let kmax = harmonic_count(drive.freq_hz, ts, &r.drive);
            let h = analysis::harmonics(&y[..n], drive.freq_hz, ts, kmax);
            let share = h.iter().map(|t| t.amp * t.amp / 2.0).sum::<f64>() / variance(&y[..n]).max(1e-300);
            if share < w.min_driven_share {
                return Err(NoResponse::Uncorrelated {
                    share,
                    periodic: true,
                    least: w.min_driven_share,
                    max_lag_s: 0.0,
                });
            }
        }
        DriveKind::Multisine => {
            let p = drive.period_samples.unwrap_or(1.0).round().max(1.0) as usize;
            let share = averaged_period_share(y, p);
            if share < w.min_driven_share {
                return Err(NoResponse::Uncorrelated {
                    share,
                    periodic: true,
                    least: w.min_driven_share,
                    max_lag_s: 0.0,
                });
            }
        }
        DriveKind::Aperiodic => {
            let lags = ((w.max_lag_s / ts) as usize).min((w.max_lag_share * y.len() as f64) as usize);
            let c = max_correlation(u, y, lags);
            if c < w.min_correlation {
                return Err(NoResponse::Uncorrelated {
                    share: c,
                    periodic: false,
                    least: w.min_correlation,
                    max_lag_s: w.max_lag_s,
                });
            }
        }
        DriveKind::None => {}
    }
    Ok(())
}

/// Share of the variance of `x` in its average over periods of `p` samples.
fn averaged_period_share(x: &[f64], p: usize) -> f64 {
    let m = x.len() / p.max(1);
    if m < 2 {
        return 1.0;
    }
    let mut avg = vec![0.0; p];
    for k in 0..m * p {
        avg[k % p] += x[k] / m as f64;
    }
    (variance(&avg) / variance(&x[..m * p]).max(1e-300)).min(1.0)
}

/// The largest `|corr(u[k], y[k + lag])|` for `lag` in `0..=lags`.
fn max_correlation(u: &[f64], y: &[f64], lags: usize) -> f64 {
    let n = u.len().min(y.len());
    let (mu, my) = (analysis::mean(&u[..n]), analysis::mean(&y[..n]));
    let (su, sy) = (variance(&u[..n]).sqrt(), variance(&y[..n]).sqrt());
    if !(su > 0.0 && sy > 0.0) {
        return 0.0;
    }
    let len = (2 * n).next_power_of_two();
    let mut a: Vec<Complex<f64>> =
        (0..len).map(|k| Complex::new(if k < n { u[k] - mu } else { 0.0 }, 0.0)).collect();
    let mut b: Vec<Complex<f64>> =
        (0..len).map(|k| Complex::new(if k < n { y[k] - my } else { 0.0 }, 0.0)).collect();
    let mut planner = FftPlanner::new();
    let fwd = planner.plan_fft_forward(len);
    fwd.process(&mut a);
    fwd.process(&mut b);
    let mut c: Vec<Complex<f64>> = a.iter().zip(&b).map(|(x, y)| x.conj() * y).collect();
    planner.plan_fft_inverse(len).process(&mut c);
    (0..=lags.min(n - 1))
        .map(|l| (c[l].re / len as f64 / (n - l) as f64 / (su * sy)).abs())
        .fold(0.0, f64::max)
}

/// The output's noise floor (µm) in a window and how it was measured: for a periodic
/// drive what does not repeat from period to period (a sine or periodic drive: the output
/// less its harmonics of the drive and a slow cubic trend, or less its average period and
/// the trend over whole-sample periods; a multisine: less its average period), else from the
/// second difference (an upper bound for a smooth output); at least the RMS error `q/√12`
/// of the grid of step `q` the output's values lie on ([`resolution`]: `"quantisation"`).
pub fn noise_floor(y: &[f64], ts: f64, drive: &Drive, r: &Rules) -> (f64, &'static str) {
    let (noise, how) = noise_floor_of_drive(y, ts, drive, &r.drive);
    // A sensor's steps repeat with an output that repeats: they stay out of what differs
    // from period to period, yet no model fits them.
    match resolution(y, &r.window) {
        Some(q) if q / 12f64.sqrt() > noise => (q / 12f64.sqrt(), "quantisation"),
        _ => (noise, how),
    }
}

/// The step of the grid `y`'s values lie on (a sensor's or converter's resolution, µm), if
/// they lie on one: fewer distinct values than `window.grid_max_share` of the samples, every
/// gap between neighbouring values a whole multiple of the smallest (to
/// `window.grid_tolerance` of it).
pub fn resolution(y: &[f64], r: &WindowRules) -> Option<f64> {
    let mut v: Vec<f64> = y.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    v.dedup();
    if v.len() < r.min_levels || v.len() as f64 > r.grid_max_share * y.len() as f64 {
        return None;
    }
    let q = v.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
    let on_grid = v.windows(2).all(|w| {
        let k = (w[1] - w[0]) / q;
        (k - k.round()).abs() <= r.grid_tolerance * k.max(1.0)
    });
    (q > 0.0 && q.is_finite() && on_grid).then_some(q)
}

/// [`noise_floor`] from what does not repeat with the drive alone.
fn noise_floor_of_drive(y: &[f64], ts: f64, drive: &Drive, r: &DriveRules) -> (f64, &'static str) {
    // What does not repeat from one period of `p` samples to the next: every harmonic, the
    // fast ones too (a triangle's corners, a converter's steps at a fraction of the sampling
    // rate), without fitting them.
    let by_average = |x: &[f64], p: usize| {
        let (avg, m) = analysis::average_period(x, p);
        let e: Vec<f64> = (0..m * p).map(|k| x[k] - avg[k % p]).collect();
        // The deviation from a mean of m periods underestimates by √((m−1)/m).
        analysis::rms(&e) * (m as f64 / (m as f64 - 1.0)).sqrt()
    };
    match drive.kind {
        DriveKind::Sine | DriveKind::Periodic => {
            let n = analysis::whole_periods(y.len(), drive.freq_hz, ts);
            // Over whole-sample periods, every harmonic, the fast ones too.
            if let Some(p) = analysis::whole_sample_period(drive.freq_hz, ts, n) {
                let m = (n / p) as f64;
                let e = analysis::periodic_residual(&y[..n], p);
                return (analysis::rms(&e) * (m / (m - 1.0)).sqrt(), "period_to_period");
            }
            let kmax = harmonic_count(drive.freq_hz, ts, r);
            let h = analysis::harmonics(&y[..n], drive.freq_hz, ts, kmax);
            let mut rest: Vec<f64> = y[..n].to_vec();
            for t in &h {
                analysis::add_tone(&mut rest, &Tone { amp: -t.amp, ..*t }, ts, 0.0);
            }
            (analysis::rms(&detrend_cubic(&rest)), "period_to_period")
        }
        DriveKind::Multisine => {
            let p = drive.period_samples.unwrap_or(1.0).round().max(1.0) as usize;
            if y.len() / p >= 2 {
                return (by_average(y, p), "period_to_period");
            }
            (second_difference_noise(y), "second_difference")
        }
        _ => (second_difference_noise(y), "second_difference"),
    }
}

fn second_difference_noise(y: &[f64]) -> f64 {
    if y.len() < 3 {
        return 0.0;
    }
    let d: Vec<f64> = y.windows(3).map(|w| w[2] - 2.0 * w[1] + w[0]).collect();
    analysis::rms(&d) / 6f64.sqrt()
}

/// `x` minus its least-squares cubic in time.
fn detrend_cubic(x: &[f64]) -> Vec<f64> {
    let n = x.len();
    if n < 8 {
        return detrend(x);
    }
    let half = (n - 1) as f64 / 2.0;
    let mut ata = nalgebra::Matrix4::<f64>::zeros();
    let mut atb = nalgebra::Vector4::<f64>::zeros();
    for (k, &v) in x.iter().enumerate() {
        let t = (k as f64 - half) / half;
        let p = nalgebra::Vector4::new(1.0, t, t * t, t * t * t);
        ata += p * p.transpose();
        atb += p * v;
    }
    let Some(c) = ata.cholesky().map(|ch| ch.solve(&atb)) else { return detrend(x) };
    x.iter()
        .enumerate()
        .map(|(k, &v)| {
            let t = (k as f64 - half) / half;
            v - (c[0] + t * (c[1] + t * (c[2] + t * c[3])))
        })
        .collect()
}

/// `x` minus its least-squares line.
fn detrend(x: &[f64]) -> Vec<f64> {
    let n = x.len();
    if n < 3 {
        return vec![0.0; n];
    }
    let mid = (n - 1) as f64 / 2.0;
    let m = analysis::mean(x);
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (k, &v) in x.iter().enumerate() {
        let t = k as f64 - mid;
        sxy += t * (v - m);
        sxx += t * t;
    }
    let slope = sxy / sxx.max(1e-300);
    x.iter().enumerate().map(|(k, &v)| v - m - slope * (k as f64 - mid)).collect()
}

fn fmt_s(x: f64) -> String {
    let s = format!("{x:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// One steady sine of a record that steps through several ([`sine_segments`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SineSegment {
    /// First sample.
    pub start: usize,
    /// One past the last sample.
    pub end: usize,
    /// The sine's frequency (Hz).
    pub freq_hz: f64,
    /// Its amplitude (V).
    pub amplitude_v: f64,
}

/// The steady sines a record steps through (a stepped sine: the same actuator at a series
/// of frequencies or amplitudes in one file), in order; empty unless there are at least
/// two that differ in frequency or amplitude.
///
/// The record is cut into blocks (`drive.segment_blocks` of them, the cut that covers most
/// of the record); each block's drive is classified on its own, and consecutive sine blocks
/// of one frequency (within `drive.segment_freq_tolerance`) and amplitude (within
/// `window.level_tolerance`) make a segment, kept if it spans `drive.min_segment_blocks` or
/// more and `drive.min_segment_periods` whole periods (a sine that changes from block to
/// block, a chirp or a modulation, is no step). The segments must cover
/// `drive.min_segments_share` of the record. A block that straddles a step is not a clean sine, so a
/// segment ends at most a block short of its step.
pub fn sine_segments(u: &[f64], ts: f64, r: &Rules) -> Vec<SineSegment> {
    let (d, tol) = (&r.drive, r.window.level_tolerance);
    let mut best: Vec<SineSegment> = vec![];
    let covered = |v: &[SineSegment]| v.iter().map(|s| s.end - s.start).sum::<usize>();
    for count in d.segment_blocks {
        let w = u.len() / count;
        if w < d.min_segment_block_samples {
            continue;
        }
        let blocks: Vec<Option<(f64, f64)>> = u
            .chunks_exact(w)
            .map(|b| {
                let b = classify(b, ts, r);
                let amp = b.harmonics.first().map_or(0.0, |t| t.amp);
                (b.kind == DriveKind::Sine && amp > 0.0).then_some((b.freq_hz, amp))
            })
            .collect();
        // Runs of blocks of one sine, [first, last + 1), found from the blocks alone.
        let mut runs: Vec<(usize, usize)> = vec![];
        let mut k = 0;
        while k < blocks.len() {
            let Some((f, a)) = blocks[k] else {
                k += 1;
                continue;
            };
            let mut e = k + 1;
            while let Some(Some((f2, a2))) = blocks.get(e) {
                if (f2 - f).abs() > d.segment_freq_tolerance * f || (a2 - a).abs() > tol * a.max(*a2) {
                    break;
                }
                e += 1;
            }
            // A sine that changes from block to block (a chirp, a modulation) is no step.
            if e - k >= d.min_segment_blocks {
                runs.push((k, e));
            }
            k = e;
        }
        if runs == [(0, blocks.len())] {
            // One steady sine throughout: finer cuts only split it further.
            return vec![];
        }
        let run_blocks: usize = runs.iter().map(|(k, e)| e - k).sum();
        if runs.len() < 2 || ((run_blocks * w) as f64) < d.min_segments_share * u.len() as f64 {
            continue;
        }
        // Each run's sine over its whole length, and its periods.
        let segs: Vec<SineSegment> = runs
            .iter()
            .filter_map(|&(k, e)| {
                let (start, end) = (k * w, e * w);
                let c = classify(&u[start..end], ts, r);
                let amp = c.harmonics.first().map_or(0.0, |t| t.amp);
                (c.kind == DriveKind::Sine && (end - start) as f64 * ts * c.freq_hz >= d.min_segment_periods)
                    .then_some(SineSegment { start, end, freq_hz: c.freq_hz, amplitude_v: amp })
            })
            .collect();
        let distinct = segs.windows(2).any(|p| {
            (p[0].freq_hz - p[1].freq_hz).abs() > d.segment_freq_tolerance * p[0].freq_hz
                || (p[0].amplitude_v - p[1].amplitude_v).abs() > tol * p[0].amplitude_v
        });
        let most = covered(&segs) as f64 >= d.min_segments_share * u.len() as f64;
        if segs.len() >= 2 && distinct && most && covered(&segs) > covered(&best) {
            best = segs;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::LazyLock;

    static R: LazyLock<Rules> = LazyLock::new(Rules::default);
    use std::f64::consts::TAU;

    fn sine(n: usize, f: f64, ts: f64, a: f64) -> Vec<f64> {
        (0..n).map(|k| a * (TAU * f * k as f64 * ts).sin()).collect()
    }

    #[test]
    fn kinds_of_drive() {
        let ts = 1e-3;
        let s = sine(5000, 23.0, ts, 1.0);
        let d = classify(&s, ts, &R);
        assert_eq!(d.kind, DriveKind::Sine, "{d:?}");
        // The distortion of a pure sine is what a frequency estimated to ~1e-9 Hz leaves when
        // the whole periods it counts end a sample short (about 1e-5), far below
        // `diagnose::DRIVE_DISTORTION_FLOOR`.
        assert!((d.freq_hz - 23.0).abs() < 1e-6 && d.thd < 1e-4, "{} {}", d.freq_hz, d.thd);
        // A sine with 3 % of its own 3rd harmonic is still a sine, and the 3rd is measured.
        let dist: Vec<f64> =
            (0..5000).map(|k| s[k] + 0.03 * (TAU * 69.0 * k as f64 * ts + 0.4).sin()).collect();
        let d = classify(&dist, ts, &R);
        assert_eq!(d.kind, DriveKind::Sine);
        assert!((d.harmonic_rel(3) - 0.03).abs() < 1e-4, "{}", d.harmonic_rel(3));
        // A triangle and a square are periodic.
        let tri: Vec<f64> = (0..5000)
            .map(|k| (2.0 / std::f64::consts::PI) * (TAU * 7.0 * k as f64 * ts).sin().asin())
            .collect();
        let d = classify(&tri, ts, &R);
        assert_eq!(d.kind, DriveKind::Periodic, "{d:?}");
        assert!((d.freq_hz - 7.0).abs() < 1e-3);
        let sq: Vec<f64> = (0..5000).map(|k| (TAU * 4.0 * k as f64 * ts).sin().signum()).collect();
        assert_eq!(classify(&sq, ts, &R).kind, DriveKind::Periodic);
        // An odd random-phase multisine of period 1024 samples.
        let mut g = 7u64;
        let mut rnd = || {
            g ^= g << 13;
            g ^= g >> 7;
            g ^= g << 17;
            (g >> 11) as f64 / (1u64 << 53) as f64
        };
        let phases: Vec<f64> = (0..40).map(|_| TAU * rnd()).collect();
        let ms: Vec<f64> = (0..8192)
            .map(|k| {
                (0..40).map(|l| (TAU * (2 * l + 1) as f64 * k as f64 / 1024.0 + phases[l]).sin()).sum::<f64>()
                    * 0.1
            })
            .collect();
        let d = classify(&ms, ts, &R);
        assert_eq!(d.kind, DriveKind::Multisine, "{}", d.describe());
        assert_eq!(d.period_samples, Some(1024.0));
        assert_eq!(d.lines.len(), 40);
        assert!(d.lines.iter().all(|l| l.0 % 2 == 1));
        // Two tones, 10 and 17 Hz: their lines almost line up at 0.294 s, but the period is 1 s.
        let two: Vec<f64> = (0..10_000)
            .map(|k| 0.7 * (TAU * 10.0 * k as f64 * ts).sin() + 0.5 * (TAU * 17.0 * k as f64 * ts).sin())
            .collect();
        let d = classify(&two, ts, &R);
        assert_eq!((d.kind, d.period_samples), (DriveKind::Multisine, Some(1000.0)), "{}", d.describe());
        assert_eq!(d.lines.iter().map(|l| l.0).collect::<Vec<_>>(), vec![10, 17]);
        // Noise and a chirp are aperiodic; a constant is none.
        let noise: Vec<f64> = (0..8000).map(|_| rnd() - 0.5).collect();
        assert_eq!(classify(&noise, ts, &R).kind, DriveKind::Aperiodic);
        let chirp: Vec<f64> =
            (0..8000).map(|k| (TAU * (1.0 + 5.0 * k as f64 * ts) * k as f64 * ts).sin()).collect();
        assert_eq!(
            classify(&chirp, ts, &R).kind,
            DriveKind::Aperiodic,
            "{}",
            classify(&chirp, ts, &R).describe()
        );
        assert_eq!(classify(&vec![0.3; 1000], ts, &R).kind, DriveKind::None);
    }

    #[test]
    fn a_unipolar_drive_is_a_pure_sine_over_its_whole_record() {
        // 0–100 V about 50 V, as a piezo stack's amplifier drives it, starting at 0 V: the mean
        // leaked into a tone fitted without a constant (0.985 Hz, 1.6 % "distortion" and an
        // output "settling" for 3 s were read from such a record).
        for (ts, n) in [(1e-4, 100_000), (1e-3, 10_000)] {
            let u: Vec<f64> = (0..n).map(|k| 50.0 - 50.0 * (TAU * 1.0 * k as f64 * ts).cos()).collect();
            let y: Vec<f64> = u.iter().map(|v| 0.15 * v).collect();
            let (w, d) = steady_window(&u, &y, ts, None, &R).unwrap();
            assert_eq!(d.kind, DriveKind::Sine);
            assert!((d.freq_hz - 1.0).abs() < 1e-7 && d.thd < 1e-5, "{} Hz, thd {}", d.freq_hz, d.thd);
            // Every one of the ten periods, the last one too.
            assert_eq!((w.start, w.end), (0, n), "{}", w.why);
        }
    }

    #[test]
    fn a_triangle_s_period_is_where_it_matches_itself() {
        // Its own harmonics pull the fundamental's tone off over few periods (a 1 Hz triangle
        // over 5 s read as 0.999 Hz); over many short periods the multiple searched must not
        // reach the next one (63 samples, 158 periods: 63.4 samples were read).
        let tri = |n: usize, p: f64| -> Vec<f64> {
            (0..n).map(|k| (2.0 / std::f64::consts::PI) * (TAU * k as f64 / p).sin().asin()).collect()
        };
        for (n, p) in [(50_000, 10_000.0), (9_954, 63.0), (9_954, 62.7), (20_000, 1_234.5)] {
            let d = classify(&tri(n, p), 1e-3, &R);
            assert_eq!(d.kind, DriveKind::Periodic);
            let got = d.period_samples.unwrap();
            assert!((got - p).abs() < 1e-3 * p.max(100.0) / 100.0, "{n} samples of {p}: {got}");
        }
    }

    #[test]
    fn a_slow_drive_of_three_periods_is_counted_as_such() {
        // 0.1 Hz over 30 s: blocks of a period are too few to compare (four are needed), and a
        // piece of the slow sine was read as "1 whole period of a 1.174 Hz drive".
        let ts = 1e-3;
        let u = sine(30_000, 0.1, ts, 50.0);
        let y: Vec<f64> = u.iter().map(|v| 0.15 * v).collect();
        let (w, d) = steady_window(&u, &y, ts, None, &R).unwrap();
        assert_eq!(d.kind, DriveKind::Sine);
        assert!((d.freq_hz - 0.1).abs() < 1e-6, "{}", d.freq_hz);
        assert_eq!((w.start, w.end), (0, 30_000), "{}", w.why);
    }

    #[test]
    fn a_random_staircase_is_aperiodic_not_one_step_s_period() {
        // Levels held 0.5 s each: one step's block looked like a period of 2.5 Hz before.
        let ts = 1e-3;
        let mut g = 11u64;
        let u: Vec<f64> = (0..20)
            .flat_map(|_| {
                g = g.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let v = (g >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
                std::iter::repeat_n(v, 500)
            })
            .collect();
        let y: Vec<f64> = u.iter().map(|v| 8.0 * v).collect();
        let (w, drive) = steady_window(&u, &y, ts, None, &R).unwrap();
        assert_eq!(drive.kind, DriveKind::Aperiodic, "{} in {w:?}", drive.describe());
        assert_eq!((w.start, w.end), (0, u.len()));
    }

    #[test]
    fn a_square_wave_is_steady_over_its_whole_drive() {
        // Blocks shorter than a half period sit flat between busy ones: the square waves
        // below were called aperiodic from a window of a few blocks before.
        let ts = 1e-3;
        for (f, seconds, lead) in [(4.0, 10.0, 0), (5.0, 5.0, 0), (23.0, 10.0, 0), (5.0, 10.0, 1500)] {
            let n = (seconds / ts) as usize;
            let mut u = vec![0.0; lead];
            u.extend((0..n).map(|k| (TAU * f * k as f64 * ts).sin().signum()));
            let y: Vec<f64> = u.iter().map(|v| 8.0 * v).collect();
            let (w, drive) = steady_window(&u, &y, ts, None, &R).unwrap();
            assert_eq!(drive.kind, DriveKind::Periodic, "{f} Hz: {}", drive.describe());
            assert!((drive.freq_hz - f).abs() < 1e-2 * f, "{f} Hz: {}", drive.describe());
            let covered = (w.end - w.drive_on) as f64 / n as f64;
            // The edge to within a tenth of a period.
            let edge = (w.drive_on as f64 - lead as f64).abs() * ts * f;
            assert!(covered > 0.9 && edge <= 0.1, "{f} Hz: {w:?}");
        }
    }

    #[test]
    fn idle_lead_in_step_on_and_lead_out_are_left_out() {
        let ts = 1e-3;
        // 3.3 s idle, the drive steps onto a sine at its peak (5 Hz, 1 V), 1 s idle at the end.
        let mut u = vec![0.0; 3300];
        u.extend((0..6000).map(|k| (TAU * 5.0 * k as f64 * ts + 1.5).sin()));
        u.extend(vec![0.0; 1000]);
        // The output rings at 300 Hz after the step, decaying in 0.1 s.
        let y: Vec<f64> = (0..u.len())
            .map(|k| {
                let ring = if k >= 3300 {
                    (-((k - 3300) as f64) * ts / 0.05).exp() * (TAU * 300.0 * k as f64 * ts).sin()
                } else {
                    0.0
                };
                10.0 * u[k] + 5.0 * ring
            })
            .collect();
        let (w, drive) = steady_window(&u, &y, ts, None, &R).unwrap();
        assert_eq!(drive.kind, DriveKind::Sine);
        assert!((3250..3300 + 100).contains(&w.drive_on), "{w:?}");
        assert!(w.start >= 3300 + 150 && w.start < 3300 + 600, "{w:?}");
        assert!(w.end <= 9300 && w.end > 9300 - 200, "{w:?}");
        let periods = (w.end - w.start) as f64 / 200.0;
        assert!((periods - periods.round()).abs() < 1e-9, "{periods}");
        assert!(w.why.contains("drive steady from 3.29"), "{}", w.why);
        assert!(w.why.contains("start-up transient"), "{}", w.why);
    }

    #[test]
    fn an_amplitude_change_keeps_the_longer_level() {
        let ts = 1e-3;
        let mut u = sine(3000, 10.0, ts, 1.0);
        u.extend(sine(6000, 10.0, ts, 2.0));
        let y = u.clone();
        let (w, _) = steady_window(&u, &y, ts, None, &R).unwrap();
        assert!(w.drive_on >= 2950 && w.drive_on <= 3100, "{w:?}");
        assert!(w.end > 8800, "{w:?}");
    }

    #[test]
    fn a_given_window_is_used_as_given_cut_to_whole_periods() {
        let ts = 1e-3;
        let u = sine(5000, 10.0, ts, 1.0);
        let (w, d) = steady_window(&u, &u, ts, Some((1000, 3050)), &R).unwrap();
        assert_eq!((w.drive_on, w.start, w.end), (1000, 1000, 3000));
        assert_eq!(d.kind, DriveKind::Sine);
        assert!(w.given);
    }

    #[test]
    fn a_stepped_sine_is_cut_into_its_steps_and_a_chirp_or_a_modulation_is_not() {
        let ts = 1e-3;
        let sine = |f: f64, a: f64, n: usize| (0..n).map(move |k| a * (TAU * f * k as f64 * ts).sin());
        // Frequencies and amplitudes; the steps found within a block of their true edges.
        let u: Vec<f64> =
            sine(5.0, 1.0, 4000).chain(sine(12.0, 1.0, 4000)).chain(sine(12.0, 2.0, 4000)).collect();
        let segs = sine_segments(&u, ts, &R);
        let got: Vec<(f64, f64)> = segs.iter().map(|s| (s.freq_hz, s.amplitude_v)).collect();
        assert_eq!(segs.len(), 3, "{got:?}");
        for (g, want) in got.iter().zip([(5.0, 1.0), (12.0, 1.0), (12.0, 2.0)]) {
            assert!((g.0 - want.0).abs() < 1e-6 && (g.1 - want.1).abs() < 1e-3, "{got:?}");
        }
        let w = u.len() / 16;
        for (s, (a, b)) in segs.iter().zip([(0, 4000), (4000, 8000), (8000, 12000)]) {
            assert!(s.start >= a && s.start <= a + w && s.end <= b && s.end + w >= b, "{s:?}");
        }
        // One sine, a sine after idle, a chirp and an amplitude modulation: no steps.
        let one: Vec<f64> = sine(23.0, 1.0, 10_000).collect();
        let idle_then: Vec<f64> = std::iter::repeat_n(0.0, 2000).chain(sine(23.0, 1.0, 8000)).collect();
        let chirp: Vec<f64> =
            (0..10_000).map(|k| (TAU * (2.0 + 2.0 * k as f64 * ts) * k as f64 * ts).sin()).collect();
        let am: Vec<f64> = (0..10_000)
            .map(|k| {
                let t = k as f64 * ts;
                (1.0 + 0.5 * (TAU * 0.5 * t).sin()) * (TAU * 20.0 * t).sin()
            })
            .collect();
        for (name, u) in [("one", one), ("idle then", idle_then), ("chirp", chirp), ("am", am)] {
            assert!(sine_segments(&u, ts, &R).is_empty(), "{name}: {:?}", sine_segments(&u, ts, &R));
        }
    }
}

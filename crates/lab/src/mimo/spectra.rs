//! The DFT lines of a [`MimoRecord`]'s period means, and the noise from its periods.
//!
//! For realisation `r` and channel `c`, with `P` periods `x_p[n]` of `N` samples:
//! ```text
//! X_k = Σ_n x̄[n] e^{−i2πkn/N},  x̄ = (1/P) Σ_p x_p          (lines k = 1 … N/2 − 1)
//! σ²_k = (1/(P(P−1))) Σ_p |X_{p,k} − X_k|²                   (noise variance of X_k)
//! ```
//! A line is *excited* when the inputs' power there, summed over channels and realisations,
//! is above [`EXCITED_FRACTION`] of the strongest line's (a multisine that excites only part
//! of the band leaves the other lines at the rounding error, which a median would take as the
//! reference when they are more than half the lines).

use super::MimoError;
use crate::record::mimo::{Level, MimoRecord};
use nalgebra::Complex;
use rustfft::FftPlanner;

/// Complex `f64`.
pub type C64 = Complex<f64>;

/// A line is excited when its input power is above this fraction of the strongest line's
/// (−30 dB).
pub const EXCITED_FRACTION: f64 = 1e-3;

/// The lines of one level.
#[derive(Clone, Debug)]
pub struct LevelSpectra {
    /// The level's tag.
    pub tag: String,
    /// Inputs per realisation, `[r][(k−1)·m + c]` for lines `k = 1 … N/2 − 1`.
    pub u: Vec<Vec<C64>>,
    /// Outputs per realisation, `[r][(k−1)·p + o]`.
    pub y: Vec<Vec<C64>>,
    /// Noise variance of each output line's period mean, `[r][(k−1)·p + o]` (0 with one period).
    pub y_noise: Vec<Vec<f64>>,
    /// Periods averaged.
    pub periods: usize,
    /// The record's realisation index of each kept realisation.
    pub realisations: Vec<usize>,
}

/// The lines of every level of a record.
#[derive(Clone, Debug)]
pub struct Spectra {
    /// Samples per period `N`.
    pub samples: usize,
    /// Inputs `m`.
    pub inputs: usize,
    /// Outputs `p`.
    pub outputs: usize,
    /// Whether line `k` (index `k − 1`) is excited.
    pub excited: Vec<bool>,
    /// Per level.
    pub levels: Vec<LevelSpectra>,
}

impl Spectra {
    /// Number of lines `N/2 − 1` (lines `1 … N/2 − 1`).
    pub fn lines(&self) -> usize {
        self.excited.len()
    }

    /// `z_k = e^{i2πk/N}` of line index `i` (line `k = i + 1`).
    pub fn z(&self, i: usize) -> C64 {
        let w = std::f64::consts::TAU * (i + 1) as f64 / self.samples as f64;
        Complex::new(w.cos(), w.sin())
    }

    /// The spectra of `rec`, with only the realisations `keep(level, r)` of each level.
    pub fn new(rec: &MimoRecord, keep: &dyn Fn(usize, usize) -> bool) -> Result<Self, MimoError> {
        let (m, p, n) = rec.dims();
        if n < 8 || m == 0 || p == 0 {
            return Err(MimoError::Data(format!("{n} samples per period, {m} inputs, {p} outputs")));
        }
        let mut planner = FftPlanner::new();
        let fft = planner.plan_fft_forward(n);
        let lines = n / 2 - 1;
        let dft = |x: &[f64]| -> Vec<C64> {
            let mut buf: Vec<C64> = x.iter().map(|&v| Complex::new(v, 0.0)).collect();
            fft.process(&mut buf);
            buf[1..=lines].to_vec()
        };
        let mut levels = Vec::new();
        for (li, l) in rec.levels.iter().enumerate() {
            levels.push(level_spectra(l, li, keep, &dft, lines)?);
        }
        if levels.iter().all(|l| l.u.is_empty()) {
            return Err(MimoError::Data("no realisation kept".into()));
        }
        let mut power = vec![0.0; lines];
        for l in &levels {
            for u in &l.u {
                for (k, pw) in power.iter_mut().enumerate() {
                    *pw += u[k * m..(k + 1) * m].iter().map(|c| c.norm_sqr()).sum::<f64>();
                }
            }
        }
        let strongest = power.iter().copied().fold(0.0, f64::max);
        if strongest <= 0.0 {
            return Err(MimoError::Data("the inputs are zero".into()));
        }
        let excited = power.iter().map(|&v| v > EXCITED_FRACTION * strongest).collect();
        Ok(Self { samples: n, inputs: m, outputs: p, excited, levels })
    }
}

fn level_spectra(
    l: &Level,
    li: usize,
    keep: &dyn Fn(usize, usize) -> bool,
    dft: &dyn Fn(&[f64]) -> Vec<C64>,
    lines: usize,
) -> Result<LevelSpectra, MimoError> {
    let (m, p, np) = (l.u.channels, l.y.channels, l.u.periods);
    let mut out = LevelSpectra {
        tag: l.tag.clone(),
        u: vec![],
        y: vec![],
        y_noise: vec![],
        periods: np,
        realisations: vec![],
    };
    for r in (0..l.u.realisations).filter(|&r| keep(li, r)) {
        let mut u = vec![Complex::new(0.0, 0.0); lines * m];
        for c in 0..m {
            for (k, v) in dft(&l.u.mean_period(r, c)).into_iter().enumerate() {
                u[k * m + c] = v;
            }
        }
        let mut y = vec![Complex::new(0.0, 0.0); lines * p];
        let mut var = vec![0.0; lines * p];
        for o in 0..p {
            let per: Vec<Vec<C64>> = (0..np).map(|pp| dft(l.y.get(r, pp, o))).collect();
            for k in 0..lines {
                let mean = per.iter().map(|x| x[k]).sum::<C64>() / np as f64;
                y[k * p + o] = mean;
                if np > 1 {
                    let ss: f64 = per.iter().map(|x| (x[k] - mean).norm_sqr()).sum();
                    var[k * p + o] = ss / ((np * (np - 1)) as f64);
                }
            }
        }
        out.u.push(u);
        out.y.push(y);
        out.y_noise.push(var);
        out.realisations.push(r);
    }
    Ok(out)
}

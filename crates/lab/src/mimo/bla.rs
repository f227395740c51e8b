//! The best linear approximation (BLA) of a MIMO system from multisine realisations, its
//! noise and nonlinear-distortion variances, and per output what a linear model leaves.
//!
//! ## Estimate (Pintelon and Schoukens 2012, ch. 3–4; notes/multisine.md)
//! With `m` inputs, realisations come in groups of `m` (realisations `g·m … g·m + m − 1`)
//! whose phases make the `m × m` input matrix `U_g(k) = [U_{g·m}(k) … ]` well conditioned.
//! On each excited line `k`, for each complete group `g` of the kept realisations:
//! ```text
//! G_g(k) = Y_g(k) U_g(k)⁻¹,            G(k) = (1/M) Σ_g G_g(k)
//! σ²_noise(k)[o,j] = (1/M²) Σ_g Σ_r σ²_{Y,r,o}(k) |U_g(k)⁻¹[r,j]|²     (from the periods)
//! σ²_total(k)[o,j] = (1/(M(M−1))) Σ_g |G_g(k)[o,j] − G(k)[o,j]|²        (from the groups, M ≥ 2)
//! σ²_NL(k) = max(σ²_total − σ²_noise, 0)
//! ```
//! ## What a linear model leaves, per output
//! For each kept realisation, `E_r(k) = Y_r(k) − G(k)U_r(k)` on excited lines and `Y_r(k)` on
//! the others (a linear model puts nothing there). Its power over a period in the time domain
//! is `(2/N²) Σ_k |E_r(k)|²`; on excited lines it is scaled by `M/(M−1)` (with `M ≥ 2`), the
//! share of the spread the mean of `M` groups absorbs. The noise of the period mean is
//! `(2/N²) Σ_k σ²_{Y,r}(k)`; the nonlinear distortion is what is left above it.

use super::MimoError;
use super::spectra::{C64, Spectra};
use nalgebra::{Complex, DMatrix};

/// The BLA of one level on the excited lines.
#[derive(Clone, Debug)]
pub struct Bla {
    /// The level's tag.
    pub tag: String,
    /// Line indices (into [`Spectra::excited`]) of the estimate.
    pub lines: Vec<usize>,
    /// `G(k)`, `p × m` per line.
    pub g: Vec<DMatrix<C64>>,
    /// Noise variance of each entry of `G(k)`.
    pub var_noise: Vec<DMatrix<f64>>,
    /// Total variance of each entry (zero with one group).
    pub var_total: Vec<DMatrix<f64>>,
    /// Groups averaged `M`.
    pub groups: usize,
}

/// Per output of one level: RMS over a period (µm) of the output, of what the BLA leaves,
/// of the noise of the period mean and of one period, and of the nonlinear distortion.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputSplit {
    /// The output's RMS.
    pub output_rms: f64,
    /// What the BLA leaves (noise and nonlinear distortion).
    pub linear_leaves_rms: f64,
    /// Noise of the period mean.
    pub noise_rms: f64,
    /// Noise of one period (the floor of a per-period error).
    pub noise_rms_period: f64,
    /// Nonlinear distortion: `√(leaves² − noise²)`.
    pub nonlinear_rms: f64,
}

/// The diagnosis of one level: its BLA and the split per output.
#[derive(Clone, Debug)]
pub struct LevelDiagnosis {
    /// The BLA.
    pub bla: Bla,
    /// Per output.
    pub outputs: Vec<OutputSplit>,
}

/// The BLA of level `li` of `spectra`.
pub fn bla(s: &Spectra, li: usize) -> Result<Bla, MimoError> {
    let l = s.levels.get(li).ok_or_else(|| MimoError::Data(format!("no level {li}")))?;
    let (m, p) = (s.inputs, s.outputs);
    if l.u.is_empty() {
        return Err(MimoError::Data(format!("level {}: no realisation kept", l.tag)));
    }
    // Complete groups of m kept realisations (positions in l.u).
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let max_r = l.realisations.iter().copied().max().unwrap_or(0);
    for g in 0..=max_r / m {
        let members: Option<Vec<usize>> =
            (g * m..(g + 1) * m).map(|r| l.realisations.iter().position(|&x| x == r)).collect();
        if let Some(members) = members {
            groups.push(members);
        }
    }
    if groups.is_empty() {
        return Err(MimoError::Data(format!("level {}: no complete group of {m} realisations", l.tag)));
    }
    let mm = groups.len() as f64;
    let lines: Vec<usize> = (0..s.lines()).filter(|&k| s.excited[k]).collect();
    let mut out = Bla {
        tag: l.tag.clone(),
        lines: lines.clone(),
        g: vec![],
        var_noise: vec![],
        var_total: vec![],
        groups: groups.len(),
    };
    for &k in &lines {
        let mut gs = Vec::with_capacity(groups.len());
        let mut vn = DMatrix::<f64>::zeros(p, m);
        for grp in &groups {
            let u = DMatrix::from_fn(m, m, |c, j| l.u[grp[j]][k * m + c]);
            let y = DMatrix::from_fn(p, m, |o, j| l.y[grp[j]][k * p + o]);
            let ui = u.try_inverse().ok_or(MimoError::Numerical("BLA: singular input matrix of a group"))?;
            for o in 0..p {
                for j in 0..m {
                    vn[(o, j)] +=
                        (0..m).map(|r| l.y_noise[grp[r]][k * p + o] * ui[(r, j)].norm_sqr()).sum::<f64>();
                }
            }
            gs.push(y * ui);
        }
        let mean = gs.iter().fold(DMatrix::<C64>::zeros(p, m), |a, b| a + b) / Complex::new(mm, 0.0);
        let vt = if groups.len() > 1 {
            DMatrix::from_fn(p, m, |o, j| {
                gs.iter().map(|gg| (gg[(o, j)] - mean[(o, j)]).norm_sqr()).sum::<f64>() / (mm * (mm - 1.0))
            })
        } else {
            DMatrix::zeros(p, m)
        };
        out.g.push(mean);
        out.var_noise.push(vn / (mm * mm));
        out.var_total.push(vt);
    }
    Ok(out)
}

/// The BLA of level `li` and, per output, what a linear model leaves, split into noise and
/// nonlinear distortion.
pub fn diagnose_level(s: &Spectra, li: usize) -> Result<LevelDiagnosis, MimoError> {
    let b = bla(s, li)?;
    let l = &s.levels[li];
    let (m, p, n) = (s.inputs, s.outputs, s.samples as f64);
    let scale = 2.0 / (n * n);
    let bias = if b.groups > 1 { b.groups as f64 / (b.groups as f64 - 1.0) } else { 1.0 };
    let mut outputs = Vec::with_capacity(p);
    let nr = l.u.len() as f64;
    let mut line_of = vec![usize::MAX; s.lines()];
    for (i, &k) in b.lines.iter().enumerate() {
        line_of[k] = i;
    }
    for o in 0..p {
        let (mut out_ms, mut left_ms, mut noise_ms) = (0.0, 0.0, 0.0);
        for r in 0..l.u.len() {
            for (k, &li_) in line_of.iter().enumerate() {
                let y = l.y[r][k * p + o];
                out_ms += y.norm_sqr();
                noise_ms += l.y_noise[r][k * p + o];
                if li_ == usize::MAX {
                    left_ms += y.norm_sqr();
                } else {
                    let g = &b.g[li_];
                    let pred: C64 = (0..m).map(|j| g[(o, j)] * l.u[r][k * m + j]).sum();
                    left_ms += bias * (y - pred).norm_sqr();
                }
            }
        }
        let f = scale / nr;
        let (out_ms, left_ms, noise_ms) = (out_ms * f, left_ms * f, noise_ms * f);
        outputs.push(OutputSplit {
            output_rms: out_ms.sqrt(),
            linear_leaves_rms: left_ms.sqrt(),
            noise_rms: noise_ms.sqrt(),
            noise_rms_period: (noise_ms * l.periods as f64).sqrt(),
            nonlinear_rms: (left_ms - noise_ms).max(0.0).sqrt(),
        });
    }
    Ok(LevelDiagnosis { bla: b, outputs })
}

/// The mean of the levels' BLAs on their common lines (the start of one model for all levels).
pub fn mean_bla(blas: &[Bla]) -> Result<Bla, MimoError> {
    let first = blas.first().ok_or_else(|| MimoError::Data("no BLA".into()))?;
    if blas.iter().any(|b| b.lines != first.lines) {
        return Err(MimoError::Shape("the levels' BLAs are on different lines".into()));
    }
    let w = Complex::new(1.0 / blas.len() as f64, 0.0);
    let nw = 1.0 / (blas.len() * blas.len()) as f64;
    let mut out = first.clone();
    out.tag = "mean".into();
    for i in 0..first.lines.len() {
        out.g[i] =
            blas.iter().fold(DMatrix::zeros(first.g[i].nrows(), first.g[i].ncols()), |a, b| a + &b.g[i]) * w;
        out.var_noise[i] = blas
            .iter()
            .fold(DMatrix::zeros(first.g[i].nrows(), first.g[i].ncols()), |a, b| a + &b.var_noise[i])
            * nw;
        out.var_total[i] = blas
            .iter()
            .fold(DMatrix::zeros(first.g[i].nrows(), first.g[i].ncols()), |a, b| a + &b.var_total[i])
            * nw;
    }
    out.groups = blas.iter().map(|b| b.groups).sum();
    Ok(out)
}

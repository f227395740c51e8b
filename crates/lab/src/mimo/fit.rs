//! The whole identification of a [`MimoModel`] from a [`MimoRecord`], across levels.
//!
//! ## Steps ([`fit_structure`])
//! 1. Spectra of the period means of the kept realisations ([`Spectra`]), the BLA of each
//!    level and their mean ([`bla`]).
//! 2. Subspace identification of order `n` from the mean BLA ([`linear::fsid`]).
//! 3. Output-error refinement on every kept realisation of every level at once
//!    ([`linear::refine_oe`]): the **linear model for all levels**.
//! 4. The nonlinear model ([`FitOptions::feedback`], the default): from the linear model of
//!    step 3, the piezos' hysteresis on the inputs, a Bouc–Wen restoring force in feedback on
//!    each mode and each mode's stiffness scheduled by the inputs' envelope, fitted together
//!    by output error in the time domain ([`feedback`]): the **hysteretic model**.
//!
//!    Without it, the open-loop hysteresis branch ([`model`] module docs, used only when
//!    [`FitOptions::input_channels`] or [`FitOptions::mode_channels`] is set): channels on
//!    each input and on each mode's
//!    displacement (of the linear model's own state), each divided by its RMS on the data.
//!    For each candidate shape ([`FitOptions::shapes`], one shape for every channel) the
//!    channels' steady-state loops are simulated and taken to the lines, and
//!    `Θ = [[B, E], [D, F]]` is the least-squares solution over every line `k = 1 … N/2 − 1`
//!    and kept realisation of
//!    ```text
//!    Y_r(k) = Φ(k) Θ V_r(k),   Φ(k) = [C (z_kI − A)⁻¹, I_p],   V_r = [U_r; W_r]
//!    ```
//!    (normal equations `Σ_k Re[(Σ_r V̄_r V_rᵀ) ⊗ Φᴴ Φ] vec Θ = Re vec(Φᴴ Σ_r Y_r V_rᴴ)`), with
//!    `A` and `C` from step 3; the shape with the least cost is kept: the **hysteretic model**.
//!
//! ## Order choice and the score kept apart ([`fit_mimo`])
//! With [`FitOptions::holdout`] = `h`, each candidate order is fitted on the other
//! realisations of every level and scored by [`benchmark_error`] on realisation `h` of every
//! level; the order with the least mean score over the levels (of the hysteretic model, or of
//! the linear one when the branch is off) wins, and its model is kept as fitted (not fitted
//! again on `h`, so its score stays a held-out one). Without `h`, the first order is fitted
//! on every realisation and nothing is scored.
//!
//! ## The benchmark's metric ([`benchmark_error`])
//! Per output, the RMS of `y − ŷ` over each period after its first [`SKIP_SAMPLES`] samples,
//! averaged over periods, realisations and outputs. `ŷ` is simulated from the period's own
//! measured input only, in periodic steady state: the input period is run once from rest
//! as a warm-up ([`Warmup::Periods`]`(1)`; the input is periodic, so this is the state the
//! system is in at the period's start), then once more, scored.

use super::MimoError;
use super::bla::{self, LevelDiagnosis};
use super::feedback::{self, FeedbackOptions, Periods};
use super::hysteresis::Shape;
use super::linear::{self, Mode, OeData, Resolvent};
use super::model::{Branch, Channel, MimoModel, Source, Warmup, advance};
use super::spectra::{C64, Spectra};
use crate::record::mimo::{Level, MimoRecord};
use nalgebra::{Complex, DMatrix, DVector};
use rayon::prelude::*;
use rustfft::FftPlanner;
use std::time::Instant;

/// Samples at the start of each test period that the metric does not score.
pub const SKIP_SAMPLES: usize = 100;

/// Where a fit is.
#[derive(Clone, Debug, PartialEq)]
pub struct Progress {
    /// The step (`"bla"`, `"subspace"`, `"oe"`, `"feedback"`, `"hysteresis"`, `"order"`, `"final"`).
    pub stage: &'static str,
    /// What it did, for a person.
    pub message: String,
}

/// What to fit.
#[derive(Clone, Debug, PartialEq)]
pub struct FitOptions {
    /// Candidate orders of `A` (one: no choice).
    pub orders: Vec<usize>,
    /// Levenberg–Marquardt iterations of the output-error refinement, at most.
    pub lm_iterations: usize,
    /// The modal LFR ([`feedback`]): a Bouc–Wen restoring force in feedback on each mode,
    /// fitted by output error in the time domain (`None`: no loop).
    pub feedback: Option<FeedbackOptions>,
    /// An open-loop hysteresis channel on each input (Hammerstein); used only without
    /// [`Self::feedback`].
    pub input_channels: bool,
    /// A hysteresis channel on each mode's displacement.
    pub mode_channels: bool,
    /// Candidate loop shapes (of the channels scaled to unit RMS).
    pub shapes: Vec<Shape>,
    /// The realisation of every level kept apart from the fit, to choose the order and score
    /// the model (`None`: every realisation fitted, nothing scored).
    pub holdout: Option<usize>,
    /// Weigh each level's squared errors by `1/RMS` of its outputs, so that each level's RMS
    /// error counts alike in the sum of the metric (otherwise the loudest level dominates).
    pub balance_levels: bool,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            orders: vec![28],
            lm_iterations: 10,
            feedback: Some(FeedbackOptions::default()),
            input_channels: false,
            mode_channels: false,
            shapes: vec![Shape::symmetric(0.1), Shape::symmetric(0.3), Shape::symmetric(1.0)],
            holdout: Some(5),
            balance_levels: true,
        }
    }
}

impl FitOptions {
    /// No hysteresis branch: the linear model only.
    pub fn linear(mut self) -> Self {
        self.feedback = None;
        self.input_channels = false;
        self.mode_channels = false;
        self
    }
}

/// The models of one structure fit.
#[derive(Clone, Debug)]
pub struct Fitted {
    /// The linear model for all fitted levels (step 3).
    pub linear: MimoModel,
    /// The hysteretic model (step 4), `None` without channels.
    pub hysteretic: Option<MimoModel>,
    /// RMS (µm) of the linear model's error on the fitted period means (Parseval), with the
    /// level weights of [`FitOptions::balance_levels`] (the quietest level weighs 1).
    pub linear_fit_rms: f64,
}

impl Fitted {
    /// The hysteretic model, or the linear one without a branch.
    pub fn best(&self) -> &MimoModel {
        self.hysteretic.as_ref().unwrap_or(&self.linear)
    }
}

/// The score of one candidate order on the kept-apart realisation.
#[derive(Clone, Debug, PartialEq)]
pub struct OrderScore {
    /// The order.
    pub order: usize,
    /// [`benchmark_error`] of the linear model per level (µm).
    pub linear: Vec<f64>,
    /// The same of the hysteretic model (empty without a branch).
    pub hysteretic: Vec<f64>,
}

/// The result of [`fit_mimo`].
#[derive(Clone, Debug)]
pub struct MimoFit {
    /// The model (hysteretic, or linear without a branch).
    pub model: MimoModel,
    /// The linear model for all levels of the same order.
    pub linear: MimoModel,
    /// The chosen order.
    pub order: usize,
    /// The kept model's and its linear part's benchmark metric per level on the realisation
    /// kept apart ([`FitOptions::holdout`]; `None` without one).
    pub held_out: Option<OrderScore>,
    /// Every candidate order's scores (empty without a realisation kept apart).
    pub order_scores: Vec<OrderScore>,
    /// The BLA diagnosis of each level.
    pub diagnosis: Vec<LevelDiagnosis>,
    /// Wall time of the fit, s.
    pub seconds: f64,
}

/// Identifies one model for every level of `rec` (module docs), reporting through `progress`.
///
/// With [`FitOptions::holdout`] `Some(h)`, realisation `h` of every level is kept apart from
/// every step (the order's choice and the fit) and the model is scored on it with the
/// benchmark's metric ([`MimoFit::held_out`]); with `None` every realisation is fitted and
/// nothing is scored.
pub fn fit_mimo(
    rec: &MimoRecord,
    opts: &FitOptions,
    progress: &(dyn Fn(&Progress) + Sync),
) -> Result<MimoFit, MimoError> {
    let t0 = Instant::now();
    let levels: Vec<usize> = (0..rec.levels.len()).collect();
    let realisations = rec.levels.iter().map(|l| l.u.realisations).min().unwrap_or(0);
    if let Some(h) = opts.holdout {
        if h >= realisations || realisations < 2 {
            return Err(MimoError::Data(format!(
                "realisation {} kept apart, but the record has {realisations} per level (at least 2 to keep one apart)",
                h + 1
            )));
        }
    }
    let all = Spectra::new(rec, &|_, _| true)?;
    let diagnosis = levels.iter().map(|&li| bla::diagnose_level(&all, li)).collect::<Result<Vec<_>, _>>()?;
    progress(&Progress {
        stage: "bla",
        message: format!("BLA of {} levels on {} excited lines", levels.len(), diagnosis[0].bla.lines.len()),
    });
    let keep = |_: usize, r: usize| Some(r) != opts.holdout;
    let score = |f: &Fitted, n: usize, h: usize| -> Result<OrderScore, MimoError> {
        let score = |m: &MimoModel| -> Result<Vec<f64>, MimoError> {
            rec.levels.iter().map(|l| benchmark_error(m, l, &[h])).collect()
        };
        Ok(OrderScore {
            order: n,
            linear: score(&f.linear)?,
            hysteretic: f.hysteretic.as_ref().map(score).transpose()?.unwrap_or_default(),
        })
    };
    let mut order_scores = Vec::new();
    let mut fits = Vec::new();
    if opts.orders.is_empty() {
        return Err(MimoError::Data("no candidate order".into()));
    }
    let orders = if opts.holdout.is_some() { opts.orders.as_slice() } else { &opts.orders[..1] };
    for &n in orders {
        let f = fit_structure(rec, &keep, &levels, n, opts, progress)?;
        if let Some(h) = opts.holdout {
            let s = score(&f, n, h)?;
            progress(&Progress {
                stage: "order",
                message: format!(
                    "order {n}: held out (realisation {}) linear {:?} hysteretic {:?} µm",
                    h + 1,
                    round4(&s.linear),
                    round4(&s.hysteretic)
                ),
            });
            order_scores.push(s);
        }
        fits.push(f);
    }
    let mean = |s: &OrderScore| {
        let v = if s.hysteretic.is_empty() { &s.linear } else { &s.hysteretic };
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let best = (0..fits.len()).min_by(|&a, &b| match (order_scores.get(a), order_scores.get(b)) {
        (Some(x), Some(y)) => mean(x).total_cmp(&mean(y)),
        _ => std::cmp::Ordering::Equal,
    });
    let i = best.unwrap_or(0);
    let f = fits.swap_remove(i);
    let order = orders[i];
    let held_out = order_scores.get(i).cloned();
    progress(&Progress {
        stage: "final",
        message: format!("order {order} kept; the whole fit took {:.1} s", t0.elapsed().as_secs_f64()),
    });
    Ok(MimoFit {
        model: f.best().clone(),
        linear: f.linear,
        order,
        held_out,
        order_scores,
        diagnosis,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

fn round4(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| (x * 1e4).round() / 1e4).collect()
}

/// Steps 1–4 of the module docs at order `n`, on the realisations `keep(level, r)` of `levels`.
pub fn fit_structure(
    rec: &MimoRecord,
    keep: &(dyn Fn(usize, usize) -> bool + Sync),
    levels: &[usize],
    n: usize,
    opts: &FitOptions,
    progress: &(dyn Fn(&Progress) + Sync),
) -> Result<Fitted, MimoError> {
    let t0 = Instant::now();
    let sp = Spectra::new(rec, &|li, r| levels.contains(&li) && keep(li, r))?;
    let blas = levels.iter().map(|&li| bla::bla(&sp, li)).collect::<Result<Vec<_>, _>>()?;
    let mean = bla::mean_bla(&blas)?;
    let z: Vec<C64> = mean.lines.iter().map(|&k| sp.z(k)).collect();
    let ss0 = linear::fsid(&z, &mean.g, n, None)?;
    let weights: Vec<f64> = levels
        .iter()
        .map(|&li| {
            let l = &sp.levels[li];
            let ms = l.y.iter().map(|y| y.iter().map(|v| v.norm_sqr()).sum::<f64>()).sum::<f64>()
                / l.y.len().max(1) as f64;
            if opts.balance_levels && ms > 0.0 { 1.0 / ms.sqrt() } else { 1.0 }
        })
        .collect();
    let wmax = weights.iter().copied().fold(0.0, f64::max);
    let weights: Vec<f64> = weights.iter().map(|w| w / wmax).collect();
    let oe = OeData::weighted(&sp, levels, &weights)?;
    let c0 = oe.cost(&ss0);
    progress(&Progress {
        stage: "subspace",
        message: format!(
            "order {n}: subspace model, fit RMS {:.4} µm ({:.1} s)",
            oe.rms(c0),
            t0.elapsed().as_secs_f64()
        ),
    });
    let report = |it: usize, c: f64| {
        if it % 5 == 0 {
            progress(&Progress {
                stage: "oe",
                message: format!("order {n}: output error, iteration {it}, fit RMS {:.4} µm", oe.rms(c)),
            });
        }
    };
    let (ss, rep) = linear::refine_oe(&ss0, &oe, opts.lm_iterations, &report)?;
    let linear_fit_rms = oe.rms(rep.cost.1);
    progress(&Progress {
        stage: "oe",
        message: format!(
            "order {n}: linear model, fit RMS {linear_fit_rms:.4} µm after {} iterations ({:.1} s)",
            rep.iterations,
            t0.elapsed().as_secs_f64()
        ),
    });
    let lin = MimoModel::linear(&ss, rec.sample_rate_hz);
    let hysteretic = if let Some(fo) = &opts.feedback {
        let mut data = Periods {
            inputs: sp.inputs,
            outputs: sp.outputs,
            samples: sp.samples,
            u: vec![],
            y: vec![],
            weight: vec![],
        };
        for (&li, &w) in levels.iter().zip(&weights) {
            let l = &rec.levels[li];
            for &r in &sp.levels[li].realisations {
                data.u.push(l.u.mean_channels(r));
                data.y.push(l.y.mean_channels(r));
                data.weight.push(w);
            }
        }
        let t1 = Instant::now();
        let report = |it: usize, c: f64| {
            let rms = (c / data.weight.iter().sum::<f64>() / (data.samples * data.outputs) as f64).sqrt();
            progress(&Progress {
                stage: "feedback",
                message: format!(
                    "order {n}: feedback loop, iteration {it}, fit RMS {rms:.4} µm ({:.1} s)",
                    t1.elapsed().as_secs_f64()
                ),
            });
        };
        let (m, rep) = feedback::fit_feedback(&lin, &data, fo, &report)?;
        let w = data.weight.iter().sum::<f64>() * (data.samples * data.outputs) as f64;
        progress(&Progress {
            stage: "feedback",
            message: format!(
                "order {n}: feedback loop, fit RMS {:.4} → {:.4} µm after {} iterations ({:.1} s)",
                (rep.cost.0 / w).sqrt(),
                (rep.cost.1 / w).sqrt(),
                rep.iterations,
                t0.elapsed().as_secs_f64()
            ),
        });
        Some(m)
    } else if opts.input_channels || opts.mode_channels {
        let m = fit_branch(rec, &sp, levels, &weights, &lin, opts)?;
        progress(&Progress {
            stage: "hysteresis",
            message: format!("order {n}: hysteresis branch ({:.1} s)", t0.elapsed().as_secs_f64()),
        });
        Some(m)
    } else {
        None
    };
    Ok(Fitted { linear: lin, hysteretic, linear_fit_rms })
}

/// Steady-state `x_l` (n × N, state-major) of one period `u` (m × N channels-major).
fn modal_states(modes: &[Mode], b0: &[f64], u: &[f64], m: usize) -> Vec<f64> {
    let n: usize = modes.iter().map(Mode::size).sum();
    let len = u.len() / m.max(1);
    let (mut x, mut nx) = (vec![0.0; n], vec![0.0; n]);
    let mut out = vec![0.0; n * len];
    for pass in 0..2 {
        for k in 0..len {
            if pass == 1 {
                for i in 0..n {
                    out[i * len + k] = x[i];
                }
            }
            advance(modes, &x, &mut nx);
            for i in 0..n {
                x[i] = nx[i] + (0..m).map(|c| b0[i * m + c] * u[c * len + k]).sum::<f64>();
            }
        }
    }
    out
}

/// Step 4: the hysteresis branch on the linear model `lin`.
fn fit_branch(
    rec: &MimoRecord,
    sp: &Spectra,
    levels: &[usize],
    weights: &[f64],
    lin: &MimoModel,
    opts: &FitOptions,
) -> Result<MimoModel, MimoError> {
    let (m, p, len) = (sp.inputs, sp.outputs, sp.samples);
    let n = lin.order();
    let lines = sp.lines();
    // Channel sources.
    let mut sources = Vec::new();
    if opts.input_channels {
        sources.extend((0..m).map(Source::Input));
    }
    if opts.mode_channels {
        let mut at = 0;
        for md in &lin.modes {
            sources.push(Source::State(at));
            at += md.size();
        }
    }
    let q = sources.len();
    // The kept realisations: their mean input periods, the channels' raw signals and Y.
    let mut z_raw: Vec<Vec<f64>> = Vec::new(); // per realisation, q × N
    let mut u_lines: Vec<&[C64]> = Vec::new();
    let mut y_lines: Vec<&[C64]> = Vec::new();
    let mut w_real: Vec<f64> = Vec::new();
    for (&li, &wl) in levels.iter().zip(weights) {
        let ls = &sp.levels[li];
        for (ri, &r) in ls.realisations.iter().enumerate() {
            let u = rec.levels[li].u.mean_channels(r);
            let xl = modal_states(&lin.modes, &lin.b, &u, m);
            let mut z = vec![0.0; q * len];
            for (j, s) in sources.iter().enumerate() {
                let src = match *s {
                    Source::Input(i) => &u[i * len..(i + 1) * len],
                    Source::State(i) | Source::Feedback(i) => &xl[i * len..(i + 1) * len],
                };
                z[j * len..(j + 1) * len].copy_from_slice(src);
            }
            z_raw.push(z);
            u_lines.push(&ls.u[ri]);
            y_lines.push(&ls.y[ri]);
            w_real.push(wl);
        }
    }
    let nr = z_raw.len();
    let scales: Vec<f64> = (0..q)
        .map(|j| {
            let ss: f64 =
                z_raw.iter().map(|z| z[j * len..(j + 1) * len].iter().map(|v| v * v).sum::<f64>()).sum();
            (ss / (nr * len) as f64).sqrt().max(1e-300)
        })
        .collect();
    let yy: f64 =
        y_lines.iter().zip(&w_real).map(|(y, w)| w * y.iter().map(|v| v.norm_sqr()).sum::<f64>()).sum();
    let ss = lin.linear_part();
    let c = ss.c.clone();
    let fft = FftPlanner::<f64>::new().plan_fft_forward(len);
    let dim_v = m + q;
    let np = n + p;
    let dim = dim_v * np;
    let mut best: Option<(f64, Shape, DVector<f64>)> = None;
    for &shape in &opts.shapes {
        shape.validate()?;
        // W lines per realisation: [k·q + j].
        let w_lines: Vec<Vec<C64>> = z_raw
            .par_iter()
            .map(|z| {
                let mut out = vec![Complex::new(0.0, 0.0); lines * q];
                for j in 0..q {
                    let zz: Vec<f64> = z[j * len..(j + 1) * len].iter().map(|v| v / scales[j]).collect();
                    let h = shape.periodic(&zz, 1);
                    let mut buf: Vec<C64> = h.iter().map(|&v| Complex::new(v, 0.0)).collect();
                    fft.process(&mut buf);
                    for k in 0..lines {
                        out[k * q + j] = buf[k + 1];
                    }
                }
                out
            })
            .collect();
        let (nn, rhs) = (0..lines)
            .into_par_iter()
            .fold(
                || (DMatrix::<f64>::zeros(dim, dim), DVector::<f64>::zeros(dim)),
                |(mut nn, mut rhs), k| {
                    let r = Resolvent::new(&ss.modes, sp.z(k));
                    let cr = r.right_of(&c, &ss.modes);
                    let mut phi = DMatrix::<C64>::zeros(p, np);
                    phi.columns_mut(0, n).copy_from(&cr);
                    for o in 0..p {
                        phi[(o, n + o)] = Complex::new(1.0, 0.0);
                    }
                    let pp = phi.adjoint() * &phi;
                    let mut svv = DMatrix::<C64>::zeros(dim_v, dim_v);
                    let mut tyv = DMatrix::<C64>::zeros(p, dim_v);
                    for ri in 0..nr {
                        let v = DVector::from_fn(dim_v, |i, _| {
                            if i < m { u_lines[ri][k * m + i] } else { w_lines[ri][k * q + i - m] }
                        });
                        let y = DVector::from_fn(p, |o, _| y_lines[ri][k * p + o]);
                        // Σ V̄ Vᵀ and Σ Y Vᴴ
                        let wr = Complex::new(w_real[ri], 0.0);
                        svv += v.map(|x| x.conj()) * v.transpose() * wr;
                        tyv += &y * v.adjoint() * wr;
                    }
                    let pr = pp.map(|x| x.re);
                    let pi = pp.map(|x| x.im);
                    for i in 0..dim_v {
                        for j in 0..dim_v {
                            let (sr, si) = (svv[(i, j)].re, svv[(i, j)].im);
                            if sr == 0.0 && si == 0.0 {
                                continue;
                            }
                            let mut blk = nn.view_mut((i * np, j * np), (np, np));
                            blk += &pr * sr - &pi * si;
                        }
                    }
                    let ph_t = phi.adjoint() * tyv; // np × dim_v
                    for i in 0..dim_v {
                        for a in 0..np {
                            rhs[i * np + a] += ph_t[(a, i)].re;
                        }
                    }
                    (nn, rhs)
                },
            )
            .reduce(|| (DMatrix::zeros(dim, dim), DVector::zeros(dim)), |a, b| (a.0 + b.0, a.1 + b.1));
        let rhs_m = DMatrix::from_column_slice(dim, 1, rhs.as_slice());
        let theta =
            linear::solve_spd(nn, &rhs_m).ok_or(MimoError::Numerical("hysteresis branch least squares"))?;
        let theta = DVector::from_column_slice(theta.as_slice());
        let cost = yy - theta.dot(&rhs);
        if best.as_ref().is_none_or(|b| cost < b.0) {
            best = Some((cost, shape, theta));
        }
    }
    let (_, shape, theta) = best.ok_or_else(|| MimoError::Data("no candidate hysteresis shape".into()))?;
    // Θ column i (input or channel) holds [B or E column; D or F column].
    let th = |a: usize, i: usize| theta[i * np + a];
    let mut model = lin.clone();
    model.b = (0..n).flat_map(|a| (0..m).map(move |i| (a, i))).map(|(a, i)| th(a, i)).collect();
    model.d = (0..p).flat_map(|o| (0..m).map(move |i| (o, i))).map(|(o, i)| th(n + o, i)).collect();
    let e = (0..n).flat_map(|a| (0..q).map(move |j| (a, j))).map(|(a, j)| th(a, m + j)).collect();
    let f = (0..p).flat_map(|o| (0..q).map(move |j| (o, j))).map(|(o, j)| th(n + o, m + j)).collect();
    let channels =
        sources.iter().zip(&scales).map(|(&source, &scale)| Channel { source, scale, shape }).collect();
    model.branch = Some(Branch { channels, b0: lin.b.clone(), e, f });
    model.validate()?;
    Ok(model)
}

/// The benchmark's metric (module docs) of `model` on the realisations `realisations` of
/// `level`, µm: the mean over outputs of [`benchmark_outputs`].
pub fn benchmark_error(model: &MimoModel, level: &Level, realisations: &[usize]) -> Result<f64, MimoError> {
    let per = benchmark_outputs(model, level, realisations)?;
    Ok(per.iter().sum::<f64>() / per.len() as f64)
}

/// Per output, the RMS error (µm) of `model` over each period of the realisations
/// `realisations` of `level` after its first [`SKIP_SAMPLES`] samples, averaged over periods
/// and realisations.
pub fn benchmark_outputs(
    model: &MimoModel,
    level: &Level,
    realisations: &[usize],
) -> Result<Vec<f64>, MimoError> {
    let (m, p, len) = (level.u.channels, level.y.channels, level.u.samples);
    if m != model.inputs || p != model.outputs {
        return Err(MimoError::Shape(format!(
            "a {m}-input {p}-output level for a {}×{} model",
            model.inputs, model.outputs
        )));
    }
    if len <= SKIP_SAMPLES {
        return Err(MimoError::Data(format!("periods of {len} samples")));
    }
    let jobs: Vec<(usize, usize)> =
        realisations.iter().flat_map(|&r| (0..level.u.periods).map(move |pp| (r, pp))).collect();
    if jobs.is_empty() || realisations.iter().any(|&r| r >= level.u.realisations) {
        return Err(MimoError::Data("no such realisation".into()));
    }
    let errs = jobs
        .par_iter()
        .map(|&(r, pp)| {
            let u: Vec<f64> = (0..m).flat_map(|c| level.u.get(r, pp, c).iter().copied()).collect();
            let yhat = model.simulate(&u, Warmup::Periods(1))?;
            Ok((0..p)
                .map(|o| {
                    let y = level.y.get(r, pp, o);
                    let ms: f64 =
                        (SKIP_SAMPLES..len).map(|k| (y[k] - yhat[o * len + k]).powi(2)).sum::<f64>()
                            / (len - SKIP_SAMPLES) as f64;
                    ms.sqrt()
                })
                .collect::<Vec<f64>>())
        })
        .collect::<Result<Vec<Vec<f64>>, MimoError>>()?;
    Ok((0..p).map(|o| errs.iter().map(|e| e[o]).sum::<f64>() / errs.len() as f64).collect())
}

//! `boucwen identify DATA.csv`: fit a model on the first part of a record and report its
//! parameters and its free-run RMS error on the rest.
//!
//! `--method oe` (default) fits the free-run (output) error ([`boucwen_lab::fit::fit_oe`]);
//! `--method rls` runs the paper's section 3 RLS procedure
//! ([`boucwen_lab::fit::fit_paper_rls`], at most one branch). `--model extended` (default)
//! or `enhanced`, whose branches are `--harmonics` or, if not given, the odd harmonic that
//! stands out in the fitted part of the output (3 if none does).

use crate::cmd_diagnose::read_for_fit;
use boucwen_lab::fit::{self, Averaging, DataUsed, Fit, HostModel, ModelSpec, OeOptions};
use boucwen_lab::{analysis, diagnose, sweep};
use std::path::PathBuf;

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ModelKind {
    /// Bouc–Wen hysteresis, asymmetric term and structure (eq. 3 in the AR form of eq. 9).
    Extended,
    /// The extended model plus harmonic branches of the drive (eqs. 6/7).
    Enhanced,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Method {
    /// Output-error fit: minimises the free-run error.
    Oe,
    /// The paper's RLS identification (running-sum regressors, section 3).
    Rls,
}

#[derive(clap::Args)]
pub struct IdentifyArgs {
    /// The record: CSV with columns t (s), u (V), y (µm).
    data: PathBuf,
    /// The model to fit.
    #[arg(long, value_enum, default_value = "extended")]
    model: ModelKind,
    /// Harmonic orders of the enhanced model's branches (comma-separated, each ≥ 2).
    #[arg(long, value_delimiter = ',')]
    harmonics: Vec<u32>,
    /// Identification method.
    #[arg(long, value_enum, default_value = "oe")]
    method: Method,
    /// Fraction of the record fitted (from the start); the rest is held out.
    #[arg(long, default_value_t = 0.5)]
    fit_fraction: f64,
    /// Drive frequency (Hz) for the branches; estimated from u if omitted.
    #[arg(long)]
    drive_hz: Option<f64>,
    /// Output-error fit: accept only a loop the direct inverse (eqs. 16/17) can invert.
    #[arg(long)]
    invertible: bool,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(a: IdentifyArgs) -> Result<(), String> {
    let name = a.data.display().to_string();
    let r = read_for_fit(&a.data)?;
    if !(a.fit_fraction.is_finite() && (0.1..=0.9).contains(&a.fit_fraction)) {
        return Err(format!("--fit-fraction {}: must be between 0.1 and 0.9", a.fit_fraction));
    }
    let (u, y, ts) = (&r.u, &r.y, r.ts);
    let split = (a.fit_fraction * r.len() as f64).round() as usize;
    let drive_hz = match a.drive_hz {
        Some(f) if f.is_finite() && f > 0.0 && f < 0.5 / ts => f,
        Some(f) => return Err(format!("--drive-hz {f}: must be above 0 and below {} Hz", 0.5 / ts)),
        None => analysis::estimate_drive(u, ts).unwrap_or(0.0),
    };
    let harmonics = match a.model {
        ModelKind::Extended if !a.harmonics.is_empty() => {
            return Err("--harmonics needs --model enhanced".into());
        }
        ModelKind::Extended => vec![],
        ModelKind::Enhanced => {
            if drive_hz <= 0.0 {
                return Err(format!(
                    "{name}: the input has no oscillating component to take the drive frequency from (give --drive-hz)"
                ));
            }
            if a.harmonics.is_empty() {
                vec![standing_out(&y[..split], drive_hz, ts)]
            } else {
                a.harmonics.clone()
            }
        }
    };
    let spec = ModelSpec { drive_hz: drive_hz.max(1e-3), harmonics, drift_degree: None };
    // The output is averaged over periods only in steady state: the model has no drift term.
    let opt = OeOptions {
        lm_starts: diagnose::TERM_STARTS,
        require_invertible: a.invertible,
        averaging: Averaging::Periods,
        ..diagnose::fit_options(split, ts)
    };
    let (model, fit) = match a.method {
        Method::Oe => {
            let t0 = std::time::Instant::now();
            let fit = fit::fit_oe(u, y, ts, split, &spec, &[], &opt).map_err(|e| format!("{name}: {e}"))?;
            (fit.model.clone(), Some((fit, t0.elapsed().as_secs_f64())))
        }
        Method::Rls => {
            (fit::fit_paper_rls(u, y, ts, split, &spec).map_err(|e| format!("{name}: {e}"))?, None)
        }
    };
    let sim = model.simulate(u, ts).map_err(|e| format!("{name}: {e}"))?;
    let fit_rms = analysis::rms_diff(&y[opt.skip..split], &sim[opt.skip..split]);
    let held_out_rms = analysis::rms_diff(&y[split..], &sim[split..]);
    if a.json {
        let mut j = json(&model, &a, drive_hz, split, r.len() - split, fit_rms, held_out_rms);
        if let Some((f, seconds)) = &fit {
            j["fit"] = fit_json(f, *seconds);
        }
        println!("{j}");
    } else {
        print!("{}", text(&model, &name, &a, split, r.len(), ts, fit_rms, held_out_rms));
        if let Some((f, _)) = &fit {
            println!("{}", fit_text(f));
        }
    }
    Ok(())
}

/// The odd harmonic (3..=9) that stands out in `y`, else 3.
fn standing_out(y: &[f64], f: f64, ts: f64) -> u32 {
    let n = analysis::whole_periods(y.len(), f, ts);
    let amp = analysis::harmonics(&y[..n], f, ts, 1).first().map_or(0.0, |t| t.amp);
    analysis::dominant_odd_harmonic(&y[..n], f, ts, 0.0, sweep::MIN_HARMONIC_REL * amp)
        .map(|(order, _)| order)
        .filter(|&o| o <= diagnose::MAX_TERM_ORDER && f64::from(o) * f < 0.5 / ts)
        .unwrap_or(3)
}

fn method_name(m: Method) -> &'static str {
    match m {
        Method::Oe => "output error",
        Method::Rls => "paper RLS",
    }
}

/// How the output-error fit ended, what it was computed on and how long it took (s).
fn fit_json(f: &Fit, seconds: f64) -> serde_json::Value {
    let data = match f.data {
        DataUsed::Samples { from, to } => serde_json::json!({"kind": "samples", "from": from, "to": to}),
        DataUsed::Periods { from, to, periods, scored } => serde_json::json!({
            "kind": "average_period", "from": from, "to": to, "periods": periods, "scored_samples": scored,
        }),
    };
    serde_json::json!({
        "stop": f.stop.as_str(),
        "iterations": f.iterations,
        "evaluations": f.evaluations,
        "criterion_rms_um": f.rms_fit,
        "data": data,
        "seconds": seconds,
    })
}

fn fit_text(f: &Fit) -> String {
    let data = match f.data {
        DataUsed::Samples { from, to } => format!("samples {from}..{to}"),
        DataUsed::Periods { from, to, periods, .. } => {
            format!("the average of {periods} periods of samples {from}..{to}")
        }
    };
    format!(
        "fit on {data}: stopped after {} iterations ({}), {} evaluations",
        f.iterations, f.stop, f.evaluations
    )
}

fn json(
    m: &HostModel,
    a: &IdentifyArgs,
    f: f64,
    fit: usize,
    held: usize,
    fit_rms: f64,
    rms: f64,
) -> serde_json::Value {
    let bw = &m.ext.bw;
    let branches: Vec<serde_json::Value> = m
        .branches
        .iter()
        .map(
            |b| serde_json::json!({"order": b.order, "alpha_s": b.alpha_s, "alpha_c": b.alpha_c, "ar": b.ar}),
        )
        .collect();
    serde_json::json!({
        "model": m.name(),
        "method": method_name(a.method),
        "drive_hz": f,
        "fit_samples": fit,
        "held_out_samples": held,
        "fit_rms_um": fit_rms,
        "rms_um": rms,
        "params": {
            "ar": m.ext.ar,
            "a1": bw.a1, "a": bw.a, "a0": bw.a0, "gamma": bw.gamma, "beta": bw.beta,
            "delay_samples": m.delay,
            "branches": branches,
        },
    })
}

#[allow(clippy::too_many_arguments)]
fn text(
    m: &HostModel,
    name: &str,
    a: &IdentifyArgs,
    split: usize,
    n: usize,
    ts: f64,
    fit_rms: f64,
    rms: f64,
) -> String {
    use std::fmt::Write;
    let bw = &m.ext.bw;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{name}: {} model by {}, fitted on samples 0..{split}, tested on {split}..{n} (Ts = {} s)",
        m.name(),
        method_name(a.method),
        ts
    );
    let _ = writeln!(s, "  structure  a1 = {:.6}, a2 = {:.6}", m.ext.ar[0], m.ext.ar[1]);
    if let Some(f) = diagnose::resonance_hz(m.ext.ar, ts) {
        let _ = writeln!(s, "             resonance {f:.1} Hz");
    }
    let _ = writeln!(
        s,
        "  hysteresis A1 = {:.6}, A = {:.6}, A0 = {:.6}, gamma = {:.6}, beta = {:.6}",
        bw.a1, bw.a, bw.a0, bw.gamma, bw.beta
    );
    let _ = writeln!(s, "  input delay {:.3} samples", m.delay);
    for b in &m.branches {
        let _ = writeln!(
            s,
            "  branch n = {}: alpha_s = {:.6}, alpha_c = {:.6}, ar = [{:.6}, {:.6}]",
            b.order, b.alpha_s, b.alpha_c, b.ar[0], b.ar[1]
        );
    }
    let _ = writeln!(s, "free-run RMS error: {fit_rms:.4} µm on the fitted part, {rms:.4} µm held out");
    s
}

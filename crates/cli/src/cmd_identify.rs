//! `boucwen identify DATA.csv`: fit a model on the first part of a record's steady window
//! and report its parameters, its free-run RMS error and fit on the rest, and whether it is
//! stable (exit code 1 when it is not). Any drive: sine, periodic, multisine, aperiodic.
//!
//! `--method oe` (default) fits the free-run (output) error ([`boucwen_lab::fit::fit_oe`]);
//! `--method rls` runs the paper's section 3 RLS procedure
//! ([`boucwen_lab::fit::fit_paper_rls`], at most one branch). `--model extended` (default)
//! or `enhanced`, whose branches are `--harmonics` or, if not given, the odd harmonic that
//! stands out in the fitted part of the output (3 if none does).

use crate::cmd_diagnose::import_json;
use crate::record_args::RecordArgs;
use boucwen_lab::diagnose;
use boucwen_lab::diagnose::ModelCheck;
use boucwen_lab::experiments::sweep;
use boucwen_lab::fit::{self, Averaging, DataUsed, Fit, OeOptions};
use boucwen_lab::model::{HostModel, ModelSpec};
use boucwen_lab::signal::analysis;
use boucwen_lab::signal::steady::{self, Drive, DriveKind};
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
    /// The record: t, u, y of a hysteretic actuator, any drive (see --columns and the units
    /// for other layouts).
    data: PathBuf,
    #[command(flatten)]
    record: RecordArgs,
    /// The model to fit.
    #[arg(long, value_enum, default_value = "extended")]
    model: ModelKind,
    /// Harmonic orders of the enhanced model's branches (comma-separated, each ≥ 2).
    #[arg(long, value_delimiter = ',')]
    harmonics: Vec<u32>,
    /// Identification method.
    #[arg(long, value_enum, default_value = "oe")]
    method: Method,
    /// Fraction of the steady window fitted (from its start, whole periods for a periodic
    /// drive); the rest is held out.
    #[arg(long, default_value_t = 0.5)]
    fit_fraction: f64,
    /// Drive frequency (Hz) for the branches; found in u if omitted.
    #[arg(long)]
    drive_hz: Option<f64>,
    /// Output-error fit: accept only a loop the direct inverse (eqs. 16/17) can invert.
    #[arg(long)]
    invertible: bool,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// What identify measured.
struct Outcome<'a> {
    model: &'a HostModel,
    drive: &'a Drive,
    window_s: [f64; 2],
    why: &'a str,
    fit_samples: usize,
    held_samples: usize,
    fit_rms: Option<f64>,
    check: ModelCheck,
    held_rms: f64,
    noise: (f64, &'static str),
    drive_hz: f64,
}

pub fn run(a: IdentifyArgs) -> Result<(), String> {
    let name = a.data.display().to_string();
    if !(a.fit_fraction.is_finite() && (0.1..=0.9).contains(&a.fit_fraction)) {
        return Err(format!("--fit-fraction {}: must be between 0.1 and 0.9", a.fit_fraction));
    }
    let imported = a.record.read(&a.data)?;
    let r = &imported.record;
    r.validate_for_fit(diagnose::MIN_SAMPLES).map_err(|e| e.to_string())?;
    let given = a.record.window(r)?;
    let ts = r.ts;
    let (w, drive) = steady::steady_window(&r.u, &r.y, ts, given).map_err(|e| format!("{name}: {e}"))?;
    if drive.kind == DriveKind::None {
        return Err(format!("{name}: {}", diagnose::DiagnoseError::NoDrive { std_v: drive.std_v }));
    }
    steady::check_response(&r.u[w.start..w.end], &r.y[w.start..w.end], ts, &drive)
        .map_err(|e| format!("{name}: {e}"))?;
    let window_s = w.seconds(r.t0, ts);
    if w.end - w.start < diagnose::MIN_SAMPLES {
        return Err(format!(
            "{name}: the steady window {:.3}–{:.3} s holds {} samples; identify needs at least {}",
            window_s[0],
            window_s[1],
            w.end - w.start,
            diagnose::MIN_SAMPLES
        ));
    }
    // The model runs from the start of the steady drive; fitted and held-out parts split the
    // window (at a whole period for a periodic drive).
    let (u, y) = (&r.u[w.drive_on..w.end], &r.y[w.drive_on..w.end]);
    let start = w.start - w.drive_on;
    let len = w.end - w.start;
    let mut fitted = (a.fit_fraction * len as f64).round() as usize;
    if let (true, Some(p)) = (drive.is_periodic(), drive.period_samples) {
        let periods = ((len as f64 + 0.5) / p).floor();
        let k = (a.fit_fraction * periods).round().clamp(1.0, (periods - 1.0).max(1.0));
        if periods >= 2.0 {
            fitted = (k * p).round() as usize;
        }
    }
    let split = start + fitted.clamp(1, len - 1);
    let drive_hz = match a.drive_hz {
        Some(f) if f.is_finite() && f > 0.0 && f < 0.5 / ts => f,
        Some(f) => return Err(format!("--drive-hz {f}: must be above 0 and below {} Hz", 0.5 / ts)),
        None => drive.freq_hz,
    };
    let harmonics = match a.model {
        ModelKind::Extended if !a.harmonics.is_empty() => {
            return Err("--harmonics needs --model enhanced".into());
        }
        ModelKind::Extended => vec![],
        ModelKind::Enhanced => {
            if !matches!(drive.kind, DriveKind::Sine | DriveKind::Periodic) && a.drive_hz.is_none() {
                return Err(format!(
                    "{name}: the drive is {}; the enhanced model's branches need a drive frequency (give --drive-hz)",
                    drive.describe()
                ));
            }
            if a.harmonics.is_empty() {
                vec![standing_out(&y[start..split], drive_hz, ts)]
            } else {
                a.harmonics.clone()
            }
        }
    };
    let spec = ModelSpec { drive_hz: drive_hz.max(1e-3), harmonics, drift_degree: None };
    // The output is averaged over periods only in steady state: the model has no drift term.
    let mut opt = OeOptions {
        lm_starts: diagnose::TERM_STARTS,
        require_invertible: a.invertible,
        averaging: Averaging::Periods,
        ..diagnose::fit_options(split, ts)
    };
    opt.skip = start.max(opt.skip.min(split.saturating_sub(diagnose::FIT_MIN_SAMPLES)));
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
    let mut check = ModelCheck::of(&model, &sim[split..], &y[split..], ts);
    check.check_amplitudes(&model.ext.bw, model.ext.ar, u, ts, |v| model.simulate(v, ts).ok());
    let fit_check = diagnose::instability(model.ext.ar, &sim[..split], ts);
    let o = Outcome {
        model: &model,
        drive: &drive,
        window_s,
        why: &w.why,
        fit_samples: split - start,
        held_samples: y.len() - split,
        fit_rms: fit_check.is_none().then(|| analysis::rms_diff(&y[opt.skip..split], &sim[opt.skip..split])),
        held_rms: analysis::rms_diff(&y[split..], &sim[split..]),
        check,
        noise: steady::noise_floor(&y[split..], ts, &drive),
        drive_hz,
    };
    if a.json {
        let mut j = json(&o, &a);
        j["file"] = serde_json::json!(name);
        j["import"] = import_json(&imported);
        if let Some((f, seconds)) = &fit {
            j["fit"] = fit_json(f, *seconds);
        }
        println!("{j}");
    } else {
        println!("read as {}", imported.info.describe());
        print!("{}", text(&o, &name, &a, ts));
        if let Some((f, _)) = &fit {
            println!("{}", fit_text(f));
        }
    }
    match &o.check.unstable {
        Some(why) => Err(format!(
            "{name}: no stable model was found ({} by {}): {why}",
            model.name(),
            method_name(a.method)
        )),
        None => Ok(()),
    }
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

fn json(o: &Outcome, a: &IdentifyArgs) -> serde_json::Value {
    let m = o.model;
    let bw = &m.ext.bw;
    let branches: Vec<serde_json::Value> = m
        .branches
        .iter()
        .map(
            |b| serde_json::json!({"order": b.order, "alpha_s": b.alpha_s, "alpha_c": b.alpha_c, "ar": b.ar}),
        )
        .collect();
    let stable = o.check.unstable.is_none();
    serde_json::json!({
        "model": m.name(),
        "method": method_name(a.method),
        "drive_hz": o.drive_hz,
        "drive": {"kind": o.drive.kind.as_str(), "freq_hz": o.drive.freq_hz, "thd_pct": 100.0 * o.drive.thd},
        "window_s": o.window_s,
        "window_why": o.why,
        "fit_samples": o.fit_samples,
        "held_out_samples": o.held_samples,
        "stable": stable,
        "unstable_reason": o.check.unstable,
        "narrow": o.check.narrow,
        "fit_rms_um": o.fit_rms,
        "rms_um": stable.then_some(o.held_rms),
        "fit_pct": o.check.fit_pct,
        "noise_um": o.noise.0,
        "noise_method": o.noise.1,
        "params": {
            "ar": m.ext.ar,
            "a1": bw.a1, "a": bw.a, "a0": bw.a0, "gamma": bw.gamma, "beta": bw.beta,
            "delay_samples": m.delay,
            "branches": branches,
        },
    })
}

fn text(o: &Outcome, name: &str, a: &IdentifyArgs, ts: f64) -> String {
    use std::fmt::Write;
    let m = o.model;
    let bw = &m.ext.bw;
    let mut s = String::new();
    let _ = writeln!(s, "{name}: drive {}", o.drive.describe());
    let _ = writeln!(s, "window {:.3} to {:.3} s: {}", o.window_s[0], o.window_s[1], o.why);
    let _ = writeln!(
        s,
        "{} model by {}, fitted on {} samples, tested on the {} after them (Ts = {ts} s)",
        m.name(),
        method_name(a.method),
        o.fit_samples,
        o.held_samples,
    );
    let _ = writeln!(s, "  structure  a1 = {:.6}, a2 = {:.6}", m.ext.ar[0], m.ext.ar[1]);
    if let Some(f) = diagnose::resonance_hz(m.ext.ar, ts) {
        let _ = writeln!(s, "             resonance {f:.1} Hz (where the record excites it: see diagnose)");
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
    match (&o.check.unstable, o.check.fit_pct) {
        (Some(why), _) => {
            let _ = writeln!(s, "free run: not stable, {why}");
        }
        (None, fit) => {
            let _ = writeln!(
                s,
                "free-run RMS error: {} on the fitted part, {:.4} µm held out; held-out fit {:.1} %; noise floor {:.4} µm",
                o.fit_rms.map_or("not stable".to_string(), |v| format!("{v:.4} µm")),
                o.held_rms,
                fit.unwrap_or(f64::NAN),
                o.noise.0
            );
            if fit.is_some_and(|f| f < diagnose::MIN_FIT_PCT) {
                let _ = writeln!(
                    s,
                    "the drive explains less than {:.0} % of the held-out output: another input or a disturbance drives it",
                    diagnose::MIN_FIT_PCT
                );
            }
            if let Some(why) = &o.check.narrow {
                let _ = writeln!(s, "note: {why}");
            }
        }
    }
    s
}

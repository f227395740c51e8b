//! The share of right diagnoses over a randomized batch of records with hidden effects.
//!
//! Run with `cargo bench --bench diagnose_batch` (options after `--`: `--per-effect N`,
//! default 40, and `--seed S`, default 1000, the first seed; `--verbose` prints every case;
//! `--dump DIR` writes every record there as `EFFECT-SEED.csv`, a multisine's realisations
//! as `EFFECT-SEED-rN.csv`, for `boucwen diagnose`).
//! For every effect of [`EFFECTS`] it draws `N` cases ([`boucwen_lab::fixtures::hidden::Case`],
//! seeds `S..S+N`), records each on the virtual bimorph and diagnoses it with the default
//! thresholds. A diagnosis is right when:
//! - a hidden harmonic or drift: the first finding names it (kind, order, frequency within
//!   2 Hz) and the extended model lowers the held-out RMS by at least 50 %;
//! - a clean record: there is no finding.
//!
//! It prints one line per effect (right / drawn, and the median gain) and the whole share,
//! with the wall time. This is a measurement, not a test: it asserts nothing and exits 0
//! unless a case cannot be drawn or recorded.
//!
//! Then (`--kinds new` runs only these, `--kinds old` only the ones above) the kinds of
//! [`boucwen_lab::fixtures::effects`], `N` seeds each from `S`: sine records with saturation of the
//! drive or of the output, creep, an input delay, a 5th harmonic with drift and the sensor's
//! range with a 3rd harmonic, right when every hidden effect is named (kind; order for a
//! harmonic) and the first finding is one of them; periodic records (a multisine in two
//! realisations, a triangle) with a hidden odd or even nonlinearity, right when the first
//! finding names its parity, and clean, right when there is no finding. `--only PART` runs
//! only the new kinds whose name contains `PART` (e.g. `--only triangle`).

use boucwen_lab::diagnose::periodic::Realisation;
use boucwen_lab::diagnose::{self, Diagnosis, Kind};
use boucwen_lab::fixtures::effects::{
    Nonlinearity, PeriodicCase, PeriodicDrive, SineCase, SineEffect, Truth,
};
use boucwen_lab::fixtures::hidden::{Case, Effect};
use boucwen_lab::record::Record;
use boucwen_lab::rules::Rules;
use rayon::prelude::*;
use std::time::Instant;

/// The effects drawn, in the order printed.
const EFFECTS: [Effect; 8] = [
    Effect::OddHarmonic(3),
    Effect::OddHarmonic(5),
    Effect::OddHarmonic(7),
    Effect::EvenHarmonic(2),
    Effect::EvenHarmonic(4),
    Effect::Drift,
    Effect::Clean,
    Effect::Clean,
];

/// Is the diagnosis right about `case`? Returns the verdict and a one-line account.
fn judge(case: &Case, d: &Diagnosis) -> (bool, String) {
    let first = d.findings.first();
    let named = first.map_or("none".to_string(), |f| match f.order {
        Some(n) => format!("{} {n} at {:.1} Hz", f.kind.as_str(), f.freq_hz),
        None => f.kind.as_str().to_string(),
    });
    let want = |kind: Kind, order: Option<u32>, freq: f64| {
        first.is_some_and(|f| f.kind == kind && f.order == order && (f.freq_hz - freq).abs() <= 2.0)
            && d.gain_pct() >= 50.0
    };
    let right = match case.effect {
        Effect::Clean => d.findings.is_empty(),
        Effect::OddHarmonic(n) => want(Kind::OddHarmonic, Some(n), f64::from(n) * case.drive_hz),
        Effect::EvenHarmonic(n) => want(Kind::EvenHarmonic, Some(n), f64::from(n) * case.drive_hz),
        Effect::Drift => want(Kind::Drift, None, 0.0),
    };
    let line = format!(
        "{:>9} seed {:>5}: f {:5.1} Hz, resonance {:5.1} Hz -> {named}, gain {:5.1}% ({:.3} -> {:.3} µm) {}",
        case.effect.name(),
        case.seed,
        case.drive_hz,
        case.resonance_hz,
        d.gain_pct(),
        d.baseline_rms_um,
        d.model_rms_um,
        if right { "right" } else { "WRONG" }
    );
    (right, line)
}

/// Clean record: the largest term any candidate carried in any trial. Effect record: what the
/// trial of the hidden effect's term carried in round 0. Both relative to the RMS of the
/// output's fundamental.
fn carried(case: &Case, d: &Diagnosis) -> f64 {
    let out_rms = d.output_amplitude_um / std::f64::consts::SQRT_2;
    let hidden = |t: &&diagnose::evidence::Trial| match case.effect {
        Effect::Clean => true,
        Effect::OddHarmonic(n) | Effect::EvenHarmonic(n) => t.round == 0 && t.candidate.order == Some(n),
        Effect::Drift => t.round == 0 && t.candidate.kind == Kind::Drift,
    };
    let terms = d.trials.iter().filter(hidden).map(|t| t.term_rms_um / out_rms.max(1e-300));
    if case.effect == Effect::Clean { terms.fold(0.0, f64::max) } else { terms.fold(f64::NAN, f64::max) }
}

struct Args {
    per_effect: u64,
    seed: u64,
    verbose: bool,
    dump: Option<std::path::PathBuf>,
    /// Run the kinds of `hidden` (old), of `effects` (new), or both.
    old: bool,
    new: bool,
    /// Only the new kinds whose name contains this (`--only triangle`).
    only: Option<String>,
}

fn args() -> Result<Args, String> {
    let mut a =
        Args { per_effect: 40, seed: 1000, verbose: false, dump: None, old: true, new: true, only: None };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| -> Result<u64, String> {
            let v = it.next().ok_or(format!("{name} needs a value"))?;
            v.parse().map_err(|_| format!("{name}: {v:?} is not a whole number"))
        };
        match arg.as_str() {
            "--per-effect" => a.per_effect = value("--per-effect")?,
            "--seed" => a.seed = value("--seed")?,
            "--verbose" => a.verbose = true,
            "--dump" => a.dump = Some(it.next().ok_or("--dump needs a directory")?.into()),
            "--only" => {
                a.only = Some(it.next().ok_or("--only needs a part of a kind's name")?);
                a.old = false;
            }
            "--kinds" => match it.next().as_deref() {
                Some("old") => a.new = false,
                Some("new") => a.old = false,
                Some("all") => {}
                other => return Err(format!("--kinds: {other:?} is not old, new or all")),
            },
            // cargo bench passes `--bench`; criterion-style filters are not used here.
            "--bench" => {}
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    Ok(a)
}

/// One record's outcome: the hidden effect, whether the diagnosis named it, its gain (%),
/// the report line, and what [`carried`] measures.
type Outcome = (Effect, bool, f64, String, f64);

fn main() {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("diagnose_batch: {e}");
            std::process::exit(2);
        }
    };
    if a.old {
        old_kinds(&a);
    }
    if a.new {
        new_kinds(&a);
    }
}

/// The sine effects of `effects`, in the order printed.
const SINE_EFFECTS: [SineEffect; 6] = SineEffect::ALL;

fn truth_named(t: &Truth, kind: Kind, order: Option<u32>) -> bool {
    match t {
        Truth::Harmonic { order: n, .. } => kind == Kind::OddHarmonic && order == Some(*n),
        Truth::Drift => kind == Kind::Drift,
        Truth::Saturation { .. } => kind == Kind::Saturation,
        Truth::Creep => kind == Kind::Creep,
        Truth::Delay { .. } => kind == Kind::InputDelay,
        Truth::OddDistortion => kind == Kind::OddDistortion,
        Truth::EvenDistortion => kind == Kind::EvenDistortion,
    }
}

/// One new-kind case: its name, the records, the truth.
enum NewCase {
    Sine(SineEffect),
    Periodic(PeriodicDrive, Nonlinearity),
}

impl NewCase {
    fn name(&self) -> String {
        match self {
            NewCase::Sine(e) => e.name(),
            NewCase::Periodic(d, n) => {
                format!(
                    "{}-{}",
                    if *d == PeriodicDrive::Triangle { "triangle" } else { "multisine" },
                    n.name()
                )
            }
        }
    }

    /// The records and the truth of seed `seed`.
    fn draw(&self, seed: u64) -> Result<(Vec<Record>, Vec<Truth>), String> {
        match self {
            NewCase::Sine(e) => {
                let c = SineCase::generate(*e, seed).map_err(|e| e.to_string())?;
                Ok((vec![c.record().map_err(|e| e.to_string())?], c.truth.clone()))
            }
            NewCase::Periodic(d, n) => {
                let c = PeriodicCase::generate(*d, *n, seed).map_err(|e| e.to_string())?;
                Ok((c.records().map_err(|e| e.to_string())?, c.truth().into_iter().collect()))
            }
        }
    }
}

/// The kinds of `effects`: the share right per kind (see the module docs).
fn new_kinds(a: &Args) {
    let mut cases: Vec<NewCase> = SINE_EFFECTS.iter().map(|&e| NewCase::Sine(e)).collect();
    for d in [PeriodicDrive::Multisine, PeriodicDrive::Triangle] {
        for n in [Nonlinearity::None, Nonlinearity::Odd, Nonlinearity::Even] {
            cases.push(NewCase::Periodic(d, n));
        }
    }
    if let Some(only) = &a.only {
        cases.retain(|c| c.name().contains(only.as_str()));
        if cases.is_empty() {
            eprintln!("diagnose_batch: --only {only:?} names no kind");
            std::process::exit(2);
        }
    }
    let jobs: Vec<(usize, u64)> =
        (0..cases.len()).flat_map(|i| (0..a.per_effect).map(move |k| (i, a.seed + k))).collect();
    let start = Instant::now();
    let results: Vec<Result<(usize, bool, f64, String), String>> = jobs
        .par_iter()
        .map(|&(i, seed)| {
            let c = &cases[i];
            let (records, truth) = c.draw(seed).map_err(|e| format!("{} {seed}: {e}", c.name()))?;
            if let Some(dir) = &a.dump {
                std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
                for (r, rec) in records.iter().enumerate() {
                    let part = if records.len() > 1 { format!("-r{}", r + 1) } else { String::new() };
                    let path = dir.join(format!("{}-{seed}{part}.csv", c.name()));
                    rec.write(&path).map_err(|e| e.to_string())?;
                }
            }
            let recs: Vec<Realisation> =
                records.iter().map(|r| Realisation { u: &r.u, y: &r.y, t0: r.t0, given: None }).collect();
            let o = match diagnose::diagnose_drive(&recs, records[0].ts, &Rules::default()) {
                Ok(o) => o,
                Err(e) => return Ok((i, false, 0.0, format!("{} seed {seed}: no diagnosis: {e}", c.name()))),
            };
            let found: Vec<(Kind, Option<u32>, bool)> =
                o.findings().iter().map(|f| (f.kind, f.order, f.kept)).collect();
            let right = if truth.is_empty() {
                found.is_empty()
            } else {
                truth.iter().all(|t| found.iter().any(|f| truth_named(t, f.0, f.1)))
                    && found.first().is_some_and(|f| truth.iter().any(|t| truth_named(t, f.0, f.1)))
            };
            let gain = o.gain_pct();
            let line = format!(
                "{:>18} seed {seed:>5}: {:?} -> {:?}, gain {gain:5.1}% {}",
                c.name(),
                truth,
                found,
                if right { "right" } else { "WRONG" }
            );
            Ok((i, right, gain, line))
        })
        .collect();
    let wall = start.elapsed().as_secs_f64();
    let mut ok = vec![];
    for r in results {
        match r {
            Ok(v) => ok.push(v),
            Err(e) => {
                eprintln!("diagnose_batch: {e}");
                std::process::exit(1);
            }
        }
    }
    for (_, right, _, line) in &ok {
        if a.verbose || !right {
            println!("{line}");
        }
    }
    println!(
        "
kind                right/drawn  median gain"
    );
    for (i, c) in cases.iter().enumerate() {
        let of: Vec<_> = ok.iter().filter(|r| r.0 == i).collect();
        let right = of.iter().filter(|r| r.1).count();
        let mut gains: Vec<f64> = of.iter().map(|r| r.2).collect();
        gains.sort_by(f64::total_cmp);
        let median = gains.get(gains.len() / 2).copied().unwrap_or(0.0);
        println!("{:<18} {right:>5}/{:<5}  {median:6.1}%", c.name(), of.len());
    }
    let right = ok.iter().filter(|r| r.1).count();
    println!(
        "all new kinds      {right:>5}/{:<5}  share {:.1}%   (seeds from {}, {wall:.0} s wall on {} threads)",
        ok.len(),
        100.0 * right as f64 / ok.len().max(1) as f64,
        a.seed,
        rayon::current_num_threads()
    );
}

/// The kinds of `hidden` (see the module docs).
fn old_kinds(a: &Args) {
    // Two clean entries: as many clean records as effect records of any one kind would make
    // clean cases a small minority; two draws of seeds keep them apart.
    let jobs: Vec<(Effect, u64)> = EFFECTS
        .iter()
        .enumerate()
        .flat_map(|(i, &e)| {
            let base = a.seed + if i == EFFECTS.len() - 1 { 1_000_000 } else { 0 };
            (0..a.per_effect).map(move |k| (e, base + k))
        })
        .collect();
    let start = Instant::now();
    let results: Vec<Result<Outcome, String>> = jobs
        .par_iter()
        .map(|&(effect, seed)| {
            let case = Case::generate(effect, seed).map_err(|e| format!("{} {seed}: {e}", effect.name()))?;
            let rec = case.record().map_err(|e| format!("{} {seed}: {e}", effect.name()))?;
            if let Some(dir) = &a.dump {
                let path = dir.join(format!("{}-{seed}.csv", effect.name()));
                std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
                rec.write(&path).map_err(|e| e.to_string())?;
            }
            match diagnose::diagnose(&rec.u, &rec.y, rec.ts, &Rules::default()) {
                Ok(d) => {
                    let (right, line) = judge(&case, &d);
                    Ok((effect, right, d.gain_pct(), line, carried(&case, &d)))
                }
                Err(e) => Ok((
                    effect,
                    false,
                    0.0,
                    format!("{} seed {seed}: no diagnosis: {e}", effect.name()),
                    f64::NAN,
                )),
            }
        })
        .collect();
    let wall = start.elapsed().as_secs_f64();
    let mut ok: Vec<Outcome> = Vec::new();
    for r in results {
        match r {
            Ok(v) => ok.push(v),
            Err(e) => {
                eprintln!("diagnose_batch: {e}");
                std::process::exit(1);
            }
        }
    }
    if a.verbose {
        for (_, _, _, line, _) in &ok {
            println!("{line}");
        }
    } else {
        for (_, right, _, line, _) in &ok {
            if !right {
                println!("{line}");
            }
        }
    }
    println!("\neffect     right/drawn  median gain");
    let mut names: Vec<String> = EFFECTS.iter().map(Effect::name).collect();
    names.dedup();
    for name in &names {
        let of: Vec<&(Effect, bool, f64, String, f64)> = ok.iter().filter(|r| &r.0.name() == name).collect();
        let right = of.iter().filter(|r| r.1).count();
        let mut gains: Vec<f64> = of.iter().map(|r| r.2).collect();
        gains.sort_by(f64::total_cmp);
        let median = gains.get(gains.len() / 2).copied().unwrap_or(0.0);
        println!("{name:<10} {right:>5}/{:<5}  {median:6.1}%", of.len());
    }
    // The evidence for the default `min_term_rel`: what terms carry on clean records and on
    // records with an effect, relative to the output's fundamental RMS.
    let clean_max = ok.iter().filter(|r| r.0 == Effect::Clean).map(|r| r.4).fold(0.0, f64::max);
    let mut effect_terms: Vec<f64> =
        ok.iter().filter(|r| r.0 != Effect::Clean && r.4.is_finite()).map(|r| r.4).collect();
    effect_terms.sort_by(f64::total_cmp);
    println!(
        "largest term any candidate carried on a clean record: {:.2}% of the output's fundamental RMS; \
         the term naming the effect carried at least {:.2}% (5th percentile {:.2}%)",
        100.0 * clean_max,
        100.0 * effect_terms.first().copied().unwrap_or(f64::NAN),
        100.0 * effect_terms.get(effect_terms.len() / 20).copied().unwrap_or(f64::NAN),
    );
    let right = ok.iter().filter(|r| r.1).count();
    println!(
        "all        {right:>5}/{:<5}  share {:.1}%   ({} records, seeds from {}, {wall:.0} s wall on {} threads)",
        ok.len(),
        100.0 * right as f64 / ok.len().max(1) as f64,
        ok.len(),
        a.seed,
        rayon::current_num_threads()
    );
}

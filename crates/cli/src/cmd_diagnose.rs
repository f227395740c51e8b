//! `boucwen diagnose DATA.csv [MORE.csv …] [--realisations] [--json] [--report DIR]`: what
//! the extended model gets wrong on a record, the cause, the term that removes it and the
//! gain (see [`boucwen_lab::diagnose`]; a sine drive, or a periodic or multisine drive, see
//! [`boucwen_lab::diagnose::periodic`]). Several records run on all cores, one report (or one JSON
//! line) per record in the order given; with `--realisations` they are realisations of one
//! periodic or multisine drive, diagnosed together.

use crate::record_args::RecordArgs;
use boucwen_lab::diagnose::Outcome;
use boucwen_lab::diagnose::periodic::Realisation;
use boucwen_lab::diagnose::steps::{self, SineStep};
use boucwen_lab::record::Imported;
use boucwen_lab::report::diagnosis as text;
use boucwen_lab::rules::Rules;
use boucwen_lab::{diagnose, report};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct DiagnoseArgs {
    /// The records: t, u, y of a hysteretic actuator driven by a sine, a periodic waveform
    /// (triangle, square) or a multisine (see --columns and the units for other layouts).
    #[arg(required_unless_present = "print_rules")]
    data: Vec<PathBuf>,
    /// The rules the diagnosis decides by, from a TOML (or .json) file: any field of the
    /// table overrides its default (see --print-rules); --json echoes the rules used.
    #[arg(long, value_name = "FILE")]
    rules: Option<PathBuf>,
    /// Print the default rules as TOML (a file to start --rules from) and exit.
    #[arg(long)]
    print_rules: bool,
    /// The records are realisations of one periodic or multisine drive (the same lines, new
    /// phases): one diagnosis, the models fitted on the first and tested on the others.
    #[arg(long)]
    realisations: bool,
    #[command(flatten)]
    record: RecordArgs,
    /// Print one JSON object per record (one line each) on stdout instead of the report.
    #[arg(long)]
    json: bool,
    /// Also write the report as a page with SVG figures into this directory (one
    /// subdirectory per record when several are given).
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
}

/// One record's outcome: what to print on stdout, or the one-line error.
fn one(a: &DiagnoseArgs, rules: &Rules, path: &Path, report_dir: Option<PathBuf>) -> Result<String, String> {
    let name = path.display().to_string();
    let imported = a.record.read(path)?;
    let r = &imported.record;
    r.validate_for_fit(rules.sine.min_samples).map_err(|e| e.to_string())?;
    let given = a.record.window(r)?;
    if given.is_none() {
        if let Some(steps) = steps::diagnose_steps(&r.u, &r.y, r.ts, r.t0, rules) {
            return stepped(a, rules, &imported, &name, &steps, report_dir);
        }
    }
    let rec = Realisation { u: &r.u, y: &r.y, t0: r.t0, given };
    let d = diagnose::diagnose_drive(&[rec], r.ts, rules).map_err(|e| format!("{name}: {e}"))?;
    if let Some(dir) = &report_dir {
        write_report(&d, &r.u, &r.y, &name, dir, rules)?;
    }
    Ok(if a.json {
        let mut j = text::json(&d, rules);
        j["file"] = serde_json::json!(name);
        j["import"] = import_json(&imported);
        format!("{j}\n")
    } else {
        format!("read as {}\n{}", imported.info.describe(), text::text(&d, &name, rules))
    })
}

/// A record that steps through several sines: each step's report (or JSON line, or one
/// sentence), then what changes across the steps.
fn stepped(
    a: &DiagnoseArgs,
    rules: &Rules,
    imported: &Imported,
    name: &str,
    steps: &[SineStep],
    report_dir: Option<PathBuf>,
) -> Result<String, String> {
    let r = &imported.record;
    let t = |k: usize| r.t0 + k as f64 * r.ts;
    if steps.iter().all(|s| s.outcome.is_err()) {
        let first = steps[0].outcome.as_ref().err().map(ToString::to_string).unwrap_or_default();
        return Err(format!(
            "{name}: {}; none could be: the first ({:.3} Hz) because {first}",
            text::steps_sentence(steps, r.ts, r.t0),
            steps[0].segment.freq_hz
        ));
    }
    let mut out = String::new();
    if !a.json {
        out.push_str(&format!(
            "read as {}
{name}: {}
",
            imported.info.describe(),
            text::steps_sentence(steps, r.ts, r.t0)
        ));
    }
    for (i, s) in steps.iter().enumerate() {
        let (from, to) = (t(s.segment.start), t(s.segment.end));
        let label = format!("{name} [step {} of {}: {:.3} Hz]", i + 1, steps.len(), s.segment.freq_hz);
        let step_json = serde_json::json!({
            "index": i + 1, "of": steps.len(), "freq_hz": s.segment.freq_hz,
            "amplitude_v": s.segment.amplitude_v, "from_s": from, "to_s": to,
        });
        match &s.outcome {
            Ok(d) => {
                if let Some(dir) = &report_dir {
                    let (u, y) = (&r.u[s.segment.start..s.segment.end], &r.y[s.segment.start..s.segment.end]);
                    write_report(d, u, y, &label, &dir.join(format!("step-{}", i + 1)), rules)?;
                }
                let j = text::json(d, rules);
                if a.json {
                    let mut j = j;
                    j["file"] = serde_json::json!(name);
                    j["step"] = step_json;
                    j["import"] = import_json(imported);
                    out.push_str(&format!("{j}\n"));
                } else {
                    out.push_str(&format!(
                        "\n== step {} of {}: {from} to {to} s ==\n{}",
                        i + 1,
                        steps.len(),
                        text::text(d, &label, rules)
                    ));
                }
            }
            Err(e) => {
                if a.json {
                    let j = serde_json::json!({"file": name, "step": step_json, "error": format!("{label}: {e}")});
                    out.push_str(&format!("{j}\n"));
                } else {
                    out.push_str(&format!(
                        "\n== step {} of {}: {from} to {to} s ==\n{label}: {e}\n",
                        i + 1,
                        steps.len()
                    ));
                }
            }
        }
    }
    if !a.json {
        let across: Vec<String> = steps.iter().map(text::step_line).collect();
        out.push_str(&format!("\nacross the steps (held out):\n{}\n", across.join("\n")));
    }
    Ok(out)
}

fn write_report(
    d: &Outcome,
    u: &[f64],
    y: &[f64],
    name: &str,
    dir: &Path,
    rules: &Rules,
) -> Result<(), String> {
    match d {
        Outcome::Sine(d) => report::write_diagnosis(d, d.analysed(u), d.analysed(y), name, dir, rules),
        Outcome::Periodic(d) => report::write_periodic(d, name, dir, rules),
    }
    .map(|_| ())
    .map_err(|e| e.to_string())
}

/// The records as realisations of one drive: one diagnosis.
fn together(a: &DiagnoseArgs, rules: &Rules) -> Result<(), String> {
    let imported: Vec<Imported> = a.data.par_iter().map(|p| a.record.read(p)).collect::<Result<_, _>>()?;
    let mut recs = vec![];
    for (i, path) in imported.iter().zip(&a.data) {
        let r = &i.record;
        r.validate_for_fit(rules.sine.min_samples).map_err(|e| e.to_string())?;
        if (r.ts - imported[0].record.ts).abs() > 1e-6 * r.ts {
            return Err(format!(
                "{}: sampled every {} s, {} every {} s: realisations of one drive share the sample interval",
                path.display(),
                r.ts,
                a.data[0].display(),
                imported[0].record.ts
            ));
        }
        recs.push(Realisation { u: &r.u, y: &r.y, t0: r.t0, given: a.record.window(r)? });
    }
    let names: Vec<String> = a.data.iter().map(|p| p.display().to_string()).collect();
    let name = names.join(" + ");
    let ts = imported[0].record.ts;
    let d = diagnose::diagnose_drive(&recs, ts, rules).map_err(|e| format!("{name}: {e}"))?;
    if let Some(dir) = &a.report {
        write_report(&d, recs[0].u, recs[0].y, &name, dir, rules)?;
    }
    if a.json {
        let mut j = text::json(&d, rules);
        j["files"] = serde_json::json!(names);
        j["import"] = serde_json::json!(imported.iter().map(import_json).collect::<Vec<_>>());
        println!("{j}");
    } else {
        print!("{}", text::text(&d, &name, rules));
    }
    if let Some(dir) = &a.report {
        eprintln!("wrote {}", dir.join("index.html").display());
    }
    Ok(())
}

/// How the record was read, for the JSON.
pub fn import_json(i: &Imported) -> serde_json::Value {
    report::import_json(&i.info, i.record.len(), i.record.ts)
}

/// The rules: the defaults, or a file's overrides of them.
fn rules_of(a: &DiagnoseArgs) -> Result<Rules, String> {
    let Some(path) = &a.rules else { return Ok(Rules::default()) };
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| format!("{name}: {e}"))?;
    Rules::parse(&name, &text).map_err(|e| e.to_string())
}

pub fn run(a: DiagnoseArgs) -> Result<(), String> {
    if a.print_rules {
        print!("{}", Rules::default().to_toml());
        return Ok(());
    }
    let rules = rules_of(&a)?;
    if a.realisations {
        return together(&a, &rules);
    }
    if let [path] = a.data.as_slice() {
        if let Some(rec) = a.record.mimo(path) {
            if a.rules.is_some() || a.realisations {
                return Err("--rules and --realisations are for records of one input and one output".into());
            }
            return crate::cmd_mimo::diagnose(&rec?, a.json, a.report.as_deref());
        }
        let out = one(&a, &rules, path, a.report.clone())?;
        print!("{out}");
        if let Some(dir) = &a.report {
            eprintln!("wrote {}", dir.join("index.html").display());
        }
        return Ok(());
    }
    // Several records: all cores, printed in the order given.
    let results: Vec<Result<String, String>> = a
        .data
        .par_iter()
        .map(|path| {
            let dir = a.report.as_ref().map(|d| {
                d.join(path.file_stem().map_or_else(|| "record".into(), |s| s.to_string_lossy().into_owned()))
            });
            one(&a, &rules, path, dir)
        })
        .collect();
    let mut failed = 0;
    for (path, r) in a.data.iter().zip(results) {
        match r {
            Ok(out) if a.json => print!("{out}"),
            Ok(out) => println!("{out}"),
            Err(e) => {
                failed += 1;
                if a.json {
                    println!("{}", serde_json::json!({"file": path.display().to_string(), "error": e}));
                }
                eprintln!("boucwen: {e}");
            }
        }
    }
    match failed {
        0 => Ok(()),
        n => Err(format!("{n} of {} records could not be diagnosed (see above)", a.data.len())),
    }
}

//! The share of right diagnoses over a randomized batch of messy records: the cases of
//! `diagnose_batch` recorded and written as bench records come ([`boucwen_lab::fixtures::messy`]).
//!
//! Run with `cargo bench --bench diagnose_messy` (options after `--`: `--per-mess N`,
//! default 12, records per mess; `--seed S`, default 5000, the first seed; `--verbose`
//! prints every record; `--dump DIR` writes every record's text there with its flags in
//! `DIR/flags.txt`). For every mess of [`Mess::ALL`] it draws `N` records, cycling through
//! the effects the mess is drawn with, reads each with the flags a user would pass
//! ([`boucwen_lab::record::import_text`]) and diagnoses it in its steady window. A diagnosis
//! is right by the rule of `diagnose_batch` ([`Messy::is_right`]); a record that gets no
//! diagnosis gets one sentence (the error), which is counted and printed, and is not right.
//!
//! This is a measurement, not a test: it asserts nothing and exits 0 unless a record cannot
//! be drawn.

use boucwen_lab::diagnose;
use boucwen_lab::fixtures::messy::{Mess, Messy};
use boucwen_lab::record::import_text;
use boucwen_lab::rules::Rules;
use rayon::prelude::*;
use std::time::Instant;

struct Args {
    per_mess: u64,
    seed: u64,
    verbose: bool,
    dump: Option<std::path::PathBuf>,
}

fn args() -> Result<Args, String> {
    let mut a = Args { per_mess: 12, seed: 5000, verbose: false, dump: None };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| -> Result<u64, String> {
            let v = it.next().ok_or(format!("{name} needs a value"))?;
            v.parse().map_err(|_| format!("{name}: {v:?} is not a whole number"))
        };
        match arg.as_str() {
            "--per-mess" => a.per_mess = value("--per-mess")?,
            "--seed" => a.seed = value("--seed")?,
            "--verbose" => a.verbose = true,
            "--dump" => a.dump = Some(it.next().ok_or("--dump needs a directory")?.into()),
            "--bench" => {}
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    Ok(a)
}

/// One record's outcome: (mess, right, got a diagnosis, line).
type Outcome = (Mess, bool, bool, String);

fn main() {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("diagnose_messy: {e}");
            std::process::exit(2);
        }
    };
    let jobs: Vec<(Mess, u64)> =
        Mess::ALL.iter().flat_map(|&m| (0..a.per_mess).map(move |k| (m, a.seed + k))).collect();
    let start = Instant::now();
    let results: Vec<Result<Outcome, String>> = jobs
        .par_iter()
        .map(|&(mess, seed)| {
            let effects = mess.effects();
            let effect = effects[(seed as usize) % effects.len()];
            let m = Messy::generate(mess, effect, seed).map_err(|e| format!("{} {seed}: {e}", mess.name()))?;
            if let Some(dir) = &a.dump {
                std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
                std::fs::write(dir.join(m.file_name()), &m.text).map_err(|e| e.to_string())?;
            }
            let name = m.file_name();
            let line = match import_text(&m.text, &name, &m.opts) {
                Err(e) => return Ok((mess, false, false, format!("{name}: {e}"))),
                Ok(i) => {
                    let r = i.record;
                    match diagnose::diagnose_record(&r.u, &r.y, r.ts, r.t0, None, &Rules::default()) {
                        Err(e) => return Ok((mess, false, false, format!("{name}: {e}"))),
                        Ok(d) => {
                            let right = m.is_right(&d);
                            let first = d.findings.first().map_or("none".to_string(), |f| match f.order {
                                Some(n) => format!("{} {n} at {:.1} Hz", f.kind.as_str(), f.freq_hz),
                                None => f.kind.as_str().to_string(),
                            });
                            let [w0, w1] = d.window_s();
                            (
                                right,
                                format!(
                                    "{name}: drive {:.2} Hz, window {w0:.2}-{w1:.2} s ({:?} periods) -> {first}, gain {:.1}% {}",
                                    d.drive_hz,
                                    d.periods,
                                    d.gain_pct(),
                                    if right { "right" } else { "WRONG" }
                                ),
                            )
                        }
                    }
                }
            };
            Ok((mess, line.0, true, line.1))
        })
        .collect();
    let wall = start.elapsed().as_secs_f64();
    let mut ok: Vec<Outcome> = vec![];
    for r in results {
        match r {
            Ok(v) => ok.push(v),
            Err(e) => {
                eprintln!("diagnose_messy: {e}");
                std::process::exit(1);
            }
        }
    }
    if let Some(dir) = &a.dump {
        let flags: Vec<String> = jobs
            .iter()
            .filter_map(|&(mess, seed)| {
                let effects = mess.effects();
                let m = Messy::generate(mess, effects[(seed as usize) % effects.len()], seed).ok()?;
                Some(format!("{} {}", m.file_name(), m.flags.join(" ")))
            })
            .collect();
        let _ = std::fs::write(dir.join("flags.txt"), flags.join("\n") + "\n");
    }
    for (_, right, _, line) in &ok {
        if a.verbose || !right {
            println!("{line}");
        }
    }
    println!("\nmess             right/drawn  no diagnosis (one sentence)");
    for mess in Mess::ALL {
        let of: Vec<&Outcome> = ok.iter().filter(|r| r.0 == mess).collect();
        let right = of.iter().filter(|r| r.1).count();
        let refused = of.iter().filter(|r| !r.2).count();
        println!("{:<16} {right:>5}/{:<5}  {refused}", mess.name(), of.len());
    }
    let right = ok.iter().filter(|r| r.1).count();
    let refused = ok.iter().filter(|r| !r.2).count();
    println!(
        "all              {right:>5}/{:<5}  {refused}   share {:.1}%   ({} records, seeds from {}, {wall:.0} s wall on {} threads)",
        ok.len(),
        100.0 * right as f64 / ok.len().max(1) as f64,
        ok.len(),
        a.seed,
        rayon::current_num_threads()
    );
}

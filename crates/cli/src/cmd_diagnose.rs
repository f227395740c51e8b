//! `boucwen diagnose DATA.csv [MORE.csv …] [--json] [--report DIR]`: what the extended model
//! gets wrong on a record, the cause, the term that removes it and the gain (see
//! [`boucwen_lab::diagnose`]). Several records run on all cores, one report (or one JSON
//! line) per record in the order given.

use crate::record_args::RecordArgs;
use boucwen_lab::record::Imported;
use boucwen_lab::{diagnose, report};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct DiagnoseArgs {
    /// The records: t, u, y of a hysteretic actuator driven by a sine (see --columns and the
    /// units for other layouts).
    #[arg(required = true)]
    data: Vec<PathBuf>,
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
fn one(a: &DiagnoseArgs, path: &Path, report_dir: Option<PathBuf>) -> Result<String, String> {
    let name = path.display().to_string();
    let imported = a.record.read(path)?;
    let r = &imported.record;
    r.validate_for_fit(diagnose::MIN_SAMPLES).map_err(|e| e.to_string())?;
    let given = a.record.window(r)?;
    let d = diagnose::diagnose_record(&r.u, &r.y, r.ts, r.t0, given, &diagnose::Thresholds::default())
        .map_err(|e| format!("{name}: {e}"))?;
    if let Some(dir) = &report_dir {
        report::write_diagnosis(&d, d.analysed(&r.u), d.analysed(&r.y), &name, dir)
            .map_err(|e| e.to_string())?;
    }
    Ok(if a.json {
        let mut j = d.json();
        j["file"] = serde_json::json!(name);
        j["import"] = import_json(&imported);
        format!("{j}\n")
    } else {
        format!("read as {}\n{}", imported.info.describe(), d.summary(&name))
    })
}

/// How the record was read, for the JSON.
pub fn import_json(i: &Imported) -> serde_json::Value {
    use boucwen_lab::record::TimeSource;
    let columns: serde_json::Map<String, serde_json::Value> =
        i.info.columns.iter().map(|(role, from)| (role.to_string(), serde_json::json!(from))).collect();
    serde_json::json!({
        "separator": i.info.separator.name(),
        "header": i.info.header,
        "columns": columns,
        "u_unit": i.info.u_unit.name(),
        "y_unit": i.info.y_unit.name(),
        "sample_rate_hz": match i.info.time { TimeSource::SampleRate(hz) => Some(hz), TimeSource::Column(_) => None },
        "samples": i.record.len(),
        "ts_s": i.record.ts,
    })
}

pub fn run(a: DiagnoseArgs) -> Result<(), String> {
    if let [path] = a.data.as_slice() {
        let out = one(&a, path, a.report.clone())?;
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
            one(&a, path, dir)
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

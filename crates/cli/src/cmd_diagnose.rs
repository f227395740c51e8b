//! `boucwen diagnose DATA.csv [--json] [--report DIR]`: what the extended model gets wrong
//! on a record, the cause, the term that removes it and the gain (see
//! [`boucwen_lab::diagnose`]).

use boucwen_lab::record::Record;
use boucwen_lab::{diagnose, report};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct DiagnoseArgs {
    /// The record: CSV with columns t (s), u (V), y (µm), a sine drive.
    data: PathBuf,
    /// Print one JSON object on stdout instead of the report.
    #[arg(long)]
    json: bool,
    /// Also write the report as a page with SVG figures into this directory.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
}

pub fn run(a: DiagnoseArgs) -> Result<(), String> {
    let record = read_for_fit(&a.data)?;
    let name = a.data.display().to_string();
    let d = diagnose::diagnose(&record.u, &record.y, record.ts, &diagnose::Thresholds::default())
        .map_err(|e| format!("{name}: {e}"))?;
    if let Some(dir) = &a.report {
        report::write_diagnosis(&d, &record.u, &record.y, &name, dir).map_err(|e| e.to_string())?;
    }
    if a.json {
        println!("{}", d.json());
    } else {
        print!("{}", d.summary(&name));
    }
    if let Some(dir) = &a.report {
        eprintln!("wrote {}", dir.join("index.html").display());
    }
    Ok(())
}

/// Reads a record and checks it can be fitted: enough samples and an excited input.
pub fn read_for_fit(path: &std::path::Path) -> Result<Record, String> {
    let record = Record::read(path).map_err(|e| e.to_string())?;
    record.validate_for_fit(diagnose::MIN_SAMPLES).map_err(|e| e.to_string())?;
    Ok(record)
}

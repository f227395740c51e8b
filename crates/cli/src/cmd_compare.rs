//! `boucwen compare MODEL RECORD`: a model file (`identify --save`) run in free simulation on
//! another record's drive, its RMS error, fit and NRMSE over the record or `--window`
//! ([`boucwen_lab::identify::compare`]); `--plot FILE.svg` draws the measured and simulated
//! outputs and the error.

use crate::record_args::RecordArgs;
use boucwen_lab::identify::compare;
use boucwen_lab::model::ModelFile;
use boucwen_lab::record::write_atomic;
use boucwen_lab::report::identify as report;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct CompareArgs {
    /// The model file (written by `identify --save`).
    model: PathBuf,
    /// The record to test it on: t, u, y (see the record flags for other layouts).
    data: PathBuf,
    #[command(flatten)]
    record: RecordArgs,
    /// The record is one period of a periodic drive: score the model in steady state (the
    /// period run once before the scored one) instead of from rest.
    #[arg(long)]
    periodic: bool,
    /// Write the measured and simulated outputs and the error as an SVG figure.
    #[arg(long, value_name = "FILE.svg")]
    plot: Option<PathBuf>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(a: CompareArgs) -> Result<(), String> {
    if let Some(rec) = a.record.mimo(&a.data) {
        if a.plot.is_some() || a.periodic {
            return Err("--plot and --periodic are for records of one input and one output (a record of several is scored period by period in steady state)".into());
        }
        return crate::cmd_mimo::compare(&a.model, &rec?, a.json);
    }
    let model = ModelFile::read(&a.model).map_err(|e| e.to_string())?;
    let imported = a.record.read(&a.data)?;
    let r = &imported.record;
    let name = a.data.display().to_string();
    let window = a.record.window(r)?;
    let c = compare::compare(&model, r, window, a.periodic).map_err(|e| format!("{name}: {e}"))?;
    if let Some(path) = &a.plot {
        let title = format!("{} on {name}", model.model.name());
        write_atomic(path, report::comparison_svg(&c, r, &title).as_bytes()).map_err(|e| e.to_string())?;
        eprintln!("wrote {}", path.display());
    }
    if a.json {
        let mut j = report::comparison_json(&c, &model);
        j["file"] = serde_json::json!(name);
        j["model_file"] = serde_json::json!(a.model.display().to_string());
        println!("{j}");
    } else {
        print!("{}", report::comparison_text(&c, &model, &a.model.display().to_string(), &name, r.ts));
    }
    Ok(())
}

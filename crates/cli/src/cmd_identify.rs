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
use boucwen_lab::identify::{self, Method as LabMethod, Options, Structure};
use boucwen_lab::report::diagnosis::instability_text;
use boucwen_lab::report::identify as report;
use boucwen_lab::rules::Rules;
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

pub fn run(a: IdentifyArgs) -> Result<(), String> {
    let name = a.data.display().to_string();
    let rules = Rules::default();
    let imported = a.record.read(&a.data)?;
    let r = &imported.record;
    r.validate_for_fit(rules.sine.min_samples).map_err(|e| e.to_string())?;
    let given = a.record.window(r)?;
    let opts = Options {
        structure: match a.model {
            ModelKind::Extended => Structure::Extended,
            ModelKind::Enhanced => Structure::Enhanced,
        },
        harmonics: a.harmonics.clone(),
        method: match a.method {
            Method::Oe => LabMethod::Oe,
            Method::Rls => LabMethod::Rls,
        },
        fit_fraction: a.fit_fraction,
        drive_hz: a.drive_hz,
        invertible: a.invertible,
    };
    let o = identify::identify(r, given, &opts, &rules).map_err(|e| match e {
        identify::IdentifyError::Option(why) => why,
        e => format!("{name}: {e}"),
    })?;
    if a.json {
        let mut j = report::json(&o);
        j["file"] = serde_json::json!(name);
        j["import"] = import_json(&imported);
        println!("{j}");
    } else {
        println!("read as {}", imported.info.describe());
        print!("{}", report::text(&o, &name, &rules));
    }
    match &o.check.unstable {
        Some(why) => Err(format!(
            "{name}: no stable model was found ({} by {}): {}",
            o.model.name(),
            o.method.name(),
            instability_text(why)
        )),
        None => Ok(()),
    }
}

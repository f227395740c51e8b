//! `boucwen identify DATA.csv`: fit a model on the first part of a record's steady window
//! and report its parameters, its free-run RMS error and fit on the rest, and whether it is
//! stable (exit code 1 when it is not). Any drive: sine, periodic, multisine, aperiodic.
//!
//! `--method oe` (default) fits the free-run (output) error ([`boucwen_lab::fit::fit_oe`]);
//! `--method rls` runs the paper's section 3 RLS procedure
//! ([`boucwen_lab::fit::fit_paper_rls`], at most one branch). `--model extended` (default)
//! or `enhanced`, whose branches are `--harmonics` or, if not given, the odd harmonic that
//! stands out in the fitted part of the output (3 if none does). `--model linear`,
//! `oscillator` and `auto` fit the other families on the same split
//! ([`boucwen_lab::identify::families`]); `--save MODEL.json` writes the model kept.

use crate::cmd_diagnose::import_json;
use crate::record_args::RecordArgs;
use boucwen_lab::identify::{self, Method as LabMethod, Options, Structure, families};
use boucwen_lab::model::{Family, Model, ModelFile, TermModel};
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
    /// No hysteresis: a linear output-error model, orders chosen held out.
    Linear,
    /// The Bouc–Wen oscillator: hysteresis as a restoring force inside the structure.
    Oscillator,
    /// Every family (actuator, oscillator, linear) fitted; the best held out kept, the
    /// paper's actuator unless another is better by the rules' `families.min_gain`.
    Auto,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
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
    /// Records of several inputs and outputs: candidate orders of the state-space model
    /// (comma-separated; default 28), chosen on the realisation kept apart.
    #[arg(long = "order", value_delimiter = ',', value_name = "N")]
    orders: Vec<usize>,
    /// Records of several inputs and outputs: fit every realisation (by default the last
    /// realisation of every level is kept apart and the model scored on it).
    #[arg(long)]
    fit_all: bool,
    /// Write the model kept to this file (versioned JSON, for `compare` and `simulate
    /// --model`).
    #[arg(long, value_name = "MODEL.json")]
    save: Option<PathBuf>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(a: IdentifyArgs) -> Result<(), String> {
    if let Some(rec) = a.record.mimo(&a.data) {
        if !matches!(a.model, ModelKind::Extended | ModelKind::Linear)
            || a.method == Method::Rls
            || !a.harmonics.is_empty()
        {
            return Err("a record of several inputs and outputs takes --model extended (the hysteretic state-space model, the default) or linear".into());
        }
        let m = crate::cmd_mimo::IdentifyMimo {
            linear: a.model == ModelKind::Linear,
            orders: &a.orders,
            fit_all: a.fit_all,
            save: a.save.as_deref(),
            json: a.json,
        };
        return crate::cmd_mimo::identify(&rec?, &m);
    }
    if !a.orders.is_empty() || a.fit_all {
        return Err("--order and --fit-all are for records of several inputs and outputs".into());
    }
    let name = a.data.display().to_string();
    let rules = Rules::default();
    let imported = a.record.read(&a.data)?;
    let r = &imported.record;
    r.validate_for_fit(rules.sine.min_samples).map_err(|e| e.to_string())?;
    let given = a.record.window(r)?;
    let families = match a.model {
        ModelKind::Linear => Some(vec![Family::Linear]),
        ModelKind::Oscillator => Some(vec![Family::Oscillator]),
        ModelKind::Auto => Some(Family::ALL.to_vec()),
        ModelKind::Extended | ModelKind::Enhanced => None,
    };
    if families.is_some() && (a.method == Method::Rls || !a.harmonics.is_empty()) {
        return Err("--method rls and --harmonics go with --model extended or enhanced".into());
    }
    let opts = Options {
        structure: match a.model {
            ModelKind::Enhanced => Structure::Enhanced,
            _ => Structure::Extended,
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
    let fail = |e: identify::IdentifyError| match e {
        identify::IdentifyError::Option(why) => why,
        e => format!("{name}: {e}"),
    };
    if let Some(families) = families {
        let c = families::compare(r, given, &families, &opts, &rules).map_err(fail)?;
        if a.json {
            let mut j = report::families_json(&c);
            j["file"] = serde_json::json!(name);
            j["import"] = import_json(&imported);
            println!("{j}");
        } else {
            println!("read as {}", imported.info.describe());
            print!("{}", report::families_text(&c, &name, &rules));
        }
        let kept = &c.scores[c.chosen];
        let Ok(model) = &kept.model else {
            return Err(format!("{name}: the {} model could not be fitted", kept.family.name()));
        };
        if let Some(path) = &a.save {
            save(path, model.clone(), r.ts, &name, kept.held_rms_um)?;
        }
        return match kept.held_rms_um {
            Some(_) => Ok(()),
            None => {
                Err(format!("{name}: the {} model's free run is not stable held out", kept.family.name()))
            }
        };
    }
    let o = identify::identify(r, given, &opts, &rules).map_err(fail)?;
    if a.json {
        let mut j = report::json(&o);
        j["file"] = serde_json::json!(name);
        j["import"] = import_json(&imported);
        println!("{j}");
    } else {
        println!("read as {}", imported.info.describe());
        print!("{}", report::text(&o, &name, &rules));
    }
    if let (Some(path), None) = (&a.save, &o.check.unstable) {
        let model = Model::Actuator(TermModel::from(o.model.clone()));
        save(path, model, r.ts, &name, Some(o.held_rms_um))?;
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

/// Writes the model file (atomically) and says so on stderr.
fn save(
    path: &std::path::Path,
    model: Model,
    ts: f64,
    source: &str,
    held: Option<f64>,
) -> Result<(), String> {
    let f = ModelFile {
        model,
        ts_s: ts,
        u_unit: "V".into(),
        fitted_on: Some(source.to_string()),
        held_out_rms_um: held,
    };
    f.write(path).map_err(|e| e.to_string())?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

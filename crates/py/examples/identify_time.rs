//! The Rust side of the Python module's overhead measurement (docs/book/src/python.md): the
//! median wall time of `identify` on a record, called as `boucwen.identify` calls it
//! (the fit check, the identification, the model file and the report), without Python.
//!
//! ```sh
//! cargo run --release -p boucwen-py --example identify_time -- RECORD.csv [MODEL] [RUNS]
//! python examples/python/identify_time.py RECORD.csv   # both sides, in alternating rounds
//! ```
//! `MODEL`: extended (default), enhanced, oscillator, linear or auto.

use boucwen_lab::identify::{self, Options, Structure, families};
use boucwen_lab::model::{Family, Model, ModelFile, TermModel};
use boucwen_lab::record::{self, ImportOptions};
use boucwen_lab::report::identify as report;
use boucwen_lab::rules::Rules;
use std::time::Instant;

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args.first().ok_or("usage: identify_time RECORD.csv [MODEL] [RUNS]")?;
    let model = args.get(1).map_or("extended", String::as_str);
    let runs: usize = args.get(2).map_or(Ok(7), |n| n.parse()).map_err(|e| format!("RUNS: {e}"))?;
    let r = record::import(path, &ImportOptions::default()).map_err(|e| e.to_string())?.record;
    let families = match model {
        "auto" => Some(Family::ALL.to_vec()),
        "oscillator" => Some(vec![Family::Oscillator]),
        "linear" => Some(vec![Family::Linear]),
        "extended" | "enhanced" => None,
        other => return Err(format!("MODEL {other:?}: extended, enhanced, oscillator, linear or auto")),
    };
    let opts = Options {
        structure: if model == "enhanced" { Structure::Enhanced } else { Structure::Extended },
        ..Options::default()
    };
    let mut times = vec![];
    let mut held = 0.0;
    for _ in 0..runs {
        let t = Instant::now();
        let rules = Rules::default();
        r.validate_for_fit(rules.sine.min_samples).map_err(|e| e.to_string())?;
        let (m, rms, json) = match &families {
            Some(f) => {
                let c = families::compare(&r, None, f, &opts, &rules).map_err(|e| e.to_string())?;
                let kept = &c.scores[c.chosen];
                (kept.model.clone()?, kept.held_rms_um, report::families_json(&c))
            }
            None => {
                let o = identify::identify(&r, None, &opts, &rules).map_err(|e| e.to_string())?;
                (Model::Actuator(TermModel::from(o.model.clone())), Some(o.held_rms_um), report::json(&o))
            }
        };
        let file =
            ModelFile { model: m, ts_s: r.ts, u_unit: "V".into(), fitted_on: None, held_out_rms_um: rms };
        std::hint::black_box((file.to_json(), json));
        times.push(t.elapsed().as_secs_f64());
        held = rms.unwrap_or(f64::NAN);
    }
    let each: Vec<String> = times.iter().map(|t| format!("{t:.4}")).collect();
    times.sort_by(f64::total_cmp);
    println!(
        "rust identify --model {model}: {} samples, median {:.4} s of {runs} runs (min {:.4}, max {:.4}), held out {held:.6} µm; each: {}",
        r.len(),
        times[runs / 2],
        times[0],
        times[runs - 1],
        each.join(" ")
    );
    Ok(())
}

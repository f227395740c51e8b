//! The commands on records of several inputs and outputs (a folder of NumPy files `u_TAG.npy`
//! / `y_TAG.npy`, an `.npz`, or a CSV with `--columns u=…,…,y=…,…`): `identify` fits one
//! model for every level ([`boucwen_lab::mimo::fit_mimo`]), `compare` scores a model file on
//! a record with the benchmark's metric, `diagnose` splits what a linear model leaves into
//! noise and nonlinear distortion per level and output ([`boucwen_lab::mimo::bla`]).

use boucwen_lab::mimo::bla::diagnose_level;
use boucwen_lab::mimo::fit::{FitOptions, benchmark_outputs};
use boucwen_lab::mimo::spectra::Spectra;
use boucwen_lab::mimo::{MimoModelFile, Progress, fit_mimo};
use boucwen_lab::record::mimo::MimoRecord;
use boucwen_lab::record::write_atomic;
use boucwen_lab::report::mimo::{self as report, LevelComparison};
use std::path::Path;
use std::time::Instant;

/// What `identify` asks of a MIMO fit.
pub struct IdentifyMimo<'a> {
    /// Only the linear model (no hysteresis).
    pub linear: bool,
    /// Candidate orders (empty: the default).
    pub orders: &'a [usize],
    /// Fit every realisation, none kept apart.
    pub fit_all: bool,
    /// Write the model here.
    pub save: Option<&'a Path>,
    /// One JSON object on stdout.
    pub json: bool,
}

/// `identify` on a MIMO record.
pub fn identify(rec: &MimoRecord, a: &IdentifyMimo) -> Result<(), String> {
    let mut opts = FitOptions::default();
    if a.linear {
        opts = opts.linear();
    }
    if !a.orders.is_empty() {
        if let Some(n) = a.orders.iter().find(|&&n| !(2..=200).contains(&n)) {
            return Err(format!("--order {n}: an order of 2 to 200 states"));
        }
        opts.orders = a.orders.to_vec();
    }
    let realisations = rec.levels.iter().map(|l| l.u.realisations).min().unwrap_or(0);
    opts.holdout = (!a.fit_all && realisations >= 2).then(|| realisations - 1);
    if !a.fit_all && realisations < 2 {
        eprintln!("one realisation per level: every one fitted, nothing kept apart to score the model on");
    }
    let t0 = Instant::now();
    let progress =
        |p: &Progress| eprintln!("[{:6.1} s] {}: {}", t0.elapsed().as_secs_f64(), p.stage, p.message);
    let fit = fit_mimo(rec, &opts, &progress).map_err(|e| format!("{}: {e}", rec.source))?;
    if a.json {
        println!("{}", report::identify_json(rec, &fit, opts.holdout));
    } else {
        print!("{}", report::identify_text(rec, &fit, opts.holdout));
    }
    if let Some(path) = a.save {
        let held = fit
            .held_out
            .as_ref()
            .map(|h| if h.hysteretic.is_empty() { h.linear.clone() } else { h.hysteretic.clone() });
        let f = MimoModelFile {
            model: fit.model.clone(),
            fitted_on: Some(rec.source.clone()),
            held_out_um: held.unwrap_or_default(),
            rate_given: rec.rate_given,
            period_samples: Some(rec.dims().2),
        };
        f.write(path).map_err(|e| e.to_string())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// `compare` of a MIMO model file on a MIMO record: every realisation and period of every
/// level.
pub fn compare(model_path: &Path, rec: &MimoRecord, json: bool) -> Result<(), String> {
    let f = MimoModelFile::read(model_path).map_err(|e| e.to_string())?;
    let fs = f.model.sample_rate_hz;
    if f.rate_given && rec.rate_given && ((rec.sample_rate_hz - fs) / fs).abs() > 1e-6 {
        return Err(format!("{}: sampled at {} Hz, the model at {fs} Hz", rec.source, rec.sample_rate_hz));
    }
    let levels = rec
        .levels
        .iter()
        .map(|l| {
            let all: Vec<usize> = (0..l.u.realisations).collect();
            let outputs_um = benchmark_outputs(&f.model, l, &all)
                .map_err(|e| format!("{} ({}): {e}", rec.source, l.tag))?;
            let mean_um = outputs_um.iter().sum::<f64>() / outputs_um.len() as f64;
            Ok(LevelComparison { tag: l.tag.clone(), outputs_um, mean_um })
        })
        .collect::<Result<Vec<_>, String>>()?;
    let name = model_path.display().to_string();
    if json {
        println!("{}", report::compare_json(&name, rec, &levels));
    } else {
        print!("{}", report::compare_text(&name, rec, &levels));
    }
    Ok(())
}

/// `diagnose` of a MIMO record: the BLA split per level and output; `--report DIR` writes the
/// BLA of each level as `bla-TAG.svg` and the JSON.
pub fn diagnose(rec: &MimoRecord, json: bool, report_dir: Option<&Path>) -> Result<(), String> {
    let fail = |e: boucwen_lab::mimo::MimoError| format!("{}: {e}", rec.source);
    let sp = Spectra::new(rec, &|_, _| true).map_err(fail)?;
    let diags = (0..rec.levels.len())
        .map(|li| diagnose_level(&sp, li))
        .collect::<Result<Vec<_>, _>>()
        .map_err(fail)?;
    let j = report::diagnosis_json(rec, &diags);
    if let Some(dir) = report_dir {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        for (l, d) in rec.levels.iter().zip(&diags) {
            let name = if l.tag.is_empty() { "bla.svg".to_string() } else { format!("bla-{}.svg", l.tag) };
            write_atomic(&dir.join(name), report::bla_svg(rec, d).as_bytes()).map_err(|e| e.to_string())?;
        }
        write_atomic(&dir.join("diagnosis.json"), format!("{j}\n").as_bytes()).map_err(|e| e.to_string())?;
        eprintln!("wrote {}", dir.display());
    }
    if json {
        println!("{j}");
    } else {
        print!("{}", report::diagnosis_text(rec, &diags));
    }
    Ok(())
}

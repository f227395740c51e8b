//! `boucwen simulate`: run the virtual bimorph (or, with `--model`, a model file) on a drive
//! signal and write the record
//! ([`boucwen_lab::experiments::simulate`]).

use anyhow::{Context, bail};
use boucwen_lab::experiments::simulate::{self, Drive};
use boucwen_sim::Scenario;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// The record to write (CSV with t, u, y).
    #[arg(long, default_value = "simulate.csv")]
    out: PathBuf,
    /// Scenario file of the virtual bimorph (TOML); the paper's actuator if omitted.
    #[arg(long, conflicts_with = "model")]
    scenario: Option<PathBuf>,
    /// Run this model file (`identify --save`) instead of the virtual bimorph, on the drive
    /// of --input (its column `u` unless --column says otherwise); the output file has the
    /// same rows with the model's prediction as `y [um]`.
    #[arg(long, value_name = "MODEL.json", requires = "input", conflicts_with = "freq")]
    model: Option<PathBuf>,
    /// Sine drive: frequency (Hz).
    #[arg(long, conflicts_with_all = ["input", "column"])]
    freq: Option<f64>,
    /// Sine drive: amplitude (V).
    #[arg(long, default_value_t = 1.0)]
    amplitude: f64,
    /// Sine drive: length (s).
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Drive from a CSV file (header row; comma-separated).
    #[arg(long)]
    input: Option<PathBuf>,
    /// The column of `--input` holding the drive (V); `u` by default.
    #[arg(long, requires = "input")]
    column: Option<String>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(a: SimulateArgs) -> anyhow::Result<()> {
    if let Some(model) = &a.model {
        let input = a.input.as_deref().context("--model needs --input FILE")?;
        let column = a.column.as_deref().unwrap_or("u");
        let s = simulate::run_model(model, input, column, &a.out)?;
        if a.json {
            println!("{}", serde_json::to_string(&s).context("JSON of the summary")?);
        } else {
            let at = if s.ts_s.is_finite() { format!("at {} s", s.ts_s) } else { "(per sample)".into() };
            println!(
                "{}: {} samples {at}, y from {:.3} to {:.3} µm",
                s.drive, s.samples, s.y_min_um, s.y_max_um
            );
            eprintln!("wrote {}", s.out);
        }
        return Ok(());
    }
    let scenario = match &a.scenario {
        Some(p) => Scenario::from_path(p)?,
        None => Scenario::default(),
    };
    let drive = match (a.freq, a.input, a.column) {
        (Some(freq_hz), None, None) => Drive::Sine { freq_hz, amplitude_v: a.amplitude, seconds: a.seconds },
        (None, Some(path), name) => Drive::Column { path, name: name.unwrap_or_else(|| "u".into()) },
        _ => bail!("give a sine drive (--freq HZ) or a drive file (--input FILE --column NAME)"),
    };
    let s = simulate::run(&scenario, &drive, &a.out)?;
    if a.json {
        println!("{}", serde_json::to_string(&s).context("JSON of the summary")?);
        return Ok(());
    }
    println!(
        "{}: {} samples at {} s, y from {:.3} to {:.3} µm",
        s.drive, s.samples, s.ts_s, s.y_min_um, s.y_max_um
    );
    let fund = s.harmonics.first().map_or(0.0, |h| h.amp_um);
    for h in s.harmonics.iter().filter(|h| h.order % 2 == 1) {
        let rel = if h.order == 1 {
            String::new()
        } else {
            format!(" ({:.1}% of the fundamental)", 100.0 * h.amp_um / fund)
        };
        println!("  harmonic {} at {:.1} Hz: {:.4} µm{rel}", h.order, h.freq_hz, h.amp_um);
    }
    eprintln!("wrote {}", s.out);
    Ok(())
}

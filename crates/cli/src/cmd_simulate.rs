//! `boucwen simulate`: run the virtual bimorph on a drive signal and write the record.
//!
//! The drive is a sine (`--freq`, `--amplitude`, `--seconds`) or a column of a CSV file
//! (`--input FILE --column NAME`). A drive file needs a header row; if it has a `t` column,
//! its sample interval must be the scenario's. The record (`t,u,y`) is written atomically.

use boucwen_lab::record::Record;
use boucwen_lab::{analysis, experiment};
use boucwen_sim::{Bimorph, Scenario};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// The record to write (CSV with t, u, y).
    #[arg(long, default_value = "simulate.csv")]
    out: PathBuf,
    /// Scenario file of the virtual bimorph (TOML); the paper's actuator if omitted.
    #[arg(long)]
    scenario: Option<PathBuf>,
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
    #[arg(long, requires = "column")]
    input: Option<PathBuf>,
    /// The column of `--input` holding the drive (V).
    #[arg(long, requires = "input")]
    column: Option<String>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// Longest record `simulate` writes (samples): 10⁷ (about 3 hours at 1 kHz).
const MAX_SAMPLES: usize = 10_000_000;

pub fn run(a: SimulateArgs) -> Result<(), String> {
    let scenario = match &a.scenario {
        Some(p) => Scenario::from_path(p).map_err(|e| e.to_string())?,
        None => Scenario::default(),
    };
    let ts = scenario.sampling.ts_s;
    let (u, name) = match (&a.freq, &a.input, &a.column) {
        (Some(f), None, None) => (sine_drive(*f, a.amplitude, a.seconds, ts)?, format!("sine {f} Hz")),
        (None, Some(path), Some(col)) => (column_drive(path, col, ts)?, format!("{}:{col}", path.display())),
        _ => return Err("give a sine drive (--freq HZ) or a drive file (--input FILE --column NAME)".into()),
    };
    let y = Bimorph::new(&scenario).map_err(|e| e.to_string())?.run(&u).map_err(|e| e.to_string())?;
    let record = Record::new(&a.out.display().to_string(), 0.0, ts, u, y, None).map_err(|e| e.to_string())?;
    record.write(&a.out).map_err(|e| e.to_string())?;
    let (lo, hi) =
        record.y.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    // For a sine: the fundamental and the odd harmonics over the second half.
    let harmonics = a.freq.map(|f| {
        let half = &record.y[record.len() / 2..];
        let n = analysis::whole_periods(half.len(), f, ts);
        analysis::harmonics(&half[..n], f, ts, 7)
    });
    if a.json {
        let h: Vec<serde_json::Value> = harmonics
            .iter()
            .flatten()
            .enumerate()
            .map(|(i, t)| serde_json::json!({"order": i + 1, "freq_hz": t.freq_hz, "amp_um": t.amp}))
            .collect();
        println!(
            "{}",
            serde_json::json!({
                "out": a.out.display().to_string(),
                "drive": name,
                "samples": record.len(),
                "ts_s": ts,
                "y_min_um": lo,
                "y_max_um": hi,
                "harmonics": h,
            })
        );
    } else {
        println!("{name}: {} samples at {} s, y from {lo:.3} to {hi:.3} µm", record.len(), ts);
        if let Some(h) = &harmonics {
            let fund = h.first().map_or(0.0, |t| t.amp);
            for (i, t) in h.iter().enumerate().filter(|(i, _)| *i == 0 || i % 2 == 0) {
                let rel = if i == 0 {
                    String::new()
                } else {
                    format!(" ({:.1}% of the fundamental)", 100.0 * t.amp / fund)
                };
                println!("  harmonic {} at {:.1} Hz: {:.4} µm{rel}", i + 1, t.freq_hz, t.amp);
            }
        }
        eprintln!("wrote {}", a.out.display());
    }
    Ok(())
}

fn sine_drive(f: f64, amplitude: f64, seconds: f64, ts: f64) -> Result<Vec<f64>, String> {
    if !(f.is_finite() && f > 0.0 && f < 0.5 / ts) {
        return Err(format!("--freq {f}: must be above 0 and below the Nyquist frequency {} Hz", 0.5 / ts));
    }
    if !(amplitude.is_finite() && amplitude.abs() <= 1000.0) {
        return Err(format!("--amplitude {amplitude}: must be a finite number of volts, at most 1000"));
    }
    if !(seconds.is_finite() && seconds > 0.0 && seconds / ts <= MAX_SAMPLES as f64) {
        return Err(format!("--seconds {seconds}: must be above 0 and give at most {MAX_SAMPLES} samples"));
    }
    let n = ((seconds / ts).round() as usize).max(2);
    experiment::sine(amplitude, f, ts, n).map_err(|e| e.to_string())
}

/// The drive column `name` of a CSV file; `ts` is the scenario's sample interval, which a
/// `t` column must match.
fn column_drive(path: &Path, name: &str, ts: f64) -> Result<Vec<f64>, String> {
    let file = path.display();
    let text = std::fs::read_to_string(path).map_err(|e| format!("{file}: {e}"))?;
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((hline, header)) = lines.next() else {
        return Err(format!("{file}: empty file"));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    if names.iter().any(|n| n.parse::<f64>().is_ok()) {
        return Err(format!("{file}:{hline}: no header row (the first row is numbers)"));
    }
    let Some(col) = names.iter().position(|n| *n == name) else {
        return Err(format!("{file}:{hline}: no column \"{name}\" (columns: {})", names.join(", ")));
    };
    let t_col = names.iter().position(|n| *n == "t");
    let (mut u, mut t) = (vec![], vec![]);
    for (line, row) in lines {
        let fields: Vec<&str> = row.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err(format!("{file}:{line}: {} fields, the header has {}", fields.len(), names.len()));
        }
        let value = |j: usize| -> Result<f64, String> {
            let v: f64 = fields[j].parse().map_err(|_| {
                format!("{file}:{line}: column \"{}\": \"{}\" is not a number", names[j], fields[j])
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("{file}:{line}: column \"{}\": {v} is not finite", names[j]))
            }
        };
        let v = value(col)?;
        if v.abs() > 1000.0 {
            return Err(format!("{file}:{line}: column \"{name}\": {v} V is beyond ±1000 V"));
        }
        u.push(v);
        if let Some(j) = t_col {
            let tk = value(j)?;
            if t.last().is_some_and(|&p| tk <= p) {
                return Err(format!("{file}:{line}: time {tk} does not increase"));
            }
            t.push(tk);
        }
        if u.len() > MAX_SAMPLES {
            return Err(format!("{file}:{line}: more than {MAX_SAMPLES} samples"));
        }
    }
    if u.len() < 2 {
        return Err(format!("{file}: {} samples, at least 2 needed", u.len()));
    }
    if t.len() >= 2 {
        let file_ts = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
        if ((file_ts - ts) / ts).abs() > 0.01 {
            return Err(format!(
                "{file}: sampled every {file_ts} s, the virtual bimorph every {ts} s (resample the drive or set \
                 [sampling] in the scenario)"
            ));
        }
    }
    Ok(u)
}

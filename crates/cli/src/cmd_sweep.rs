//! `boucwen sweep`: the paper's identification and compensation experiments over a frequency
//! range on the virtual bimorph; with `--measured DIR`, the identification half from measured
//! records ([`boucwen_lab::experiments::sweep_measured`]).

use crate::record_args::RecordArgs;
use boucwen_lab::design::ResponseSource;
use boucwen_lab::experiments::sweep::{self, HarmonicChoice, SweepOptions, cell};
use boucwen_lab::experiments::sweep_measured::{self, MeasuredInput};
use boucwen_lab::report;
use boucwen_sim::Scenario;
use clap::ValueEnum;
use rayon::prelude::*;
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(Clone, Copy, ValueEnum)]
enum Harmonics {
    /// From the data: the odd harmonic dominating the extended model's residual.
    Auto,
    /// The paper's table: 5th at 14 Hz, 3rd at 18–28 Hz.
    Paper,
}

#[derive(Clone, Copy, ValueEnum)]
enum Phase {
    /// Identified at the operating point: the drive plus a small probe at n·f.
    Probe,
    /// The identified model's frequency response at n·f.
    Model,
    /// The paper's table (eqs. 22/23): 0 below 66 Hz, π above.
    Table,
}

#[derive(clap::Args)]
pub struct SweepArgs {
    /// Output directory for sweep.csv and the figures.
    #[arg(long, default_value = "sweep-out")]
    out: PathBuf,
    /// Lowest drive frequency (Hz).
    #[arg(long, default_value_t = 1.0)]
    from: f64,
    /// Highest drive frequency (Hz).
    #[arg(long, default_value_t = 50.0)]
    to: f64,
    /// Frequency step (Hz).
    #[arg(long, default_value_t = 1.0)]
    step: f64,
    /// Length of each record: the identification run and each tracking run (s).
    #[arg(long, default_value_t = 15.0)]
    seconds: f64,
    /// Scenario file of the virtual bimorph (TOML); the paper's actuator if omitted.
    #[arg(long)]
    scenario: Option<PathBuf>,
    /// How the enhanced model's harmonic order is chosen.
    #[arg(long, value_enum, default_value_t = Harmonics::Auto)]
    harmonics: Harmonics,
    /// Where the harmonic cancellation takes the actuator's response at n·f from.
    #[arg(long, value_enum, default_value_t = Phase::Probe)]
    phase: Phase,
    /// Print one JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Sweep measured records instead of the virtual bimorph: a directory of records of one
    /// actuator, one sine frequency each, and one broadband (multisine) record for the
    /// structure (without it, the structure is fitted to the sines' fundamentals, at least 3
    /// frequencies); the lowest sine at or below 2 Hz gives the loop shape. Writes sweep.csv
    /// (the tracking columns nan), modelling_error.svg, summary.txt and sweep.json.
    #[arg(long, value_name = "DIR")]
    measured: Option<PathBuf>,
    /// How to read the measured records (with --measured).
    #[command(flatten)]
    record: RecordArgs,
}

/// `--measured DIR`: read the records on all cores, sweep them, write the files.
fn run_measured(a: &SweepArgs, dir: &std::path::Path) -> anyhow::Result<()> {
    if a.record.window_given() {
        anyhow::bail!("--window is not used with --measured: each record's steady window is found in it");
    }
    let paths = sweep_measured::records_in(dir)?;
    let inputs: Vec<MeasuredInput> = paths
        .par_iter()
        .map(|p| MeasuredInput { name: p.display().to_string(), record: a.record.read(p).map(|i| i.record) })
        .collect();
    let m = sweep_measured::run(inputs)?;
    let files = report::write_measured_sweep(&m, &a.out)?;
    if a.json {
        let mut j = m.json();
        j["files"] = serde_json::json!(files.iter().map(|p| p.display().to_string()).collect::<Vec<_>>());
        println!("{j}");
    } else {
        print!("{}", m.summary());
        eprintln!("wrote {} files to {}", files.len(), a.out.display());
    }
    if a.json {
        for s in &m.skipped {
            eprintln!("skipped {}", s.line());
        }
    }
    eprintln!(
        "{} frequencies in {:.2} s on {} threads",
        m.rows.len(),
        m.wall_s,
        rayon::current_num_threads()
    );
    Ok(())
}

pub fn run(a: SweepArgs) -> anyhow::Result<()> {
    if let Some(dir) = &a.measured {
        return run_measured(&a, dir);
    }
    let scenario = match &a.scenario {
        Some(p) => Scenario::from_path(p)?,
        None => Scenario::default(),
    };
    let mut opts = SweepOptions::paper(a.seconds);
    opts.freqs = sweep::frequencies(a.from, a.to, a.step)?;
    opts.scenario = scenario;
    opts.harmonics = match a.harmonics {
        Harmonics::Auto => HarmonicChoice::Auto,
        Harmonics::Paper => HarmonicChoice::Paper,
    };
    opts.response = match a.phase {
        Phase::Probe => ResponseSource::Probe,
        Phase::Model => ResponseSource::Model,
        Phase::Table => ResponseSource::Table { flip_hz: 66.0 },
    };
    let bar = std::io::stderr().is_terminal().then(|| {
        let b = indicatif::ProgressBar::new(opts.freqs.len() as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frequencies  {elapsed}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    });
    let tick = || {
        if let Some(b) = &bar {
            b.inc(1);
        }
    };
    let result = sweep::run(&opts, &tick)?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let files = report::write_sweep(&result, &a.out)?;
    if a.json {
        println!("{}", serde_json::to_string(&result.summary(&files))?);
    } else {
        print_table(&result);
        eprintln!("wrote {} files to {}", files.len(), a.out.display());
    }
    eprintln!(
        "{:.0} s of actuator time in {:.2} s on {} threads: {:.0}x real time",
        result.actuator_s,
        result.wall_s,
        rayon::current_num_threads(),
        result.speedup()
    );
    Ok(())
}

fn print_table(r: &sweep::SweepResult) {
    if let Some(f) = r.structure.resonance_hz {
        println!(
            "structure (broadband record): resonance {f:.1} Hz, fit RMS {:.3} µm",
            r.structure.rms_fit_um
        );
    }
    println!(
        "{:>7} {:>5} | {:>9} {:>9} {:>9} {:>9} | {:>9} {:>9} {:>9} {:>9} | {:>9} {:>9} {:>9}",
        "f (Hz)",
        "n/c/c",
        "ext",
        "enh",
        "u_f",
        "proposed",
        "ext OE",
        "enh OE",
        "u_f OE",
        "prop OE",
        "open",
        "PI",
        "ORC"
    );
    println!(
        "{:>13} | {:^39} | {:^39} | {:^29}",
        "", "paper RLS (µm)", "output-error fit (µm)", "peers (µm)"
    );
    for w in &r.rows {
        println!(
            "{:>7.2} {:>5} | {:>9} {:>9} {:>9} {:>9} | {:>9} {:>9} {:>9} {:>9} | {:>9} {:>9} {:>9}",
            w.freq_hz,
            format!("{}/{}/{}", w.harmonic_order, w.cancel_order, w.cancel_order_oe),
            cell(w.rms_extended_um),
            cell(w.rms_enhanced_um),
            cell(w.rmse_uf_um),
            cell(w.rmse_proposed_um),
            cell(w.rms_extended_oe_um),
            cell(w.rms_enhanced_oe_um),
            cell(w.rmse_uf_oe_um),
            cell(w.rmse_proposed_oe_um),
            cell(w.rmse_open_um),
            cell(w.rmse_pi_um),
            cell(w.rmse_orc_um)
        );
    }
}

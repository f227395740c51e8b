//! Validation records for the Bouc–Wen benchmark made from its published equations (the
//! official test records are held back): the multisine test (one steady-state period of a
//! realisation other than the training one) for each seed asked, and the sine sweep from
//! rest (20 → 50 Hz, 40 N, 153,000 samples), noise-free, as CSV files `t,u,y` with `y` in m.
//!
//! `cargo run --release -p boucwen-sim --example benchmark_records -- DIR [SEED…]`
//! (seeds 101, 202, 303 by default) writes `DIR/multisine-SEED.csv` and `DIR/sweep.csv`.
//! The sweep's law is an assumption (the benchmark gives its band, amplitude and length):
//! linear over the whole record ([`boucwen_sim::oscillator::sine_sweep`]).

use boucwen_sim::oscillator::{BenchmarkRecord, BoucWenOscillator, FS_HZ, Multisine, SWEEP_SAMPLES};
use std::io::Write;
use std::path::Path;

fn write(path: &Path, r: &BenchmarkRecord) -> std::io::Result<()> {
    let mut text = String::from("t,u,y\n");
    for (k, (u, y)) in r.u.iter().zip(&r.y).enumerate() {
        text.push_str(&format!("{:.8},{u},{y}\n", k as f64 / FS_HZ));
    }
    std::fs::File::create(path)?.write_all(text.as_bytes())?;
    println!("wrote {} ({} samples)", path.display(), r.u.len());
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = args.next().ok_or("usage: benchmark_records DIR [SEED…]")?;
    let seeds: Vec<u64> = args.map(|s| s.parse()).collect::<Result<_, _>>()?;
    let seeds = if seeds.is_empty() { vec![101, 202, 303] } else { seeds };
    std::fs::create_dir_all(&dir)?;
    let osc = BoucWenOscillator::default();
    for seed in seeds {
        let r = osc.multisine_steady_period(&Multisine::benchmark(seed)?)?;
        write(&Path::new(&dir).join(format!("multisine-{seed}.csv")), &r)?;
    }
    let r = osc.sweep_record(SWEEP_SAMPLES, 20.0, 50.0, 40.0)?;
    write(&Path::new(&dir).join("sweep.csv"), &r)?;
    Ok(())
}

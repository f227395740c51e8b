//! Prints the harmonic table of a scenario: amplitude of harmonics 1..7 (relative to the
//! fundamental) and the fundamental's amplitude and phase, for sinusoidal drives.
//!
//! ```text
//! cargo run --release -p boucwen-sim --example harmonics -- [scenario.toml] [amplitude_v] [freqs…]
//! ```
//! Defaults: the built-in default scenario with noise, drift and quantisation off, 1 V, and
//! f = 1, 10, 14, 15, 20, 22, 23, 24, 30, 35, 40, 50 Hz. Each run settles 4 s and fits the
//! next 4 s.

use boucwen_sim::measure::harmonic_fit;
use boucwen_sim::{Bimorph, Scenario, SimError};

fn main() -> Result<(), SimError> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scenario = match args.first() {
        Some(p) if p != "-" => Scenario::from_path(p)?,
        _ => Scenario::ideal(),
    };
    let amp: f64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1.0);
    let mut freqs: Vec<f64> = args.iter().skip(2).filter_map(|s| s.parse().ok()).collect();
    if freqs.is_empty() {
        freqs = vec![1.0, 10.0, 14.0, 15.0, 20.0, 22.0, 23.0, 24.0, 30.0, 35.0, 40.0, 50.0];
    }
    let ts = scenario.sampling.ts_s;
    let (settle, record) = ((4.0 / ts) as usize, (4.0 / ts) as usize);
    println!("drive {amp} V; harmonics as % of the fundamental");
    println!(
        "{:>6} {:>9} {:>8} {:>7} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>8}",
        "f Hz", "A1 µm", "φ1 deg", "offset", "H2%", "H3%", "H4%", "H5%", "H6%", "H7%", "resid"
    );
    for &f in &freqs {
        let mut plant = Bimorph::new(&scenario)?;
        let orders = ((0.5 / (f * ts)).ceil() as usize - 1).min(7);
        let u: Vec<f64> =
            (0..settle + record).map(|k| amp * (std::f64::consts::TAU * f * k as f64 * ts).sin()).collect();
        let y = plant.run(&u)?;
        let fit = harmonic_fit(&y[settle..], settle, f, ts, orders)?;
        let h1 = fit.harmonics[0];
        print!("{f:>6.1} {:>9.3} {:>8.1} {:>7.2}", h1.amplitude, h1.phase_rad.to_degrees(), fit.offset);
        for n in 2..=7 {
            match fit.relative(n) {
                Some(r) => print!(" {:>6.2}", 100.0 * r),
                None => print!(" {:>6}", "-"),
            }
        }
        println!(" {:>8.4}", fit.residual_rms);
    }
    Ok(())
}

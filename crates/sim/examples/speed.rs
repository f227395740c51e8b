//! Measures the cost of one simulated sample (release mode):
//!
//! ```text
//! cargo run --release -p boucwen-sim --example speed [scenario.toml]
//! ```
//! Runs 23 Hz at 1 V for 200 s of actuator time (200,000 samples) five times and prints
//! the best time per sample. Timing belongs in benches; this is a quick check.

use boucwen_sim::{Bimorph, Scenario, SimError};
use std::time::Instant;

fn main() -> Result<(), SimError> {
    let scenario = match std::env::args().nth(1) {
        Some(p) => Scenario::from_path(p)?,
        None => Scenario::default(),
    };
    let mut plant = Bimorph::new(&scenario)?;
    let ts = plant.ts_s();
    let n = 200_000;
    let u: Vec<f64> = (0..n).map(|k| (std::f64::consts::TAU * 23.0 * k as f64 * ts).sin()).collect();
    let mut best = f64::INFINITY;
    let mut checksum = 0.0;
    for _ in 0..5 {
        plant.reset();
        let t0 = Instant::now();
        for &uk in &u {
            checksum += plant.step(uk)?;
        }
        best = best.min(t0.elapsed().as_secs_f64());
    }
    println!(
        "{:.0} ns/sample (best of 5 runs of {n} samples, substeps = {}; checksum {checksum:.3})",
        best / n as f64 * 1e9,
        scenario.sampling.substeps
    );
    Ok(())
}

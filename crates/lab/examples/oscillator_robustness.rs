//! How far the oscillator fit's start (one linear mode, the stiffness split evenly, the loop
//! off) carries: systems other than the benchmark's, each fitted on two noisy periods of one
//! multisine realisation (7.4 µm noise) and scored on a steady period of another, noise-free.
//!
//! `cargo run --release -p boucwen-lab --example oscillator_robustness`

use boucwen_lab::fit::oscillator::{OscillatorOptions, fit_oscillator};
use boucwen_lab::signal::analysis::rms_diff;
use boucwen_sim::oscillator::{BoucWenOscillator, FS_HZ, MULTISINE_PERIOD, Multisine, add_noise};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let b = BoucWenOscillator::default();
    let cases = [
        ("benchmark", b, false),
        ("loop twice as strong (beta 2e3)", BoucWenOscillator { beta: 2e3, ..b }, false),
        (
            "small loop share (k 8e4, alpha 2e4)",
            BoucWenOscillator { stiffness_n_per_m: 8e4, alpha_n_per_m: 2e4, ..b },
            false,
        ),
        ("saturating loop (gamma 0.5, delta 0.5)", BoucWenOscillator { gamma: 0.5, delta: 0.5, ..b }, false),
        ("nu 1.5 (beta 150), nu fitted", BoucWenOscillator { nu: 1.5, beta: 150.0, ..b }, true),
    ];
    let ts = 1.0 / FS_HZ;
    let n = MULTISINE_PERIOD;
    for (name, sys, fit_nu) in cases {
        let mut train = sys.multisine_record(&Multisine::benchmark(21)?, 2)?;
        add_noise(&mut train.y, 7.4e-6, 21);
        let test = sys.multisine_steady_period(&Multisine::benchmark(22)?)?;
        let opt = OscillatorOptions { fit_nu, ..OscillatorOptions::benchmark(n) };
        let t0 = Instant::now();
        match fit_oscillator(&train.u, &train.y, ts, &opt) {
            Ok(f) => {
                let e = rms_diff(&f.model.simulate_periodic(&test.u, ts, 1)?, &test.y);
                let p = f.model.params;
                println!(
                    "{name}: output RMS {:.0} µm, fit {:.3} µm, test {:.3} µm, {:.1} s, {} iterations; \
                     m {:.4} c {:.3} k {:.0} alpha {:.0} bg {:.2} bd {:.2} nu {:.4} \
                     (truth bg {:.2} bd {:.2})",
                    rms_diff(&test.y, &vec![0.0; n]) * 1e6,
                    f.rms_fit * 1e6,
                    e * 1e6,
                    t0.elapsed().as_secs_f64(),
                    f.iterations,
                    p.m,
                    p.c,
                    p.k,
                    p.alpha,
                    p.beta_gamma,
                    p.beta_delta,
                    p.nu,
                    sys.beta * sys.gamma,
                    sys.beta * sys.delta
                );
            }
            Err(e) => println!("{name}: fit failed: {e}"),
        }
    }
    Ok(())
}

//! The Bouc–Wen oscillator fit finds a hysteresis hidden in the restoring force.
//!
//! Records come from the virtual oscillator (`boucwen_sim::oscillator`, the benchmark's
//! published equations, integrator and decimation): the fit sees one multisine realisation
//! (two periods from rest, 7.4 µm of white noise, as the benchmark's training record) and is
//! judged on another realisation in steady state and on a sine sweep from rest, both
//! noise-free. The oscillator must come within a fraction of the noise of them, with its
//! identifiable parameters near the truth; the best linear model of orders 3/3 must be far
//! worse, so what gains is the hysteresis in the restoring force.

use boucwen_lab::fit::Tolerances;
use boucwen_lab::fit::linear::fit_linear_oe;
use boucwen_lab::fit::oscillator::{OscillatorOptions, fit_oscillator};
use boucwen_lab::model::linear::OeOrders;
use boucwen_lab::model::oscillator::{OscillatorModel, OscillatorParams};
use boucwen_lab::signal::analysis::rms_diff;
use boucwen_sim::oscillator::{BoucWenOscillator, FS_HZ, MULTISINE_PERIOD, Multisine, add_noise};

const NOISE_M: f64 = 7.4e-6;

#[test]
fn oscillator_finds_the_hysteresis_and_generalises() {
    let truth = BoucWenOscillator::default();
    let ts = 1.0 / FS_HZ;
    let n = MULTISINE_PERIOD;
    let mut train = truth.multisine_record(&Multisine::benchmark(11).expect("multisine"), 2).expect("train");
    add_noise(&mut train.y, NOISE_M, 11);
    let test = truth.multisine_steady_period(&Multisine::benchmark(12).expect("multisine")).expect("test");
    let sweep = truth.sweep_record(20_000, 20.0, 50.0, 40.0).expect("sweep");

    let fit = fit_oscillator(&train.u, &train.y, ts, &OscillatorOptions::benchmark(n)).expect("fit");
    // The residual on the training record is the noise.
    assert!((fit.rms_fit / NOISE_M - 1.0).abs() < 0.05, "fit {:.3} µm", fit.rms_fit * 1e6);
    let e_ms = rms_diff(&fit.model.simulate_periodic(&test.u, ts, 1).expect("sim"), &test.y);
    let e_sw = rms_diff(&fit.model.simulate(&sweep.u, ts).expect("sim"), &sweep.y);
    assert!(e_ms < 0.15 * NOISE_M, "multisine test {:.3} µm", e_ms * 1e6);
    assert!(e_sw < 0.15 * NOISE_M, "sweep test {:.3} µm", e_sw * 1e6);

    // The identifiable parameters, near the truth.
    let p = fit.model.params;
    let t = OscillatorParams::BENCHMARK;
    for (name, got, want, rel) in [
        ("m", p.m, t.m, 0.005),
        ("c", p.c, t.c, 0.05),
        ("k", p.k, t.k, 0.01),
        ("alpha", p.alpha, t.alpha, 0.01),
        ("beta_gamma", p.beta_gamma, t.beta_gamma, 0.02),
        ("beta_delta", p.beta_delta, t.beta_delta, 0.02),
    ] {
        assert!((got / want - 1.0).abs() < rel, "{name}: {got} vs {want}");
    }

    // The linear model is far worse on the same test.
    let lin = fit_linear_oe(
        &train.u,
        &train.y,
        OeOrders { nb: 3, nf: 3, nk: 0 },
        0..train.u.len(),
        &Tolerances::default(),
    )
    .expect("linear");
    let e_lin = rms_diff(&lin.model.simulate_periodic(&test.u, 1).expect("sim"), &test.y);
    assert!(
        e_lin > 50e-6 && e_lin > 100.0 * e_ms,
        "linear {:.1} µm vs oscillator {:.3} µm",
        e_lin * 1e6,
        e_ms * 1e6
    );
}

#[test]
fn model_files_round_trip_and_bad_input_is_an_error() {
    let m = OscillatorModel::benchmark_truth();
    let text = serde_json::to_string(&m).expect("json");
    let back: OscillatorModel = serde_json::from_str(&text).expect("parse");
    assert_eq!(back, m);
    let names: Vec<&str> = m.params().iter().map(|(n, _)| *n).collect();
    assert_eq!(names, ["m", "c", "k", "alpha", "beta_gamma", "beta_delta", "nu"]);
    let mut u = vec![1.0; 200];
    u[50] = f64::NAN;
    assert!(m.simulate(&u, 1.0 / FS_HZ).is_err());
    let bad = OscillatorModel { params: OscillatorParams { m: -1.0, ..OscillatorParams::BENCHMARK }, ..m };
    assert!(bad.simulate(&[0.0; 200], 1.0 / FS_HZ).is_err());
}

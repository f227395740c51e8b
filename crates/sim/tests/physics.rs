//! The virtual bimorph's physics against the behaviour it must show (paper figs. 6 and 15)
//! and its numerical and signal-chain properties.

use boucwen_sim::measure::{HarmonicFit, harmonic_fit};
use boucwen_sim::scenario::{CreepTerm, StiffeningTerm};
use boucwen_sim::{Bimorph, Scenario, SimError};
use std::f64::consts::TAU;

fn sine(amplitude_v: f64, freq_hz: f64, ts_s: f64, n: usize) -> Vec<f64> {
    (0..n).map(|k| amplitude_v * (TAU * freq_hz * k as f64 * ts_s).sin()).collect()
}

/// Drives `scenario` with a sine, discards `settle_s` and fits harmonics 1..=7 (fewer if
/// they would pass Nyquist) over the next `record_s`.
fn harmonics(
    scenario: &Scenario,
    amplitude_v: f64,
    freq_hz: f64,
    settle_s: f64,
    record_s: f64,
) -> HarmonicFit {
    let ts = scenario.sampling.ts_s;
    let settle = (settle_s / ts) as usize;
    let record = (record_s / ts) as usize;
    let mut plant = Bimorph::new(scenario).unwrap();
    let y = plant.run(&sine(amplitude_v, freq_hz, ts, settle + record)).unwrap();
    let orders = ((0.5 / (freq_hz * ts)).ceil() as usize - 1).min(7);
    harmonic_fit(&y[settle..], settle, freq_hz, ts, orders).unwrap()
}

fn rel(fit: &HarmonicFit, n: usize) -> f64 {
    fit.relative(n).unwrap()
}

#[test]
fn halving_the_integration_step_changes_the_output_by_less_than_the_sensor_resolution() {
    let coarse = Scenario::ideal();
    let fine = Scenario::ideal().with_substeps(16);
    let ts = coarse.sampling.ts_s;
    for &f in &[1.0, 14.0, 23.0, 35.0, 50.0] {
        let u = sine(1.0, f, ts, 4000);
        let y8 = Bimorph::new(&coarse).unwrap().run(&u).unwrap();
        let y16 = Bimorph::new(&fine).unwrap().run(&u).unwrap();
        let worst = y8.iter().zip(&y16).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(worst < 0.01, "{f} Hz: substeps 8 vs 16 differ by {worst} µm");
    }
}

#[test]
fn default_scenario_shows_odd_harmonic_oscillation_at_14_and_23_hz_only() {
    let s = Scenario::ideal();
    let f23 = harmonics(&s, 1.0, 23.0, 4.0, 4.0);
    let f14 = harmonics(&s, 1.0, 14.0, 4.0, 4.0);
    let f15 = harmonics(&s, 1.0, 15.0, 4.0, 4.0);
    // Fundamental of order 20 µm at 1 V.
    assert!((15.0..30.0).contains(&f23.harmonics[0].amplitude), "{:?}", f23.harmonics[0]);
    assert!(rel(&f23, 3) > 0.15, "23 Hz third harmonic {}", rel(&f23, 3));
    assert!(rel(&f14, 5) > 0.08, "14 Hz fifth harmonic {}", rel(&f14, 5));
    assert!(rel(&f15, 5) < 0.05, "15 Hz fifth harmonic {}", rel(&f15, 5));
    for &f in &[10.0, 30.0, 40.0] {
        let fit = harmonics(&s, 1.0, f, 4.0, 4.0);
        for n in 2..=fit.harmonics.len() {
            assert!(rel(&fit, n) < 0.05, "{f} Hz harmonic {n}: {}", rel(&fit, n));
        }
    }
}

#[test]
fn the_stiffening_is_the_main_source_of_the_23_hz_third_harmonic() {
    let with = harmonics(&Scenario::ideal(), 1.0, 23.0, 4.0, 4.0);
    let without = harmonics(&Scenario::ideal().without_stiffening(), 1.0, 23.0, 4.0, 4.0);
    assert!(
        rel(&without, 3) < 0.5 * rel(&with, 3),
        "third harmonic {} with the stiffening, {} without",
        rel(&with, 3),
        rel(&without, 3)
    );
    let f14 = harmonics(&Scenario::ideal().without_stiffening(), 1.0, 14.0, 4.0, 4.0);
    assert!(rel(&f14, 5) < 0.02, "14 Hz fifth harmonic without stiffening {}", rel(&f14, 5));
}

#[test]
fn the_loop_polarity_inverts_between_66_and_69_hz() {
    // Small drive, where the stiffening is negligible: the bending resonance alone.
    let s = Scenario::ideal();
    let phase = |f: f64| harmonics(&s, 0.02, f, 3.0, 2.0).harmonics[0].phase_rad.to_degrees();
    let (p66, p69) = (phase(66.0), phase(69.0));
    assert!(p66 > -70.0, "66 Hz phase {p66}°");
    assert!(p69 < -110.0, "69 Hz phase {p69}°");
}

#[test]
fn phase_lag_grows_with_frequency_at_one_volt() {
    let s = Scenario::ideal();
    let phases: Vec<f64> = [1.0, 10.0, 30.0, 40.0, 50.0]
        .iter()
        .map(|&f| harmonics(&s, 1.0, f, 4.0, 2.0).harmonics[0].phase_rad.to_degrees())
        .collect();
    assert!(phases.windows(2).all(|w| w[1] < w[0]), "{phases:?}");
    assert!(phases[0] < 0.0 && phases[4] < -5.0, "{phases:?}");
}

#[test]
fn the_one_hertz_loop_is_off_centre() {
    let fit = harmonics(&Scenario::ideal(), 1.0, 1.0, 20.0, 4.0);
    // The loop's centre sits below zero by a sizeable fraction of its amplitude.
    assert!(fit.offset < -0.03 * fit.harmonics[0].amplitude, "offset {} µm", fit.offset);
}

#[test]
fn the_sensor_quantises_to_its_resolution() {
    let s = Scenario::default();
    let mut plant = Bimorph::new(&s).unwrap();
    let y = plant.run(&sine(1.0, 7.0, s.sampling.ts_s, 3000)).unwrap();
    for &v in &y {
        let steps = v / 0.01;
        assert!((steps - steps.round()).abs() < 1e-6, "{v} is not a multiple of 0.01 µm");
    }
    assert!(y.iter().any(|v| v.abs() > 5.0));
}

#[test]
fn dac_and_driver_saturate() {
    let s = Scenario::ideal();
    let mut plant = Bimorph::new(&s).unwrap();
    let d = plant.step_detail(100.0).unwrap();
    assert_eq!(d.u_dac_v, 10.0);
    let d = plant.step_detail(-100.0).unwrap();
    assert_eq!(d.u_dac_v, -10.0);

    // 16-bit quantisation: a code of 10/32768 V, and the top code is one below +10 V.
    let q = Bimorph::new(&Scenario::default()).unwrap();
    let lsb = 10.0 / 32768.0;
    assert_eq!(q.dac(100.0), 10.0 - lsb);
    assert_eq!(q.dac(-100.0), -10.0);
    assert_eq!(q.dac(0.3 * lsb), 0.0);
    assert_eq!(q.dac(0.7 * lsb), lsb);

    // Driver rails: gain 20 asks for 200 V, the output settles at the 150 V rail.
    let mut hot = Scenario::ideal();
    hot.driver.gain = 20.0;
    let mut plant = Bimorph::new(&hot).unwrap();
    let mut v = 0.0f64;
    for _ in 0..20 {
        v = plant.step_detail(10.0).unwrap().v_v;
    }
    assert!((v - 150.0).abs() < 1e-9, "driver output {v} V");
}

#[test]
fn same_seed_same_record_different_seed_different_noise() {
    let s = Scenario::default();
    let u = sine(1.0, 5.0, s.sampling.ts_s, 2000);
    let a = Bimorph::new(&s).unwrap().run(&u).unwrap();
    let b = Bimorph::new(&s).unwrap().run(&u).unwrap();
    assert_eq!(a, b);
    let c = Bimorph::new(&s.clone().with_seed(2)).unwrap().run(&u).unwrap();
    let differing = a.iter().zip(&c).filter(|(x, y)| x != y).count();
    assert!(differing > 1000, "only {differing} of 2000 samples differ");
    // The difference is noise of two independent draws (σ = 0.01 µm each) plus the walks.
    let rms = (a.iter().zip(&c).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64).sqrt();
    assert!((0.005..0.05).contains(&rms), "rms difference {rms} µm");

    // Reset repeats the record exactly.
    let mut plant = Bimorph::new(&s).unwrap();
    let first = plant.run(&u).unwrap();
    plant.reset();
    assert_eq!(plant.run(&u).unwrap(), first);
}

#[test]
fn non_finite_input_is_rejected_and_leaves_the_plant_untouched() {
    let s = Scenario::default();
    let u = sine(1.0, 5.0, s.sampling.ts_s, 500);
    let clean = Bimorph::new(&s).unwrap().run(&u).unwrap();
    let mut plant = Bimorph::new(&s).unwrap();
    let mut y = Vec::new();
    for (k, &uk) in u.iter().enumerate() {
        if k == 250 {
            assert_eq!(plant.step(f64::NAN), Err(SimError::NonFiniteInput { sample: 250 }));
            assert!(plant.step(f64::INFINITY).is_err());
        }
        y.push(plant.step(uk).unwrap());
    }
    assert_eq!(y, clean);
    assert!(Bimorph::new(&s).unwrap().run(&[0.0, f64::NAN]).is_err());
}

#[test]
fn a_structure_that_escapes_reports_divergence_without_panicking() {
    let mut s = Scenario::ideal();
    // Strong softening: the restoring force vanishes at 9 µm and the beam escapes.
    s.structure.modes[0].stiffening = vec![StiffeningTerm { power: 3, coeff: -5.0 }];
    let mut plant = Bimorph::new(&s).unwrap();
    let mut result = Ok(0.0);
    for _ in 0..5000 {
        result = plant.step(10.0);
        if result.is_err() {
            break;
        }
    }
    assert!(matches!(result, Err(SimError::Diverged { .. })), "{result:?}");
    let k = plant.samples();
    assert!(plant.step(10.0).is_err());
    assert_eq!(plant.samples(), k, "a failed step must not advance the plant");
}

#[test]
fn transport_delay_holds_the_output_at_rest() {
    // 3.3 ms rounds to 26 steps of 0.125 ms = 3.25 ms: the command of sample 0 reaches the
    // driver 0.75 ms before the end of interval 3.
    let mut s = Scenario::ideal();
    s.delay.transport_s = 3.3e-3;
    let mut plant = Bimorph::new(&s).unwrap();
    assert!((plant.effective_delay_s() - 3.25e-3).abs() < 1e-12);
    let y: Vec<f64> = (0..5).map(|_| plant.step(1.0).unwrap()).collect();
    assert_eq!(&y[..3], &[0.0, 0.0, 0.0]);
    assert!(y[3] != 0.0 && y[4] > y[3], "{y:?}");

    let mut plant = Bimorph::new(&Scenario::ideal().without_delay()).unwrap();
    assert!(plant.step(1.0).unwrap() != 0.0);
}

#[test]
fn creep_adds_slow_deflection_under_a_held_input() {
    let mut s = Scenario::ideal();
    s.creep.terms = vec![CreepTerm { amplitude: 0.05, tau_s: 2.0 }];
    let hold = |s: &Scenario| {
        let mut plant = Bimorph::new(s).unwrap();
        let y = plant.run(&vec![1.0; 12_000]).unwrap();
        (y[1999], y[11_999])
    };
    let (early, late) = hold(&s);
    // 5 % with τ = 2 s: from 2 s (the bending transient has died out) to 12 s the creep
    // state grows by 5 %·(e^-1 - e^-6) of the instantaneous deflection.
    let expected = 0.05 * ((-1.0f64).exp() - (-6.0f64).exp()) / (1.0 + 0.05 * (1.0 - (-6.0f64).exp()));
    let grown = (late - early) / late;
    assert!((grown - expected).abs() < 0.01, "grew {grown}, expected about {expected}");
    let (early, late) = hold(&s.without_creep());
    assert!(((late - early) / late).abs() < 1e-3);
}

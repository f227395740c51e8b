//! The virtual bimorph through the core's `Plant` trait.

use boucwen_core::Plant;
use boucwen_sim::{Bimorph, Scenario, SimError};

/// The command of a short identification run: a 23 Hz sine of 1.5 V at 1 kHz.
fn sine(n: usize, ts: f64) -> Vec<f64> {
    (0..n).map(|k| 1.5 * (2.0 * std::f64::consts::PI * 23.0 * k as f64 * ts).sin()).collect()
}

fn run<P: Plant<f64> + ?Sized>(p: &mut P, u: &[f64]) -> Result<Vec<f64>, P::Error> {
    let mut y = vec![0.0; u.len()];
    p.run_into(u, &mut y)?;
    Ok(y)
}

#[test]
fn bimorph_through_the_trait_resets_to_a_repeatable_run() {
    let mut bimorph = Bimorph::new(&Scenario::default()).unwrap();
    let plant: &mut dyn Plant<f64, Error = SimError> = &mut bimorph;
    assert_eq!(plant.name(), "virtual bimorph");
    let ts = plant.sample_interval_s();
    assert!(ts > 0.0);
    let u = sine(500, ts);
    let first = run(plant, &u).unwrap();
    let moved = first.iter().fold(0.0f64, |m, y| m.max(y.abs()));
    assert!(moved > 1.0, "the actuator moves under 1.5 V (peak {moved} µm)");
    plant.reset().unwrap();
    assert_eq!(run(plant, &u).unwrap(), first, "reset reseeds noise: same run");
}

#[test]
fn bimorph_rejects_non_finite_input_and_keeps_its_state() {
    let scenario = Scenario::default();
    let mut a = Bimorph::new(&scenario).unwrap();
    let mut b = Bimorph::new(&scenario).unwrap();
    let u = sine(50, a.ts_s());
    let ya = run(&mut a, &u[..25]).unwrap();
    let e = Plant::step(&mut a, f64::INFINITY).unwrap_err();
    assert_eq!(e, SimError::NonFiniteInput { sample: 25 });
    let ya_rest = run(&mut a, &u[25..]).unwrap();
    let yb = run(&mut b, &u).unwrap();
    assert_eq!([ya, ya_rest].concat(), yb, "the rejected sample left no trace");
}

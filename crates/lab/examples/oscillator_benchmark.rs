//! The Bouc–Wen benchmark end to end: fits the oscillator (and linear output-error models) on
//! `train.csv` only, and scores them on held-out periods of it and on test records made by
//! the virtual oscillator from the published equations (other multisine realisations in
//! steady state, the sine sweep from rest), all noise-free.
//!
//! `cargo run --release -p boucwen-lab --example oscillator_benchmark -- [train.csv] [--folds] [--more]`
//!
//! `--folds` refits with each period of `train.csv` held out in turn; `--more` fits with `ν`
//! free, and fits on a generated noisy sweep (cubic-spline input) instead of `train.csv`.

use boucwen_lab::fit::Tolerances;
use boucwen_lab::fit::linear::{fit_linear_oe, select_linear_oe};
use boucwen_lab::fit::oscillator::{OscillatorOptions, fit_oscillator, free_run_rms};
use boucwen_lab::model::linear::OeOrders;
use boucwen_lab::model::oscillator::{InputReconstruction, OscillatorModel};
use boucwen_lab::signal::analysis::rms_diff;
use boucwen_sim::oscillator::{
    BoucWenOscillator, FS_HZ, MULTISINE_PERIOD, Multisine, SWEEP_SAMPLES, add_noise,
};
use std::time::Instant;

fn read(path: &str) -> Result<(Vec<f64>, Vec<f64>), Box<dyn std::error::Error>> {
    let text = std::fs::read_to_string(path)?;
    let (mut u, mut y) = (Vec::new(), Vec::new());
    for line in text.lines().skip(1) {
        let f: Vec<f64> = line.split(',').map(str::parse).collect::<Result<_, _>>()?;
        u.push(f[1]);
        y.push(f[2]);
    }
    Ok((u, y))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args.iter().find(|a| !a.starts_with("--")).cloned();
    let path = path.unwrap_or_else(|| "../shared/data/bouc-wen-benchmark/train.csv".into());
    let folds = args.iter().any(|a| a == "--folds");
    let (u, y) = read(&path)?;
    let ts = 1.0 / FS_HZ;
    let n = MULTISINE_PERIOD;
    let periods = u.len() / n;
    let um = 1e6;

    // Test records from the published equations.
    let truth = BoucWenOscillator::default();
    let t0 = Instant::now();
    let tests: Vec<_> = [101u64, 202, 303]
        .iter()
        .map(|&s| Multisine::benchmark(s).and_then(|ms| truth.multisine_steady_period(&ms)))
        .collect::<Result<_, _>>()?;
    let sweep = truth.sweep_record(SWEEP_SAMPLES, 20.0, 50.0, 40.0)?;
    println!("test records simulated in {:.1} s", t0.elapsed().as_secs_f64());
    let y_rms = rms_diff(&tests[0].y, &vec![0.0; n]);
    println!(
        "multisine test output RMS {:.1} µm, sweep output RMS {:.1} µm",
        y_rms * um,
        rms_diff(&sweep.y, &vec![0.0; sweep.y.len()]) * um
    );

    // The truth as a model (the protocol's floor).
    let tm = OscillatorModel::benchmark_truth();
    for (i, t) in tests.iter().enumerate() {
        let sim = tm.simulate_periodic(&t.u, ts, 1)?;
        println!("true model, multisine test {}: {:.3} µm", i + 1, rms_diff(&sim, &t.y) * um);
    }
    let sim = tm.simulate(&sweep.u, ts)?;
    println!("true model, sweep: {:.3} µm", rms_diff(&sim, &sweep.y) * um);

    // Linear models.
    let tol = Tolerances::default();
    let t0 = Instant::now();
    let sel = select_linear_oe(
        &u,
        &y,
        0..(periods - 1) * n,
        (periods - 1) * n..periods * n,
        OeOrders { nb: 5, nf: 5, nk: 1 },
        &tol,
    )?;
    println!(
        "linear order selection in {:.1} s (fit periods 1..{}, held out {periods}):",
        t0.elapsed().as_secs_f64(),
        periods - 1
    );
    for s in &sel.scores {
        println!(
            "  nb {} nf {} nk {}: fit {:.2} µm, held out {:.2} µm",
            s.orders.nb,
            s.orders.nf,
            s.orders.nk,
            s.rms_fit * um,
            s.rms_held_out * um
        );
    }
    let c = sel.scores[sel.chosen].orders;
    println!("  chosen: nb {} nf {} nk {}", c.nb, c.nf, c.nk);
    for o in [OeOrders { nb: 3, nf: 3, nk: 0 }, OeOrders { nb: 3, nf: 3, nk: 1 }, c] {
        let lf = fit_linear_oe(&u, &y, o, 0..u.len(), &tol)?;
        let ms: Vec<f64> = tests
            .iter()
            .map(|t| lf.model.simulate_periodic(&t.u, 1).map(|s| rms_diff(&s, &t.y) * um))
            .collect::<Result<_, _>>()?;
        let sw = rms_diff(&lf.model.simulate(&sweep.u)?, &sweep.y) * um;
        println!(
            "linear OE nb {} nf {} nk {} on all of train.csv: fit {:.2} µm; multisine tests {:.2?} µm; sweep {:.2} µm",
            o.nb,
            o.nf,
            o.nk,
            lf.rms_fit * um,
            ms,
            sw
        );
    }

    // The oscillator on all of train.csv.
    let opt = OscillatorOptions::benchmark(n);
    let input = InputReconstruction::Periodic { period: n };
    let t0 = Instant::now();
    let fit = fit_oscillator(&u, &y, ts, &opt)?;
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "oscillator fit on train.csv in {secs:.2} s: {:.3} µm, {} after {} iterations, {} evaluations",
        fit.rms_fit * um,
        fit.stop,
        fit.iterations,
        fit.evaluations
    );
    for (name, v) in fit.model.params() {
        println!("  {name} = {v:.6}");
    }
    for p in 0..periods {
        let r = free_run_rms(&fit.model, &u, &y, ts, input, p * n..(p + 1) * n)?;
        println!("  residual on period {}: {:.3} µm", p + 1, r * um);
    }
    for (i, t) in tests.iter().enumerate() {
        let sim = fit.model.simulate_periodic(&t.u, ts, 1)?;
        println!(
            "  multisine test {} (seed {}): e_RMS {:.3} µm",
            i + 1,
            [101, 202, 303][i],
            rms_diff(&sim, &t.y) * um
        );
    }
    let sim = fit.model.simulate(&sweep.u, ts)?;
    println!("  sweep: e_RMS {:.3} µm", rms_diff(&sim, &sweep.y) * um);

    if folds {
        // Each period held out in turn: fitted on the others' samples (the simulation still
        // runs from rest through the whole record, so the held-out period is free-run).
        for p in 0..periods {
            let scored = vec![0..p * n, (p + 1) * n..periods * n];
            let o = OscillatorOptions { scored: scored.clone(), ..opt.clone() };
            let f = fit_oscillator(&u, &y, ts, &o)?;
            let held = free_run_rms(&f.model, &u, &y, ts, input, p * n..(p + 1) * n)?;
            let test = rms_diff(&f.model.simulate_periodic(&tests[0].u, ts, 1)?, &tests[0].y);
            println!(
                "fold: fitted on samples {:?}, period {} held out: {:.3} µm (fit {:.3} µm, multisine test 1 {:.3} µm)",
                scored,
                p + 1,
                held * um,
                f.rms_fit * um,
                test * um
            );
        }
    }
    if args.iter().any(|a| a == "--more") {
        let score = |m: &OscillatorModel| -> Result<(Vec<f64>, f64), Box<dyn std::error::Error>> {
            let ms: Vec<f64> = tests
                .iter()
                .map(|t| m.simulate_periodic(&t.u, ts, 1).map(|s| rms_diff(&s, &t.y) * um))
                .collect::<Result<_, _>>()?;
            Ok((ms, rms_diff(&m.simulate(&sweep.u, ts)?, &sweep.y) * um))
        };
        let o = OscillatorOptions { fit_nu: true, ..opt.clone() };
        let t0 = Instant::now();
        let f = fit_oscillator(&u, &y, ts, &o)?;
        let (ms, sw) = score(&f.model)?;
        println!(
            "ν free on train.csv: {:.2} s, fit {:.3} µm, ν = {:.5}; multisine tests {:.3?} µm, sweep {:.3} µm",
            t0.elapsed().as_secs_f64(),
            f.rms_fit * um,
            f.model.params.nu,
            ms,
            sw
        );
        // Fitted on a generated sweep (40,000 samples from rest, 7.4 µm noise), the input
        // reconstructed by the cubic spline.
        let mut rec = truth.sweep_record(40_000, 20.0, 50.0, 40.0)?;
        add_noise(&mut rec.y, 7.4e-6, 9);
        let o = OscillatorOptions { input: InputReconstruction::CubicSpline, ..opt.clone() };
        let t0 = Instant::now();
        let f = fit_oscillator(&rec.u, &rec.y, ts, &o)?;
        let (ms, sw) = score(&f.model)?;
        println!(
            "fitted on a generated 40,000-sample sweep: {:.2} s, fit {:.3} µm; multisine tests {:.3?} µm, full sweep {:.3} µm",
            t0.elapsed().as_secs_f64(),
            f.rms_fit * um,
            ms,
            sw
        );
        for (name, v) in f.model.params() {
            println!("  {name} = {v:.6}");
        }
    }
    Ok(())
}

//! Speed of the output-error fit, and of a whole diagnosis against the record's length.
//!
//! Run with `cargo bench --bench fit` (`-- --quick` for a short run). IDs:
//! - `fit/oe/extended/20k`, `fit/oe/enhanced3/20k`: `fit::fit_oe` as `boucwen identify`
//!   runs it (the diagnosis' fit options, five starts) on the first half of a 20,000-sample
//!   record of the virtual bimorph with a hidden 3rd harmonic (seed 1);
//! - `fit/oscillator/benchmark`: `fit::oscillator::fit_oscillator` on the Bouc–Wen
//!   benchmark's training record (`../shared/data/bouc-wen-benchmark/train.csv` from the
//!   workspace root; skipped with a message when missing), the benchmark's options;
//! - `diagnose/10k`, `diagnose/100k`, `diagnose/1m`: reading a CSV record of the default
//!   actuator under a 23 Hz sine (10⁴, 10⁵, 10⁶ samples at 1 kHz) and diagnosing it, as
//!   `boucwen diagnose` does (less the printing). The records are simulated and written
//!   before the timing.
//!
//! - `mimo/simulate/...`: one simulation of a MIMO model of the Fine Steering Mirror's size
//!   (`mimo_simulate`).
//!
//! Before the timing, one run of each prints what it fitted or found.

use boucwen_lab::design::closed_loop;
use boucwen_lab::diagnose;
use boucwen_lab::fit::oscillator::{OscillatorOptions, fit_oscillator};
use boucwen_lab::fit::{self, Averaging, OeOptions};
use boucwen_lab::fixtures::hidden::{Case, Effect};
use boucwen_lab::model::ModelSpec;
use boucwen_lab::record::Record;
use boucwen_lab::rules::Rules;
use boucwen_lab::signal::analysis;
use boucwen_sim::oscillator::{FS_HZ, MULTISINE_PERIOD};
use boucwen_sim::{Bimorph, Scenario};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Duration;

fn fits(c: &mut Criterion) {
    let mut case = Case::generate(Effect::OddHarmonic(3), 1).expect("case");
    case.seconds = 20.0;
    let rec = case.record().expect("record");
    let (u, y, ts) = (&rec.u, &rec.y, rec.ts);
    let split = u.len() / 2;
    let f = analysis::estimate_drive(u, ts).expect("drive");
    let opt = OeOptions {
        averaging: Averaging::Periods,
        ..diagnose::plan::fit_options(split, ts, &Rules::default())
    };
    let mut g = c.benchmark_group("fit/oe");
    g.sample_size(20).measurement_time(Duration::from_secs(10));
    for (id, spec) in
        [("extended/20k", ModelSpec::extended(f)), ("enhanced3/20k", ModelSpec::enhanced(f, &[3]))]
    {
        let run = || fit::fit_oe(u, y, ts, split, &spec, &[], &opt).expect("fit");
        let first = run();
        let held = fit::free_run_rms(&first.model, u, y, ts, split).expect("simulate");
        println!(
            "fit/oe/{id}: {} held out {held:.4} µm, {} after {} iterations, {} evaluations",
            first.model.name(),
            first.stop,
            first.iterations,
            first.evaluations
        );
        g.bench_function(id, |b| b.iter(|| black_box(run().rms_fit)));
    }
    g.finish();
}

fn diagnoses(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("boucwen-bench-fit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let scenario = Scenario::default();
    let ts = scenario.sampling.ts_s;
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10).warm_up_time(Duration::from_millis(1)).measurement_time(Duration::from_secs(20));
    for (id, n) in [("10k", 10_000), ("100k", 100_000), ("1m", 1_000_000)] {
        let u = closed_loop::sine(1.0, 23.0, ts, n).expect("drive");
        let y = Bimorph::new(&scenario).and_then(|mut b| b.run(&u)).expect("simulation");
        let path = dir.join(format!("sine23-{id}.csv"));
        Record::new("sine23", 0.0, ts, u, y, None).and_then(|r| r.write(&path)).expect("record");
        let run = || {
            let r = Record::read(&path).expect("read");
            r.validate_for_fit(Rules::default().sine.min_samples).expect("valid");
            diagnose::diagnose(&r.u, &r.y, r.ts, &Rules::default()).expect("diagnosis")
        };
        let t0 = std::time::Instant::now();
        let d = run();
        println!(
            "diagnose/{id}: {} -> {} held out {:.4} -> {:.4} µm in {:.2} s",
            d.baseline.name(),
            d.model.name(),
            d.baseline_rms_um,
            d.model_rms_um,
            t0.elapsed().as_secs_f64()
        );
        g.bench_function(id, |b| b.iter(|| black_box(run().model_rms_um)));
    }
    g.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

/// `mimo/simulate`: one simulation of a MIMO model of the Fine Steering Mirror's size (order
/// 28, 3 inputs, 3 outputs, a hysteresis branch on the 3 inputs and the 14 modes) over one
/// period of 8192 samples after a one-period warm-up (as the benchmark's metric runs it).
/// The model is seeded, not fitted: the simulation's cost does not depend on the values.
fn mimo_simulate(c: &mut Criterion) {
    use boucwen_lab::mimo::hysteresis::Shape;
    use boucwen_lab::mimo::linear::{ModalSs, Mode};
    use boucwen_lab::mimo::model::{Branch, Channel, MimoModel, Source, Warmup};
    use rand_core::{RngCore, SeedableRng};
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(27);
    let mut uni = move || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
    let (n, m, p, len) = (28, 3, 3, 8192);
    let modes: Vec<Mode> = (0..n / 2)
        .map(|i| {
            let th = 0.1 + 0.2 * i as f64;
            Mode::Pair { sigma: 0.99 * th.cos(), omega: 0.99 * th.sin() }
        })
        .collect();
    let ss = ModalSs {
        modes,
        b: nalgebra::DMatrix::from_fn(n, m, |_, _| uni()),
        c: nalgebra::DMatrix::from_fn(p, n, |_, _| uni()),
        d: nalgebra::DMatrix::from_fn(p, m, |_, _| uni()),
    };
    let mut model = MimoModel::linear(&ss, 6400.0);
    let sources: Vec<Source> =
        (0..m).map(Source::Input).chain((0..n).step_by(2).map(Source::State)).collect();
    let q = sources.len();
    model.branch = Some(Branch {
        channels: sources
            .into_iter()
            .map(|source| Channel { source, scale: 1.0, shape: Shape::symmetric(0.3) })
            .collect(),
        b0: model.b.clone(),
        e: (0..n * q).map(|_| 0.01 * uni()).collect(),
        f: (0..p * q).map(|_| 0.01 * uni()).collect(),
    });
    let u: Vec<f64> = (0..m * len).map(|_| uni()).collect();
    let mut g = c.benchmark_group("mimo/simulate");
    g.sample_size(20);
    g.bench_function("order28-branch17-8192x2", |b| {
        b.iter(|| black_box(model.simulate(black_box(&u), Warmup::Periods(1)).expect("simulation")))
    });
    let linear = MimoModel { branch: None, ..model.clone() };
    g.bench_function("order28-linear-8192x2", |b| {
        b.iter(|| black_box(linear.simulate(black_box(&u), Warmup::Periods(1)).expect("simulation")))
    });
    g.finish();
}

fn oscillator(c: &mut Criterion) {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/bouc-wen-benchmark/train.csv");
    let Ok(text) = std::fs::read_to_string(&path) else {
        println!("fit/oscillator/benchmark: skipped, {} not found", path.display());
        return;
    };
    let (mut u, mut y) = (Vec::new(), Vec::new());
    for line in text.lines().skip(1) {
        let f: Vec<f64> = line.split(',').map(|v| v.parse().expect("number")).collect();
        u.push(f[1]);
        y.push(f[2]);
    }
    let opt = OscillatorOptions::benchmark(MULTISINE_PERIOD);
    let run = || fit_oscillator(&u, &y, 1.0 / FS_HZ, &opt).expect("fit");
    let t0 = std::time::Instant::now();
    let first = run();
    println!(
        "fit/oscillator/benchmark: {:.3} µm in {:.2} s, {} after {} iterations, {} evaluations",
        first.rms_fit * 1e6,
        t0.elapsed().as_secs_f64(),
        first.stop,
        first.iterations,
        first.evaluations
    );
    let mut g = c.benchmark_group("fit/oscillator");
    g.sample_size(10).warm_up_time(Duration::from_millis(1)).measurement_time(Duration::from_secs(40));
    g.bench_function("benchmark", |b| b.iter(|| black_box(run().rms_fit)));
    g.finish();
}

criterion_group!(benches, fits, diagnoses, oscillator, mimo_simulate);
criterion_main!(benches);

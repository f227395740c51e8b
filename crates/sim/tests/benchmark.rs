//! The virtual Bouc–Wen oscillator against the benchmark's training record: driven by
//! `train.csv`'s input, it reproduces the record's output to the record's noise (about
//! 7.4 µm RMS). Skipped, with a message, when `../shared/data/bouc-wen-benchmark/train.csv`
//! (from the workspace root) is missing.

use boucwen_sim::oscillator::{BoucWenOscillator, MULTISINE_PERIOD, UPSAMPLING, interpolate_periodic};

#[test]
fn reproduces_train_csv_to_its_noise() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/bouc-wen-benchmark/train.csv");
    let Ok(text) = std::fs::read_to_string(&path) else {
        eprintln!("skipped: {} not found", path.display());
        return;
    };
    let (mut u, mut y) = (Vec::new(), Vec::new());
    for line in text.lines().skip(1) {
        let f: Vec<f64> = line.split(',').map(|v| v.parse().expect("number")).collect();
        u.push(f[1]);
        y.push(f[2]);
    }
    let n = MULTISINE_PERIOD;
    let periods = u.len() / n;
    assert_eq!(periods, 5);
    let fine = interpolate_periodic(&u, n, UPSAMPLING).expect("interpolate");
    // The input is exactly periodic, and the fine period sampled back gives the record's input.
    for (i, v) in u.iter().enumerate() {
        assert!((fine[(i % n) * UPSAMPLING] - v).abs() < 1e-9 * 50.0, "u[{i}]");
    }
    let sim = BoucWenOscillator::default().measure(&fine.repeat(periods + 1)).expect("simulate");
    let rms = |r: std::ops::Range<usize>| {
        (r.clone().map(|i| (sim[i] - y[i]).powi(2)).sum::<f64>() / r.len() as f64).sqrt()
    };
    for p in 0..periods {
        let e = rms(p * n..(p + 1) * n);
        assert!(e < 7.7e-6, "period {}: {:.3} µm", p + 1, e * 1e6);
    }
    // Averaged over the steady periods the noise drops by 2: what is left is not the noise's.
    let mean: f64 = (0..n)
        .map(|j| ((1..periods).map(|p| y[p * n + j] - sim[p * n + j]).sum::<f64>() / 4.0).powi(2))
        .sum::<f64>()
        / n as f64;
    assert!(mean.sqrt() < 3.85e-6, "averaged residual {:.3} µm", mean.sqrt() * 1e6);
}

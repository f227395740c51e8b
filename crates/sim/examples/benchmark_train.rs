//! The virtual Bouc–Wen oscillator against the benchmark's training record: drives the
//! simulator with `train.csv`'s input (reconstructed at 15 kHz by band-limited
//! interpolation of one period, exact for the multisine) and prints the RMS difference of
//! the outputs per period, with the noise estimated from consecutive periods.
//!
//! `cargo run --release -p boucwen-sim --example benchmark_train -- [path/to/train.csv]`

use boucwen_sim::oscillator::{BoucWenOscillator, MULTISINE_PERIOD, UPSAMPLING, interpolate_periodic};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path =
        std::env::args().nth(1).unwrap_or_else(|| "../shared/data/bouc-wen-benchmark/train.csv".into());
    let text = std::fs::read_to_string(&path)?;
    let (mut u, mut y) = (Vec::new(), Vec::new());
    for line in text.lines().skip(1) {
        let f: Vec<f64> = line.split(',').map(str::parse).collect::<Result<_, _>>()?;
        u.push(f[1]);
        y.push(f[2]);
    }
    let n = MULTISINE_PERIOD;
    let periods = u.len() / n;
    let fine = interpolate_periodic(&u, n, UPSAMPLING)?;
    // One period more than the record, for the decimation filter's end (as the benchmark).
    let u_fine = fine.repeat(periods + 1);
    let osc = BoucWenOscillator::default();
    let t0 = std::time::Instant::now();
    let sim = osc.measure(&u_fine)?;
    println!("simulated {} fine samples in {:.2} s", u_fine.len(), t0.elapsed().as_secs_f64());
    let rms = |a: &[f64], b: &[f64]| {
        (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
    };
    for p in 0..periods {
        let r = p * n..(p + 1) * n;
        let noise = if p + 1 < periods {
            rms(&y[r.clone()], &y[r.end..r.end + n]) / 2f64.sqrt() * 1e6
        } else {
            f64::NAN
        };
        println!(
            "period {}: simulator vs record {:.3} µm, record vs next period / √2 {:.3} µm",
            p + 1,
            rms(&sim[r.clone()], &y[r]) * 1e6,
            noise
        );
    }
    // The residual averaged over the steady periods 2.. (noise down by √(periods−1)): what
    // the simulator does not explain.
    let steady = periods - 1;
    let mean: Vec<f64> = (0..n)
        .map(|j| (1..periods).map(|p| y[p * n + j] - sim[p * n + j]).sum::<f64>() / steady as f64)
        .collect();
    println!(
        "residual averaged over periods 2..{periods}: {:.3} µm (noise alone would give {:.3} µm)",
        rms(&mean, &vec![0.0; n]) * 1e6,
        7.4 / (steady as f64).sqrt()
    );
    // Without the decimation filter: the fine output at the sample instants.
    let (fine_y, _) = osc.integrate(&u_fine, 1.0 / (750.0 * UPSAMPLING as f64), Default::default())?;
    let plain: Vec<f64> = fine_y.iter().step_by(UPSAMPLING).copied().collect();
    println!(
        "without the decimation filter, steady periods: {:.3} µm against the record, {:.3} µm against the filtered simulation",
        rms(&plain[n..periods * n], &y[n..periods * n]) * 1e6,
        rms(&plain[n..periods * n], &sim[n..periods * n]) * 1e6
    );
    println!("output RMS {:.1} µm", rms(&y, &vec![0.0; y.len()]) * 1e6);
    Ok(())
}

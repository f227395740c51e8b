//! The Fine Steering Mirror benchmark's metric on training realisations kept apart.
//!
//! `cargo run --release -p boucwen-lab --example fsm_eval -- [FOLDER] [--quick]`
//! (FOLDER defaults to /work/shared/data/fine-steering-mirror). For each fold `h` (the
//! realisation kept apart; `--quick`: only the last), fits on the other five realisations of
//! every level: a linear model per level, one linear model for all levels, and the
//! hysteretic model, and prints the benchmark's metric on realisation `h` per level. Then the
//! whole fit ([`fit_mimo`], order choice included) on every training realisation, timed.
//! `--no-per-level` skips the per-level linear models, `--no-full` the whole fit;
//! `MIMO_ORDER=n` sets the folds' order (28).

use boucwen_lab::mimo::fit::{FitOptions, benchmark_error, fit_mimo, fit_structure};
use boucwen_lab::record::mimo::{MimoOptions, MimoRecord};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let quick = args.iter().any(|a| a == "--quick");
    let per_level = !args.iter().any(|a| a == "--no-per-level");
    let full = !args.iter().any(|a| a == "--no-full");
    let dir = args
        .iter()
        .find(|a| !a.starts_with("--"))
        .cloned()
        .unwrap_or_else(|| "/work/shared/data/fine-steering-mirror".into());
    let rec = MimoRecord::read_npy_folder(&dir, &MimoOptions::fine_steering_mirror())?;
    let nl = rec.levels.len();
    let opts = FitOptions::default();
    let order = std::env::var("MIMO_ORDER").ok().and_then(|s| s.parse().ok()).unwrap_or(28);
    let quiet = |_: &boucwen_lab::mimo::Progress| {};
    let folds: Vec<usize> = if quick { vec![5] } else { (0..6).collect() };
    let mut sums = vec![[0.0; 3]; nl];
    for &h in &folds {
        let keep = move |_: usize, r: usize| r != h;
        let t = Instant::now();
        let all: Vec<usize> = (0..nl).collect();
        let joint = fit_structure(&rec, &keep, &all, order, &opts, &quiet)?;
        let mut line = format!("fold {} (order {order}, {:.1} s):", h + 1, t.elapsed().as_secs_f64());
        for (li, sum) in sums.iter_mut().enumerate() {
            let l = &rec.levels[li];
            let e = [
                if per_level {
                    benchmark_error(
                        &fit_structure(&rec, &keep, &[li], order, &opts.clone().linear(), &quiet)?.linear,
                        l,
                        &[h],
                    )?
                } else {
                    f64::NAN
                },
                benchmark_error(&joint.linear, l, &[h])?,
                benchmark_error(joint.best(), l, &[h])?,
            ];
            for (s, v) in sum.iter_mut().zip(e) {
                *s += v;
            }
            line +=
                &format!("  {}: per-level {:.4} all-levels {:.4} hysteretic {:.4}", l.tag, e[0], e[1], e[2]);
        }
        println!("{line}");
    }
    let k = folds.len() as f64;
    println!("mean over {} fold(s), µm (linear per level / linear all levels / hysteretic):", folds.len());
    for (li, s) in sums.iter().enumerate() {
        println!(
            "  {:>12}: {:.4} / {:.4} / {:.4}   hysteresis removes {:.1} % of the all-levels linear error",
            rec.levels[li].tag,
            s[0] / k,
            s[1] / k,
            s[2] / k,
            100.0 * (1.0 - s[2] / s[1])
        );
    }
    if !full {
        return Ok(());
    }
    let t = Instant::now();
    let show = |p: &boucwen_lab::mimo::Progress| {
        eprintln!("[{:>6.1} s] {}: {}", t.elapsed().as_secs_f64(), p.stage, p.message)
    };
    let fit = fit_mimo(&rec, &opts, &show)?;
    println!("whole fit on every training realisation: order {} in {:.1} s", fit.order, fit.seconds);
    for d in &fit.diagnosis {
        let o: Vec<String> = d
            .outputs
            .iter()
            .map(|s| {
                format!(
                    "out {:.3} leaves {:.4} noise {:.4} (period {:.4}) NL {:.4}",
                    s.output_rms, s.linear_leaves_rms, s.noise_rms, s.noise_rms_period, s.nonlinear_rms
                )
            })
            .collect();
        println!("  BLA {}: {}", d.bla.tag, o.join(" | "));
    }
    Ok(())
}

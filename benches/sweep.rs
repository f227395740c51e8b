//! Whole-process speed of the main job: `boucwen sweep` on the default scenario, as the CLI
//! runs it (all cores), with the default record length and with the paper's 100 s.
//!
//! Run with `cargo bench --bench sweep`. IDs: `sweep/default` (1..50 Hz, `--seconds 15`)
//! and `sweep/seconds100` (`--seconds 100`). Before the timing, one run of each prints its
//! simulated actuator time and its speed-up over real time.

use boucwen_lab::experiments::sweep::{self, SweepOptions};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Duration;

/// The CLI's default record length (s).
const DEFAULT_SECONDS: f64 = 15.0;

fn options(seconds: f64) -> SweepOptions {
    // As `boucwen sweep`: the same options, figures' traces included.
    SweepOptions::paper(seconds)
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("sweep");
    g.sample_size(10).warm_up_time(Duration::from_millis(1)).measurement_time(Duration::from_secs(30));
    for (id, seconds) in [("default", DEFAULT_SECONDS), ("seconds100", 100.0)] {
        let opts = options(seconds);
        match sweep::run(&opts, &|| {}) {
            Ok(r) => println!(
                "sweep/{id}: {:.0} s of actuator time in {:.2} s on {} threads ({:.0}x real time)",
                r.actuator_s,
                r.wall_s,
                rayon::current_num_threads(),
                r.speedup()
            ),
            Err(e) => {
                eprintln!("sweep/{id} failed: {e}");
                std::process::exit(1);
            }
        }
        g.bench_function(id, |b| {
            b.iter(|| black_box(sweep::run(black_box(&opts), &|| {}).map(|r| r.rows.len())))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

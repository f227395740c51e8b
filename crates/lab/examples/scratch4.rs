//! scratch4: periodic
use boucwen_lab::diagnose::{self, Outcome, Thresholds};
use boucwen_lab::effects::*;
use boucwen_lab::periodic::Realisation;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let drive = if args.get(1).map(|s| s.as_str()) == Some("tri") {
        PeriodicDrive::Triangle
    } else {
        PeriodicDrive::Multisine
    };
    let n: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3);
    for nl in [Nonlinearity::None, Nonlinearity::Odd, Nonlinearity::Even] {
        for seed in 1..=n {
            let c = PeriodicCase::generate(drive, nl, seed).unwrap();
            let recs = c.records().unwrap();
            let rs: Vec<Realisation> =
                recs.iter().map(|r| Realisation { u: &r.u, y: &r.y, t0: 0.0, given: None }).collect();
            let t = std::time::Instant::now();
            match diagnose::diagnose_drive(&rs, recs[0].ts, &Thresholds::default()) {
                Ok(Outcome::Periodic(d)) => {
                    println!(
                        "{} fr {:.0}: odd {:?} even {:?}; steps {:?}; findings {:?} ({:.1}s)",
                        c.name(),
                        c.resonance_hz,
                        d.odd.map(|l| (l.db * 10.0).round() / 10.0),
                        d.even.map(|l| (l.db * 10.0).round() / 10.0),
                        d.steps
                            .iter()
                            .map(|s| format!("{:.4}/{:.0}/{:.0}", s.rms_um, s.odd.db, s.even.db))
                            .collect::<Vec<_>>(),
                        d.findings
                            .iter()
                            .map(|f| (f.kind.as_str(), f.kept, f.level.map(|l| (l.0 * 10.0).round() / 10.0)))
                            .collect::<Vec<_>>(),
                        t.elapsed().as_secs_f64()
                    );
                    if std::env::var("TRIALS").is_ok() {
                        for t in &d.trials {
                            println!("   {:?}", t);
                        }
                    }
                    if std::env::var("SUMMARY").is_ok() {
                        println!("{}", d.summary(&c.name()));
                    }
                }
                Ok(Outcome::Sine(_)) => println!("{}: sine?", c.name()),
                Err(e) => println!("{}: {e}", c.name()),
            }
        }
    }
}

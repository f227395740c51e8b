//! scratch
use boucwen_lab::diagnose::{self, Thresholds};
use boucwen_lab::effects::*;
use boucwen_lab::hidden::{Case, Effect};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let which = args.get(1).map(|s| s.as_str()).unwrap_or("sat");
    let n: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    for seed in 1..=n {
        let (r, truth) = match which {
            "clean" => (Case::generate(Effect::Clean, seed).unwrap().record().unwrap(), String::new()),
            "odd3" => {
                (Case::generate(Effect::OddHarmonic(3), seed).unwrap().record().unwrap(), String::new())
            }
            "odd5" => {
                (Case::generate(Effect::OddHarmonic(5), seed).unwrap().record().unwrap(), String::new())
            }
            "even2" => {
                (Case::generate(Effect::EvenHarmonic(2), seed).unwrap().record().unwrap(), String::new())
            }
            "drift" => (Case::generate(Effect::Drift, seed).unwrap().record().unwrap(), String::new()),
            w => {
                let e = match w {
                    "sat" => SineEffect::Saturation,
                    "sensor" => SineEffect::SensorRange,
                    "creep" => SineEffect::Creep,
                    "delay" => SineEffect::Delay,
                    "h5d" => SineEffect::HarmonicAndDrift(5),
                    "sat5" => SineEffect::RangeAndHarmonic(5),
                    _ => SineEffect::RangeAndHarmonic(3),
                };
                let c = SineCase::generate(e, seed).unwrap();
                (c.record().unwrap(), format!("{:?}", c.truth))
            }
        };
        let t = std::time::Instant::now();
        let d = match diagnose::diagnose(&r.u, &r.y, r.ts, &Thresholds::default()) {
            Ok(d) => d,
            Err(e) => {
                println!("{}: {e}", r.source);
                continue;
            }
        };
        println!(
            "{} {truth} f {:.1} base {:.4} -> {} {:.4} ({:.0}%) delay {:?} findings {:?} ({:.1}s)",
            r.source,
            d.drive_hz,
            d.baseline_rms_um,
            d.model_name(),
            d.model_rms_um,
            d.gain_pct(),
            d.delay.map(|x| (x.samples * 100.0).round() / 100.0),
            d.findings
                .iter()
                .map(|f| (f.kind.as_str(), f.order, f.kept, f.level.map(|l| (l.0 * 1000.0).round() / 1000.0)))
                .collect::<Vec<_>>(),
            t.elapsed().as_secs_f64()
        );
        if std::env::var("TRIALS").is_ok() {
            let ar = d.baseline.ext.ar;
            let disc = ar[0] * ar[0] + 4.0 * ar[1];
            println!(
                "   baseline ar {:?} disc {disc:.5} poles {:?}",
                ar,
                if disc >= 0.0 {
                    let r1 = (ar[0] + disc.sqrt()) / 2.0;
                    let r2 = (ar[0] - disc.sqrt()) / 2.0;
                    format!("real {r1:.5} {r2:.5} tau1 {:.3}s", -d.ts / r1.abs().ln())
                } else {
                    format!("complex {:?}", boucwen_lab::diagnose::resonance_hz(ar, d.ts))
                }
            );
        }
        if std::env::var("TRIALS").is_ok() {
            for t in &d.trials {
                println!(
                    "   trial r{} {} {:?} rms {:.4} term {:.4} gain {:.1}% kept {} {:?}",
                    t.round,
                    t.candidate.kind.as_str(),
                    t.candidate.order,
                    t.rms_um,
                    t.term_rms_um,
                    t.gain_pct,
                    t.kept,
                    t.reason
                );
            }
        }
        if std::env::var("CAUSE").is_ok() {
            for f in &d.findings {
                println!("   {}", f.cause);
            }
        }
    }
}

//! scratch3
use boucwen_lab::effects::*;
fn main() {
    for seed in 1..=8u64 {
        let c = SineCase::generate(SineEffect::Creep, seed).unwrap();
        let r = c.record().unwrap();
        let n = r.y.len();
        let m = |a: usize, b: usize| r.y[a..b].iter().sum::<f64>() / (b - a) as f64;
        println!(
            "creep-{seed}: {:?} offset {:.3} amp {:.3}; y mean 0.5-1.5s {:.3} 2-3s {:.3} 4-5s {:.3} 8-10s {:.3}",
            c.case.scenario.creep.terms,
            c.offset_v,
            c.case.amplitude_v,
            m(500, 1500),
            m(2000, 3000),
            m(4000, 5000),
            m(8000, n)
        );
    }
}

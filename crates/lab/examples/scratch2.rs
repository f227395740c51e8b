//! scratch: delay from the start-up
use boucwen_lab::analysis;
use boucwen_lab::effects::*;
use boucwen_lab::fit::{self, ModelSpec, OeOptions};
use boucwen_lab::hidden::{Case, Effect};
fn main() {
    for (name, seed) in
        [("clean", 1u64), ("clean", 2), ("delay", 1), ("delay", 2), ("delay", 3), ("clean", 3)]
    {
        let r = if name == "clean" {
            Case::generate(Effect::Clean, seed).unwrap().record().unwrap()
        } else {
            SineCase::generate(SineEffect::Delay, seed).unwrap().record().unwrap()
        };
        let truth = if name == "delay" {
            format!("{:?}", SineCase::generate(SineEffect::Delay, seed).unwrap().truth)
        } else {
            "~1.1".into()
        };
        let f = analysis::estimate_drive(&r.u, r.ts).unwrap();
        let n = r.u.len();
        let split = n / 2;
        let spec = ModelSpec { drift_degree: Some(0), ..ModelSpec::extended(f) };
        let mut line = format!("{name}-{seed} f {f:.1} truth {truth}:");
        for d in 0..=10usize {
            let ud: Vec<f64> = (0..n).map(|k| if k >= d { r.u[k - d] } else { 0.0 }).collect();
            let o = OeOptions {
                skip: 0,
                max_samples: 1000,
                require_invertible: false,
                lm_starts: 3,
                max_iter: 15,
                ..OeOptions::default()
            };
            let o2 = OeOptions { skip: 1, ..o.clone() };
            let fitr = fit::fit_oe(&ud, &r.y, r.ts, split, &spec, &[], &o2);
            if let Ok(fr) = fitr {
                let sim = fr.model.simulate(&ud, r.ts).unwrap();
                let start = analysis::rms_diff(&sim[..100], &r.y[..100]);
                line.push_str(&format!(" d{d}: {:.4}/{:.4}", fr.rms_fit, start));
            }
        }
        println!("{line}");
    }
}

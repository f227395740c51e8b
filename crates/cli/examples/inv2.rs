use boucwen_cli::{analysis, experiment};
use boucwen_core::compensator::{DirectInverse, InverseState, Saturation, InverseCase};
use boucwen_core::model::{BoucWenParams, ExtendedParams};
fn main() {
    let ts = 1e-3; let f = 31.0; let n = 10000;
    for bw in [BoucWenParams { a1: 4.360035235038821, a: 1.8089978546776178, a0: 0.21052040018076532, gamma: -0.016426393619580967, beta: 0.9923825930047868 },
               BoucWenParams { a1: 3.613100457548644, a: 1.724224970356706, a0: 0.4682888482147814, gamma: 0.0004283852957216604, beta: 2.1897496516134267 }] {
        let m = ExtendedParams { bw, ar: [1.7984810392423423, -0.9717424801765748] };
        let inv = DirectInverse::new(m).unwrap();
        let mut st = InverseState::default();
        let d = experiment::sine(22.0, f, ts, n).unwrap();
        let fade = 500.0;
        let mut cases = [0; 4]; let mut first_bad = None;
        let uf: Vec<f64> = d.iter().enumerate().map(|(k, &dk)| { let env = if (k as f64) < fade { 0.5 - 0.5*(std::f64::consts::PI*k as f64/fade).cos() } else { 1.0 }; let o = inv.step(&mut st, dk*env, &Saturation::symmetric(10.0)); let c = match o.case { InverseCase::Rising => 0, InverseCase::Falling => 1, InverseCase::Both => 2, InverseCase::Neither => 3 }; cases[c] += 1; if c >= 2 && first_bad.is_none() { first_bad = Some((k, st.h, o.u_f)); } o.u_f }).collect();
        println!("cases {:?} first bad {:?} u_f amp {:.3} max {:.3}", cases, first_bad, analysis::harmonics(&uf[2000..], f, ts, 1)[0].amp, uf.iter().fold(0.0f64, |a,b| a.max(b.abs())));
        println!("  slopes at h=0: {:.3} {:.3}; h_max(rise) = {:.3}", bw.a1 - bw.slope(0.0, true), bw.a1 - bw.slope(0.0, false), bw.a / (bw.gamma + bw.beta));
    }
}

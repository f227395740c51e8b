use boucwen_cli::{experiment, fit, analysis, sweep};
use boucwen_core::compensator::{DirectInverse, InverseState, Saturation, InverseCase};
use boucwen_sim::{Bimorph, Scenario};
fn main() {
    let ts = 1e-3; let n = 10_000;
    let st = sweep::identify_structure(&Scenario::default()).unwrap();
    println!("structure {:?} res {:?}", st.model.ext, st.resonance_hz);
    let freqs: Vec<f64> = std::env::args().skip(1).map(|a| a.parse().unwrap()).collect();
    for f in freqs {
        let u = experiment::sine(1.0, f, ts, n).unwrap();
        let y = Bimorph::new(&Scenario::default()).unwrap().run(&u).unwrap();
        let yh = analysis::harmonics(&y[5000..], f, ts, 5);
        let opt = fit::OeOptions { structure: Some(st.model.ext.ar), fix_structure: true, ..Default::default() };
        let m = fit::fit_oe(&u, &y, ts, n/2, &fit::ModelSpec::extended(f), &[], &opt).unwrap().model;
        let sim = m.simulate(&u, ts).unwrap();
        let r: Vec<f64> = y[1000..5000].iter().zip(&sim[1000..5000]).map(|(a,b)| a-b).collect();
        println!("  id residual rms {:.3} harmonics {:?}", analysis::rms(&r), analysis::harmonics(&r, f, ts, 5).iter().map(|t| (t.amp*1000.0).round()/1000.0).collect::<Vec<_>>());
        let inv = DirectInverse::new(m.ext).unwrap();
        let mut s = InverseState::default();
        let alpha = experiment::eq25_amplitude(&u, &y);
        let d = experiment::sine(alpha, f, ts, n).unwrap();
        let mut cases = [0usize; 5];
        let uf: Vec<f64> = d.iter().map(|&dk| { let o = inv.step(&mut s, dk, &Saturation::symmetric(10.0)); cases[match o.case { InverseCase::Rising => 0, InverseCase::Falling => 1, InverseCase::Both => 2, InverseCase::Neither => 3 }] += 1; if o.guarded { cases[4] += 1; } o.u_f }).collect();
        let ym = m.simulate(&uf, ts).unwrap();
        let yp = Bimorph::new(&Scenario::default()).unwrap().run(&uf).unwrap();
        let e: Vec<f64> = yp.iter().zip(&d).map(|(a,b)| a-b).collect();
        let uh = analysis::harmonics(&uf[2000..], f, ts, 5);
        println!("{f} Hz: model {:?} res {:?}\n   y harmonics {:?}\n   u_f harmonics {:?} max {:.2} cases R/F/B/N/guard {:?}\n   model-track {:.3} plant-track {:.3}, err harmonics {:?}", m.ext, boucwen_cli::diagnose::resonance_hz(m.ext.ar, ts), yh.iter().map(|t| (t.amp*1000.0).round()/1000.0).collect::<Vec<_>>(), uh.iter().map(|t| (t.amp*1000.0).round()/1000.0).collect::<Vec<_>>(), uf.iter().fold(0.0f64, |a,b| a.max(b.abs())), cases, analysis::rms_diff(&ym[2000..], &d[2000..]), analysis::rms(&e[2000..]), analysis::harmonics(&e[2000..], f, ts, 5).iter().map(|t| (t.amp*1000.0).round()/1000.0).collect::<Vec<_>>());
    }
}

use boucwen_cli::{analysis, experiment, fit, sweep};
use boucwen_sim::{Bimorph, Scenario};
fn main() {
    let ts = 1e-3; let n = 10_000;
    let st = sweep::identify_structure(&Scenario::default()).unwrap();
    for f in std::env::args().skip(1).map(|a| a.parse::<f64>().unwrap()) {
        let u = experiment::sine(1.0, f, ts, n).unwrap();
        let y = Bimorph::new(&Scenario::default()).unwrap().run(&u).unwrap();
        let opt = fit::OeOptions { structure: Some(st.model.ext.ar), fix_structure: true, ..Default::default() };
        let ext = fit::fit_oe(&u, &y, ts, n/2, &fit::ModelSpec::extended(f), &[], &opt).unwrap();
        let enh = fit::fit_oe(&u, &y, ts, n/2, &fit::ModelSpec::enhanced(f, &[3]), &[ext.model.clone()], &opt).unwrap();
        let alpha = experiment::eq25_amplitude(&u, &y);
        for (name, m, ord) in [("ext uf", &ext.model, vec![]), ("enh uf", &enh.model, vec![]), ("ext+c3", &ext.model, vec![3]), ("enh+c3", &enh.model, vec![3])] {
            let mut b = Bimorph::new(&Scenario::default()).unwrap();
            let mut p = |x: f64| b.step(x).unwrap();
            let t = experiment::track(&mut p, m, &ord, alpha, f, ts, n, &Default::default()).unwrap();
            let e = t.error();
            let h = analysis::harmonics(&e[2000..], f, ts, 4);
            println!("{f} Hz {name} (inv ext {} enh {}): rms {:.3} err {:?} max|u| {:.2}", ext.invertible, enh.invertible, analysis::rms(&e[2000..]), h.iter().map(|t| (t.amp*1000.0).round()/1000.0).collect::<Vec<_>>(), t.u.iter().fold(0.0f64, |a, b| a.max(b.abs())));
        }
        let g = boucwen_core::compensator::harmonic_response(&ext.model.ext, 3, f, ts, boucwen_core::compensator::PhaseRule::Model);
        println!("   ext {:?}\n   enh {:?} res {:?}", ext.model.ext, enh.model.ext, boucwen_cli::diagnose::resonance_hz(enh.model.ext.ar, ts));
        println!("   G(3f) model {:.2} ∠{:.0}°  enh branch {:?}", g.norm(), g.arg().to_degrees(), enh.model.branches);
    }
}

use boucwen_cli::{analysis, experiment, fit, sweep};
use boucwen_sim::{Bimorph, Scenario};
fn main() {
    let ts = 1e-3; let n = 10_000;
    let st = sweep::identify_structure(&Scenario::default()).unwrap();
    for f in std::env::args().skip(1).map(|a| a.parse::<f64>().unwrap()) {
        let u = experiment::sine(1.0, f, ts, n).unwrap();
        let y = Bimorph::new(&Scenario::default()).unwrap().run(&u).unwrap();
        let opt = fit::OeOptions { structure: Some(st.model.ext.ar), fix_structure: true, ..Default::default() };
        let fitr = fit::fit_oe(&u, &y, ts, n/2, &fit::ModelSpec::extended(f), &[], &opt).unwrap();
        let m = fitr.model;
        let alpha = experiment::eq25_amplitude(&u, &y);
        let mut b = Bimorph::new(&Scenario::default()).unwrap();
        let mut p = |x: f64| b.step(x).unwrap();
        let t = experiment::track(&mut p, &m, &[], alpha, f, ts, n, &Default::default()).unwrap();
        let e = t.error();
        let h = analysis::harmonics(&e[2000..], f, ts, 6);
        let yh = analysis::harmonics(&y[5000..], f, ts, 6);
        let uh = analysis::harmonics(&t.u[2000..], f, ts, 6);
        let r = |v: &[analysis::Tone]| v.iter().map(|t| (t.amp*1000.0).round()/1000.0).collect::<Vec<_>>();
        println!("{f} Hz inv={} rms {:.3}: err {:?}\n   y(sine) {:?}\n   u_f {:?}", fitr.invertible, analysis::rms(&e[2000..]), r(&h), r(&yh), r(&uh));
    }
}

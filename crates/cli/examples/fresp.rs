use boucwen_cli::{analysis, experiment};
use boucwen_sim::{Bimorph, Scenario};
fn main() {
    let sc = Scenario::default().without_hysteresis().without_stiffening().without_noise().without_quantisation().without_drift().without_creep();
    let ts = 1e-3;
    for f in [1.0, 2.0, 5.0, 10.0, 14.0, 20.0, 23.0, 30.0, 40.0, 50.0, 60.0, 66.0, 69.0, 75.0, 90.0, 115.0, 150.0, 200.0, 300.0, 400.0] {
        let n = 6000;
        let u = experiment::sine(0.1, f, ts, n).unwrap();
        let y = Bimorph::new(&sc).unwrap().run(&u).unwrap();
        let tu = analysis::tone(&u[3000..], f, ts);
        let ty = analysis::tone(&y[3000..], f, ts);
        println!("{f} {} {}", ty.amp / tu.amp, ty.phase - tu.phase);
    }
}

//! Where the hysteresis sits, end to end through `boucwen identify --model auto --save`,
//! `boucwen compare` and `boucwen diagnose`: a record of a Bouc–Wen oscillator (hysteresis as
//! a restoring force, with parameters other than the benchmark's and noise) is given to the
//! oscillator, a bimorph's record stays the paper's actuator's, and the benchmark's training
//! record (from `../shared`, skipped with a message when missing) gives a model whose error on
//! test records made from the published equations is under the best published result.

use boucwen_sim::oscillator::{BoucWenOscillator, FS_HZ, Multisine, add_noise};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn boucwen(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_boucwen")).args(args).output().expect("run boucwen")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("boucwen-families-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn json(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("one JSON object")
}

/// A CSV record `t,u,y` with `y` in m.
fn write(path: &Path, u: &[f64], y: &[f64]) {
    let mut text = String::from("t,u,y\n");
    for (k, (u, y)) in u.iter().zip(y).enumerate() {
        text.push_str(&format!("{:.8},{u},{y}\n", k as f64 / FS_HZ));
    }
    std::fs::write(path, text).unwrap();
}

/// The hidden system: a stiffer structure with a smaller loop than the benchmark's, a
/// heavier mass and more damping; 3 µm of noise.
fn hidden() -> BoucWenOscillator {
    BoucWenOscillator {
        mass_kg: 3.0,
        damping_n_s_per_m: 20.0,
        stiffness_n_per_m: 8e4,
        alpha_n_per_m: 2e4,
        ..BoucWenOscillator::default()
    }
}

/// Five periods of a shorter multisine (2,048 samples, lines 5–150 Hz, 50 N RMS) of
/// realisation `seed`, from rest.
fn record(osc: &BoucWenOscillator, seed: u64, noise_m: f64) -> (Vec<f64>, Vec<f64>) {
    let ms = Multisine::new(2048, 20, (14, 410), 50.0, seed).unwrap();
    let r = osc.multisine_record(&ms, 5).unwrap();
    let mut y = r.y;
    add_noise(&mut y, noise_m, seed + 1);
    (r.u, y)
}

#[test]
fn a_restoring_force_is_found_fitted_saved_and_tested_on_another_realisation() {
    let osc = hidden();
    let (u, y) = record(&osc, 7, 3e-6);
    let train = tmp("hidden-train.csv");
    write(&train, &u, &y);
    let t = train.to_str().unwrap();
    // The diagnosis names the restoring force first, with its gain over the extended model.
    let d = json(&boucwen(&["diagnose", t, "--y-unit", "m", "--json"]));
    let f = &d["findings"][0];
    assert_eq!(f["kind"], "restoring_force_hysteresis", "{}", d["findings"]);
    let e = &f["evidence"];
    assert!(e["gain_pct"].as_f64().unwrap() >= 30.0, "{e}");
    let truth_bg = osc.beta * osc.gamma;
    let bg = e["params"]["beta_gamma"].as_f64().unwrap();
    assert!((bg - truth_bg).abs() < 0.1 * truth_bg, "beta*gamma {bg} vs {truth_bg}");
    // identify --model auto keeps the oscillator, says why, and saves it.
    let model = tmp("hidden.json");
    let m = model.to_str().unwrap();
    let j = json(&boucwen(&["identify", t, "--y-unit", "m", "--model", "auto", "--save", m, "--json"]));
    assert_eq!(j["chosen"], "oscillator", "{j}");
    assert_eq!(j["choice"], "better_held_out");
    assert_eq!(j["model"]["hysteresis"], "in the restoring force");
    // Another realisation, noise-free: the model from the file, run from its drive alone.
    let (u2, y2) = record(&osc, 8, 0.0);
    let test = tmp("hidden-test.csv");
    write(&test, &u2, &y2);
    let c = json(&boucwen(&["compare", m, test.to_str().unwrap(), "--y-unit", "m", "--json"]));
    let rms = c["rms_um"].as_f64().unwrap();
    let out = c["output_rms_um"].as_f64().unwrap();
    assert!(rms < 0.01 * out, "compare: {rms} µm of {out} µm");
    assert!((c["fit_pct"].as_f64().unwrap() - 100.0 * (1.0 - c["nrmse"].as_f64().unwrap())).abs() < 1e-9);
    // simulate --model writes the same prediction for the same drive.
    let pred = tmp("hidden-pred.csv");
    let s = boucwen(&[
        "simulate",
        "--model",
        m,
        "--input",
        test.to_str().unwrap(),
        "--out",
        pred.to_str().unwrap(),
    ]);
    assert!(s.status.success(), "{}", String::from_utf8_lossy(&s.stderr));
    let text = std::fs::read_to_string(&pred).unwrap();
    assert!(text.starts_with("t,u,y [um]\n"), "{}", &text[..40]);
    let last: f64 = text.lines().last().unwrap().rsplit(',').next().unwrap().parse().unwrap();
    assert!((last - 1e6 * y2[y2.len() - 1]).abs() < 0.05 * out, "{last}");
}

#[test]
fn a_bimorph_record_stays_the_paper_actuator() {
    let rec = tmp("bimorph.csv");
    let r = rec.to_str().unwrap();
    let s = boucwen(&["simulate", "--freq", "23", "--amplitude", "40", "--seconds", "6", "--out", r]);
    assert!(s.status.success());
    let j = json(&boucwen(&["identify", r, "--model", "auto", "--json"]));
    assert_eq!(j["chosen"], "actuator", "{j}");
    assert_eq!(j["choice"], "paper_model");
    let fams: Vec<&str> =
        j["families"].as_array().unwrap().iter().map(|f| f["family"].as_str().unwrap()).collect();
    assert_eq!(fams, ["actuator", "oscillator", "linear"]);
}

#[test]
fn a_bad_model_file_gets_one_line() {
    let rec = tmp("bimorph-for-bad.csv");
    let r = rec.to_str().unwrap();
    assert!(boucwen(&["simulate", "--freq", "10", "--seconds", "1", "--out", r]).status.success());
    for (name, text, want) in [
        ("empty.json", "", "not JSON"),
        ("other.json", r#"{"format": "boucwen-design", "version": 1}"#, "not a model file"),
        ("newer.json", r#"{"format": "boucwen-model", "version": 9}"#, "newer boucwen"),
    ] {
        let p = tmp(name);
        std::fs::write(&p, text).unwrap();
        let o = boucwen(&["compare", p.to_str().unwrap(), r]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains(name) && err.contains(want), "{want}: {err}");
    }
}

#[test]
fn the_benchmark_model_beats_the_published_results_on_records_from_the_equations() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bouc-wen-benchmark/train.csv");
    if !path.exists() {
        eprintln!("skipped: {} not found", path.display());
        return;
    }
    let model = tmp("benchmark.json");
    let m = model.to_str().unwrap();
    let j = json(&boucwen(&[
        "identify",
        path.to_str().unwrap(),
        "--y-unit",
        "m",
        "--model",
        "auto",
        "--save",
        m,
        "--json",
    ]));
    assert_eq!(j["chosen"], "oscillator", "{j}");
    // A steady-state period of another realisation of the benchmark's multisine.
    let osc = BoucWenOscillator::default();
    let r = osc.multisine_steady_period(&Multisine::benchmark(202).unwrap()).unwrap();
    let test = tmp("benchmark-test.csv");
    write(&test, &r.u, &r.y);
    let c = json(&boucwen(&["compare", m, test.to_str().unwrap(), "--y-unit", "m", "--periodic", "--json"]));
    let rms = c["rms_um"].as_f64().unwrap();
    assert!(rms <= 7.5, "e_RMS {rms} µm; gr-SS-NN published 7.53 µm");
}

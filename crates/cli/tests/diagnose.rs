//! `boucwen diagnose` and `boucwen identify` end to end: a record with a hidden odd
//! harmonic written to CSV, the report on the terminal, as JSON and as a page; bad input.

use boucwen_lab::fixtures::hidden::{Case, Effect};
use std::path::PathBuf;
use std::process::Command;

fn boucwen(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_boucwen")).args(args).output().expect("run boucwen")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("boucwen-diagnose-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A record of the virtual bimorph with a hidden 5th harmonic, as a CSV file.
fn hidden_record() -> (Case, PathBuf) {
    let case = Case::generate(Effect::OddHarmonic(5), 1).unwrap();
    let path = tmp("odd5.csv");
    case.record().unwrap().write(&path).unwrap();
    (case, path)
}

#[test]
fn diagnose_names_the_hidden_harmonic_in_text_json_and_a_report_page() {
    let (case, data) = hidden_record();
    let data = data.to_str().unwrap();

    let o = boucwen(&["diagnose", data]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8(o.stdout).unwrap();
    assert!(text.contains("odd harmonic oscillation: the output's 5th harmonic"), "{text}");
    assert!(text.contains("what the baseline gets wrong"), "{text}");

    let report = tmp("report");
    let o = boucwen(&["diagnose", data, "--json", "--report", report.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    assert!((j["drive_hz"].as_f64().unwrap() - case.drive_hz).abs() < 0.05);
    assert!(j["baseline"]["model"].as_str().unwrap().starts_with("extended"));
    let f = &j["findings"][0];
    assert_eq!(f["kind"], "odd_harmonic");
    assert_eq!(f["order"], 5);
    assert!((f["freq_hz"].as_f64().unwrap() - 5.0 * case.drive_hz).abs() < 2.0);
    let share = f["residual_share"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&share));
    assert!(j["extended"]["model"].as_str().unwrap().contains("enhanced(5"));
    let (before, after) =
        (j["baseline"]["rms_um"].as_f64().unwrap(), j["extended"]["rms_um"].as_f64().unwrap());
    let gain = j["gain_pct"].as_f64().unwrap();
    assert!((gain - 100.0 * (1.0 - after / before)).abs() < 1e-9);
    assert!(gain >= 50.0, "{gain}");
    for file in [
        "index.html",
        "diagnosis.json",
        "residual_spectrum.svg",
        "loops.svg",
        "time_series.svg",
        "residual.svg",
    ] {
        let p = report.join(file);
        let body = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        assert!(body.len() > 200, "{file}");
    }
    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    assert!(html.contains("<img src=\"loops.svg\""));
    assert!(html.contains("5th harmonic"));
}

#[test]
fn identify_fits_the_extended_and_the_enhanced_model_by_both_methods() {
    let (_, data) = hidden_record();
    let data = data.to_str().unwrap();
    let run = |extra: &[&str]| -> serde_json::Value {
        let mut args = vec!["identify", data, "--json"];
        args.extend_from_slice(extra);
        let o = boucwen(&args);
        assert!(o.status.success(), "{extra:?}: {}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).expect("json")
    };
    let ext = run(&[]);
    assert_eq!(ext["model"], "extended");
    // The fit says why it stopped: by a criterion, not the iteration limit.
    let stop = ext["fit"]["stop"].as_str().expect("stop reason");
    assert!(["cost_decrease", "step_size", "gradient"].contains(&stop), "{ext}");
    assert_eq!(ext["fit"]["data"]["kind"], "average_period", "{ext}");
    let enh = run(&["--model", "enhanced"]);
    // The branch order is found in the data: the hidden 5th.
    assert_eq!(enh["model"], "enhanced(5)");
    assert_eq!(enh["params"]["branches"][0]["order"], 5);
    assert!(enh["rms_um"].as_f64().unwrap() < 0.5 * ext["rms_um"].as_f64().unwrap(), "{enh} vs {ext}");
    let rls = run(&["--model", "enhanced", "--harmonics", "5", "--method", "rls"]);
    assert_eq!(rls["method"], "paper RLS");
    assert!(rls.get("fit").is_none(), "{rls}");
    assert!(rls["rms_um"].as_f64().unwrap().is_finite());
    // Text output names the parameters.
    let o = boucwen(&["identify", data]);
    let text = String::from_utf8(o.stdout).unwrap();
    assert!(text.contains("hysteresis A1 ="), "{text}");
}

/// A sine record as CSV text, `n` rows.
fn sine_csv(n: usize) -> String {
    let mut s = String::from("t,u,y\n");
    for k in 0..n {
        let t = k as f64 * 1e-3;
        let u = (std::f64::consts::TAU * 20.0 * t).sin();
        s.push_str(&format!("{t},{u},{}\n", 10.0 * u));
    }
    s
}

#[test]
fn bad_records_are_one_line_errors_naming_file_and_row() {
    let good = sine_csv(3000);
    let rows: Vec<String> = good.lines().map(String::from).collect();
    let replace = |rows: &[String], i: usize, line: &str| -> String {
        let mut r = rows.to_vec();
        r[i] = line.into();
        r.join("\n") + "\n"
    };
    let cases: Vec<(&str, String, &str)> = vec![
        ("empty", String::new(), "no header"),
        ("no-header", good.lines().skip(1).collect::<Vec<_>>().join("\n"), ":1:"),
        ("missing-column", good.replace("t,u,y", "t,u,x"), ":1:"),
        ("not-a-number", replace(&rows, 5, "0.004,abc,1"), ":6:"),
        ("not-finite", replace(&rows, 5, "0.004,NaN,1"), ":6:"),
        ("out-of-range", replace(&rows, 5, "0.004,5000,1"), ":6:"),
        ("ragged", replace(&rows, 5, "0.004,1"), ":6:"),
        ("time-backwards", replace(&rows, 5, "0.001,0.5,1"), ":6:"),
        ("non-uniform", replace(&rows, 5, "0.0047,0.5,1"), ":6:"),
        ("too-few", sine_csv(100), "samples"),
        (
            "no-excitation",
            sine_csv(3000)
                .lines()
                .enumerate()
                .map(|(i, l)| {
                    if i == 0 {
                        l.to_string()
                    } else {
                        let f: Vec<&str> = l.split(',').collect();
                        format!("{},0.5,{}", f[0], f[2])
                    }
                })
                .collect::<Vec<_>>()
                .join("\n"),
            "no excitation",
        ),
    ];
    for (name, body, want) in &cases {
        let path = tmp(&format!("{name}.csv"));
        std::fs::write(&path, body).unwrap();
        for cmd in ["diagnose", "identify"] {
            let o = boucwen(&[cmd, path.to_str().unwrap()]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(1), "{cmd} {name}: {err}");
            assert!(!err.contains("panicked"), "{cmd} {name}: {err}");
            assert_eq!(err.trim_end().lines().count(), 1, "{cmd} {name}: {err}");
            assert!(err.contains(&format!("{name}.csv")), "{cmd} {name}: {err}");
            assert!(err.contains(want), "{cmd} {name}: want {want:?} in {err}");
            assert!(o.stdout.is_empty(), "{cmd} {name}");
        }
    }
    // A file that does not exist, and a report directory that cannot be made.
    let o = boucwen(&["diagnose", "/nonexistent/rec.csv"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/rec.csv"));
    let (_, data) = hidden_record();
    let blocker = tmp("a-file");
    std::fs::write(&blocker, "x").unwrap();
    let o = boucwen(&["diagnose", data.to_str().unwrap(), "--report", blocker.join("sub").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("a-file"), "{}", String::from_utf8_lossy(&o.stderr));
    // Identify's own options.
    let o = boucwen(&["identify", data.to_str().unwrap(), "--fit-fraction", "2"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--fit-fraction 2"));
    let o = boucwen(&["identify", data.to_str().unwrap(), "--harmonics", "3"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--model enhanced"));
}

/// Two realisations of an odd random-phase multisine through an actuator with a hidden
/// nonlinearity, diagnosed together with `--realisations`: the finding names the hidden
/// parity, the held-out error is on the other realisation, and the page is written.
#[test]
fn realisations_of_a_multisine_are_diagnosed_together() {
    use boucwen_lab::fixtures::effects::{Nonlinearity, PeriodicCase, PeriodicDrive};
    for (nl, want, avoid) in [
        (Nonlinearity::Even, "even_distortion", "odd_distortion"),
        (Nonlinearity::Odd, "odd_distortion", "even_distortion"),
    ] {
        let case = PeriodicCase::generate(PeriodicDrive::Multisine, nl, 1).unwrap();
        let paths: Vec<String> = case
            .records()
            .unwrap()
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let p = tmp(&format!("{}-r{}.csv", case.name(), i + 1));
                r.write(&p).unwrap();
                p.to_str().unwrap().to_string()
            })
            .collect();
        assert_eq!(paths.len(), 2);
        let dir = tmp(&format!("{}-report", case.name()));
        let mut args = vec!["diagnose", "--realisations", "--json", "--report", dir.to_str().unwrap()];
        args.extend(paths.iter().map(String::as_str));
        let o = boucwen(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
        assert_eq!(j["drive"]["kind"], "multisine", "{j}");
        assert_eq!(j["realisations"], 2, "{j}");
        assert_eq!(j["held_out"], "realisations", "{j}");
        assert_eq!(j["files"].as_array().map(Vec::len), Some(2), "{j}");
        let kinds: Vec<&str> =
            j["findings"].as_array().unwrap().iter().filter_map(|f| f["kind"].as_str()).collect();
        assert_eq!(kinds.first(), Some(&want), "{}: {j}", case.name());
        assert!(!kinds.contains(&avoid), "{}: {j}", case.name());
        for f in ["index.html", "diagnosis.json", "lines.svg"] {
            assert!(dir.join(f).is_file(), "{f} not written");
        }
        // Without --realisations each record is its own diagnosis, one JSON line each.
        let mut args = vec!["diagnose", "--json"];
        args.extend(paths.iter().map(String::as_str));
        let o = boucwen(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let lines: Vec<serde_json::Value> =
            String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
        assert_eq!(lines.len(), 2);
        assert!(lines.iter().all(|l| l["held_out"] == "periods"), "{lines:?}");
        // Realisations of one drive share the sample interval: another is one line.
        let r2 = &case.records().unwrap()[1];
        let slow =
            boucwen_lab::record::Record::new("slow", 0.0, 2.0 * r2.ts, r2.u.clone(), r2.y.clone(), None)
                .unwrap();
        let p = tmp(&format!("{}-slow.csv", case.name()));
        slow.write(&p).unwrap();
        let o = boucwen(&["diagnose", "--realisations", &paths[0], p.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains("share the sample interval") && err.contains("-slow.csv"), "{err}");
    }
}

//! Records as they come, end to end through `boucwen diagnose` and `boucwen identify`: the
//! flags that read them, the sentences for records without a response or with a drive
//! diagnose does not analyse, several records at once, and a model that is not stable.

use boucwen_lab::fixtures::hidden::Effect;
use boucwen_lab::fixtures::messy::{self, Mess, Messy};
use std::f64::consts::TAU;
use std::path::PathBuf;
use std::process::{Command, Output};

fn boucwen(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_boucwen")).args(args).output().expect("run boucwen")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("boucwen-records-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn write_messy(mess: Mess, effect: Effect, seed: u64) -> (Messy, PathBuf) {
    let m = Messy::generate(mess, effect, seed).unwrap();
    let path = tmp(&m.file_name());
    std::fs::write(&path, &m.text).unwrap();
    (m, path)
}

/// One line on stderr naming the file, exit code 1, nothing on stdout.
fn assert_one_line_error(o: &Output, file: &str, want: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains(file), "{err}");
    assert!(err.contains(want), "want {want:?} in {err}");
    assert!(!err.contains("panicked"), "{err}");
}

fn json(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("one JSON object")
}

#[test]
fn a_record_in_metres_needs_the_flag_and_is_diagnosed_with_it() {
    let (_, path) = write_messy(Mess::Metres, Effect::OddHarmonic(3), 2);
    let p = path.to_str().unwrap();
    for cmd in ["diagnose", "identify"] {
        assert_one_line_error(&boucwen(&[cmd, p]), p, "give --y-unit m");
    }
    let j = json(&boucwen(&["diagnose", p, "--y-unit", "m", "--json"]));
    assert_eq!(j["findings"][0]["kind"], "odd_harmonic");
    assert_eq!(j["import"]["y_unit"], "m");
    assert_eq!(j["file"], p);
    let fit = j["extended"]["fit_pct"].as_f64().unwrap();
    assert!(fit > 90.0 && fit <= 100.0, "{fit}");
    assert!(j["noise_um"].as_f64().unwrap() > 0.0);
}

#[test]
fn no_header_no_time_read_with_columns_and_sample_rate() {
    let (m, path) = write_messy(Mess::NoHeader, Effect::Clean, 1);
    let p = path.to_str().unwrap();
    assert_one_line_error(&boucwen(&["diagnose", p]), p, "--columns");
    let mut args = vec!["diagnose", p, "--json"];
    let flags: Vec<&str> = m.flags.iter().map(String::as_str).collect();
    args.extend(&flags);
    let j = json(&boucwen(&args));
    assert_eq!(j["findings"].as_array().unwrap().len(), 0, "{j}");
    assert_eq!(j["import"]["header"], false);
    assert_eq!(j["import"]["columns"]["u"], "column 1");
    let mut args = vec!["identify", p, "--json"];
    args.extend(&flags);
    let j = json(&boucwen(&args));
    assert_eq!(j["stable"], true);
    assert_eq!(j["drive"]["kind"], "sine");
}

#[test]
fn the_window_is_stated_and_can_be_given() {
    let (m, path) = write_messy(Mess::LeadIn, Effect::Clean, 2);
    let p = path.to_str().unwrap();
    let j = json(&boucwen(&["diagnose", p, "--json"]));
    let w0 = j["window_s"][0].as_f64().unwrap();
    assert!(w0 >= m.drive_s.0, "{w0} vs {}", m.drive_s.0);
    assert!(j["window_why"].as_str().unwrap().contains("idle"), "{j}");
    let (a, b) = (m.drive_s.0 + 1.0, m.drive_s.0 + 6.0);
    let given = format!("{a}:{b}");
    let j = json(&boucwen(&["diagnose", p, "--json", "--window", &given]));
    assert!((j["window_s"][0].as_f64().unwrap() - a).abs() < 2e-3, "{j}");
    assert!(j["window_s"][1].as_f64().unwrap() <= b + 1e-9);
    assert!(j["window_why"].as_str().unwrap().starts_with("given by --window"));
    assert_one_line_error(&boucwen(&["diagnose", p, "--window", "50:60"]), p, "is not a part of the record");
    let o = boucwen(&["diagnose", p, "--window", "x"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("expected START:END"));
}

#[test]
fn several_records_one_json_line_each_in_order() {
    let (_, a) = write_messy(Mess::Renamed, Effect::OddHarmonic(5), 1);
    let (_, b) = write_messy(Mess::SecondInput, Effect::Clean, 1);
    let bad = tmp("bad.csv");
    std::fs::write(&bad, "t,u,y\n0,0,0\n0.001,abc,1\n").unwrap();
    let (a, b, bad) = (a.to_str().unwrap(), b.to_str().unwrap(), bad.to_str().unwrap());
    let o = boucwen(&["diagnose", a, bad, b, "--json"]);
    assert_eq!(o.status.code(), Some(1), "one record failed");
    let out = String::from_utf8(o.stdout).unwrap();
    let lines: Vec<serde_json::Value> = out.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 3, "{out}");
    assert_eq!(lines[0]["file"], a);
    assert_eq!(lines[0]["findings"][0]["order"], 5);
    assert_eq!(lines[1]["file"], bad);
    assert!(lines[1]["error"].as_str().unwrap().contains(":3: column \"u\""), "{}", lines[1]);
    assert_eq!(lines[2]["findings"][0]["kind"], "other_input");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("1 of 3 records could not be diagnosed"), "{err}");
}

#[test]
fn an_unstable_model_is_marked_never_printed_and_identify_fails() {
    let r = messy::unstable_rls_record().unwrap();
    let path = tmp("rls-40hz.csv");
    r.write(&path).unwrap();
    let p = path.to_str().unwrap();
    let o = boucwen(&["identify", p, "--method", "rls", "--json"]);
    assert_eq!(o.status.code(), Some(1));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["stable"], false, "{j}");
    assert!(j["rms_um"].is_null() && j["fit_pct"].is_null(), "{j}");
    assert!(j["unstable_reason"].as_str().unwrap().contains("diverges"), "{j}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("no stable model was found"), "{err}");
    let o = boucwen(&["identify", p, "--method", "rls"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("free run: not stable"), "{text}");
    assert!(!text.contains("held out;"), "{text}");
    // The output-error fit of the same record is stable.
    let j = json(&boucwen(&["identify", p, "--json"]));
    assert_eq!(j["stable"], true);
}

/// A CSV of `n` rows at 1 kHz with the given drive and output.
fn csv(n: usize, u: impl Fn(f64) -> f64, y: impl Fn(usize, f64) -> String) -> String {
    let mut s = String::from("t,u,y\n");
    for k in 0..n {
        let t = k as f64 * 1e-3;
        s.push_str(&format!("{t},{},{}\n", u(t), y(k, t)));
    }
    s
}

#[test]
fn records_without_a_response_or_with_another_drive_get_one_sentence() {
    let sine = |t: f64| (TAU * 20.0 * t).sin();
    let mut g = 99u64;
    let mut noise = move || {
        g ^= g << 13;
        g ^= g >> 7;
        g ^= g << 17;
        (g >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let noisy: Vec<f64> = (0..5000).map(|_| noise()).collect();
    let cases: Vec<(&str, String, &str)> = vec![
        ("dead", csv(5000, sine, |_, _| "0".into()), "the output is constant"),
        (
            "subnormal",
            csv(5000, sine, |k, _| if k % 2 == 0 { "5e-324".into() } else { "0".into() }),
            "the output is constant",
        ),
        ("coarse", csv(5000, sine, |k, _| format!("{}", (k % 3) as f64 * 0.01)), "takes only 3 values"),
        ("unrelated", csv(5000, sine, |k, _| format!("{}", noisy[k])), "does not follow the drive"),
    ];
    for (name, body, want) in &cases {
        let path = tmp(&format!("{name}.csv"));
        std::fs::write(&path, body).unwrap();
        for cmd in ["diagnose", "identify"] {
            assert_one_line_error(&boucwen(&[cmd, path.to_str().unwrap()]), name, want);
        }
    }
    // A multisine through a linear system: diagnose analyses it at its lines and finds no
    // distortion; identify fits it.
    let lines: Vec<f64> = (0..20).map(|l| 0.7 * l as f64).collect();
    let ms = move |t: f64| {
        lines
            .iter()
            .enumerate()
            .map(|(l, ph)| 0.1 * (TAU * (2 * l + 1) as f64 * t / 0.512 + ph).sin())
            .sum::<f64>()
    };
    let path = tmp("multisine.csv");
    std::fs::write(&path, csv(8192, &ms, |_, t| format!("{}", 10.0 * ms(t) + 0.5 * ms(t - 0.002)))).unwrap();
    let p = path.to_str().unwrap();
    let d = json(&boucwen(&["diagnose", p, "--json"]));
    assert_eq!(d["drive"]["kind"], "multisine", "{d}");
    assert_eq!(d["findings"].as_array().map(Vec::len), Some(0), "{d}");
    let j = json(&boucwen(&["identify", p, "--json"]));
    assert_eq!(j["drive"]["kind"], "multisine");
    assert!(j["fit_pct"].as_f64().unwrap() > 90.0, "{j}");
    // A field of a million characters is quoted short.
    let path = tmp("long-field.csv");
    std::fs::write(&path, format!("t,u,y\n0,0,0\n0.001,{},0\n", "7".repeat(1_000_000) + "x")).unwrap();
    let o = boucwen(&["diagnose", path.to_str().unwrap()]);
    assert_one_line_error(&o, "long-field.csv", "is not a number");
    assert!(o.stderr.len() < 300, "{} bytes", o.stderr.len());
}

#[test]
fn a_spreadsheet_s_and_an_instrument_s_exports_are_read_as_they_come() {
    let (_, path) = write_messy(Mess::Spreadsheet, Effect::OddHarmonic(3), 2);
    let p = path.to_str().unwrap();
    let j = json(&boucwen(&["diagnose", p, "--json"]));
    assert_eq!(
        (j["import"]["separator"].as_str(), j["import"]["decimal_comma"].as_bool()),
        (Some("semicolon"), Some(true))
    );
    assert_eq!(j["import"]["t_unit"], "ms");
    assert_eq!(j["findings"][0]["kind"], "odd_harmonic");
    let (_, path) = write_messy(Mess::Instrument, Effect::Clean, 1);
    let p = path.to_str().unwrap();
    let j = json(&boucwen(&["diagnose", p, "--json"]));
    assert_eq!(j["import"]["preamble"]["lines"], 20);
    assert!(j["import"]["cut_short_line"].as_u64().is_some());
    assert_eq!(j["findings"].as_array().map(Vec::len), Some(0));
    // Whole milliseconds under a header without a unit: refused, then read with the flag.
    let m = messy::Messy::generate(Mess::Spreadsheet, Effect::Clean, 1).unwrap();
    let text = m.text.replacen("\"Time, ms\"", "\"Time\"", 1);
    let path = tmp("whole-ms.csv");
    std::fs::write(&path, text).unwrap();
    let p = path.to_str().unwrap();
    assert_one_line_error(&boucwen(&["diagnose", p]), p, "give --t-unit ms");
    let j = json(&boucwen(&["diagnose", p, "--t-unit", "ms", "--json"]));
    assert_eq!(j["ts_s"].as_f64().or(j["import"]["ts_s"].as_f64()), Some(0.001));
}

#[test]
fn a_stepped_sine_is_diagnosed_step_by_step_in_text_and_json() {
    // Two steps of the paper's actuator, simulated from a drive file as a user would.
    let drive: String = std::iter::once("u\n".to_string())
        .chain([14.0, 23.0].iter().flat_map(|&f: &f64| {
            (0..5000).map(move |k| format!("{:.6}\n", (TAU * f * k as f64 * 1e-3).sin()))
        }))
        .collect();
    let (drive_path, rec) = (tmp("steps-drive.csv"), tmp("steps.csv"));
    std::fs::write(&drive_path, drive).unwrap();
    let o = boucwen(&[
        "simulate",
        "--input",
        drive_path.to_str().unwrap(),
        "--column",
        "u",
        "--out",
        rec.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let p = rec.to_str().unwrap();
    let o = boucwen(&["diagnose", p]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(text.contains("the drive steps through 2 sines: 14.000 Hz 1.000 V (0 to "), "{text}");
    assert!(text.contains("== step 2 of 2:") && text.contains("across the steps (held out):"), "{text}");
    let o = boucwen(&["diagnose", p, "--json"]);
    assert!(o.status.success());
    let lines: Vec<serde_json::Value> =
        String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 2);
    for (i, (j, order)) in lines.iter().zip([5, 3]).enumerate() {
        assert_eq!(j["step"]["index"], i + 1);
        assert_eq!(j["findings"][0]["kind"], "odd_harmonic", "{j}");
        assert_eq!(j["findings"][0]["order"], order, "{j}");
    }
    // A window given: that part only, as one record.
    let j = json(&boucwen(&["diagnose", p, "--window", "5.5:10", "--json"]));
    assert_eq!(j["findings"][0]["order"], 3);
    assert!(j.get("step").is_none());
}

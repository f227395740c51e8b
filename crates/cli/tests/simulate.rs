//! `boucwen simulate` end to end: a sine through the virtual bimorph, the record read back,
//! the same drive from a CSV column, and bad input.

use boucwen_lab::record::Record;
use std::path::PathBuf;
use std::process::Command;

fn boucwen(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_boucwen")).args(args).output().expect("run boucwen")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("boucwen-simulate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn a_sine_record_shows_the_odd_harmonic_and_replays_from_its_own_column() {
    let out = tmp("s23.csv");
    let o =
        boucwen(&["simulate", "--freq", "23", "--seconds", "4", "--json", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(j["samples"], 4000);
    let h = j["harmonics"].as_array().unwrap();
    let (a1, a3) = (h[0]["amp_um"].as_f64().unwrap(), h[2]["amp_um"].as_f64().unwrap());
    // The default actuator: about 20 µm at 23 Hz with a 3rd harmonic of about a fifth of it.
    assert!((15.0..25.0).contains(&a1), "{a1}");
    assert!(a3 > 0.1 * a1, "{a3} vs {a1}");
    let r = Record::read(&out).expect("record");
    assert_eq!(r.len(), 4000);
    assert!((r.ts - 1e-3).abs() < 1e-12);

    // The same drive from the file's u column gives the same output (same seed).
    let again = tmp("again.csv");
    let o = boucwen(&[
        "simulate",
        "--input",
        out.to_str().unwrap(),
        "--column",
        "u",
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r2 = Record::read(&again).expect("record");
    assert_eq!(r2.u, r.u);
    assert_eq!(r2.y, r.y);
}

#[test]
fn bad_drives_are_one_line_errors_naming_file_and_line() {
    let bad = tmp("bad.csv");
    std::fs::write(&bad, "t,v\n0,0\n0.001,abc\n").unwrap();
    let out = tmp("never.csv");
    let o = boucwen(&[
        "simulate",
        "--input",
        bad.to_str().unwrap(),
        "--column",
        "v",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("bad.csv:3") && err.contains("not a number"), "{err}");
    assert!(!out.exists());

    let o = boucwen(&["simulate", "--input", bad.to_str().unwrap(), "--column", "w"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no column \"w\""));

    std::fs::write(&bad, "t,v\n0,0\n0.002,1\n0.004,0\n").unwrap();
    let o = boucwen(&[
        "simulate",
        "--input",
        bad.to_str().unwrap(),
        "--column",
        "v",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("sampled every"));
    assert!(!out.exists());

    let o = boucwen(&["simulate", "--freq", "700"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("Nyquist"));
}

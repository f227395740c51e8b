//! Each finding keeps its evidence in the JSON of `diagnose` (issue 13, item 4): `kind`,
//! `order` where one applies, `freq_hz` or a band, `level` or `residual_share`, `cause`,
//! `kept` and `term_rms_um`, most important first (the kept terms in the order they were
//! chosen, then what no term removed). Checked on sine records with each hidden cause of
//! [`boucwen_lab::fixtures::effects`] (and two at once) and on periodic and multisine records with a
//! hidden odd or even nonlinearity; the truth is kept by the test, and each hidden effect
//! must be named.

use boucwen_lab::diagnose::periodic::Realisation;
use boucwen_lab::diagnose::{self, Outcome};
use boucwen_lab::fixtures::effects::{
    Nonlinearity, PeriodicCase, PeriodicDrive, SineCase, SineEffect, Truth,
};
use boucwen_lab::record::Record;
use boucwen_lab::report::diagnosis::json;
use boucwen_lab::rules::Rules;
use serde_json::Value;

fn outcome(records: &[Record]) -> Outcome {
    let recs: Vec<Realisation> =
        records.iter().map(|r| Realisation { u: &r.u, y: &r.y, t0: r.t0, given: None }).collect();
    diagnose::diagnose_drive(&recs, records[0].ts, &Rules::default()).expect("diagnosis")
}

/// The evidence of every finding, and kept findings before the others; returns the kinds
/// (with the order for harmonics) in the JSON's order.
fn evidence(j: &Value, what: &str) -> Vec<(String, Option<u64>, bool)> {
    let findings = j["findings"].as_array().unwrap_or_else(|| panic!("{what}: no findings array: {j}"));
    let mut seen_not_kept = false;
    let mut out = vec![];
    for f in findings {
        let kind = f["kind"].as_str().unwrap_or_else(|| panic!("{what}: kind: {f}"));
        let kept = f["kept"].as_bool().unwrap_or_else(|| panic!("{what}: kept: {f}"));
        assert!(f["cause"].as_str().is_some_and(|c| c.len() > 20), "{what}: cause: {f}");
        assert!(
            f["term_rms_um"].as_f64().is_some_and(|x| x.is_finite() && x > 0.0),
            "{what}: term_rms_um: {f}"
        );
        let has_freq = f["freq_hz"].as_f64().is_some_and(f64::is_finite);
        let has_band = f["band_hz"].as_array().is_some_and(|b| b.len() == 2);
        assert!(has_freq || has_band, "{what}: freq_hz or band_hz: {f}");
        let has_level = f["level"].as_f64().is_some_and(f64::is_finite) && f["level_unit"].is_string();
        let has_share = f["residual_share"].as_f64().is_some_and(|s| (0.0..=1.0).contains(&s));
        assert!(has_level || has_share, "{what}: level or residual_share: {f}");
        let harmonic = kind.ends_with("_harmonic");
        assert_eq!(f["order"].as_u64().is_some(), harmonic, "{what}: order only for harmonics: {f}");
        if kind.ends_with("_distortion") {
            assert!(has_level && has_band, "{what}: a distortion's level and band: {f}");
        }
        if kind == "saturation" || kind == "input_delay" {
            assert!(has_level, "{what}: the {kind} level: {f}");
        }
        assert!(
            kept || !seen_not_kept || kind == "input_delay",
            "{what}: a kept finding after one not kept: {j}"
        );
        seen_not_kept |= !kept;
        out.push((kind.to_string(), f["order"].as_u64(), kept));
    }
    out
}

fn named(found: &[(String, Option<u64>, bool)], t: &Truth) -> bool {
    found.iter().any(|(kind, order, _)| match t {
        Truth::Harmonic { order: n, .. } => kind == "odd_harmonic" && *order == Some(u64::from(*n)),
        Truth::Drift => kind == "drift",
        Truth::Saturation { .. } => kind == "saturation",
        Truth::Creep => kind == "creep",
        Truth::Delay { .. } => kind == "input_delay",
        Truth::OddDistortion => kind == "odd_distortion",
        Truth::EvenDistortion => kind == "even_distortion",
    })
}

#[test]
fn sine_findings_carry_their_evidence_and_name_each_hidden_cause() {
    for e in SineEffect::ALL {
        let c = SineCase::generate(e, 1).expect("case");
        let o = outcome(&[c.record().expect("record")]);
        let j = json(&o, &Rules::default());
        let what = format!("{} seed 1", e.name());
        let found = evidence(&j, &what);
        eprintln!("{what}: truth {:?}; gain {:.1} %", c.truth, j["gain_pct"]);
        for f in j["findings"].as_array().unwrap() {
            eprintln!(
                "  {} order {} level {} {} share {:.3} kept {}",
                f["kind"], f["order"], f["level"], f["level_unit"], f["residual_share"], f["kept"]
            );
        }
        for t in &c.truth {
            assert!(named(&found, t), "{what}: {t:?} not named: {found:?}");
        }
    }
}

#[test]
fn periodic_findings_carry_their_evidence_and_name_the_hidden_parity() {
    for (drive, nl) in [
        (PeriodicDrive::Multisine, Nonlinearity::Odd),
        (PeriodicDrive::Multisine, Nonlinearity::Even),
        (PeriodicDrive::Triangle, Nonlinearity::Even),
    ] {
        let c = PeriodicCase::generate(drive, nl, 1).expect("case");
        let o = outcome(&c.records().expect("records"));
        let j = json(&o, &Rules::default());
        let found = evidence(&j, &c.name());
        eprintln!("{}: {found:?}; gain {:.1} %", c.name(), j["gain_pct"]);
        for f in j["findings"].as_array().unwrap() {
            eprintln!("  {} level {} band {} kept {}", f["kind"], f["level"], f["band_hz"], f["kept"]);
        }
        let t = c.truth().expect("a hidden nonlinearity");
        assert!(named(&found, &t), "{}: {t:?} not named: {found:?}", c.name());
        assert!(
            !found.is_empty() && named(&found[..1], &t),
            "{}: first finding not {t:?}: {found:?}",
            c.name()
        );
    }
}

/// A sensor's range: the drive the finding advises (`drive_within_range_v`) keeps the
/// actuator's output inside the range when the record is measured again with it, and leaves
/// little of it unused (the model's loop is not the actuator's, hence the margin).
#[test]
fn a_clipped_output_gets_the_drive_that_keeps_it_inside_the_range() {
    for seed in 1..=4 {
        let c = SineCase::generate(SineEffect::SensorRange, seed).expect("case");
        let [lo, hi] = c.sensor_range.expect("a sensor range");
        let j = json(&outcome(&[c.record().expect("record")]), &Rules::default());
        let what = format!("sensor-range seed {seed}");
        let f = &j["findings"][0];
        assert_eq!(f["kind"], "saturation", "{what}: {j}");
        let v = f["drive_within_range_v"].as_f64().unwrap_or_else(|| panic!("{what}: no advised drive: {f}"));
        assert!(v > 0.0 && v < c.case.amplitude_v, "{what}: advised {v} V of {} V", c.case.amplitude_v);
        let share_on = |amplitude_v: f64| {
            let mut again = c.clone();
            again.case.amplitude_v = amplitude_v;
            let r = again.record().expect("record at the advised drive");
            let settled = &r.y[r.y.len() / 5..];
            settled.iter().filter(|&&y| y <= lo || y >= hi).count() as f64 / settled.len() as f64
        };
        let (at, above) = (share_on(v), share_on(1.25 * v));
        eprintln!(
            "{what}: {:.3} V advised of {:.3} V; on the range {at:.4} there, {above:.4} at 1.25×",
            v, c.case.amplitude_v
        );
        assert_eq!(at, 0.0, "{what}: the advised drive still clips");
        assert!(
            above > 0.0,
            "{what}: a quarter more than the advised drive does not reach the range: the advice wastes it"
        );
    }
}

//! A sensor may count the actuator's stroke either way: a laser that measures its distance
//! to the actuator reads the stroke downwards. The models are odd in the output (`y → −y` is
//! `A1, A, A0, γ → −A1, −A, −A0, −γ` with the loop's shape unchanged, and the branches',
//! offset's and drift's weights negated), so the diagnosis of `−y` must be the diagnosis of
//! `y`: the same findings in the same order, the same held-out errors (to 1 %: the
//! refinements stop by tolerances). Checked on a record of every kind of hidden effect and
//! drive. The fit finds the output's sign as `boucwen_lab::fit::fit_oe_on` says.

use boucwen_lab::diagnose::periodic::Realisation;
use boucwen_lab::diagnose::{self, Outcome};
use boucwen_lab::fixtures::effects::{Nonlinearity, PeriodicCase, PeriodicDrive, SineCase, SineEffect};
use boucwen_lab::fixtures::hidden::{Case, Effect};
use boucwen_lab::record::Record;
use boucwen_lab::rules::Rules;
use serde_json::Value;

fn outcome(records: &[Record], flip: bool) -> Value {
    let ys: Vec<Vec<f64>> =
        records.iter().map(|r| r.y.iter().map(|&y| if flip { -y } else { y }).collect()).collect();
    let recs: Vec<Realisation> =
        records.iter().zip(&ys).map(|(r, y)| Realisation { u: &r.u, y, t0: r.t0, given: None }).collect();
    let o: Outcome = diagnose::diagnose_drive(&recs, records[0].ts, &Rules::default()).expect("diagnosis");
    boucwen_lab::report::diagnosis::json(&o, &Rules::default())
}

fn findings(j: &Value) -> Vec<(String, Option<u64>, bool)> {
    j["findings"]
        .as_array()
        .map(|f| {
            f.iter()
                .map(|f| {
                    (f["kind"].as_str().unwrap_or("").to_string(), f["order"].as_u64(), f["kept"] == true)
                })
                .collect()
        })
        .unwrap_or_default()
}

fn assert_same_either_way(name: &str, records: &[Record]) {
    let (up, down) = (outcome(records, false), outcome(records, true));
    let (f_up, f_down) = (findings(&up), findings(&down));
    assert_eq!(f_up, f_down, "{name}: findings of y and of −y");
    for key in ["baseline", "extended"] {
        let (a, b) = (up[key]["rms_um"].as_f64(), down[key]["rms_um"].as_f64());
        let (Some(a), Some(b)) = (a, b) else { panic!("{name}: no {key} RMS: {up} / {down}") };
        assert!((a - b).abs() <= 0.01 * a.max(b) + 1e-6, "{name}: {key} {a} µm for y, {b} µm for −y");
    }
    eprintln!(
        "{name}: {f_up:?}; y {} -> {} µm, −y {} -> {} µm",
        up["baseline"]["rms_um"],
        up["extended"]["rms_um"],
        down["baseline"]["rms_um"],
        down["extended"]["rms_um"]
    );
}

#[test]
fn a_hidden_effect_is_found_the_same_whichever_way_the_sensor_counts() {
    for effect in [Effect::OddHarmonic(3), Effect::EvenHarmonic(2), Effect::Drift, Effect::Clean] {
        let case = Case::generate(effect, 1).expect("case");
        assert_same_either_way(&format!("{} seed 1", effect.name()), &[case.record().expect("record")]);
    }
}

#[test]
fn saturation_creep_delay_and_two_effects_are_found_the_same_whichever_way_the_sensor_counts() {
    for e in SineEffect::ALL {
        let c = SineCase::generate(e, 1).expect("case");
        assert_same_either_way(&format!("{} seed 1", e.name()), &[c.record().expect("record")]);
    }
}

#[test]
fn periodic_drives_are_diagnosed_the_same_whichever_way_the_sensor_counts() {
    for (drive, nl) in [
        (PeriodicDrive::Multisine, Nonlinearity::Odd),
        (PeriodicDrive::Multisine, Nonlinearity::Even),
        (PeriodicDrive::Triangle, Nonlinearity::Even),
        (PeriodicDrive::Triangle, Nonlinearity::None),
    ] {
        let c = PeriodicCase::generate(drive, nl, 1).expect("case");
        assert_same_either_way(&c.name(), &c.records().expect("records"));
    }
}

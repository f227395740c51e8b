//! An identification as text and JSON.

use super::diagnosis::{instability_text, narrow_text};
use crate::fit::{DataUsed, Fit};
use crate::identify::Identified;
use crate::rules::Rules;
use serde_json::{Value, json};
use std::fmt::Write;

/// How the output-error fit ended, what it was computed on and how long it took (s).
pub fn fit_json(f: &Fit, seconds: f64) -> Value {
    let data = match f.data {
        DataUsed::Samples { from, to } => json!({"kind": "samples", "from": from, "to": to}),
        DataUsed::Periods { from, to, periods, scored } => json!({
            "kind": "average_period", "from": from, "to": to, "periods": periods, "scored_samples": scored,
        }),
    };
    json!({
        "stop": f.stop.as_str(),
        "iterations": f.iterations,
        "evaluations": f.evaluations,
        "criterion_rms_um": f.rms_fit,
        "data": data,
        "seconds": seconds,
    })
}

/// How the output-error fit ended, in words.
pub fn fit_text(f: &Fit) -> String {
    let data = match f.data {
        DataUsed::Samples { from, to } => format!("samples {from}..{to}"),
        DataUsed::Periods { from, to, periods, .. } => {
            format!("the average of {periods} periods of samples {from}..{to}")
        }
    };
    format!(
        "fit on {data}: stopped after {} iterations ({}), {} evaluations",
        f.iterations, f.stop, f.evaluations
    )
}

/// The JSON object of `boucwen identify --json`.
pub fn json(o: &Identified) -> Value {
    let m = &o.model;
    let bw = &m.ext.bw;
    let branches: Vec<Value> = m
        .branches
        .iter()
        .map(|b| json!({"order": b.order, "alpha_s": b.alpha_s, "alpha_c": b.alpha_c, "ar": b.ar}))
        .collect();
    let stable = o.check.unstable.is_none();
    let mut j = json!({
        "model": m.name(),
        "method": o.method.name(),
        "drive_hz": o.drive_hz,
        "drive": {"kind": o.drive.kind.as_str(), "freq_hz": o.drive.freq_hz, "thd_pct": 100.0 * o.drive.thd},
        "window_s": o.window_s,
        "window_why": o.why,
        "fit_samples": o.samples.0,
        "held_out_samples": o.samples.1,
        "stable": stable,
        "unstable_reason": o.check.unstable.as_ref().map(instability_text),
        "narrow": o.check.narrow.as_ref().map(narrow_text),
        "fit_rms_um": o.fit_rms_um,
        "rms_um": stable.then_some(o.held_rms_um),
        "fit_pct": o.check.fit_pct,
        "noise_um": o.noise_um.0,
        "noise_method": o.noise_um.1,
        "params": {
            "ar": m.ext.ar,
            "a1": bw.a1, "a": bw.a, "a0": bw.a0, "gamma": bw.gamma, "beta": bw.beta,
            "delay_samples": m.delay,
            "branches": branches,
        },
    });
    if let Some((f, seconds)) = &o.fit {
        j["fit"] = fit_json(f, *seconds);
    }
    j
}

/// The terminal report of `boucwen identify`.
pub fn text(o: &Identified, name: &str, rules: &Rules) -> String {
    let m = &o.model;
    let bw = &m.ext.bw;
    let mut s = String::new();
    let _ = writeln!(s, "{name}: drive {}", o.drive.describe());
    let _ = writeln!(s, "window {:.3} to {:.3} s: {}", o.window_s[0], o.window_s[1], o.why);
    let _ = writeln!(
        s,
        "{} model by {}, fitted on {} samples, tested on the {} after them (Ts = {} s)",
        m.name(),
        o.method.name(),
        o.samples.0,
        o.samples.1,
        o.ts
    );
    let _ = writeln!(s, "  structure  a1 = {:.6}, a2 = {:.6}", m.ext.ar[0], m.ext.ar[1]);
    if let Some(f) = crate::model::poles::resonance_hz(&m.ext.ar, o.ts) {
        let _ = writeln!(s, "             resonance {f:.1} Hz (where the record excites it: see diagnose)");
    }
    let _ = writeln!(
        s,
        "  hysteresis A1 = {:.6}, A = {:.6}, A0 = {:.6}, gamma = {:.6}, beta = {:.6}",
        bw.a1, bw.a, bw.a0, bw.gamma, bw.beta
    );
    let _ = writeln!(s, "  input delay {:.3} samples", m.delay);
    for b in &m.branches {
        let _ = writeln!(
            s,
            "  branch n = {}: alpha_s = {:.6}, alpha_c = {:.6}, ar = [{:.6}, {:.6}]",
            b.order, b.alpha_s, b.alpha_c, b.ar[0], b.ar[1]
        );
    }
    match (&o.check.unstable, o.check.fit_pct) {
        (Some(why), _) => {
            let _ = writeln!(s, "free run: not stable, {}", instability_text(why));
        }
        (None, fit) => {
            let _ = writeln!(
                s,
                "free-run RMS error: {} on the fitted part, {:.4} µm held out; held-out fit {:.1} %; noise floor {:.4} µm",
                o.fit_rms_um.map_or("not stable".to_string(), |v| format!("{v:.4} µm")),
                o.held_rms_um,
                fit.unwrap_or(f64::NAN),
                o.noise_um.0
            );
            let min = rules.checks.min_fit_pct;
            if fit.is_some_and(|f| f < min) {
                let _ = writeln!(
                    s,
                    "the drive explains less than {min:.0} % of the held-out output: another input or a disturbance drives it"
                );
            }
            if let Some(why) = &o.check.narrow {
                let _ = writeln!(s, "note: {}", narrow_text(why));
            }
        }
    }
    if let Some((f, _)) = &o.fit {
        let _ = writeln!(s, "{}", fit_text(f));
    }
    s
}

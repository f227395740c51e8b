//! An identification as text and JSON.

use super::diagnosis::{instability_text, narrow_text};
use crate::fit::{DataUsed, Fit};
use crate::identify::Identified;
use crate::identify::compare::Comparison;
use crate::identify::families::{Choice, Compared};
use crate::model::{Model, ModelFile};
use crate::report::plot::{Chart, Series};
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

/// A model's structure and parameters as JSON.
pub fn model_json(m: &Model) -> Value {
    let s = m.structure();
    let params: serde_json::Map<String, Value> =
        m.parameters().into_iter().map(|(k, v)| (k, json!(v))).collect();
    json!({
        "name": m.name(),
        "family": s.family.name(),
        "hysteresis": s.hysteresis.name(),
        "poles": s.poles,
        "zeros": s.zeros,
        "delay_samples": s.delay_samples,
        "terms": s.terms,
        "params": params,
    })
}

/// The families `identify --model linear|oscillator|auto` fitted, and the one kept, as JSON.
pub fn families_json(c: &Compared) -> Value {
    let scores: Vec<Value> = c
        .scores
        .iter()
        .map(|s| {
            json!({
                "family": s.family.name(),
                "model": s.model.as_ref().ok().map(model_json),
                "error": s.model.as_ref().err(),
                "fit_rms_um": s.fit_rms_um,
                "rms_um": s.held_rms_um,
                "stable": s.held_rms_um.is_some(),
                "seconds": s.seconds,
            })
        })
        .collect();
    let (choice, gain, ratio) = match c.choice {
        Choice::Asked => ("asked", None, None),
        Choice::PaperModel { best_other_gain, noise_ratio } => ("paper_model", best_other_gain, noise_ratio),
        Choice::Better { gain, noise_ratio } => ("better_held_out", Some(gain), Some(noise_ratio)),
        Choice::OnlyOther => ("only_stable_family", None, None),
    };
    json!({
        "families": scores,
        "chosen": c.scores[c.chosen].family.name(),
        "model": c.model().map(model_json),
        "rms_um": c.scores[c.chosen].held_rms_um,
        "choice": choice,
        "gain_pct": gain.map(|g| 100.0 * g),
        "noise_um": c.noise_um,
        "noise_ratio": ratio,
        "window_s": c.window_s,
        "fit_samples": c.samples.0,
        "held_out_samples": c.samples.1,
    })
}

fn um(v: Option<f64>) -> String {
    v.map_or("unstable".to_string(), |v| format!("{v:.4} µm"))
}

/// The terminal report of the families fitted and the one kept.
pub fn families_text(c: &Compared, name: &str, rules: &Rules) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{name}: window {:.3} to {:.3} s, fitted on {} samples, tested on the {} after them",
        c.window_s[0], c.window_s[1], c.samples.0, c.samples.1
    );
    for (i, f) in c.scores.iter().enumerate() {
        let mark = if i == c.chosen { "*" } else { " " };
        match &f.model {
            Ok(m) => {
                let st = m.structure();
                let _ = writeln!(
                    s,
                    "{mark} {:<10} {:<28} hysteresis {:<22} fit {:>12}, held out {:>12} ({:.1} s)",
                    f.family.name(),
                    m.name(),
                    st.hysteresis.name(),
                    um(f.fit_rms_um),
                    um(f.held_rms_um),
                    f.seconds
                );
            }
            Err(e) => {
                let _ = writeln!(s, "{mark} {:<10} not fitted: {e}", f.family.name());
            }
        }
    }
    let kept = c.scores[c.chosen].family.name();
    let min = 100.0 * rules.families.min_gain;
    let max_ratio = rules.families.max_noise_ratio;
    let why = match c.choice {
        Choice::Asked => format!("the {kept} model, as asked"),
        Choice::PaperModel { best_other_gain: Some(g), noise_ratio } => format!(
            "kept the paper's actuator: the best other family is {:.1} % {} held out and leaves {:.1} times the noise floor of \
             {:.4} µm; another family needs {min:.0} % better and at most {max_ratio:.1} times the noise",
            100.0 * g.abs(),
            if g >= 0.0 { "better" } else { "worse" },
            noise_ratio.unwrap_or(f64::NAN),
            c.noise_um
        ),
        Choice::PaperModel { best_other_gain: None, .. } => {
            "kept the paper's actuator: no other family gave a stable model".into()
        }
        Choice::Better { gain, noise_ratio } => format!(
            "kept the {kept} model: {:.1} % lower held-out RMS than the paper's actuator (at least {min:.0} % needed), {:.2} \
             times the noise floor of {:.4} µm (at most {max_ratio:.1}); the hysteresis sits {}",
            100.0 * gain,
            noise_ratio,
            c.noise_um,
            c.scores[c.chosen].family.hysteresis().name()
        ),
        Choice::OnlyOther => format!("kept the {kept} model: the paper's actuator gave no stable model"),
    };
    let _ = writeln!(s, "{why}");
    if let Some(m) = c.model() {
        let p: Vec<String> = m.parameters().iter().map(|(k, v)| format!("{k} = {v:.6}")).collect();
        let _ = writeln!(s, "  {}", p.join(", "));
    }
    s
}

/// The terminal report of `compare`.
pub fn comparison_text(c: &Comparison, model: &ModelFile, model_name: &str, record: &str, ts: f64) -> String {
    let (a, b) = c.window;
    format!(
        "{model_name} ({}) on {record}, samples {a}..{b} ({:.3} s): RMS error {:.4} µm, fit {:.2} %, NRMSE {:.5} (output {:.4} µm RMS)\n",
        model.model.name(),
        (b - a) as f64 * ts,
        c.rms_um,
        c.fit_pct,
        c.nrmse,
        c.output_rms_um
    )
}

/// `compare --json`.
pub fn comparison_json(c: &Comparison, model: &ModelFile) -> Value {
    json!({
        "model": model_json(&model.model),
        "fitted_on": model.fitted_on,
        "window_samples": [c.window.0, c.window.1],
        "rms_um": c.rms_um,
        "fit_pct": c.fit_pct,
        "nrmse": c.nrmse,
        "output_rms_um": c.output_rms_um,
    })
}

/// The measured and simulated outputs over the window, as an SVG figure.
pub fn comparison_svg(c: &Comparison, r: &crate::record::Record, title: &str) -> String {
    let (a, b) = c.window;
    let t: Vec<f64> = (a..b).map(|k| r.time(k)).collect();
    Chart::new(title, "t (s)", "y (µm)")
        .with(Series::line("measured", t.clone(), r.y[a..b].to_vec(), 0))
        .with(Series::line("model", t.clone(), c.simulated[a..b].to_vec(), 1).dashed())
        .with(Series::line("error", t, (a..b).map(|k| r.y[k] - c.simulated[k]).collect(), 2))
        .to_svg()
}

//! A sine diagnosis as text and JSON.

use super::{
    check_text, finding_json, finding_text, instability_text, narrow_text, not_kept_text, ordinal,
    resonance_text, trial_line,
};
use crate::diagnose::Diagnosis;
use crate::diagnose::checks::ModelCheck;
use crate::diagnose::evidence::{Kind, Trial};
use crate::rules::Rules;
use crate::signal::analysis::Tone;
use serde_json::{Value, json};
use std::fmt::Write;

/// The residual's part periodic above the harmonics is reported when it holds this share of
/// the residual's power (%).
const ABOVE_SHARE_PCT: f64 = 5.0;
/// The largest harmonics of the residual reported.
const TOP_HARMONICS: usize = 4;

/// Seconds to three decimals, trailing zeros dropped.
fn fmt_s(x: f64) -> String {
    let s = format!("{x:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// A model's JSON: name, held-out RMS (`null` when not stable), fit, stability and why not.
fn model_json(name: String, rms: f64, c: &ModelCheck) -> Value {
    let mut o = json!({
        "model": name,
        "rms_um": if c.unstable.is_none() { json!(rms) } else { json!(null) },
        "fit_pct": c.fit_pct,
        "stable": c.unstable.is_none(),
    });
    if let Some(why) = &c.unstable {
        o["unstable_reason"] = json!(instability_text(why));
    }
    if let Some(why) = &c.narrow {
        o["narrow"] = json!(narrow_text(why));
    }
    o
}

/// A trial as JSON.
fn trial_json(t: &Trial) -> Value {
    let mut o = json!({
        "round": t.round,
        "kind": t.candidate.kind.as_str(),
        "freq_hz": t.candidate.freq_hz,
        "rms_um": t.rms_um,
        "term_rms_um": t.term_rms_um,
        "gain_pct": t.gain_pct,
        "kept": t.kept,
        "reason": t.reason.as_ref().map(not_kept_text),
    });
    if let Some(n) = t.candidate.order {
        o["order"] = json!(n);
    }
    o
}

/// The JSON object of `boucwen diagnose --json` for a sine drive (see the book for every
/// field): `drive_hz`, `window_s`, `window_why`, `drive`, `periods`, `noise_um`, `baseline
/// {model, rms_um, fit_pct, stable}`, `findings`, `extended {…}`, `delay`, `gain_pct`,
/// `not_kept`, the residual decomposition, every term tried (`trials`), `resonance_hz` (null
/// unless the record supports it) with `resonance_note`, and `drive_note`.
pub fn sine_json(d: &Diagnosis, r: &Rules) -> Value {
    let res = &d.residual;
    let not_kept: Vec<Value> = d
        .not_kept()
        .into_iter()
        .map(|t| {
            let mut o = json!({
                "kind": t.candidate.kind.as_str(),
                "freq_hz": t.candidate.freq_hz,
                "round": t.round,
                "gain_pct": t.gain_pct,
                "reason": t.reason.as_ref().map(not_kept_text),
            });
            if let Some(n) = t.candidate.order {
                o["order"] = json!(n);
            }
            o
        })
        .collect();
    json!({
        "drive_hz": d.drive_hz,
        "window_s": d.window_s(),
        "window_why": d.window.why,
        "drive": {
            "kind": d.drive.kind.as_str(),
            "freq_hz": d.drive.freq_hz,
            "thd_pct": 100.0 * d.drive.thd,
            "harmonics_rel": (1..=r.sine.max_term_order as usize).map(|k| d.drive.harmonic_rel(k)).collect::<Vec<_>>(),
        },
        "periods": {"fitted": d.periods.0, "held_out": d.periods.1},
        "noise_um": d.noise_um.0,
        "noise_method": d.noise_um.1,
        "baseline": model_json(d.baseline.name(), d.baseline_rms_um, &d.baseline_check),
        "findings": d.findings.iter().map(finding_json).collect::<Vec<_>>(),
        "extended": model_json(d.model_name(), d.model_rms_um, &d.model_check),
        "delay": d.delay.as_ref().map(|e| json!({
            "samples": e.samples,
            "startup_rms_without_um": e.rms_without_um,
            "startup_rms_with_um": e.rms_with_um,
        })),
        "gain_pct": d.gain_pct(),
        "not_kept": not_kept,
        "residual": {
            "rms_um": res.rms_um,
            "periodic_rms_um": res.periodic_rms_um(),
            "trend_rms_um": res.trend_rms_um,
            "noise_rms_um": res.noise_rms_um,
            "above_harmonics_um": res.above_um,
            "harmonics_um": res.harmonics.iter().map(|h| h.amp).collect::<Vec<_>>(),
        },
        "trials": d.trials.iter().map(trial_json).collect::<Vec<_>>(),
        "resonance_hz": d.resonance_hz(),
        "resonance_note": resonance_text(&d.resonance),
        "drive_note": d.drive_note.as_ref().map(not_kept_text),
        "fit_samples": d.split - d.fit_start(),
        "held_out_samples": d.baseline_sim.len() - d.split,
    })
}

/// The terminal report of a sine diagnosis: the window and the drive, the baseline and what
/// it gets wrong, the findings with their evidence, the terms that gained but were not kept,
/// and the extended model's gain.
pub fn sine_text(d: &Diagnosis, source: &str, r: &Rules) -> String {
    let mut s = String::new();
    header(&mut s, d, source);
    if d.findings.first().is_some_and(|f| f.kind == Kind::OtherInput) {
        let _ = writeln!(s, "\nfinding: {}", finding_text(&d.findings[0]));
        return s;
    }
    residual_lines(&mut s, d);
    findings_lines(&mut s, d, r);
    let not_kept = d.not_kept();
    if !not_kept.is_empty() {
        let _ = writeln!(
            s,
            "\nterms that lowered the held-out RMS by {:.0}% or more but were not kept:",
            100.0 * r.terms.min_gain
        );
        for t in not_kept {
            let _ = writeln!(s, "{}", trial_line(t));
        }
    }
    if let Some(e) = &d.delay {
        let _ = writeln!(
            s,
            "\nthe output answers the step onto the drive {:.1} samples ({:.2} ms) late (the model fitted over the \
             start-up: {:.4} µm without a delay, {:.4} µm with it)",
            e.samples,
            1e3 * e.samples * d.ts,
            e.rms_without_um,
            e.rms_with_um
        );
    }
    let _ = writeln!(
        s,
        "\nextended model: {} (free run): held-out RMS {:.4} µm, {}; {:.4} µm before: {:.1}% lower{}",
        d.model_name(),
        d.model_rms_um,
        check_text(&d.model_check),
        d.baseline_rms_um,
        d.gain_pct(),
        if d.findings.iter().any(|f| f.kept) { "" } else { " (no term kept: the baseline stays)" }
    );
    if let Some(why) = &d.model_check.narrow {
        let _ = writeln!(s, "note: {}", narrow_text(why));
    }
    s
}

/// The window, the periods, the baseline and the resonance.
fn header(s: &mut String, d: &Diagnosis, source: &str) {
    let n = d.baseline_sim.len();
    let [w0, w1] = d.window_s();
    let fitted_s = (d.split - d.fit_start()) as f64 * d.ts;
    let _ = writeln!(s, "{source}: drive {}, sampled every {} s", d.drive.describe(), d.ts);
    let _ = writeln!(s, "window {} to {} s: {}", fmt_s(w0), fmt_s(w1), d.window.why);
    let _ = writeln!(
        s,
        "fitted on {} periods ({} s), tested on the {} periods after them ({} s)",
        d.periods.0,
        fmt_s(fitted_s),
        d.periods.1,
        fmt_s((n - d.split) as f64 * d.ts),
    );
    let _ = writeln!(
        s,
        "output fundamental {:.3} µm, noise floor {:.4} µm{}; baseline {} (free run): held-out RMS {:.4} µm, {}",
        d.output_amplitude_um,
        d.noise_um.0,
        if d.noise_um.1 == "quantisation" { " (the sensor's resolution: its steps' RMS error)" } else { "" },
        d.baseline.name(),
        d.baseline_rms_um,
        check_text(&d.baseline_check),
    );
    let _ = match d.resonance_hz() {
        Some(f) => writeln!(s, "structure resonance {f:.1} Hz ({})", resonance_text(&d.resonance)),
        None => writeln!(s, "{}", resonance_text(&d.resonance)),
    };
}

/// What the baseline gets wrong: the residual's parts and its largest harmonics.
fn residual_lines(s: &mut String, d: &Diagnosis) {
    let r = &d.residual;
    let _ = writeln!(s, "\nwhat the baseline gets wrong (held-out residual, RMS {:.4} µm):", r.rms_um);
    let p = (r.rms_um * r.rms_um).max(1e-300);
    let pct = |x: f64| 100.0 * x * x / p;
    let _ = writeln!(
        s,
        "  periodic with the drive {:.4} µm ({:.0}% of the power), slow trend {:.4} µm ({:.0}%), noise {:.4} µm ({:.0}%)",
        r.periodic_rms_um(),
        pct(r.periodic_rms_um()),
        r.trend_rms_um,
        pct(r.trend_rms_um),
        r.noise_rms_um,
        pct(r.noise_rms_um),
    );
    if pct(r.above_um) >= ABOVE_SHARE_PCT {
        let _ = writeln!(
            s,
            "  periodic above harmonic {} ({:.1} Hz): {:.4} µm ({:.0}% of the power), faster than the harmonics analysed (sharp corners, a converter's steps)",
            r.harmonics.len(),
            r.harmonics.last().map_or(0.0, |h| h.freq_hz),
            r.above_um,
            pct(r.above_um)
        );
    }
    let mut top: Vec<(usize, &Tone)> = r.harmonics.iter().enumerate().collect();
    top.sort_by(|a, b| b.1.amp.total_cmp(&a.1.amp));
    for (i, h) in top.iter().take(TOP_HARMONICS) {
        let _ = writeln!(
            s,
            "  harmonic {:>2} ({:6.1} Hz): {:.4} µm peak, {:4.1}% of the residual power",
            i + 1,
            h.freq_hz,
            h.amp,
            100.0 * h.amp * h.amp / 2.0 / p
        );
    }
}

/// The findings, or why there are none.
fn findings_lines(s: &mut String, d: &Diagnosis, rules: &Rules) {
    let r = &d.residual;
    let tail = if d.not_kept().is_empty() { "" } else { "; the terms below gained but were not kept" };
    if d.findings.is_empty() && r.rms_um > rules.terms.unnamed_noise_multiple * d.noise_um.0 {
        // Not "the model accounts for the record": say what it misses.
        let top = r.harmonics.iter().enumerate().max_by(|a, b| a.1.amp.total_cmp(&b.1.amp));
        let parts = [
            (
                r.above_um,
                format!(
                    "periodic with the drive above its {} harmonic (faster than the model follows: sharp corners, a converter's steps)",
                    ordinal(r.harmonics.len() as u32)
                ),
            ),
            (
                top.map_or(0.0, |(_, h)| h.amp / std::f64::consts::SQRT_2),
                top.map_or(String::new(), |(i, h)| {
                    format!("its {} harmonic at {:.1} Hz", ordinal(i as u32 + 1), h.freq_hz)
                }),
            ),
            (r.trend_rms_um, "a slow trend".to_string()),
            (r.noise_rms_um, "what does not repeat with the drive".to_string()),
        ];
        let (rms, what) = parts.iter().max_by(|a, b| a.0.total_cmp(&b.0)).cloned().unwrap_or_default();
        let _ = writeln!(
            s,
            "\nfindings: none that can be named; the baseline leaves {:.4} µm held out, {:.0} times the noise floor, \
             and no term tried removed it by enough to keep; most of it ({rms:.4} µm RMS) is {what}{tail}",
            r.rms_um,
            r.rms_um / d.noise_um.0.max(1e-300),
        );
    } else if d.findings.is_empty() {
        let _ = writeln!(
            s,
            "\nfindings: none; no term was kept (residual noise {:.4} µm of {:.4} µm){tail}",
            r.noise_rms_um, r.rms_um,
        );
    } else {
        let _ = writeln!(s, "\nfindings (most important first):");
        for (i, f) in d.findings.iter().enumerate() {
            let _ = writeln!(s, "  {}. {}", i + 1, finding_text(f));
        }
    }
}

//! A periodic or multisine diagnosis as text and JSON.

use super::{check_text, finding_json, finding_text, term_trial_line};
use crate::diagnose::periodic::terms::term_name;
use crate::diagnose::periodic::{HeldOut, ModelStep, PeriodicDiagnosis};
use crate::rules::Rules;
use crate::signal::distortion::Level;
use serde_json::{Value, json};
use std::fmt::Write;

/// A level as the JSON of the data's lines.
fn lines_json(l: &Level) -> Value {
    json!({"level_db": l.db, "lines": l.lines, "rms_um": l.rms_um, "band_hz": l.band_hz})
}

/// `10·log10(var/|G|²)`: a variance relative to the BLA's gain (dB).
fn rel_db(var: f64, g: f64) -> f64 {
    10.0 * (var / (g * g).max(1e-300)).max(1e-30).log10()
}

/// A model step as JSON.
fn model_json(s: &ModelStep) -> Value {
    json!({
        "label": s.label,
        "model": s.model.name(),
        "rms_um": if s.check.unstable.is_none() { json!(s.rms_um) } else { json!(null) },
        "fit_pct": s.check.fit_pct,
        "stable": s.check.unstable.is_none(),
        "odd_db": s.odd.db,
        "even_db": s.even.db,
    })
}

/// The JSON object of `boucwen diagnose --json` for a periodic or multisine drive:
/// `drive`, `realisations`, `windows_s`, `periods`, `held_out` (`realisations` or
/// `periods`), `noise_um`, `output_rms_um`, `lines {odd, even}` (the data's levels, `null`
/// where the drive leaves no such lines), `bla [{freq_hz, gain_um_per_v, phase_deg,
/// noise_db, distortion_db}]` (relative to `|G|`), `models` (linear, symmetric loop,
/// extended, then with each kept term), `baseline`, `findings` (as for a sine), `extended`,
/// `gain_pct` and `trials`.
pub fn periodic_json(d: &PeriodicDiagnosis) -> Value {
    json!({
        "drive": {
            "kind": d.drive.kind.as_str(),
            "period_s": 1.0 / d.drive.freq_hz,
            "line_spacing_hz": d.drive.freq_hz,
            "excited_lines": d.lines[0].lines.iter().filter(|l| l.excited).count(),
            "odd_lines_only": d.odd_drive,
        },
        "realisations": d.windows.len(),
        "windows_s": d.windows.iter().map(|(w, t0)| w.seconds(*t0, d.ts)).collect::<Vec<_>>(),
        "periods": d.periods,
        "held_out": match d.held_out { HeldOut::Realisations => "realisations", HeldOut::Periods => "periods" },
        "noise_um": d.noise_um,
        "noise_method": d.noise_method,
        "output_rms_um": d.output_rms_um,
        "lines": {"odd": d.odd.as_ref().map(lines_json), "even": d.even.as_ref().map(lines_json)},
        "bla": d.bla.iter().map(|b| json!({
            "freq_hz": b.freq_hz,
            "gain_um_per_v": b.g.norm(),
            "phase_deg": b.g.arg().to_degrees(),
            "noise_db": rel_db(b.noise_var, b.g.norm()),
            "distortion_db": rel_db(b.distortion_var, b.g.norm()),
        })).collect::<Vec<_>>(),
        "models": d.steps().map(model_json).collect::<Vec<_>>(),
        "baseline": model_json(d.baseline()),
        "findings": d.findings.iter().map(finding_json).collect::<Vec<_>>(),
        "extended": model_json(d.model()),
        "gain_pct": d.gain_pct(),
        "placement": d.placement.as_ref().map(|p| json!({
            "kept": p.kept,
            "family": "oscillator",
            "evidence": crate::report::diagnosis::evidence_json(&crate::diagnose::evidence::Evidence::RestoringForce(p.evidence)),
        })),
        "trials": d.trials.iter().map(|t| json!({
            "round": t.round,
            "term": term_name(t.parity),
            "parity": t.parity.as_str(),
            "rms_um": t.rms_um,
            "term_rms_um": t.term_rms_um,
            "gain_pct": t.gain_pct,
            "kept": t.kept,
            "reason": t.reason.as_ref().map(super::not_kept_text),
        })).collect::<Vec<_>>(),
    })
}

/// " from 10.0 to 40.0 Hz".
fn band_text(b: Option<[f64; 2]>) -> String {
    b.map_or(String::new(), |b| format!(" from {:.1} to {:.1} Hz", b[0], b[1]))
}

/// The terminal report of a periodic diagnosis: the drive and the windows, the data's
/// distortion, the BLA, the models and what each leaves, the findings and the gain.
pub fn periodic_text(d: &PeriodicDiagnosis, source: &str, r: &Rules) -> String {
    let mut s = String::new();
    header(&mut s, d, source);
    data_lines(&mut s, d);
    models_lines(&mut s, d);
    findings_lines(&mut s, d, r);
    let not_kept: Vec<_> = d.trials.iter().filter(|t| t.reason.is_some()).collect();
    if !not_kept.is_empty() {
        let _ = writeln!(s, "\nterms that lowered the held-out RMS by enough but were not kept:");
        for t in not_kept {
            let _ = writeln!(s, "{}", term_trial_line(t));
        }
    }
    let (b, m) = (d.baseline(), d.model());
    if let Some(p) = &d.placement {
        let e = &p.evidence;
        let _ = writeln!(
            s,
            "\nwhere the hysteresis sits: the Bouc–Wen oscillator (in the restoring force) {:.4} µm held out, the extended \
             model (at the drive) {:.4} µm: {:.1}% lower, {:.1} times the noise floor ({}: the rules ask {:.0}% and at most {:.1} times)",
            e.restoring_um,
            e.at_drive_um,
            100.0 * e.gain(),
            e.noise_ratio(),
            if p.kept { "kept" } else { "not kept" },
            100.0 * e.min_gain,
            e.max_noise_ratio
        );
    }
    match d.placement.as_ref().filter(|p| p.kept) {
        Some(p) => {
            let _ = writeln!(
                s,
                "\nmodel: oscillator (free run): held-out RMS {:.4} µm; {:.4} µm before (the extended model): {:.1}% lower",
                p.evidence.restoring_um,
                b.rms_um,
                d.gain_pct()
            );
        }
        None => {
            let _ = writeln!(
                s,
                "\nextended model: {} (free run): held-out RMS {:.4} µm; {:.4} µm before: {:.1}% lower",
                m.model.name(),
                m.rms_um,
                b.rms_um,
                d.gain_pct()
            );
        }
    }
    s
}

/// The drive, the windows, how the models are tested, the output and its noise.
fn header(s: &mut String, d: &PeriodicDiagnosis, source: &str) {
    let _ = writeln!(s, "{source}: drive {}, sampled every {} s", d.drive.describe(), d.ts);
    for (i, ((w, t0), m)) in d.windows.iter().zip(&d.periods).enumerate() {
        let [a, b] = w.seconds(*t0, d.ts);
        let which = if d.windows.len() > 1 { format!("realisation {}: ", i + 1) } else { String::new() };
        let _ = writeln!(s, "{which}window {a:.3} to {b:.3} s, {m} whole periods: {}", w.why);
    }
    let realisations = d.held_out == HeldOut::Realisations;
    let _ = writeln!(
        s,
        "models fitted on {}, tested in free run on {}",
        if realisations { "the first realisation" } else { "the first half of the periods" },
        if realisations {
            "the other realisations (new phases)"
        } else {
            "the later periods (the same phases: this tests the fit against noise, not against a new realisation)"
        }
    );
    let _ = writeln!(
        s,
        "output {:.3} µm RMS, noise floor {:.4} µm ({})",
        d.output_rms_um,
        d.noise_um,
        if d.noise_method == "quantisation" {
            "the sensor's resolution: its steps' RMS error"
        } else {
            "from period to period"
        }
    );
}

/// The data's levels at the lines and the BLA.
fn data_lines(s: &mut String, d: &PeriodicDiagnosis) {
    let lv = |l: &Option<Level>, what: &str| match l {
        Some(l) => format!(
            "{what}: {:.1} dB above the noise over {} lines ({:.4} µm){}{}",
            l.db,
            l.lines,
            l.rms_um,
            band_text(l.band_hz),
            if l.detected { "" } else { ": noise" }
        ),
        None => format!("{what}: none free of the drive"),
    };
    if d.odd_drive {
        let _ = writeln!(s, "\nthe output at the lines the drive does not excite:");
        let _ = writeln!(s, "  {}", lv(&d.odd, "odd lines left out (odd distortion)"));
        let _ = writeln!(s, "  {}", lv(&d.even, "even lines (even distortion)"));
    } else {
        let _ = writeln!(
            s,
            "\nthe drive excites odd and even lines: odd and even distortion cannot be told apart at the lines"
        );
    }
    if d.bla.is_empty() {
        return;
    }
    let med = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let noise = med(d.bla.iter().map(|b| rel_db(b.noise_var, b.g.norm())).collect());
    let dist = med(d.bla.iter().map(|b| rel_db(b.distortion_var, b.g.norm())).collect());
    let (lo, hi) = (d.bla[0].freq_hz, d.bla[d.bla.len() - 1].freq_hz);
    let _ = writeln!(
        s,
        "best linear approximation over {} excited lines ({lo:.2} to {hi:.2} Hz, |G| {:.2} to {:.2} µm/V): noise \
         {noise:.1} dB, nonlinear distortion {dist:.1} dB relative to |G| (median; distortion from {})",
        d.bla.len(),
        d.bla.iter().map(|b| b.g.norm()).fold(f64::INFINITY, f64::min),
        d.bla.iter().map(|b| b.g.norm()).fold(0.0, f64::max),
        if d.windows.len() > 1 { "the spread over realisations" } else { "the non-excited lines nearby" }
    );
}

/// The models, what each leaves at the lines, and what the hysteresis accounts for.
fn models_lines(s: &mut String, d: &PeriodicDiagnosis) {
    let _ = writeln!(
        s,
        "\nmodels (held-out RMS; held-out residual at the odd and even lines, dB above the noise):"
    );
    for st in d.steps() {
        let label = format!("{} ({})", st.label, st.model.name());
        let _ = if st.usable() {
            writeln!(
                s,
                "  {label:<48} {:.4} µm, {}; odd {:.1} dB, even {:.1} dB",
                st.rms_um,
                check_text(&st.check),
                st.odd.db,
                st.even.db
            )
        } else {
            writeln!(s, "  {label:<48} {}", check_text(&st.check))
        };
    }
    let (lin, sym, ext) = (&d.compared[0], &d.compared[1], &d.compared[2]);
    let pct = |a: f64, b: f64| 100.0 * (1.0 - b / a.max(1e-300));
    let _ = match (lin.usable(), sym.usable(), ext.usable()) {
        (true, true, true) => writeln!(
            s,
            "the hysteresis loop lowers the linear model's held-out RMS by {:.0} % (odd lines {:.1} -> {:.1} dB), its \
             asymmetric term by {:.0} % more (even lines {:.1} -> {:.1} dB)",
            pct(lin.rms_um, sym.rms_um),
            lin.odd.db,
            sym.odd.db,
            pct(sym.rms_um, ext.rms_um),
            sym.even.db,
            ext.even.db
        ),
        (true, false, true) => writeln!(
            s,
            "the symmetric loop's free run is not stable; the extended model lowers the linear model's held-out RMS by \
             {:.0} % (odd lines {:.1} -> {:.1} dB, even lines {:.1} -> {:.1} dB)",
            pct(lin.rms_um, ext.rms_um),
            lin.odd.db,
            ext.odd.db,
            lin.even.db,
            ext.even.db
        ),
        _ => writeln!(
            s,
            "not every one of these models runs stably on the held-out data: they are not compared"
        ),
    };
}

/// The findings, or why there are none. Distortion the model leaves at lines where the data
/// hold it but no finding names (under `terms.unexplained_share` of the distortion power, or
/// `terms.min_term_rel` of the output) is said as such, the same way whatever else the
/// record holds.
fn findings_lines(s: &mut String, d: &PeriodicDiagnosis, r: &Rules) {
    let base = d.baseline();
    if !d.findings.is_empty() {
        let _ = writeln!(s, "\nfindings (most important first):");
        for (i, f) in d.findings.iter().enumerate() {
            let _ = writeln!(s, "  {}. {}", i + 1, finding_text(f));
        }
        return;
    }
    let m = d.model();
    let left: Vec<String> = [("odd", m.odd), ("even", m.even)]
        .iter()
        .filter(|(_, l)| l.detected)
        .map(|(p, l)| format!("the {p} lines {:.1} dB above their noise ({:.4} µm)", l.db, l.rms_um))
        .collect();
    let leaves = if left.is_empty() {
        String::new()
    } else {
        format!(
            "; the model leaves {} in its held-out residual, distortion too small beside the rest to name as a finding",
            left.join(" and ")
        )
    };
    let _ = if base.rms_um > r.periodic.noise_multiple * d.noise_um {
        writeln!(
            s,
            "\nfindings: none that can be named; the {} model leaves {:.4} µm held out, {:.0} times the noise floor, and \
             no term tried (a cubic stiffening, a quadratic stiffness) lowered it by enough to keep: what it misses is \
             not one of these{leaves}",
            base.label,
            base.rms_um,
            base.rms_um / d.noise_um.max(1e-300)
        )
    } else {
        writeln!(
            s,
            "\nfindings: none; the extended model accounts for the distortion the record shows (no term lowered its \
             held-out RMS by enough to keep){leaves}"
        )
    };
}

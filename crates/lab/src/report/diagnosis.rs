//! A diagnosis as text and JSON: every sentence of `boucwen diagnose` is written here, from
//! the typed findings and evidence of [`crate::diagnose`].

use crate::diagnose::evidence::{
    DelayEvidence, DistortionEvidence, Evidence, Finding, HarmonicEvidence, Instability, Kind, Lines, Narrow,
    NotKept, ResidualReading, Resonance, Step, Term, Trial,
};
use crate::diagnose::periodic::TermTrial;
use crate::diagnose::periodic::terms::term_name;
use crate::signal::distortion::{Level, Parity};
use serde_json::{Value, json};
use std::fmt::Write;

/// "1st", "2nd", "3rd", "11th", …
pub fn ordinal(n: u32) -> String {
    let suffix = match (n % 10, n % 100) {
        (1, r) if r != 11 => "st",
        (2, r) if r != 12 => "nd",
        (3, r) if r != 13 => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

/// Seconds to three decimals, trailing zeros dropped.
fn fmt_s(x: f64) -> String {
    let s = format!("{x:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// "3rd harmonic branch", "drift line", "clamp of the drive".
pub fn term_text(t: Term) -> String {
    match t {
        Term::Drift => "drift line".into(),
        Term::OutputClamp => "clamp of the output".into(),
        Term::DriveClamp => "clamp of the drive".into(),
        Term::Creep => "creep states".into(),
        Term::Branch(n) => format!("{} harmonic branch", ordinal(n)),
        Term::Stiffening(p) => term_name(p).into(),
    }
}

/// "a 3rd harmonic branch added to the baseline lowers the held-out RMS from … (60%)".
fn step_text(s: &Step, term: &str) -> String {
    let to = if s.first { "the baseline" } else { "the model with the terms above" };
    format!(
        "{term} added to {to} lowers the held-out RMS from {:.4} to {:.4} µm ({:.0}%)",
        s.before_um,
        s.after_um,
        s.gain_pct()
    )
}

/// Why a model's free run is not stable, in words.
pub fn instability_text(i: &Instability) -> String {
    match *i {
        Instability::Pole { modulus, ar: [a1, a2] } => format!(
            "the structure has a pole of modulus {modulus:.6} (a1 = {a1:.6}, a2 = {a2:.6}; stable needs every pole \
             inside the unit circle)"
        ),
        Instability::LeavesRange { limit_um, after_s } => {
            let when = if after_s == 0.0 {
                "from its first sample".to_string()
            } else {
                format!("{} s after its first sample", fmt_s(after_s))
            };
            format!(
                "its free run leaves the physical range (±{limit_um} µm) {when} over the held-out part: it diverges"
            )
        }
        Instability::RunsAway { spans, range_um: [lo, hi], after_s } => format!(
            "its free run leaves {spans} times the output's span beyond its range ([{lo:.3}, {hi:.3}] µm) {} s after \
             the held-out part's first sample: it runs away from the record",
            fmt_s(after_s)
        ),
    }
}

/// Why a model may hold its record's amplitude only, in words.
pub fn narrow_text(n: &Narrow) -> String {
    let scales = |v: &[f64]| v.iter().map(|k| format!("{k}×")).collect::<Vec<_>>().join(" and ");
    let shape = format!(
        "its loop is outside the Bouc–Wen model's bounded class (γ + β = {:.4} ≤ 0: the hysteresis state grows \
         exponentially along one branch)",
        n.gamma_plus_beta
    );
    if n.diverges_at.is_empty() {
        format!(
            "{shape}; its free run at {} this drive stays in range, but a larger swing makes it grow exponentially: \
             check it at the amplitudes it is to be used at before compensating with it",
            scales(&n.scales)
        )
    } else {
        format!(
            "the model holds near this record's amplitude only: its free run at {} this drive diverges{}; measure at \
             the amplitudes it is to be used at before compensating with it",
            scales(&n.diverges_at),
            if n.unbounded { format!(", and {shape}") } else { String::new() }
        )
    }
}

/// What the record says of the structure's resonance, in words.
pub fn resonance_text(r: &Resonance) -> String {
    match *r {
        Resonance::NoneFitted => "the fitted structure has no resonance (its poles are real)".into(),
        Resonance::NotAssessed => {
            "the structure's resonance is not reported: the model explains too little of the output".into()
        }
        Resonance::Excited { order, freq_hz } => {
            let what = if order == 1 {
                "the drive".to_string()
            } else {
                format!("the output's {} harmonic", ordinal(order))
            };
            format!("excited: {what} at {freq_hz:.1} Hz lies near it")
        }
        Resonance::InResidual { freq_hz } => {
            format!("shown in the residual: its harmonic at {freq_hz:.1} Hz lies near it")
        }
        Resonance::NotIdentifiable { fitted_hz, drive_hz, top_hz } => format!(
            "the structure's resonance is not identifiable from this record: the fit puts one at {fitted_hz:.0} Hz, but \
             nothing the record excites lies near it (the drive at {drive_hz:.1} Hz and output harmonics up to \
             {top_hz:.1} Hz)"
        ),
    }
}

/// Why a term that gained enough was not kept, in words.
pub fn not_kept_text(n: &NotKept) -> String {
    match n {
        NotKept::DriveHarmonic { order, drive_rel, share, gain_pct, floor } => {
            let o = ordinal(*order);
            format!(
                "the drive itself carries {:.2}% at the {o} harmonic, which accounts (through the baseline) for {:.0}% \
                 of the output's {o} harmonic: a {o} harmonic branch would lower the held-out RMS by {gain_pct:.0}%, but \
                 this record cannot tell a harmonic of the actuator from its response to the drive's own (a purer drive \
                 would: one under {:.1}% at the {o} harmonic, where the diagnosis leaves the drive's harmonics out)",
                100.0 * drive_rel,
                100.0 * share,
                100.0 * floor,
            )
        }
        NotKept::CarriesTooLittle { carried_um, need_um, min_term_rel, noise_factor, removed } => {
            match removed {
                Some((removed_um, multiple, noise_um)) => format!(
                    "its term carries only {carried_um:.4} µm in the model, less than the {need_um:.4} µm a term must carry \
                 ({:.0} % of the output's RMS), and removes {removed_um:.4} µm from the held-out residual, less than \
                 {multiple} times its noise ({noise_um:.4} µm)",
                    100.0 * min_term_rel
                ),
                None => format!(
                    "its term carries only {carried_um:.4} µm in the model, less than the {need_um:.4} µm a term must carry \
                 ({:.0} % of the output's fundamental RMS{})",
                    100.0 * min_term_rel,
                    noise_factor.map_or(String::new(), |k| format!(", or {k} times the residual's noise"))
                ),
            }
        }
        NotKept::LowerRms { winner, winner_um, this_um, round } => format!(
            "the {} lowered the held-out RMS further ({winner_um:.4} µm against {this_um:.4} µm) and was kept in round \
             {round}",
            term_text(*winner)
        ),
        NotKept::MoreEvidence { winner, winner_evidence, this_evidence, db: true, round } => format!(
            "the {} stands for more evidence ({winner_evidence:.1} dB against {this_evidence:.1} dB) and was kept in \
             round {round}",
            term_text(*winner)
        ),
        NotKept::MoreEvidence { winner, winner_evidence, this_evidence, db: false, round } => format!(
            "the {} had more evidence in the record ({winner_evidence:.4} µm against {this_evidence:.4} µm) and was \
             kept in round {round}",
            term_text(*winner)
        ),
    }
}

/// A harmonic branch's cause in words.
fn harmonic_text(kind: Kind, e: &HarmonicEvidence) -> String {
    let (n, f) = (e.order, e.freq_hz);
    let o = ordinal(n);
    let mut s = format!(
        "the output's {o} harmonic at {f:.1} Hz is {:.3} µm ({:.1}% of the fundamental); {}",
        e.output_um,
        100.0 * e.output_rel,
        step_text(&e.step, &format!("a {o} harmonic branch"))
    );
    let share = 100.0 * e.residual_share;
    match e.reading {
        ResidualReading::Holds => {
            let _ = write!(s, " (in the baseline's residual the harmonic holds {share:.0}% of the power)");
        }
        ResidualReading::Imitated => {
            let _ = write!(
                s,
                " (the baseline imitates the harmonic, {:.3} µm left, {share:.0}% of its residual power, by bending its \
                 structure, and pays at other harmonics)",
                e.residual_um
            );
        }
        ResidualReading::Plain => {}
    }
    if let Some(d) = e.drive {
        let _ = write!(
            s,
            "; the drive itself carries {:.2}% at this harmonic, which accounts for {:.3} µm of it through the model",
            100.0 * d.rel,
            d.part_um
        );
    }
    let confirm = |r: f64, needs: bool| {
        if needs {
            format!(
                " (the model with the branch leaves it elsewhere; one sine places a resonance only through the \
                 harmonics it makes: a multisine or a sweep through {r:.0} Hz tells whether it is there)"
            )
        } else {
            String::new()
        }
    };
    if kind == Kind::EvenHarmonic {
        let mut t = format!(
            "even harmonic: {s}; an even harmonic needs an asymmetry the model's loop lacks (an asymmetric stiffness, an \
             off-centre operating point)"
        );
        if let Some(r) = e.resonance {
            let _ = write!(
                t,
                ", amplified by the resonance near {:.0} Hz{}",
                r.hz,
                confirm(r.hz, r.needs_confirming)
            );
        }
        return t;
    }
    match e.resonance {
        Some(r) => format!(
            "odd harmonic oscillation: {s}; the fitted structure has a resonance near {:.0} Hz{}, which amplifies the {o} \
             harmonic of a nonlinearity the Bouc–Wen loop does not hold (e.g. a stiffening of the actuator or its \
             mechanism)",
            r.hz,
            confirm(r.hz, r.needs_confirming)
        ),
        None => format!("odd harmonic oscillation: {s}; a nonlinearity beyond the Bouc–Wen loop"),
    }
}

/// An input delay's cause in words.
fn delay_text(e: &DelayEvidence) -> String {
    let gain = 100.0 * (1.0 - e.startup_with_um / e.startup_without_um.max(1e-300));
    let before = e.held_out_before_um;
    let held = match e.held_out_after_um {
        Some(a) => format!("the extended model carries it: held-out RMS {a:.4} µm ({before:.4} µm without)"),
        None => format!(
            "it is not added to the extended model: with it the held-out RMS would rise above {:.0} % of its \
             {before:.4} µm",
            100.0 * e.held_out_slack
        ),
    };
    format!(
        "input delay: the output answers the step onto the drive {:.1} samples ({:.2} ms) after the drive, beyond the \
         {:.0} samples a sampled actuator's hold and driver explain; a single sine cannot tell a delay from the \
         structure's phase (the model absorbs it by moving its resonance), but the step excites every frequency: \
         fitted over the start-up and the first {:.1} s with the delay, the model's RMS error there falls from {:.4} \
         to {:.4} µm ({gain:.0}%); {held}",
        e.samples,
        1e3 * e.samples * e.ts,
        e.min_samples,
        e.window_s,
        e.startup_without_um,
        e.startup_with_um,
    )
}

/// " from 10.0 to 40.0 Hz".
fn band_text(b: Option<[f64; 2]>) -> String {
    b.map_or(String::new(), |b| format!(" from {:.1} to {:.1} Hz", b[0], b[1]))
}

/// A stiffening's cause in words.
fn distortion_text(e: &DistortionEvidence) -> String {
    let (what, lines) = match e.lines {
        Lines::OddLeftOut => ("odd", "odd lines the drive leaves out"),
        Lines::Odd => ("odd", "odd lines"),
        Lines::Even => ("even", "even lines"),
    };
    let evidence = match e.data {
        Some(d) => format!(
            "the output's {lines} stand {:.1} dB above their noise{} ({:.3} µm)",
            d.db,
            band_text(d.band_hz),
            d.rms_um
        ),
        None => format!(
            "the drive excites every odd line (a {} drive's own harmonics), so odd distortion falls on excited lines and \
             shows only against a model: the term accounts for {:.3} µm there, {:.1} dB above their noise{}",
            e.drive.as_str(),
            e.contribution.rms_um,
            e.contribution.db,
            band_text(e.contribution.band_hz)
        ),
    };
    let term = match (e.parity, e.stiffening) {
        (Parity::Odd, Some((_, c, q))) => format!(
            "a cubic stiffening of the structure ({} by {:.1} % of the linear stiffness at {q:.2} µm)",
            if c >= 0.0 { "hardening" } else { "softening" },
            100.0 * c.abs()
        ),
        (Parity::Even, Some((_, c, q))) => format!(
            "a quadratic stiffness ({:.1} % of the linear stiffness at {q:.2} µm, {} on the positive side)",
            100.0 * c.abs(),
            if c >= 0.0 { "stiffer" } else { "softer" }
        ),
        (p, None) => term_name(p).to_string(),
    };
    let meaning = match e.parity {
        Parity::Odd => {
            "a symmetric stiffening of the actuator or its mechanism that the hysteresis loop does not hold"
        }
        Parity::Even => {
            "an asymmetry beyond the loop's own (an asymmetric stiffness: layers or a clamp that differ, an off-centre \
             operating point)"
        }
    };
    let (label, base) = (&e.baseline.0, e.baseline.1);
    format!(
        "{what} nonlinear distortion: {evidence}; the baseline ({label}) leaves {:.1} dB there in its held-out residual \
         ({:.3} µm); {term} lowers the held-out RMS from {:.4} to {:.4} µm ({:.0}%) and leaves {:.1} dB: {meaning}",
        base.db,
        base.rms_um,
        e.step.before_um,
        e.step.after_um,
        e.step.gain_pct(),
        e.after.db
    )
}

/// A finding's cause in words, with its evidence.
pub fn finding_text(f: &Finding) -> String {
    match &f.evidence {
        Evidence::Harmonic(e) => harmonic_text(f.kind, e),
        Evidence::Drift(e) => format!(
            "drift: a slow trend not locked to the drive holds {:.0}% of the baseline's residual power ({:.3} µm RMS, \
             mean {:.3} µm, slope {:.4} µm/s); {}",
            100.0 * e.share,
            e.rms_um,
            e.mean_um,
            e.slope_um_per_s,
            step_text(&e.step, "a drift line")
        ),
        Evidence::OtherInput { fit_pct, min_fit_pct } => format!(
            "another input or a disturbance drives the output: the baseline explains only {fit_pct:.1} % of the \
             held-out output (fit), less than {min_fit_pct:.0} %; a second actuator or signal, vibration, or a thermal \
             or sensor effect the record does not carry. No harmonic diagnosis is made on top of it"
        ),
        Evidence::OutputSaturation(e) => {
            let sides: Vec<String> = [(e.top_um, "above"), (e.bottom_um, "below")]
                .iter()
                .filter_map(|(v, side)| v.map(|v| format!("{v:.3} µm (nothing {side} it)")))
                .collect();
            let advice = e.within_range.map_or(String::new(), |w| {
                format!(
                    "; the rest of this diagnosis rests on the {:.0} % of the samples inside the range: a record driven \
                     with at most {:.3} V of amplitude ({:.0} % of this drive) keeps the model's output inside it and \
                     shows the whole loop",
                    100.0 * (1.0 - e.share),
                    w.amplitude_v,
                    100.0 * w.scale
                )
            });
            format!(
                "saturation of the output: it sits flat at {} in {:.0} % of the samples, a sensor's range or a \
                 mechanical stop; the model should not be fitted across it: with the output clamped there the samples \
                 beyond it no longer pull the fit; {}{advice}",
                sides.join(" and "),
                100.0 * e.share,
                step_text(&e.step, "clamp of the output")
            )
        }
        Evidence::DriveSaturation(e) => {
            let step = step_text(&e.step, "clamp of the drive");
            let [lo, hi] = e.levels_v;
            if lo.is_nan() || hi.is_nan() {
                return format!("saturation: {step}");
            }
            let series: Vec<String> =
                e.series.iter().map(|(n, rel)| format!("{} {:.1} %", ordinal(*n), 100.0 * rel)).collect();
            format!(
                "saturation of the drive: the actuator stops following it beyond {lo:.3} V and {hi:.3} V of u (an \
                 amplifier's rails; the level at which the model's drive, clamped, fits best), which puts a series of \
                 odd harmonics in the output ({}); the model should not be fitted across it: with the drive clamped \
                 there, {step}",
                series.join(", ")
            )
        }
        Evidence::Creep(e) => {
            let states: Vec<String> = e
                .relaxations
                .iter()
                .map(|c| {
                    format!("{:.2} s ({:.1} % of the deflection the drive asks for)", c.tau_s, 100.0 * c.gain)
                })
                .collect();
            format!(
                "creep: the output relaxes slowly after the drive, with time constants {}; the baseline's residual \
                 holds a slow part of {:.3} µm RMS (mean {:.3} µm, slope {:.4} µm/s) that follows the drive's history \
                 rather than a straight line; {}",
                if states.is_empty() { "none left after the fit".to_string() } else { states.join(" and ") },
                e.trend.rms_um,
                e.trend.mean_um,
                e.trend.slope_um_per_s,
                step_text(&e.trend.step, "creep states")
            )
        }
        Evidence::InputDelay(e) => delay_text(e),
        Evidence::Distortion(e) => distortion_text(e),
        Evidence::RestoringForce(e) => format!(
            "hysteresis in the restoring force: the Bouc–Wen oscillator (m·y'' + c·y' + k·y + z = u, the loop z inside \
             the structure) leaves {:.4} µm held out where the extended model with its terms (hysteresis at the drive) leaves {:.4} µm: \
             {:.1}% lower (at least {:.0}% asked), {:.2} times the noise floor of {:.4} µm (at most {:.1} asked); m = {:.5}, c = {:.5}, k = {:.6e}, alpha = {:.6e}, beta*gamma = {:.5}, \
             beta*delta = {:.5}; `identify --model oscillator` fits it and `--save` keeps it",
            e.restoring_um,
            e.at_drive_um,
            100.0 * e.gain(),
            100.0 * e.min_gain,
            e.noise_ratio(),
            e.noise_um,
            e.max_noise_ratio,
            e.params.m,
            e.params.c,
            e.params.k,
            e.params.alpha,
            e.params.beta_gamma,
            e.params.beta_delta
        ),
        Evidence::UnexplainedHarmonic { amp_um, share } => format!(
            "unexplained {} harmonic at {:.1} Hz: {amp_um:.3} µm, {:.0}% of the extended model's residual power; no \
             term removed it by enough to keep",
            ordinal(f.order.unwrap_or(0)),
            f.freq_hz,
            100.0 * share
        ),
        Evidence::UnexplainedTrend { rms_um, slope_um_per_s, share } => format!(
            "unexplained slow trend: {rms_um:.3} µm RMS (slope {slope_um_per_s:.4} µm/s), {:.0}% of the extended \
             model's residual power; a drift line did not remove it by enough to keep",
            100.0 * share
        ),
        Evidence::UnexplainedDistortion { parity, level, share, on_drive_lines } => format!(
            "unexplained {p} distortion: the model's held-out residual holds {:.3} µm at the {p} lines ({:.0} % of its \
             power at the distortion lines of both parities, {:.1} dB above their noise{}){}; no term removed it by \
             enough to keep",
            level.rms_um,
            100.0 * share,
            level.db,
            level.band_hz.map_or(String::new(), |b| format!(", {:.1} to {:.1} Hz", b[0], b[1])),
            if *on_drive_lines {
                "; they are lines the drive excites itself, so this is what the model gets wrong of its response to them"
            } else {
                ""
            },
            p = parity.as_str(),
        ),
    }
}

/// A level as JSON.
fn level_json(l: &Level) -> Value {
    json!({"level_db": l.db, "lines": l.lines, "rms_um": l.rms_um, "band_hz": l.band_hz, "detected": l.detected})
}

/// A step as JSON.
fn step_json(s: &Step) -> Value {
    json!({"before_um": s.before_um, "after_um": s.after_um, "first": s.first, "gain_pct": s.gain_pct()})
}

/// The typed evidence as JSON: `{"type": …, …}` with every fact the sentence rests on.
pub fn evidence_json(e: &Evidence) -> Value {
    match e {
        Evidence::Harmonic(h) => json!({
            "type": "harmonic",
            "order": h.order,
            "freq_hz": h.freq_hz,
            "output_um": h.output_um,
            "output_rel": h.output_rel,
            "residual_um": h.residual_um,
            "residual_share": h.residual_share,
            "residual_reading": match h.reading {
                ResidualReading::Holds => "holds",
                ResidualReading::Imitated => "imitated",
                ResidualReading::Plain => "plain",
            },
            "step": step_json(&h.step),
            "drive_harmonic": h.drive.map(|d| json!({"rel": d.rel, "part_um": d.part_um})),
            "resonance": h.resonance.map(|r| json!({"hz": r.hz, "needs_confirming": r.needs_confirming})),
        }),
        Evidence::Drift(t) => json!({
            "type": "drift",
            "share": t.share, "rms_um": t.rms_um, "mean_um": t.mean_um, "slope_um_per_s": t.slope_um_per_s,
            "step": step_json(&t.step),
        }),
        Evidence::OtherInput { fit_pct, min_fit_pct } => {
            json!({"type": "other_input", "fit_pct": fit_pct, "min_fit_pct": min_fit_pct})
        }
        Evidence::OutputSaturation(o) => json!({
            "type": "output_saturation",
            "top_um": o.top_um, "bottom_um": o.bottom_um, "share": o.share, "step": step_json(&o.step),
            "within_range": o.within_range.map(|w| json!({"scale": w.scale, "amplitude_v": w.amplitude_v})),
        }),
        Evidence::DriveSaturation(d) => json!({
            "type": "drive_saturation",
            "levels_v": d.levels_v,
            "series": d.series.iter().map(|(n, r)| json!({"order": n, "rel": r})).collect::<Vec<_>>(),
            "step": step_json(&d.step),
        }),
        Evidence::Creep(c) => json!({
            "type": "creep",
            "relaxations": c.relaxations.iter().map(|r| json!({"tau_s": r.tau_s, "gain": r.gain})).collect::<Vec<_>>(),
            "trend_rms_um": c.trend.rms_um, "trend_mean_um": c.trend.mean_um,
            "trend_slope_um_per_s": c.trend.slope_um_per_s, "step": step_json(&c.trend.step),
        }),
        Evidence::InputDelay(d) => json!({
            "type": "input_delay",
            "samples": d.samples, "ms": 1e3 * d.samples * d.ts, "window_s": d.window_s,
            "startup_without_um": d.startup_without_um, "startup_with_um": d.startup_with_um,
            "held_out_before_um": d.held_out_before_um, "held_out_after_um": d.held_out_after_um,
        }),
        Evidence::Distortion(d) => json!({
            "type": "distortion",
            "parity": d.parity.as_str(),
            "data": d.data.as_ref().map(level_json),
            "contribution": level_json(&d.contribution),
            "baseline": {"label": d.baseline.0, "level": level_json(&d.baseline.1)},
            "after": level_json(&d.after),
            "step": step_json(&d.step),
            "stiffening": d.stiffening.map(|(p, c, q)| json!({"power": p, "coeff": c, "q_ref_um": q})),
        }),
        Evidence::RestoringForce(e) => json!({
            "type": "restoring_force",
            "at_drive_um": e.at_drive_um, "restoring_um": e.restoring_um, "gain_pct": 100.0 * e.gain(),
            "min_gain_pct": 100.0 * e.min_gain,
            "noise_um": e.noise_um, "noise_ratio": e.noise_ratio(), "max_noise_ratio": e.max_noise_ratio, "params": e.params, "substeps": e.substeps,
        }),
        Evidence::UnexplainedHarmonic { amp_um, share } => {
            json!({"type": "unexplained_harmonic", "amp_um": amp_um, "share": share})
        }
        Evidence::UnexplainedTrend { rms_um, slope_um_per_s, share } => {
            json!({"type": "unexplained_trend", "rms_um": rms_um, "slope_um_per_s": slope_um_per_s, "share": share})
        }
        Evidence::UnexplainedDistortion { parity, level, share, on_drive_lines } => json!({
            "type": "unexplained_distortion",
            "parity": parity.as_str(), "level": level_json(level), "share": share, "on_drive_lines": on_drive_lines,
        }),
    }
}

/// One finding as JSON: `kind`, `order` (harmonics), `freq_hz`, `band_hz` (distortion),
/// `level` and `level_unit` (where one applies), `residual_share`, `cause` (the sentence),
/// `kept`, `term_rms_um`, `drive_within_range_v` (a sensor's range) and `evidence` (the
/// typed facts).
pub fn finding_json(f: &Finding) -> Value {
    let mut o = json!({
        "kind": f.kind.as_str(),
        "freq_hz": f.freq_hz,
        "residual_share": f.residual_share,
        "cause": finding_text(f),
        "kept": f.kept,
        "term_rms_um": f.term_rms_um,
        "evidence": evidence_json(&f.evidence),
    });
    if let Some(n) = f.order {
        o["order"] = json!(n);
    }
    if let Some((v, unit)) = f.level() {
        o["level"] = json!(v);
        o["level_unit"] = json!(unit);
    }
    if let Some(b) = f.band_hz() {
        o["band_hz"] = json!(b);
    }
    if let Some(v) = f.drive_within_range_v() {
        o["drive_within_range_v"] = json!(v);
    }
    o
}

mod outcome;
mod periodic;
mod sine;
mod steps;

pub use outcome::{json, text};
pub use periodic::{periodic_json, periodic_text};
pub use sine::{sine_json, sine_text};
pub use steps::{step_line, steps_sentence};

/// A model's stability and fit, in words ("fit 96.1 %", "not stable: …").
pub fn check_text(c: &crate::diagnose::checks::ModelCheck) -> String {
    match (&c.unstable, c.fit_pct) {
        (Some(why), _) => format!("not stable: {}", instability_text(why)),
        (None, Some(f)) => format!("fit {f:.1} %"),
        (None, None) => "fit not measured".into(),
    }
}

/// A trial's term and reason, for the list of terms not kept.
fn trial_line(t: &Trial) -> String {
    format!(
        "  - {} (round {}): {:.0}% lower, to {:.4} µm; {}",
        term_text(t.candidate.term()),
        t.round,
        t.gain_pct,
        t.rms_um,
        t.reason.as_ref().map(not_kept_text).unwrap_or_default()
    )
}

/// A periodic trial's term and reason.
fn term_trial_line(t: &TermTrial) -> String {
    format!(
        "  - {} (round {}): {:.0}% lower, to {:.4} µm; {}",
        term_name(t.parity),
        t.round,
        t.gain_pct,
        t.rms_um,
        t.reason.as_ref().map(not_kept_text).unwrap_or_default()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ordinals() {
        assert_eq!(ordinal(3), "3rd");
        assert_eq!(ordinal(5), "5th");
        assert_eq!(ordinal(2), "2nd");
        assert_eq!(ordinal(11), "11th");
        assert_eq!(ordinal(21), "21st");
    }
}

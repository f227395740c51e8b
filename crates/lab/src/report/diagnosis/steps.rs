//! A stepped sine's steps as text.

use crate::diagnose::Outcome;
use crate::diagnose::steps::SineStep;

/// Seconds to three decimals, trailing zeros dropped.
fn fmt_s(x: f64) -> String {
    let s = format!("{x:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// One line of what changes across the steps: "  14.000 Hz   1.000 V: baseline 0.2854 µm,
/// extended 0.0149 µm (enhanced(5,3)+offset), findings: odd_harmonic 5, odd_harmonic 3",
/// or the step's sentence.
pub fn step_line(step: &SineStep) -> String {
    let (f, a) = (step.segment.freq_hz, step.segment.amplitude_v);
    let d = match &step.outcome {
        Ok(d) => d,
        Err(e) => return format!("  {f:8.3} Hz {a:7.3} V: {e}"),
    };
    let findings: Vec<String> = d
        .findings()
        .iter()
        .filter(|f| f.kept)
        .map(|f| match f.order {
            Some(n) => format!("{} {n}", f.kind.as_str()),
            None => f.kind.as_str().to_string(),
        })
        .collect();
    let (base, ext, name) = match d {
        Outcome::Sine(d) => (d.baseline_rms_um, d.model_rms_um, d.model_name()),
        Outcome::Periodic(d) => (d.baseline().rms_um, d.model().rms_um, d.model().model.name()),
    };
    format!(
        "  {f:8.3} Hz {a:7.3} V: baseline {base:.4} µm, extended {ext:.4} µm ({name}), findings: {}",
        if findings.is_empty() { "none".to_string() } else { findings.join(", ") }
    )
}

/// The sentence that introduces a stepped sine's diagnoses: "the drive steps through 4
/// sines: 5.000 Hz 1.000 V (0 to 3.75 s), …; each is diagnosed on its own".
pub fn steps_sentence(steps: &[SineStep], ts: f64, t0: f64) -> String {
    let list: Vec<String> = steps
        .iter()
        .map(|s| {
            format!(
                "{:.3} Hz {:.3} V ({} to {} s)",
                s.segment.freq_hz,
                s.segment.amplitude_v,
                fmt_s(t0 + s.segment.start as f64 * ts),
                fmt_s(t0 + s.segment.end as f64 * ts)
            )
        })
        .collect();
    format!(
        "the drive steps through {} sines: {}; each is diagnosed on its own",
        steps.len(),
        list.join(", ")
    )
}

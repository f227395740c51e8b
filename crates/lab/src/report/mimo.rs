//! Text, JSON and figures of the commands on records with several inputs and outputs
//! ([`crate::mimo`]): the record read, the BLA diagnosis per level and output, the fit and
//! its score kept apart, a model compared on another record.

use crate::mimo::bla::LevelDiagnosis;
use crate::mimo::fit::{MimoFit, OrderScore};
use crate::mimo::model::MimoModel;
use crate::record::mimo::MimoRecord;
use crate::report::plot::{Chart, Series};
use serde_json::{Value, json};
use std::fmt::Write;

/// One line on the record: levels, channels, realisations, periods, samples, rate.
pub fn record_line(rec: &MimoRecord) -> String {
    let (m, p, n) = rec.dims();
    let levels: Vec<String> = rec
        .levels
        .iter()
        .map(|l| format!("{} ({} realisations × {} periods)", tag(&l.tag), l.u.realisations, l.u.periods))
        .collect();
    let rate = if rec.rate_given {
        format!("at {} Hz", crate::record::for_people(rec.sample_rate_hz))
    } else {
        "(no sample rate: frequencies in cycles per sample)".to_string()
    };
    format!(
        "{}: {m} inputs, {p} outputs, periods of {n} samples {rate}; levels {}",
        rec.source,
        levels.join(", ")
    )
}

fn tag(t: &str) -> &str {
    if t.is_empty() { "(untagged)" } else { t }
}

/// How the nonlinear distortion of each output changes over the levels: its RMS (µm) and
/// its share of the output's RMS, per level in the record's order.
#[derive(Clone, Debug, PartialEq)]
pub struct Growth {
    /// Per output: the nonlinear distortion's RMS per level, µm.
    pub nonlinear_um: Vec<Vec<f64>>,
    /// Per output: its share of the output's RMS per level.
    pub share: Vec<Vec<f64>>,
    /// Per output: the noise of the period mean per level, µm (a distortion below it is not
    /// told apart from the noise).
    pub noise_um: Vec<Vec<f64>>,
}

impl Growth {
    /// From the levels' diagnoses.
    pub fn of(diags: &[LevelDiagnosis]) -> Self {
        let p = diags.first().map_or(0, |d| d.outputs.len());
        let col = |f: &dyn Fn(&crate::mimo::bla::OutputSplit) -> f64| -> Vec<Vec<f64>> {
            (0..p).map(|o| diags.iter().map(|d| f(&d.outputs[o])).collect()).collect()
        };
        Self {
            nonlinear_um: col(&|s| s.nonlinear_rms),
            share: col(&|s| s.nonlinear_rms / s.output_rms.max(f64::MIN_POSITIVE)),
            noise_um: col(&|s| s.noise_rms),
        }
    }

    /// Whether output `o`'s distortion is above the noise at the loudest level.
    pub fn above_noise(&self, o: usize) -> bool {
        match (self.nonlinear_um[o].last(), self.noise_um[o].last()) {
            (Some(d), Some(n)) => d > n,
            _ => false,
        }
    }

    /// Whether output `o`'s distortion rises from each level to the next (µm) and stands
    /// above the noise at the loudest.
    pub fn grows(&self, o: usize) -> bool {
        self.above_noise(o) && self.nonlinear_um[o].windows(2).all(|w| w[1] > w[0])
    }
}

/// The diagnosis: per level and output, what the level's BLA leaves, the noise and the
/// nonlinear distortion; then how the distortion changes with the level.
pub fn diagnosis_text(rec: &MimoRecord, diags: &[LevelDiagnosis]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", record_line(rec));
    let _ = writeln!(
        s,
        "\nPer level and output, RMS over a period (µm): the output; what the level's best linear approximation (BLA) leaves; of that, the noise of the period mean (of one period) and the nonlinear distortion."
    );
    let _ = writeln!(
        s,
        "{:<14} {:>6} {:>10} {:>12} {:>20} {:>14}",
        "level", "output", "RMS", "BLA leaves", "noise (one period)", "nonlinear"
    );
    for (l, d) in rec.levels.iter().zip(diags) {
        for (o, x) in d.outputs.iter().enumerate() {
            let _ = writeln!(
                s,
                "{:<14} {:>6} {:>10.4} {:>12.4} {:>11.4} ({:.4}) {:>14.4}",
                tag(&l.tag),
                format!("y{}", o + 1),
                x.output_rms,
                x.linear_leaves_rms,
                x.noise_rms,
                x.noise_rms_period,
                x.nonlinear_rms
            );
        }
    }
    if diags.len() > 1 {
        let g = Growth::of(diags);
        let _ = writeln!(s, "\nNonlinear distortion over the levels (µm, and its share of the output):");
        for o in 0..g.nonlinear_um.len() {
            let seq = |v: &[f64], f: &dyn Fn(f64) -> String| {
                v.iter().map(|x| f(*x)).collect::<Vec<_>>().join(" → ")
            };
            let _ = writeln!(
                s,
                "  y{}: {} µm ({}): {}",
                o + 1,
                seq(&g.nonlinear_um[o], &|x| format!("{x:.4}")),
                seq(&g.share[o], &|x| format!("{:.1} %", 100.0 * x)),
                if !g.above_noise(o) {
                    "at the noise level"
                } else if g.grows(o) {
                    "grows with the level"
                } else {
                    "does not grow at every level"
                }
            );
        }
    }
    s
}

fn splits_json(rec: &MimoRecord, diags: &[LevelDiagnosis]) -> Value {
    Value::Array(
        rec.levels
            .iter()
            .zip(diags)
            .map(|(l, d)| {
                json!({
                    "tag": l.tag,
                    "amplitude_v": l.amplitude_v,
                    "realisations": l.u.realisations,
                    "periods": l.u.periods,
                    "outputs": d.outputs.iter().map(|x| json!({
                        "rms_um": x.output_rms,
                        "bla_leaves_um": x.linear_leaves_rms,
                        "noise_um": x.noise_rms,
                        "noise_one_period_um": x.noise_rms_period,
                        "nonlinear_um": x.nonlinear_rms,
                    })).collect::<Vec<_>>(),
                })
            })
            .collect(),
    )
}

/// The diagnosis as one JSON object.
pub fn diagnosis_json(rec: &MimoRecord, diags: &[LevelDiagnosis]) -> Value {
    let (m, p, n) = rec.dims();
    let g = Growth::of(diags);
    json!({
        "file": rec.source,
        "inputs": m, "outputs": p, "samples_per_period": n, "sample_rate_hz": rec.sample_rate_hz,
        "levels": splits_json(rec, diags),
        "nonlinear_growth": (0..g.nonlinear_um.len()).map(|o| json!({
            "output": o + 1, "nonlinear_um": g.nonlinear_um[o], "share": g.share[o],
            "above_noise": g.above_noise(o), "grows": g.grows(o),
        })).collect::<Vec<_>>(),
    })
}

/// The BLA of one level as a figure: per output, `|G|` (dB) from each input over the excited
/// lines, with the noise and total standard deviations of the estimate.
pub fn bla_svg(rec: &MimoRecord, d: &LevelDiagnosis) -> String {
    let (_, _, n) = rec.dims();
    let hz = |i: usize| (i + 1) as f64 * rec.sample_rate_hz / n as f64;
    let db = |v: f64| 20.0 * v.max(1e-300).log10();
    let (p, m) = d.bla.g.first().map_or((0, 0), |g| g.shape());
    let x: Vec<f64> = d.bla.lines.iter().map(|&i| hz(i)).collect();
    let mut charts = Vec::new();
    for o in 0..p {
        let mut c = Chart::new(
            format!("{}: BLA to output y{} (µm/V)", tag(&d.bla.tag), o + 1),
            "frequency (Hz)",
            "dB",
        );
        for i in 0..m {
            c = c.with(Series::line(
                format!("|G(y{}, u{})|", o + 1, i + 1),
                x.clone(),
                d.bla.g.iter().map(|g| db(g[(o, i)].norm())).collect(),
                i,
            ));
        }
        let sd = |v: &[nalgebra::DMatrix<f64>]| -> Vec<f64> {
            v.iter().map(|s| db((0..m).map(|i| s[(o, i)]).sum::<f64>().max(0.0).sqrt())).collect()
        };
        c = c.with(Series::line("noise σ (sum over inputs)", x.clone(), sd(&d.bla.var_noise), m).dashed());
        if d.bla.groups > 1 {
            c = c.with(
                Series::line("total σ (noise + nonlinear)", x.clone(), sd(&d.bla.var_total), m + 1).dashed(),
            );
        }
        charts.push(c.to_svg());
    }
    stack(&charts)
}

/// SVG documents one above the other, in one document.
fn stack(svgs: &[String]) -> String {
    let mut y = 0.0;
    let mut body = String::new();
    let mut width: f64 = 0.0;
    for s in svgs {
        let attr = |name: &str| -> f64 {
            s.find(&format!("{name}=\""))
                .and_then(|i| {
                    let rest = &s[i + name.len() + 2..];
                    rest[..rest.find('"')?].parse().ok()
                })
                .unwrap_or(0.0)
        };
        let (w, h) = (attr("width"), attr("height"));
        width = width.max(w);
        let _ = write!(body, "<g transform=\"translate(0,{y})\">{}</g>", strip_xml_decl(s));
        y += h;
    }
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width}\" height=\"{y}\" viewBox=\"0 0 {width} {y}\">{body}</svg>\n"
    )
}

fn strip_xml_decl(s: &str) -> &str {
    match s.find("<svg") {
        Some(i) => &s[i..],
        None => s,
    }
}

/// The modes of a model: frequency (Hz) and damping ratio, by frequency.
pub fn modes(model: &MimoModel) -> Vec<(f64, f64)> {
    let mut v: Vec<(f64, f64)> =
        model.modes.iter().map(|md| md.frequency_damping(model.sample_rate_hz)).collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}

fn model_kind(model: &MimoModel) -> &'static str {
    if model.branch.is_some() || model.schedule.is_some() { "hysteretic" } else { "linear" }
}

fn scores_line(tags: &[String], v: &[f64]) -> String {
    tags.iter().zip(v).map(|(t, x)| format!("{} {x:.4}", tag(t))).collect::<Vec<_>>().join(" / ")
}

/// The fit: the model kept, its modes, and its score (and its linear part's) on the
/// realisation kept apart.
pub fn identify_text(rec: &MimoRecord, fit: &MimoFit, kept_apart: Option<usize>) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", record_line(rec));
    let tags: Vec<String> = rec.levels.iter().map(|l| l.tag.clone()).collect();
    let _ = writeln!(
        s,
        "\nmodel: {} state-space model of order {}, {} inputs, {} outputs, one model for every level ({:.1} s)",
        model_kind(&fit.model),
        fit.order,
        fit.model.inputs,
        fit.model.outputs,
        fit.seconds
    );
    let all = modes(&fit.model);
    let nyquist = fit.model.sample_rate_hz / 2.0;
    let light = |&&(f, z): &&(f64, f64)| f > 0.0 && f < nyquist && z < 0.5;
    let md: Vec<String> = all
        .iter()
        .filter(light)
        .map(|(f, z)| match rec.rate_given {
            true => format!("{f:.1} Hz (ζ {z:.4})"),
            false => format!("{f:.4} cycles/sample (ζ {z:.4})"),
        })
        .collect();
    let _ = writeln!(
        s,
        "lightly damped modes: {}; and {} real or heavily damped (ζ ≥ 0.5) terms",
        md.join(", "),
        all.len() - md.len()
    );
    for sc in &fit.order_scores {
        if fit.order_scores.len() > 1 {
            let _ = writeln!(
                s,
                "order {}: {}",
                sc.order,
                scores_line(&tags, if sc.hysteretic.is_empty() { &sc.linear } else { &sc.hysteretic })
            );
        }
    }
    match (&fit.held_out, kept_apart) {
        (Some(h), Some(r)) => {
            let _ = writeln!(
                s,
                "\nheld out (realisation {} of every level, not fitted), the benchmark's metric in µm (RMS per output over each period after its first {} samples, averaged):",
                r + 1,
                crate::mimo::fit::SKIP_SAMPLES
            );
            let _ = writeln!(s, "  linear part:  {}", scores_line(&tags, &h.linear));
            if !h.hysteretic.is_empty() {
                let _ = writeln!(s, "  model kept:   {}", scores_line(&tags, &h.hysteretic));
            }
        }
        _ => {
            let _ = writeln!(s, "\nevery realisation fitted: nothing held out to score the model on");
        }
    }
    s
}

fn score_json(h: &OrderScore) -> Value {
    json!({ "order": h.order, "linear_um": h.linear, "model_um": if h.hysteretic.is_empty() { &h.linear } else { &h.hysteretic } })
}

/// The fit as one JSON object.
pub fn identify_json(rec: &MimoRecord, fit: &MimoFit, kept_apart: Option<usize>) -> Value {
    json!({
        "file": rec.source,
        "model": model_kind(&fit.model),
        "order": fit.order,
        "inputs": fit.model.inputs,
        "outputs": fit.model.outputs,
        "seconds": fit.seconds,
        "levels": rec.levels.iter().map(|l| &l.tag).collect::<Vec<_>>(),
        "modes": modes(&fit.model).iter().map(|(f, z)| json!({ "hz": f, "damping": z })).collect::<Vec<_>>(),
        "kept_apart_realisation": kept_apart.map(|r| r + 1),
        "held_out": fit.held_out.as_ref().map(score_json),
        "orders": fit.order_scores.iter().map(score_json).collect::<Vec<_>>(),
        "diagnosis": splits_json(rec, &fit.diagnosis),
    })
}

/// One level of a comparison: the benchmark's metric per output and its mean.
#[derive(Clone, Debug, PartialEq)]
pub struct LevelComparison {
    /// The level's tag.
    pub tag: String,
    /// Per output, µm.
    pub outputs_um: Vec<f64>,
    /// Their mean: the benchmark's metric, µm.
    pub mean_um: f64,
}

/// A comparison as text.
pub fn compare_text(model_file: &str, rec: &MimoRecord, c: &[LevelComparison]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{model_file} on {}", record_line(rec));
    let _ = writeln!(
        s,
        "the benchmark's metric (µm): RMS per output over each period after its first {} samples, in steady state from the period's own input, averaged over periods and realisations",
        crate::mimo::fit::SKIP_SAMPLES
    );
    for l in c {
        let outs: Vec<String> =
            l.outputs_um.iter().enumerate().map(|(o, v)| format!("y{} {v:.4}", o + 1)).collect();
        let _ = writeln!(s, "  {:<14} {:.4}  ({})", tag(&l.tag), l.mean_um, outs.join(", "));
    }
    s
}

/// A comparison as one JSON object.
pub fn compare_json(model_file: &str, rec: &MimoRecord, c: &[LevelComparison]) -> Value {
    json!({
        "model_file": model_file,
        "file": rec.source,
        "levels": c.iter().map(|l| json!({ "tag": l.tag, "mean_um": l.mean_um, "outputs_um": l.outputs_um })).collect::<Vec<_>>(),
    })
}

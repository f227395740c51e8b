//! Files the commands write: a sweep's `sweep.csv` and SVG figures in the manner of the
//! paper's Figs. 6, 10, 11, 13, 16 and 17; a diagnosis' page (`index.html`, its JSON and SVG
//! figures of the residual spectrum, the loops and the time series before and after), or for
//! a periodic or multisine drive the output at the lines of whole periods.

pub mod diagnosis;
pub mod identify;
pub mod mimo;
pub mod plot;

use crate::diagnose::Diagnosis;
use crate::diagnose::periodic::PeriodicDiagnosis;
use crate::experiments::sweep::{SweepResult, Traces};
use crate::record::{RecordError, write_atomic};
use crate::report::plot::{Chart, Series};
use crate::rules::Rules;
use crate::signal::analysis;
use std::path::{Path, PathBuf};

/// An output that could not be written.
#[derive(Debug)]
pub enum ReportError {
    /// The output directory could not be created.
    CreateDir {
        /// The directory.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A file could not be written (atomically: nothing half-written is left).
    Write(RecordError),
}

impl std::fmt::Display for ReportError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ReportError::CreateDir { path, source } => {
                write!(f, "cannot create {}: {source}", path.display())
            }
            ReportError::Write(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for ReportError {}

/// Creates `dir` (and its parents).
pub fn create_dir(dir: &Path) -> Result<(), ReportError> {
    std::fs::create_dir_all(dir).map_err(|source| ReportError::CreateDir { path: dir.to_path_buf(), source })
}

/// Files written atomically into one directory, remembered in order.
struct Output<'a> {
    dir: &'a Path,
    written: Vec<PathBuf>,
}

impl<'a> Output<'a> {
    /// Creates `dir` (and its parents).
    fn new(dir: &'a Path) -> Result<Self, ReportError> {
        create_dir(dir)?;
        Ok(Self { dir, written: vec![] })
    }

    /// Writes `text` to `dir/name` atomically.
    fn put(&mut self, name: &str, text: impl AsRef<str>) -> Result<(), ReportError> {
        let p = self.dir.join(name);
        write_atomic(&p, text.as_ref().as_bytes()).map_err(ReportError::Write)?;
        self.written.push(p);
        Ok(())
    }
}

/// Writes `sweep.csv` and the figures into `dir`; returns the files written.
pub fn write_sweep(result: &SweepResult, dir: &Path) -> Result<Vec<PathBuf>, ReportError> {
    let mut out = Output::new(dir)?;
    let mut put = |name: &str, text: String| out.put(name, text);
    put("sweep.csv", result.csv())?;
    put("modelling_error.svg", modelling_error(result).to_svg())?;
    put("compensation_rmse.svg", compensation(result).to_svg())?;
    if let Some(t) = result.traces.iter().find(|t| (t.freq_hz - 23.0).abs() < 1e-9).or(result.traces.last()) {
        let f = t.freq_hz;
        put(&format!("loops_{f}hz.svg"), loops(t).to_svg())?;
        put(&format!("tracking_{f}hz.svg"), tracking(t).to_svg())?;
        put(&format!("error_spectrum_{f}hz.svg"), error_spectrum(t).to_svg())?;
    }
    if !result.traces.is_empty() {
        put("spectra.svg", spectra(&result.traces).to_svg())?;
    }
    Ok(out.written)
}

fn col(result: &SweepResult, f: impl Fn(&crate::experiments::sweep::Row) -> f64) -> Vec<f64> {
    result.rows.iter().map(f).collect()
}

/// Fig. 10: held-out free-run RMS modelling error against frequency.
pub fn modelling_error(r: &SweepResult) -> Chart {
    modelling_error_rows(&r.rows)
}

/// Fig. 10 from the rows of a sweep, simulated or measured.
pub fn modelling_error_rows(rows: &[crate::experiments::sweep::Row]) -> Chart {
    let col = |f: fn(&crate::experiments::sweep::Row) -> f64| -> Vec<f64> { rows.iter().map(f).collect() };
    let x = col(|w| w.freq_hz);
    Chart::new("Modelling error (free run, held-out half)", "drive frequency (Hz)", "RMS error (µm)")
        .with(Series::line("extended, OE fit", x.clone(), col(|w| w.rms_extended_oe_um), 0).points())
        .with(Series::line("enhanced, OE fit", x.clone(), col(|w| w.rms_enhanced_oe_um), 1).points())
        .with(Series::line("extended, paper RLS", x.clone(), col(|w| w.rms_extended_um), 2).dashed())
        .with(Series::line("enhanced, paper RLS", x, col(|w| w.rms_enhanced_um), 3).dashed())
        .log_y()
}

/// Writes the files of `boucwen sweep --measured` into `dir`: `sweep.csv` (the columns of
/// the simulated sweep; the tracking columns `nan`: they need the actuator),
/// `modelling_error.svg` (Fig. 10), `summary.txt` (what changes with frequency, the records
/// skipped and why) and `sweep.json`. Returns the files written.
pub fn write_measured_sweep(
    m: &crate::experiments::sweep_measured::MeasuredSweep,
    dir: &Path,
) -> Result<Vec<PathBuf>, ReportError> {
    let mut out = Output::new(dir)?;
    out.put("sweep.csv", m.csv())?;
    out.put("modelling_error.svg", modelling_error_rows(&m.rows()).to_svg())?;
    out.put("summary.txt", m.summary())?;
    out.put("sweep.json", format!("{:#}\n", m.json()))?;
    Ok(out.written)
}

/// Fig. 16: tracking RMSE against frequency.
pub fn compensation(r: &SweepResult) -> Chart {
    let x = col(r, |w| w.freq_hz);
    Chart::new("Tracking RMSE after settling", "drive frequency (Hz)", "RMSE (µm)")
        .with(Series::line("u_f alone, OE model", x.clone(), col(r, |w| w.rmse_uf_oe_um), 0).points())
        .with(Series::line("proposed, OE model", x.clone(), col(r, |w| w.rmse_proposed_oe_um), 1).points())
        .with(Series::line("u_f alone, paper RLS", x.clone(), col(r, |w| w.rmse_uf_um), 2).dashed())
        .with(Series::line("proposed, paper RLS", x.clone(), col(r, |w| w.rmse_proposed_um), 3).dashed())
        .with(Series::line("open loop", x.clone(), col(r, |w| w.rmse_open_um), 4))
        .with(Series::line("PI", x.clone(), col(r, |w| w.rmse_pi_um), 5))
        .with(Series::line("ORC on the PI", x, col(r, |w| w.rmse_orc_um), 6).points())
        .log_y()
}

/// The last `periods` drive periods of a trace range.
fn last_periods(len: usize, f: f64, ts: f64, periods: f64) -> std::ops::Range<usize> {
    let n = ((periods / f) / ts).round() as usize;
    len.saturating_sub(n.max(2))..len
}

/// Fig. 11: measured and model loops in the u–y plane (held-out data).
pub fn loops(t: &Traces) -> Chart {
    let r = last_periods(t.u.len(), t.freq_hz, t.ts, 2.0);
    let u = t.u[r.clone()].to_vec();
    Chart::new(format!("Loops at {} Hz (held-out data)", t.freq_hz), "u (V)", "y (µm)")
        .with(Series::line("measured", u.clone(), t.y[r.clone()].to_vec(), 7))
        .with(Series::line("extended model", u.clone(), t.y_extended[r.clone()].to_vec(), 0).dashed())
        .with(Series::line("enhanced model", u, t.y_enhanced[r].to_vec(), 1))
}

/// Fig. 17: reference and output in time, `u_f` alone and the proposed law.
pub fn tracking(t: &Traces) -> Chart {
    let r = last_periods(t.track_uf.y.len(), t.freq_hz, t.ts, 3.0);
    let time: Vec<f64> = r.clone().map(|k| k as f64 * t.ts).collect();
    Chart::new(format!("Tracking at {} Hz", t.freq_hz), "t (s)", "y (µm)")
        .with(Series::line("reference d", time.clone(), t.track_uf.d[r.clone()].to_vec(), 7).dashed())
        .with(Series::line("u_f alone", time.clone(), t.track_uf.y[r.clone()].to_vec(), 0))
        .with(Series::line("proposed", time, t.track_proposed.y[r].to_vec(), 1))
}

/// Fig. 13: spectrum of the tracking error with `u_f` alone (and with the proposed law).
pub fn error_spectrum(t: &Traces) -> Chart {
    let half = t.track_uf.y.len() / 2;
    let (f1, a1) = analysis::spectrum(&t.track_uf.error()[half..], t.ts);
    let (f2, a2) = analysis::spectrum(&t.track_proposed.error()[half..], t.ts);
    Chart::new(format!("Tracking-error spectrum at {} Hz", t.freq_hz), "frequency (Hz)", "amplitude (µm)")
        .with(Series::line("u_f alone", f1, a1, 0))
        .with(Series::line("proposed", f2, a2, 1))
        .log_y()
}

/// Fig. 6: spectra of the actuator's response to the identification sines.
pub fn spectra(traces: &[Traces]) -> Chart {
    let mut c =
        Chart::new("Response spectra (identification records)", "frequency (Hz)", "amplitude (µm)").log_y();
    for (i, t) in traces.iter().enumerate() {
        let (f, a) = analysis::spectrum(&t.y[t.y.len() / 2..], t.ts);
        c = c.with(Series::line(format!("{} Hz drive", t.freq_hz), f, a, i));
    }
    c.x_range = Some((0.0, 200.0));
    c.y_range = Some((1e-4, 100.0));
    c
}

/// Writes a diagnosis page into `dir`: `index.html` (the terminal report, the findings and
/// the figures), `diagnosis.json` (as `--json`), `residual_spectrum.svg`, `loops.svg`,
/// `time_series.svg` and `residual.svg`. `u`, `y` are the record diagnosed; `source` names
/// it. Returns the files written.
pub fn write_diagnosis(
    d: &Diagnosis,
    u: &[f64],
    y: &[f64],
    source: &str,
    dir: &Path,
    rules: &Rules,
) -> Result<Vec<PathBuf>, ReportError> {
    let figures = [
        ("residual_spectrum.svg", residual_spectrum(d, y).to_svg()),
        ("loops.svg", diagnosis_loops(d, u, y).to_svg()),
        ("time_series.svg", diagnosis_time_series(d, y).to_svg()),
        ("residual.svg", diagnosis_residual(d, y).to_svg()),
    ];
    write_page(
        dir,
        source,
        &diagnosis::sine_text(d, source, rules),
        &figures,
        &diagnosis::sine_json(d, rules),
    )
}

/// A diagnosis page in `dir`: `index.html` (the report `summary` of `source` and the
/// `figures`), the figures and `diagnosis.json`. Returns the files written.
fn write_page(
    dir: &Path,
    source: &str,
    summary: &str,
    figures: &[(&str, String)],
    json: &serde_json::Value,
) -> Result<Vec<PathBuf>, ReportError> {
    let mut out = Output::new(dir)?;
    let mut html = format!(
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>boucwen diagnose: {0}</title>\
         <style>body{{font-family:sans-serif;max-width:980px;margin:2em auto}}pre{{background:#f6f6f6;\
         padding:1em;white-space:pre-wrap}}img{{max-width:100%}}</style></head><body>\n\
         <h1>Diagnosis of {0}</h1>\n<pre>{1}</pre>\n",
        html_escape(source),
        html_escape(summary)
    );
    for (name, svg) in figures {
        html.push_str(&format!("<p><img src=\"{name}\" alt=\"{name}\"></p>\n"));
        out.put(name, svg)?;
    }
    html.push_str("</body></html>\n");
    out.put("diagnosis.json", format!("{json:#}\n"))?;
    out.put("index.html", html)?;
    Ok(out.written)
}

fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn held_out_error(y: &[f64], sim: &[f64], from: usize) -> Vec<f64> {
    y[from..].iter().zip(&sim[from..]).map(|(a, b)| a - b).collect()
}

/// Spectrum of the held-out residual of the baseline and of the extended model.
pub fn residual_spectrum(d: &Diagnosis, y: &[f64]) -> Chart {
    let (f0, a0) = analysis::spectrum(&held_out_error(y, &d.baseline_sim, d.split), d.ts);
    let (f1, a1) = analysis::spectrum(&held_out_error(y, &d.model_sim, d.split), d.ts);
    let mut c = Chart::new(
        format!("Residual spectrum (held-out), drive {:.2} Hz", d.drive_hz),
        "frequency (Hz)",
        "amplitude (µm)",
    )
    .with(Series::line(format!("baseline: {}", d.baseline.name()), f0, a0, 0))
    .with(Series::line(format!("extended: {}", d.model.name()), f1, a1, 1))
    .log_y();
    let top = (12.0 * d.drive_hz).max(d.resonance_hz().unwrap_or(0.0) * 1.5).min(0.5 / d.ts);
    c.x_range = Some((0.0, top));
    c
}

/// Measured and model loops in the u–y plane over the last two held-out periods.
pub fn diagnosis_loops(d: &Diagnosis, u: &[f64], y: &[f64]) -> Chart {
    let r = last_periods(y.len(), d.drive_hz, d.ts, 2.0);
    let chart = Chart::new(format!("Loops at {:.2} Hz (held-out data)", d.drive_hz), "u (V)", "y (µm)");
    with_models(chart, d, &u[r.clone()], y, r)
}

/// Measured output and both models' free runs over the last three held-out periods.
pub fn diagnosis_time_series(d: &Diagnosis, y: &[f64]) -> Chart {
    let r = last_periods(y.len(), d.drive_hz, d.ts, 3.0);
    let t: Vec<f64> = r.clone().map(|k| k as f64 * d.ts).collect();
    with_models(Chart::new("Output and free-run models (held-out data)", "t (s)", "y (µm)"), d, &t, y, r)
}

/// `chart` with the measured `y`, the baseline's and the extended model's free runs over
/// the samples `r`, against `x`.
fn with_models(chart: Chart, d: &Diagnosis, x: &[f64], y: &[f64], r: std::ops::Range<usize>) -> Chart {
    chart
        .with(Series::line("measured", x.to_vec(), y[r.clone()].to_vec(), 7))
        .with(
            Series::line(
                format!("baseline: {}", d.baseline.name()),
                x.to_vec(),
                d.baseline_sim[r.clone()].to_vec(),
                0,
            )
            .dashed(),
        )
        .with(Series::line(format!("extended: {}", d.model.name()), x.to_vec(), d.model_sim[r].to_vec(), 1))
}

/// The held-out residual in time, before (baseline) and after (extended model).
pub fn diagnosis_residual(d: &Diagnosis, y: &[f64]) -> Chart {
    let t: Vec<f64> = (d.split..y.len()).map(|k| k as f64 * d.ts).collect();
    Chart::new("Held-out residual y − ŷ", "t (s)", "residual (µm)")
        .with(Series::line(
            format!("baseline: {}", d.baseline.name()),
            t.clone(),
            held_out_error(y, &d.baseline_sim, d.split),
            0,
        ))
        .with(Series::line(
            format!("extended: {}", d.model.name()),
            t,
            held_out_error(y, &d.model_sim, d.split),
            1,
        ))
}

/// Writes the page of a periodic or multisine diagnosis into `dir`: `index.html` (the
/// terminal report and the figures), `diagnosis.json`, `lines.svg` (the output at the
/// excited lines, the odd lines left out and the even lines, with the noise, for the first
/// realisation). Returns the files written.
pub fn write_periodic(
    d: &PeriodicDiagnosis,
    source: &str,
    dir: &Path,
    rules: &Rules,
) -> Result<Vec<PathBuf>, ReportError> {
    let figures = [("lines.svg", periodic_lines(d).to_svg())];
    write_page(
        dir,
        source,
        &diagnosis::periodic_text(d, source, rules),
        &figures,
        &diagnosis::periodic_json(d),
    )
}

/// The output's lines (first realisation): excited, odd left out, even, and the noise of the
/// mean at each line.
pub fn periodic_lines(d: &PeriodicDiagnosis) -> Chart {
    let l = &d.lines[0];
    let pick = |f: &dyn Fn(&crate::signal::distortion::Line) -> bool| -> (Vec<f64>, Vec<f64>) {
        l.lines.iter().filter(|x| f(x)).map(|x| (x.freq_hz, x.y.norm().max(1e-9))).unzip()
    };
    let (fe, ae) = pick(&|x| x.excited);
    let (fo, ao) = pick(&|x| !x.excited && x.k % 2 == 1);
    let (fv, av) = pick(&|x| !x.excited && x.k % 2 == 0);
    let (fn_, an): (Vec<f64>, Vec<f64>) =
        l.lines.iter().map(|x| (x.freq_hz, x.noise_var.sqrt().max(1e-9))).unzip();
    let top = l.lines.iter().filter(|x| x.excited).map(|x| x.freq_hz).fold(0.0, f64::max) * 3.0;
    let mut c = Chart::new("Output at the lines of whole periods", "frequency (Hz)", "amplitude (µm)")
        .with(Series::line("excited lines", fe, ae, 0).scatter())
        .with(Series::line("odd lines not excited", fo, ao, 1).scatter())
        .with(Series::line("even lines", fv, av, 2).scatter())
        .with(Series::line("noise (std of the mean)", fn_, an, 7).dashed())
        .log_y();
    c.x_range = Some((0.0, top.min(0.5 / d.ts).max(l.f0_hz)));
    c
}

/// How a record was read, as the `import` object of `diagnose --json` and `identify --json`
/// (the command line's and the Python module's).
pub fn import_json(info: &crate::record::ImportInfo, samples: usize, ts: f64) -> serde_json::Value {
    use crate::record::TimeSource;
    let columns: serde_json::Map<String, serde_json::Value> =
        info.columns.iter().map(|(role, from)| (role.to_string(), serde_json::json!(from))).collect();
    serde_json::json!({
        "separator": info.separator.name(),
        "decimal_comma": info.decimal_comma,
        "cut_short_line": info.cut_short,
        "missing": info.missing.map(|m| serde_json::json!({ "count": m.count, "first_s": m.first_s })),
        "preamble": info.preamble.map(|p| serde_json::json!({ "lines": p.lines, "table_line": p.table_line })),
        "header": info.header,
        "columns": columns,
        "t_unit": info.t_unit.name(),
        "u_unit": info.u_unit.name(),
        "y_unit": info.y_unit.name(),
        "sample_rate_hz": match info.time { TimeSource::SampleRate(hz) => Some(hz), TimeSource::Column(_) => None },
        "samples": samples,
        "ts_s": ts,
        "spikes": info.spikes.as_ref().map(|s| serde_json::json!({
            "count": s.count,
            "departure_um": s.departure_um,
            "first_s": s.first_s,
        })),
    })
}

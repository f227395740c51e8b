//! `boucwen sweep --measured DIR`: the identification half of the sweep (the paper's
//! Fig. 10) from measured records of one actuator instead of the virtual bimorph.
//!
//! The directory holds records of one actuator at one sample interval:
//! - **sine records**, one drive frequency each: a row of the sweep per frequency;
//! - **one broadband record** (a multisine or other aperiodic drive of small amplitude, like
//!   the simulated sweep's structure record, see [`sweep::structure_records`]): the
//!   structure and the delay, fitted as the simulated sweep fits them
//!   ([`sweep::structure_from`]); without one, the structure and the delay are fitted to the
//!   sines' fundamentals ([`sweep::structure_from_sines`], at least
//!   [`MIN_FREQUENCIES`] frequencies, the loop record's included), and the summary says so;
//! - the **loop shape** comes from the lowest-frequency sine: if it is at most
//!   [`LOOP_MAX_HZ`] it is the quasi-static loop record (fitted whole, as the simulated
//!   sweep's [`sweep::LOOP_HZ`] record, and not a row); otherwise the loop is fitted on the
//!   fitted half of that record, which stays a row.
//!
//! Each sine record starts where its steady drive starts ([`steady::steady_window`]) and ends
//! where it stops (the broadband record is taken whole); it is fitted on its first half and tested in free run on the second, by both identifications,
//! exactly as the simulated sweep does ([`sweep`] steps 1 and 2, harmonic order chosen from
//! the data): `sweep.csv` has the simulated sweep's columns, the tracking ones `nan` (they
//! need the actuator). Per frequency the loop is measured on the held-out half: the phase lag
//! of the output's fundamental behind the drive's and the loop's area relative to the
//! ellipse of the two fundamentals' amplitudes (for an elliptic loop, the sine of the lag).
//!
//! A record that steps through several sines (a stepped sine, [`steady::sine_segments`])
//! gives one sine record per step, named "FILE [step I of N: F Hz]".
//!
//! A file that cannot be read, is not a sine or a broadband record, is too short or repeats a
//! frequency is skipped with a line saying why; the frequencies run on all cores.

use crate::experiments::sweep::{self, CSV_HEADER, HarmonicChoice, Row, Structure, SweepError, cell};
use crate::fit::response::{Fundamental, MIN_FREQUENCIES};
use crate::record::Record;
use crate::rules::Rules;
use crate::signal::analysis;
use crate::signal::steady::{self, DriveKind};
use rayon::prelude::*;
use std::fmt;
use std::path::{Path, PathBuf};

/// A sine record at or below this frequency (Hz) is the quasi-static loop record.
pub const LOOP_MAX_HZ: f64 = 2.0;
/// Fewest samples of a sine record.
pub const MIN_SAMPLES: usize = 1000;
/// Fewest drive periods in a sine record's held-out half.
pub const MIN_HELD_OUT_PERIODS: f64 = 2.0;

/// One file of the directory: its name and the record read from it (or why it could not be).
#[derive(Clone, Debug)]
pub struct MeasuredInput {
    /// The file's name as shown.
    pub name: String,
    /// The record, or the reader's one-line error.
    pub record: Result<Record, String>,
}

/// A file left out, and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Skipped {
    /// The file.
    pub name: String,
    /// Why it was left out.
    pub why: String,
}

impl Skipped {
    /// "FILE: WHY" (WHY alone when it names the file already, as the reader's errors do).
    pub fn line(&self) -> String {
        if self.why.starts_with(&self.name) {
            self.why.clone()
        } else {
            format!("{}: {}", self.name, self.why)
        }
    }
}

/// One frequency of a measured sweep.
#[derive(Clone, Debug)]
pub struct MeasuredRow {
    /// The row, as the simulated sweep's (tracking columns `NaN`).
    pub row: Row,
    /// The record it comes from.
    pub source: String,
    /// Amplitude of the drive's fundamental on the held-out half (V).
    pub drive_amplitude_v: f64,
    /// Amplitude of the output's fundamental on the held-out half (µm).
    pub output_amplitude_um: f64,
    /// Phase lag of the output's fundamental behind the drive's (degrees, held-out half).
    pub phase_lag_deg: f64,
    /// Loop area over `π·U1·Y1` (held-out half, whole periods).
    pub loop_width_rel: f64,
}

/// A measured sweep.
#[derive(Clone, Debug)]
pub struct MeasuredSweep {
    /// The structure and loop shape.
    pub structure: Structure,
    /// Where the structure comes from: the broadband record, or the sines' fundamentals.
    pub structure_source: String,
    /// The record the loop shape comes from, and whether it is also a row.
    pub loop_source: (String, bool),
    /// Sample interval (s).
    pub ts: f64,
    /// One row per frequency, in frequency order.
    pub rows: Vec<MeasuredRow>,
    /// Files left out.
    pub skipped: Vec<Skipped>,
    /// Wall-clock time (s).
    pub wall_s: f64,
}

/// Why a measured sweep could not run.
#[derive(Debug)]
pub enum MeasuredError {
    /// The directory could not be listed.
    Dir {
        /// The directory.
        dir: String,
        /// The system's reason.
        why: String,
    },
    /// The directory holds no files.
    Empty(String),
    /// No broadband record for the structure, and too few sine frequencies to fit it from
    /// their fundamentals.
    NoStructure {
        /// Sine frequencies found (the loop record's included).
        sines: usize,
        /// Files skipped.
        skipped: Vec<Skipped>,
    },
    /// No sine record that can be a row.
    NoSine {
        /// The quasi-static loop record, if it was the only sine.
        loop_only: Option<String>,
        /// Files skipped.
        skipped: Vec<Skipped>,
    },
    /// The structure fit failed.
    Structure(String, SweepError),
}

fn first_skipped(s: &[Skipped]) -> String {
    match s {
        [] => String::new(),
        [one] => format!(" (1 skipped: {})", one.line()),
        [one, ..] => format!(" ({} skipped, the first: {})", s.len(), one.line()),
    }
}

impl fmt::Display for MeasuredError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MeasuredError::Dir { dir, why } => write!(f, "{dir}: cannot list the directory: {why}"),
            MeasuredError::Empty(dir) => write!(f, "{dir}: no records in the directory"),
            MeasuredError::NoStructure { sines, skipped } => write!(
                f,
                "no broadband record (a multisine of small amplitude) for the actuator's structure among \
                 the records, and sines at {sines} frequencies: the structure from sines alone needs \
                 {MIN_FREQUENCIES}{}",
                first_skipped(skipped)
            ),
            MeasuredError::NoSine { loop_only: Some(name), skipped } => write!(
                f,
                "no sine record to sweep: the only one, {name}, is at or below {LOOP_MAX_HZ} Hz and gives the loop \
                 shape{}",
                first_skipped(skipped)
            ),
            MeasuredError::NoSine { loop_only: None, skipped } => {
                write!(f, "no sine record to sweep{}", first_skipped(skipped))
            }
            MeasuredError::Structure(name, e) => write!(f, "{name}: the structure fit failed: {e}"),
        }
    }
}

impl std::error::Error for MeasuredError {}

/// The files of `dir` (not those whose name starts with a dot, not subdirectories), sorted
/// by name.
pub fn records_in(dir: &Path) -> Result<Vec<PathBuf>, MeasuredError> {
    let shown = dir.display().to_string();
    let entries =
        std::fs::read_dir(dir).map_err(|e| MeasuredError::Dir { dir: shown.clone(), why: e.to_string() })?;
    let mut files = vec![];
    for e in entries {
        let e = e.map_err(|e| MeasuredError::Dir { dir: shown.clone(), why: e.to_string() })?;
        let hidden = e.file_name().to_string_lossy().starts_with('.');
        if !hidden && e.file_type().is_ok_and(|t| t.is_file() || t.is_symlink()) {
            files.push(e.path());
        }
    }
    files.sort();
    if files.is_empty() {
        return Err(MeasuredError::Empty(shown));
    }
    Ok(files)
}

/// A record that steps through several sines ([`steady::sine_segments`]) as one input per
/// step, named "FILE [step I of N: F Hz]"; any other input as it is.
fn steps_of(input: MeasuredInput) -> Vec<MeasuredInput> {
    let Ok(r) = &input.record else { return vec![input] };
    let n = r.u.len().min(r.y.len());
    let segments = steady::sine_segments(&r.u[..n], r.ts, &Rules::default());
    if segments.len() < 2 {
        return vec![input];
    }
    segments
        .iter()
        .enumerate()
        .map(|(i, seg)| {
            let name =
                format!("{} [step {} of {}: {:.3} Hz]", input.name, i + 1, segments.len(), seg.freq_hz);
            let (a, b) = (seg.start, seg.end);
            let record = Record::new(
                &name,
                r.t0 + a as f64 * r.ts,
                r.ts,
                r.u[a..b].to_vec(),
                r.y[a..b].to_vec(),
                None,
            )
            .map_err(|e| e.to_string());
            MeasuredInput { name, record }
        })
        .collect()
}

/// What a file is to the sweep.
enum Role {
    Sine { f: f64, u: Vec<f64>, y: Vec<f64> },
    Broadband { u: Vec<f64>, y: Vec<f64> },
}

struct Classified {
    name: String,
    ts: f64,
    role: Role,
}

fn classify(input: MeasuredInput) -> Result<Classified, Skipped> {
    let name = input.name;
    let skip = |why: String| Skipped { name: name.clone(), why };
    let r = input.record.map_err(&skip)?;
    r.validate_for_fit(MIN_SAMPLES).map_err(|e| skip(e.to_string()))?;
    let rules = Rules::default();
    let (w, drive) =
        steady::steady_window(&r.u, &r.y, r.ts, None, &rules).map_err(|e| skip(e.to_string()))?;
    // A sine from where its steady drive starts to where it stops (the record's end if the
    // window was only cut to whole periods); a broadband record whole, as the structure fit
    // takes it (its steady window is a stretch of uniform level, not where it starts).
    let n = r.u.len().min(r.y.len());
    let end = match drive.period_samples {
        Some(p) if n.saturating_sub(w.end) as f64 <= p.ceil() => n,
        _ => w.end,
    };
    let (u, y) = match drive.kind {
        DriveKind::Multisine | DriveKind::Aperiodic => (r.u.clone(), r.y.clone()),
        _ => (r.u[w.drive_on..end].to_vec(), r.y[w.drive_on..end].to_vec()),
    };
    if drive.kind != DriveKind::None {
        steady::check_response(&r.u[w.start..w.end], &r.y[w.start..w.end], r.ts, &drive, &rules)
            .map_err(|e| skip(e.to_string()))?;
    }
    let role = match drive.kind {
        DriveKind::Sine => {
            let f = (drive.freq_hz * 1e6).round() / 1e6;
            if u.len() < MIN_SAMPLES {
                return Err(skip(format!(
                    "the steady drive holds {} samples; the sweep needs at least {MIN_SAMPLES}",
                    u.len()
                )));
            }
            Role::Sine { f, u, y }
        }
        DriveKind::Multisine | DriveKind::Aperiodic => Role::Broadband { u, y },
        _ => {
            return Err(skip(format!(
                "the drive is {}: the sweep takes sines (one frequency each) and one broadband record",
                drive.describe()
            )));
        }
    };
    Ok(Classified { name, ts: r.ts, role })
}

/// The fundamentals of a sine record `(u, y)` at `f`, over whole periods after its first
/// quarter (where a lightly damped structure is still settling from rest).
fn fundamental(u: &[f64], y: &[f64], f: f64, ts: f64) -> Option<Fundamental> {
    let n = u.len().min(y.len());
    let (u, y) = (&u[n / 4..n], &y[n / 4..n]);
    let fu = analysis::harmonics(u, f, ts, 1).first().copied()?;
    let fy = analysis::harmonics(y, f, ts, 1).first().copied()?;
    Some(Fundamental { freq_hz: f, u: (fu.amp, fu.phase), y: (fy.amp, fy.phase) })
}

/// The phase lag (degrees) of `y`'s fundamental behind `u`'s, and the loop's area over
/// `π·U1·Y1`, over whole periods of `f`; with the fundamentals' amplitudes.
fn loop_measures(u: &[f64], y: &[f64], f: f64, ts: f64) -> (f64, f64, f64, f64) {
    let n = analysis::whole_periods(u.len().min(y.len()), f, ts);
    let (u, y) = (&u[..n], &y[..n]);
    let fu = analysis::harmonics(u, f, ts, 1).first().copied();
    let fy = analysis::harmonics(y, f, ts, 1).first().copied();
    let (Some(fu), Some(fy)) = (fu, fy) else { return (f64::NAN, f64::NAN, 0.0, 0.0) };
    let lag = (fu.phase - fy.phase).to_degrees().rem_euclid(360.0);
    let lag = if lag > 180.0 { lag - 360.0 } else { lag };
    // ∮ y du over the whole periods (trapezoid), positive for a loop run anticlockwise.
    let area: f64 = u.windows(2).zip(y.windows(2)).map(|(a, b)| 0.5 * (b[0] + b[1]) * (a[1] - a[0])).sum();
    let periods = (n as f64 * ts * f).round().max(1.0);
    let width = (area / periods).abs() / (std::f64::consts::PI * fu.amp * fy.amp).max(1e-300);
    (lag, width, fu.amp, fy.amp)
}

/// The measured sweep of `inputs` (see the module docs); the frequencies run on all cores.
pub fn run(inputs: Vec<MeasuredInput>) -> Result<MeasuredSweep, MeasuredError> {
    let t0 = std::time::Instant::now();
    let inputs: Vec<MeasuredInput> = inputs.into_iter().flat_map(steps_of).collect();
    let classified: Vec<Result<Classified, Skipped>> = inputs.into_par_iter().map(classify).collect();
    let mut skipped = vec![];
    let mut ok = vec![];
    for c in classified {
        match c {
            Ok(c) => ok.push(c),
            Err(s) => skipped.push(s),
        }
    }
    // One sample interval: the broadband record's, or the first sine's.
    let ts = match ok.iter().find(|c| matches!(c.role, Role::Broadband { .. })).or(ok.first()) {
        Some(c) => c.ts,
        None => return Err(MeasuredError::NoSine { loop_only: None, skipped }),
    };
    let (mut broadband, mut sines) = (vec![], vec![]);
    for c in ok {
        if (c.ts - ts).abs() > 1e-6 * ts {
            skipped.push(Skipped {
                name: c.name,
                why: format!("sampled every {} s; the other records every {ts} s", c.ts),
            });
            continue;
        }
        match c.role {
            Role::Broadband { u, y } => broadband.push((c.name, u, y)),
            Role::Sine { f, u, y } => sines.push((c.name, f, u, y)),
        }
    }
    let mut broadband = broadband.into_iter();
    let structure_record = broadband.next();
    if let Some((source, ..)) = &structure_record {
        for (name, ..) in broadband {
            skipped.push(Skipped {
                name,
                why: format!("another broadband record: the structure is {source}'s"),
            });
        }
    }
    sines.sort_by(|a, b| a.1.total_cmp(&b.1).then_with(|| a.0.cmp(&b.0)));
    let mut unique: Vec<(String, f64, Vec<f64>, Vec<f64>)> = vec![];
    for s in sines {
        match unique.last() {
            Some(last) if (last.1 - s.1).abs() <= 1e-3 * s.1 => {
                let why = format!("another record at {} Hz: {} is used", s.1, last.0);
                skipped.push(Skipped { name: s.0, why });
            }
            _ => unique.push(s),
        }
    }
    if unique.is_empty() {
        return Err(MeasuredError::NoSine { loop_only: None, skipped });
    }
    // The loop shape: the quasi-static record whole, or the fitted half of the lowest sine.
    let quasi_static = unique[0].1 <= LOOP_MAX_HZ;
    let (loop_name, f_loop, u_l, y_l) = if quasi_static { unique.remove(0) } else { unique[0].clone() };
    let loop_fit = if quasi_static { u_l.len() } else { u_l.len() / 2 };
    // A row needs whole periods to test on.
    unique.retain(|(name, f, u, _)| {
        let held_out = 0.5 * u.len() as f64 * ts * f;
        let enough = held_out >= MIN_HELD_OUT_PERIODS;
        if !enough {
            skipped.push(Skipped {
                name: name.clone(),
                why: format!(
                    "{held_out:.1} periods of {f} Hz in the held-out half; the sweep needs at least \
                     {MIN_HELD_OUT_PERIODS}"
                ),
            });
        }
        enough
    });
    if unique.is_empty() {
        return Err(MeasuredError::NoSine { loop_only: quasi_static.then_some(loop_name), skipped });
    }
    let loop_is_row = unique.iter().any(|r| r.0 == loop_name);
    let lp = sweep::LoopRecord { u: &u_l, y: &y_l, hz: f_loop, fit: loop_fit };
    let (structure_source, structure) = match structure_record {
        Some((source, u_s, y_s)) => {
            let st = sweep::structure_from(&u_s, &y_s, lp, ts)
                .map_err(|e| MeasuredError::Structure(source.clone(), e))?;
            (source, st)
        }
        None => {
            // No broadband record: the structure from the sines' fundamentals, each on the
            // part of its record that is fitted (the loop record's, the rows' first halves).
            let mut records: Vec<(&[f64], &[f64], f64)> = vec![];
            if !loop_is_row {
                records.push((&u_l[..loop_fit], &y_l[..loop_fit], f_loop));
            }
            records.extend(unique.iter().map(|(_, f, u, y)| (&u[..u.len() / 2], &y[..y.len() / 2], *f)));
            let points: Vec<Fundamental> =
                records.iter().filter_map(|&(u, y, f)| fundamental(u, y, f, ts)).collect();
            if points.len() < MIN_FREQUENCIES {
                return Err(MeasuredError::NoStructure { sines: points.len(), skipped });
            }
            let source = format!("the fundamentals of {} sine records (no broadband record)", points.len());
            let st = sweep::structure_from_sines(&points, lp, ts)
                .map_err(|e| MeasuredError::Structure(source.clone(), e))?;
            (source, st)
        }
    };
    let results: Vec<Result<MeasuredRow, Skipped>> = unique
        .par_iter()
        .map(|(name, f, u, y)| {
            let id = sweep::identify_at(HarmonicChoice::Auto, ts, &structure, *f, u, y)
                .map_err(|e| Skipped { name: name.clone(), why: format!("the fit at {f} Hz failed: {e}") })?;
            let fit_end = u.len() / 2;
            let (phase_lag_deg, loop_width_rel, drive_amplitude_v, output_amplitude_um) =
                loop_measures(&u[fit_end..], &y[fit_end..], *f, ts);
            let [rms_ext_rls, rms_enh_rls, rms_ext_oe, rms_enh_oe] = id.rms;
            let row = Row {
                freq_hz: *f,
                rms_extended_um: rms_ext_rls,
                rms_enhanced_um: rms_enh_rls,
                rmse_uf_um: f64::NAN,
                rmse_proposed_um: f64::NAN,
                harmonic_order: id.order,
                cancel_order: 0,
                cancel_order_oe: 0,
                alpha_um: crate::design::closed_loop::eq25_amplitude(u, y),
                rms_extended_oe_um: rms_ext_oe,
                rms_enhanced_oe_um: rms_enh_oe,
                rmse_uf_oe_um: f64::NAN,
                rmse_proposed_oe_um: f64::NAN,
                rmse_open_um: f64::NAN,
                rmse_pi_um: f64::NAN,
                rmse_orc_um: f64::NAN,
            };
            Ok(MeasuredRow {
                row,
                source: name.clone(),
                drive_amplitude_v,
                output_amplitude_um,
                phase_lag_deg,
                loop_width_rel,
            })
        })
        .collect();
    let mut rows = vec![];
    for r in results {
        match r {
            Ok(r) => rows.push(r),
            Err(s) => skipped.push(s),
        }
    }
    if rows.is_empty() {
        return Err(MeasuredError::NoSine { loop_only: None, skipped });
    }
    Ok(MeasuredSweep {
        structure,
        structure_source,
        loop_source: (loop_name, loop_is_row),
        ts,
        rows,
        skipped,
        wall_s: t0.elapsed().as_secs_f64(),
    })
}

impl MeasuredSweep {
    /// The rows of the table.
    pub fn rows(&self) -> Vec<Row> {
        self.rows.iter().map(|r| r.row.clone()).collect()
    }

    /// `sweep.csv`: [`CSV_HEADER`] and one line per frequency.
    pub fn csv(&self) -> String {
        let mut s = String::from(CSV_HEADER);
        s.push('\n');
        for r in &self.rows {
            s.push_str(&r.row.csv_with("nan"));
            s.push('\n');
        }
        s
    }

    /// The JSON of `--json` and `sweep.json`: `structure {source, resonance_hz, rms_fit_um}`,
    /// `loop {source, also_a_row}`, `rows` (the CSV's columns, `null` for `NaN`, with `source`,
    /// `phase_lag_deg`, `loop_width_rel`, `drive_amplitude_v`, `output_amplitude_um`),
    /// `skipped [{file, why}]`, `wall_s`, `threads`.
    pub fn json(&self) -> serde_json::Value {
        use serde_json::json;
        json!({
            "structure": {
                "source": self.structure_source,
                "resonance_hz": self.structure.resonance_hz,
                "rms_fit_um": self.structure.rms_fit_um,
            },
            "loop": { "source": self.loop_source.0, "also_a_row": self.loop_source.1 },
            "rows": self.rows.iter().map(|r| {
                let mut j = serde_json::to_value(&r.row).unwrap_or_default();
                j["source"] = json!(r.source);
                j["phase_lag_deg"] = json!(r.phase_lag_deg);
                j["loop_width_rel"] = json!(r.loop_width_rel);
                j["drive_amplitude_v"] = json!(r.drive_amplitude_v);
                j["output_amplitude_um"] = json!(r.output_amplitude_um);
                j
            }).collect::<Vec<_>>(),
            "skipped": self.skipped.iter().map(|s| json!({"file": s.name, "why": s.why})).collect::<Vec<_>>(),
            "wall_s": self.wall_s,
            "threads": rayon::current_num_threads(),
        })
    }

    /// The table and what changes with frequency: where a harmonic appears and what the
    /// enhanced model gains there, how the loop's width and phase lag grow; the records
    /// skipped and why.
    pub fn summary(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let res = self
            .structure
            .resonance_hz
            .map_or("no resonance (real poles)".into(), |f| format!("resonance {f:.1} Hz"));
        let _ = writeln!(
            s,
            "structure from {}: {res}, fit RMS {:.4} µm; loop shape from {}{}",
            self.structure_source,
            self.structure.rms_fit_um,
            self.loop_source.0,
            if self.loop_source.1 {
                " (its fitted half; it is also a row)"
            } else {
                " (the quasi-static record)"
            }
        );
        let _ = writeln!(
            s,
            "{:>9} {:>3} | {:>9} {:>9} | {:>9} {:>9} | {:>8} {:>7}  record",
            "f (Hz)", "n", "ext RLS", "enh RLS", "ext OE", "enh OE", "lag (°)", "width"
        );
        let _ = writeln!(s, "{:>13} | {:^19} | {:^19} |", "", "held-out RMS (µm)", "held-out RMS (µm)");
        for r in &self.rows {
            let w = &r.row;
            let _ = writeln!(
                s,
                "{:>9.3} {:>3} | {:>9} {:>9} | {:>9} {:>9} | {:>8.1} {:>7.3}  {}",
                w.freq_hz,
                w.harmonic_order,
                cell(w.rms_extended_um),
                cell(w.rms_enhanced_um),
                cell(w.rms_extended_oe_um),
                cell(w.rms_enhanced_oe_um),
                r.phase_lag_deg,
                r.loop_width_rel,
                r.source
            );
        }
        // Where a harmonic appears.
        let with: Vec<&MeasuredRow> = self.rows.iter().filter(|r| r.row.harmonic_order > 0).collect();
        if with.is_empty() {
            let _ =
                writeln!(s, "no odd harmonic stands out in the extended model's residual at any frequency");
        } else {
            let mut orders: Vec<u32> = with.iter().map(|r| r.row.harmonic_order).collect();
            orders.sort_unstable();
            orders.dedup();
            for n in orders {
                let at: Vec<&&MeasuredRow> = with.iter().filter(|r| r.row.harmonic_order == n).collect();
                let freqs: Vec<String> = at.iter().map(|r| format!("{}", r.row.freq_hz)).collect();
                let cut: Vec<String> = at
                    .iter()
                    .map(|r| {
                        format!(
                            "{:.0} %",
                            100.0 * (1.0 - r.row.rms_enhanced_oe_um / r.row.rms_extended_oe_um)
                        )
                    })
                    .collect();
                let _ = writeln!(
                    s,
                    "harmonic {n} (at {} Hz) at {} Hz: the enhanced model cuts the held-out error (OE) by {}",
                    at.iter()
                        .map(|r| format!("{:.0}", n as f64 * r.row.freq_hz))
                        .collect::<Vec<_>>()
                        .join(", "),
                    freqs.join(", "),
                    cut.join(", ")
                );
            }
            let none: Vec<String> = self
                .rows
                .iter()
                .filter(|r| r.row.harmonic_order == 0)
                .map(|r| format!("{}", r.row.freq_hz))
                .collect();
            if !none.is_empty() {
                let _ = writeln!(s, "no harmonic term at {} Hz", none.join(", "));
            }
        }
        if let (Some(lo), Some(hi)) = (self.rows.first(), self.rows.last()) {
            if self.rows.len() > 1 {
                let _ = writeln!(
                    s,
                    "from {} Hz to {} Hz the output's fundamental lags the drive by {:.1}° to {:.1}°, the loop's \
                     width (area over π·U1·Y1) goes from {:.3} to {:.3} and the output's amplitude from {:.2} to \
                     {:.2} µm",
                    lo.row.freq_hz,
                    hi.row.freq_hz,
                    lo.phase_lag_deg,
                    hi.phase_lag_deg,
                    lo.loop_width_rel,
                    hi.loop_width_rel,
                    lo.output_amplitude_um,
                    hi.output_amplitude_um
                );
            }
        }
        for k in &self.skipped {
            let _ = writeln!(s, "skipped {}", k.line());
        }
        s
    }
}

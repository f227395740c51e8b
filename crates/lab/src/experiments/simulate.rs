//! The virtual bimorph on a drive: a sine or a column of a CSV file in, a record and a short
//! summary (range, harmonics of a sine) out. What `boucwen simulate` does.
//!
//! A drive file needs a header row; if it has a `t` column, its sample interval must be the
//! scenario's. The record (`t,u,y`) is written atomically.

use crate::design::closed_loop;
use crate::mimo::model::Warmup;
use crate::model::{ModelError, ModelFile, ModelFileError};
use crate::record::{Record, RecordError};
use crate::signal::analysis;
use boucwen_sim::{Bimorph, Scenario, SimError};
use serde::Serialize;
use std::fmt;
use std::path::Path;

/// Longest record [`run`] writes (samples): 10⁷ (about 3 hours at 1 kHz).
pub const MAX_SAMPLES: usize = 10_000_000;

/// Largest drive accepted, V.
pub const MAX_DRIVE_V: f64 = 1000.0;

/// What drives the virtual bimorph.
#[derive(Clone, Debug, PartialEq)]
pub enum Drive {
    /// `amplitude_v·sin(2π freq_hz t)` for `seconds`.
    Sine {
        /// Frequency, Hz.
        freq_hz: f64,
        /// Amplitude, V.
        amplitude_v: f64,
        /// Length, s.
        seconds: f64,
    },
    /// A column of a CSV file.
    Column {
        /// The file.
        path: std::path::PathBuf,
        /// The column's name in the header row.
        name: String,
    },
}

impl fmt::Display for Drive {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Drive::Sine { freq_hz, .. } => write!(f, "sine {freq_hz} Hz"),
            Drive::Column { path, name } => write!(f, "{}:{name}", path.display()),
        }
    }
}

/// Why a drive or a simulation failed. Errors in a drive file name the file and the line.
#[derive(Debug)]
pub enum SimulateError {
    /// The sine's frequency is not above 0 and below Nyquist.
    Frequency {
        /// The frequency asked for, Hz.
        freq_hz: f64,
        /// The Nyquist frequency, Hz.
        nyquist_hz: f64,
    },
    /// The sine's amplitude is not a finite number of volts up to [`MAX_DRIVE_V`].
    Amplitude(f64),
    /// The length is not above 0 or gives more than [`MAX_SAMPLES`] samples.
    Seconds(f64),
    /// The drive file could not be read.
    Io {
        /// The file.
        file: String,
        /// The error.
        error: std::io::Error,
    },
    /// The drive file is malformed.
    File {
        /// The file.
        file: String,
        /// The line at fault (1-based), if the error is at one line.
        line: Option<usize>,
        /// What is wrong.
        what: String,
    },
    /// The simulator refused the scenario or the drive.
    Sim(SimError),
    /// The record could not be built or written.
    Record(RecordError),
    /// The model file was refused.
    ModelFile(ModelFileError),
    /// The model cannot run on the drive.
    Model {
        /// The model file.
        file: String,
        /// Why.
        error: ModelError,
    },
}

impl fmt::Display for SimulateError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SimulateError::Frequency { freq_hz, nyquist_hz } => {
                write!(f, "--freq {freq_hz}: must be above 0 and below the Nyquist frequency {nyquist_hz} Hz")
            }
            SimulateError::Amplitude(a) => {
                write!(f, "--amplitude {a}: must be a finite number of volts, at most {MAX_DRIVE_V}")
            }
            SimulateError::Seconds(s) => {
                write!(f, "--seconds {s}: must be above 0 and give at most {MAX_SAMPLES} samples")
            }
            SimulateError::Io { file, error } => write!(f, "{file}: {error}"),
            SimulateError::File { file, line: Some(line), what } => write!(f, "{file}:{line}: {what}"),
            SimulateError::File { file, line: None, what } => write!(f, "{file}: {what}"),
            SimulateError::Sim(e) => write!(f, "{e}"),
            SimulateError::Record(e) => write!(f, "{e}"),
            SimulateError::ModelFile(e) => write!(f, "{e}"),
            SimulateError::Model { file, error } => {
                write!(f, "{file}: the model cannot run on this drive: {error}")
            }
        }
    }
}

impl std::error::Error for SimulateError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            SimulateError::Io { error, .. } => Some(error),
            SimulateError::Sim(e) => Some(e),
            SimulateError::Record(e) => Some(e),
            _ => None,
        }
    }
}

impl From<SimError> for SimulateError {
    fn from(e: SimError) -> Self {
        SimulateError::Sim(e)
    }
}

impl From<RecordError> for SimulateError {
    fn from(e: RecordError) -> Self {
        SimulateError::Record(e)
    }
}

/// One harmonic of the output of a sine drive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Harmonic {
    /// Order (1: the fundamental).
    pub order: u32,
    /// Frequency, Hz.
    pub freq_hz: f64,
    /// Amplitude, µm.
    pub amp_um: f64,
}

/// What [`run`] wrote, as `boucwen simulate --json` prints it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// The record written.
    pub out: String,
    /// The drive ([`Drive`]'s display form).
    pub drive: String,
    /// Samples in the record.
    pub samples: usize,
    /// Sample interval, s (NaN, `null` in JSON, for a model fitted without a sample rate).
    pub ts_s: f64,
    /// Lowest output, µm.
    pub y_min_um: f64,
    /// Highest output, µm.
    pub y_max_um: f64,
    /// For a sine drive, harmonics 1 to 7 of the output over the second half (whole
    /// periods); empty otherwise.
    pub harmonics: Vec<Harmonic>,
}

/// Runs the virtual bimorph of `scenario` on `drive` and writes the record `t,u,y` to `out`
/// (atomically; nothing is written on error).
pub fn run(scenario: &Scenario, drive: &Drive, out: &Path) -> Result<Summary, SimulateError> {
    let ts = scenario.sampling.ts_s;
    let u = match drive {
        Drive::Sine { freq_hz, amplitude_v, seconds } => sine_drive(*freq_hz, *amplitude_v, *seconds, ts)?,
        Drive::Column { path, name } => {
            column_drive(path, name, Some(ts), "the virtual bimorph", SCENARIO_HINT)?
        }
    };
    let y = Bimorph::new(scenario)?.run(&u)?;
    let record = Record::new(&out.display().to_string(), 0.0, ts, u, y, None)?;
    record.write(out)?;
    let (lo, hi) = crate::signal::analysis::extent(&record.y);
    let harmonics = match drive {
        Drive::Sine { freq_hz, .. } => {
            let half = &record.y[record.len() / 2..];
            let n = analysis::whole_periods(half.len(), *freq_hz, ts);
            analysis::harmonics(&half[..n], *freq_hz, ts, 7)
                .iter()
                .enumerate()
                .map(|(i, t)| Harmonic { order: i as u32 + 1, freq_hz: t.freq_hz, amp_um: t.amp })
                .collect()
        }
        Drive::Column { .. } => vec![],
    };
    Ok(Summary {
        out: out.display().to_string(),
        drive: drive.to_string(),
        samples: record.len(),
        ts_s: ts,
        y_min_um: lo,
        y_max_um: hi,
        harmonics,
    })
}

/// The sine drive, checked: `0 < f < 1/(2 Ts)`, `|amplitude| ≤` [`MAX_DRIVE_V`], at most
/// [`MAX_SAMPLES`] samples (at least 2).
pub fn sine_drive(f: f64, amplitude: f64, seconds: f64, ts: f64) -> Result<Vec<f64>, SimulateError> {
    let nyquist_hz = 0.5 / ts;
    if !(f.is_finite() && f > 0.0 && f < nyquist_hz) {
        return Err(SimulateError::Frequency { freq_hz: f, nyquist_hz });
    }
    if !(amplitude.is_finite() && amplitude.abs() <= MAX_DRIVE_V) {
        return Err(SimulateError::Amplitude(amplitude));
    }
    if !(seconds.is_finite() && seconds > 0.0 && seconds / ts <= MAX_SAMPLES as f64) {
        return Err(SimulateError::Seconds(seconds));
    }
    let n = ((seconds / ts).round() as usize).max(2);
    closed_loop::sine(amplitude, f, ts, n).map_err(|_| SimulateError::Frequency { freq_hz: f, nyquist_hz })
}

/// The drive column `name` of a CSV file; `ts` is the scenario's sample interval, which a
/// `t` column must match (within 1 %).
/// What to do when a drive file's interval is not the virtual bimorph's.
const SCENARIO_HINT: &str = "resample the drive or set [sampling] in the scenario";

/// Runs the model of the file `model` on the drive column `name` of `input` and writes its
/// rows (`t` if the input has it, else `k·Ts`) with the drive as `u` and the prediction as
/// `y [um]` to `out`, atomically.
///
/// A model of several inputs and outputs (family `"mimo"`, [`crate::mimo::MimoModelFile`])
/// takes its drives from the columns `name` lists, comma-separated (`u1,u2,u3`; `u` stands
/// for `u1` to `um`), runs from rest and writes `t`, the drives and `y1 [um]` … `yp [um]`.
pub fn run_model(model: &Path, input: &Path, name: &str, out: &Path) -> Result<Summary, SimulateError> {
    let text = std::fs::read_to_string(model).unwrap_or_default();
    if crate::mimo::file::is_mimo(&text) {
        return run_mimo_model(model, input, name, out);
    }
    let m = ModelFile::read(model).map_err(SimulateError::ModelFile)?;
    let ts = m.ts_s;
    let u = column_drive(
        input,
        name,
        Some(ts),
        "the model",
        "resample the drive; the model was fitted at this interval",
    )?;
    let y = m
        .model
        .simulate(&u, ts)
        .map_err(|error| SimulateError::Model { file: model.display().to_string(), error })?;
    let t: Vec<f64> = (0..u.len()).map(|k| k as f64 * ts).collect();
    crate::record::write_columns(out, &[("t", &t), ("u", &u), ("y [um]", &y)])?;
    let (lo, hi) = crate::signal::analysis::extent(&y);
    Ok(Summary {
        out: out.display().to_string(),
        drive: format!("{}:{name} through {}", input.display(), m.model.name()),
        samples: u.len(),
        ts_s: ts,
        y_min_um: lo,
        y_max_um: hi,
        harmonics: vec![],
    })
}

/// Two periods of a drive agree when the RMS of their difference is below this fraction of
/// the drive's RMS (the Fine Steering Mirror's measured inputs: 0.04 %).
pub const PERIOD_TOLERANCE: f64 = 0.01;

/// The drives cut into runs of agreeing periods of `n` samples: each run's periods agree with
/// its first within [`PERIOD_TOLERANCE`] on every channel (several realisations one after
/// the other are several runs). `None` when the length is not a whole number of periods.
fn periodic_runs(drives: &[Vec<f64>], n: usize) -> Option<Vec<std::ops::Range<usize>>> {
    let len = drives.first()?.len();
    if n == 0 || len == 0 || len % n != 0 {
        return None;
    }
    let ms = |v: &mut dyn Iterator<Item = f64>| v.map(|x| x * x).sum::<f64>();
    let agree = |a: usize, b: usize| {
        drives.iter().all(|d| {
            let total = ms(&mut d[a..a + n].iter().copied());
            let diff = ms(&mut d[a..a + n].iter().zip(&d[b..b + n]).map(|(x, y)| x - y));
            diff <= PERIOD_TOLERANCE * PERIOD_TOLERANCE * total
        })
    };
    let mut runs: Vec<std::ops::Range<usize>> = Vec::new();
    for start in (0..len).step_by(n) {
        match runs.last_mut() {
            Some(r) if agree(r.start, start) => r.end = start + n,
            _ => runs.push(start..start + n),
        }
    }
    Some(runs)
}

/// [`run_model`] for a model of several inputs and outputs.
///
/// A model fitted without a sample rate takes the drive's rows as its samples, whatever its
/// time column says; the output keeps the drive's `t` column when it has one. A drive of whole
/// periods of the model's training period is periodic: cut into runs of agreeing periods
/// (within [`PERIOD_TOLERANCE`]; one period counts; realisations written one after the other
/// are separate runs), each run is simulated once before its written pass, so the output is
/// each run's periodic steady state. Any other drive runs from rest.
fn run_mimo_model(model: &Path, input: &Path, names: &str, out: &Path) -> Result<Summary, SimulateError> {
    let file = crate::mimo::MimoModelFile::read(model).map_err(SimulateError::ModelFile)?;
    let m = file.model;
    let ts = if file.rate_given { Some(1.0 / m.sample_rate_hz) } else { None };
    let names: Vec<String> = if names == "u" {
        (1..=m.inputs).map(|i| format!("u{i}")).collect()
    } else {
        names.split(',').map(|n| n.trim().to_string()).collect()
    };
    if names.len() != m.inputs {
        return Err(SimulateError::File {
            file: input.display().to_string(),
            line: None,
            what: format!(
                "{} drive columns ({}) for a model of {} inputs",
                names.len(),
                names.join(", "),
                m.inputs
            ),
        });
    }
    let hint = "resample the drive; the model was fitted at this interval";
    let drives =
        names.iter().map(|n| column_drive(input, n, ts, "the model", hint)).collect::<Result<Vec<_>, _>>()?;
    let len = drives[0].len();
    let t = match column_drive(input, "t", ts, "the model", hint) {
        Ok(t) => t,
        Err(_) => (0..len).map(|k| k as f64 * ts.unwrap_or(1.0)).collect(),
    };
    let runs = file.period_samples.and_then(|n| periodic_runs(&drives, n));
    let periodic = runs.is_some();
    let (runs, warmup) = match runs {
        Some(r) => (r, Warmup::Periods(1)),
        None => (std::iter::once(0..len).collect(), Warmup::Rest),
    };
    let mut y = vec![0.0; m.outputs * len];
    for r in &runs {
        let u: Vec<f64> = drives.iter().flat_map(|d| d[r.clone()].iter().copied()).collect();
        let yr = m.simulate(&u, warmup).map_err(|e| SimulateError::File {
            file: model.display().to_string(),
            line: None,
            what: e.to_string(),
        })?;
        for o in 0..m.outputs {
            y[o * len + r.start..o * len + r.end].copy_from_slice(&yr[o * r.len()..(o + 1) * r.len()]);
        }
    }
    let y_names: Vec<String> = (1..=m.outputs).map(|o| format!("y{o} [um]")).collect();
    let mut cols: Vec<(&str, &[f64])> = vec![("t", &t)];
    cols.extend(names.iter().zip(&drives).map(|(n, d)| (n.as_str(), d.as_slice())));
    cols.extend(y_names.iter().enumerate().map(|(o, n)| (n.as_str(), &y[o * len..(o + 1) * len])));
    crate::record::write_columns(out, &cols)?;
    let (lo, hi) = crate::signal::analysis::extent(&y);
    Ok(Summary {
        out: out.display().to_string(),
        drive: format!(
            "{}:{} through a {}×{} model of order {} ({})",
            input.display(),
            names.join(","),
            m.outputs,
            m.inputs,
            m.order(),
            if periodic {
                format!("{} run(s) of whole periods, each in its steady state", runs.len())
            } else {
                "from rest".to_string()
            }
        ),
        samples: len,
        ts_s: ts.unwrap_or(f64::NAN),
        y_min_um: lo,
        y_max_um: hi,
        harmonics: vec![],
    })
}

/// The drive column `name` of a CSV file for `who` (what runs it); `ts` is its sample
/// interval, which a `t` column must match (within 1 %), else the error says `hint` (`None`:
/// any interval).
pub fn column_drive(
    path: &Path,
    name: &str,
    ts: Option<f64>,
    who: &str,
    hint: &str,
) -> Result<Vec<f64>, SimulateError> {
    let file = path.display().to_string();
    let bad = |line: Option<usize>, what: String| SimulateError::File { file: file.clone(), line, what };
    let text =
        std::fs::read_to_string(path).map_err(|error| SimulateError::Io { file: file.clone(), error })?;
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((hline, header)) = lines.next() else {
        return Err(bad(None, "empty file".into()));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    if names.iter().any(|n| n.parse::<f64>().is_ok()) {
        return Err(bad(Some(hline), "no header row (the first row is numbers)".into()));
    }
    let Some(col) = names.iter().position(|n| *n == name) else {
        return Err(bad(Some(hline), format!("no column \"{name}\" (columns: {})", names.join(", "))));
    };
    let t_col = names.iter().position(|n| *n == "t");
    let (mut u, mut t) = (vec![], vec![]);
    for (line, row) in lines {
        let fields: Vec<&str> = row.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err(bad(Some(line), format!("{} fields, the header has {}", fields.len(), names.len())));
        }
        let value = |j: usize| -> Result<f64, SimulateError> {
            let v: f64 = fields[j].parse().map_err(|_| {
                bad(Some(line), format!("column \"{}\": \"{}\" is not a number", names[j], fields[j]))
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(bad(Some(line), format!("column \"{}\": {v} is not finite", names[j])))
            }
        };
        let v = value(col)?;
        if v.abs() > MAX_DRIVE_V {
            return Err(bad(Some(line), format!("column \"{name}\": {v} V is beyond ±{MAX_DRIVE_V} V")));
        }
        u.push(v);
        if let Some(j) = t_col {
            let tk = value(j)?;
            if t.last().is_some_and(|&p| tk <= p) {
                return Err(bad(Some(line), format!("time {tk} does not increase")));
            }
            t.push(tk);
        }
        if u.len() > MAX_SAMPLES {
            return Err(bad(Some(line), format!("more than {MAX_SAMPLES} samples")));
        }
    }
    if u.len() < 2 {
        return Err(bad(None, format!("{} samples, at least 2 needed", u.len())));
    }
    if let (true, Some(ts)) = (t.len() >= 2, ts) {
        let file_ts = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
        if ((file_ts - ts) / ts).abs() > 0.01 {
            return Err(bad(None, format!("sampled every {file_ts} s, {who} every {ts} s ({hint})")));
        }
    }
    Ok(u)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("boucwen-lab-simulate-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    #[test]
    fn a_column_with_its_time_is_read_and_checked() {
        let p = tmp("drive.csv");
        std::fs::write(&p, "# a comment\nt,v\n0,0.5\n0.001,-0.25\n0.002,1\n").unwrap();
        assert_eq!(
            column_drive(&p, "v", Some(1e-3), "the virtual bimorph", SCENARIO_HINT).unwrap(),
            vec![0.5, -0.25, 1.0]
        );
        let e =
            column_drive(&p, "v", Some(2e-3), "the virtual bimorph", SCENARIO_HINT).unwrap_err().to_string();
        assert!(e.contains("sampled every 0.001 s"), "{e}");
        std::fs::write(&p, "t,v\n0,0\n0.001,2000\n").unwrap();
        let e =
            column_drive(&p, "v", Some(1e-3), "the virtual bimorph", SCENARIO_HINT).unwrap_err().to_string();
        assert_eq!(e, format!("{}:3: column \"v\": 2000 V is beyond ±1000 V", p.display()));
        std::fs::write(&p, "t,v\n0,0\n0,1\n").unwrap();
        assert!(
            column_drive(&p, "v", Some(1e-3), "the virtual bimorph", SCENARIO_HINT)
                .unwrap_err()
                .to_string()
                .ends_with(":3: time 0 does not increase")
        );
        std::fs::write(&p, "1,2\n").unwrap();
        assert!(
            column_drive(&p, "v", Some(1e-3), "the virtual bimorph", SCENARIO_HINT)
                .unwrap_err()
                .to_string()
                .contains(":1: no header row")
        );
    }

    #[test]
    fn sine_drives_are_checked() {
        assert_eq!(sine_drive(10.0, 1.0, 1.0, 1e-3).unwrap().len(), 1000);
        assert!(
            sine_drive(500.0, 1.0, 1.0, 1e-3).unwrap_err().to_string().contains("Nyquist frequency 500 Hz")
        );
        assert!(matches!(sine_drive(10.0, f64::NAN, 1.0, 1e-3), Err(SimulateError::Amplitude(_))));
        assert!(matches!(sine_drive(10.0, 1.0, 1e5, 1e-3), Err(SimulateError::Seconds(_))));
    }
}

//! The flags every command that reads a record takes, and the one way to read it
//! ([`boucwen_lab::record::import`]).

use boucwen_lab::record::mimo::{MimoColumns, MimoOptions, MimoRecord};
use boucwen_lab::record::{self, ColumnMap, ImportOptions, Imported, LengthUnit, TimeUnit, VoltUnit};
use std::path::Path;

/// How to read a record that does not say everything itself.
#[derive(clap::Args, Clone, Debug)]
pub struct RecordArgs {
    /// Which column is which: t=NAME|N,u=NAME|N,y=NAME|N[,d=NAME|N] (names case-insensitive,
    /// or positions from 1); needed for a file without a header, or with other names. Several
    /// inputs and outputs: u=u1,u2,u3,y=y1,y2,y3.
    #[arg(long, value_name = "SPEC")]
    columns: Option<String>,
    /// The sample rate (Hz) of a record without a time column.
    #[arg(long, value_name = "HZ")]
    sample_rate: Option<f64>,
    /// The unit of the time column: s, ms or us (default: the header's, else s; whole-number
    /// times with no unit stated are refused).
    #[arg(long, value_name = "UNIT")]
    t_unit: Option<TimeUnit>,
    /// The unit of the input column: V, mV or kV (default: the header's, else V).
    #[arg(long, value_name = "UNIT")]
    u_unit: Option<VoltUnit>,
    /// The unit of the output (and reference) column: m, mm, um or nm (default: the
    /// header's, else µm).
    #[arg(long, value_name = "UNIT")]
    y_unit: Option<LengthUnit>,
    /// Analyse only this part of the record, START:END in seconds of its time axis (default:
    /// the steady window found in the record).
    #[arg(long, value_name = "START:END")]
    window: Option<String>,
    /// A record of several inputs and outputs from CSV: samples per period of its periodic
    /// drive (default: the whole table is one period).
    #[arg(long, value_name = "N")]
    period_samples: Option<usize>,
    /// Keep isolated spikes of the output as read (by default a sample or two far from both
    /// its neighbours' cubic and their median, a sensor's dropout, is replaced and said so).
    #[arg(long)]
    keep_spikes: bool,
}

impl RecordArgs {
    /// Reads `path` as these flags say.
    pub fn read(&self, path: &Path) -> Result<Imported, String> {
        if let Some(hz) = self.sample_rate {
            if !(hz.is_finite() && hz > 0.0) {
                return Err(format!(
                    "--sample-rate {}: must be a positive number of Hz",
                    record::for_people(hz)
                ));
            }
        }
        let columns = match &self.columns {
            Some(spec) => Some(spec.parse::<ColumnMap>().map_err(|e| e.to_string())?),
            None => None,
        };
        let opts = ImportOptions {
            columns,
            sample_rate_hz: self.sample_rate,
            t_unit: self.t_unit,
            u_unit: self.u_unit,
            y_unit: self.y_unit,
            keep_spikes: self.keep_spikes,
        };
        record::import(path, &opts).map_err(|e| e.to_string())
    }

    /// A record of several inputs and outputs, when `path` is one: a folder or a NumPy file
    /// (`u_TAG.npy`/`y_TAG.npy`, `.npz`), or a CSV whose `--columns` name several inputs or
    /// outputs. `None`: a record of one input and one output ([`Self::read`]).
    pub fn mimo(&self, path: &Path) -> Option<Result<MimoRecord, String>> {
        let columns = match self.columns.as_deref().map(str::parse::<MimoColumns>) {
            Some(Ok(c)) if c.is_mimo() => Some(c),
            _ if MimoRecord::is_numpy(path) => None,
            _ => return None,
        };
        Some(self.read_mimo(path, columns))
    }

    fn read_mimo(&self, path: &Path, columns: Option<MimoColumns>) -> Result<MimoRecord, String> {
        if self.window.is_some() || self.t_unit.is_some() || self.keep_spikes {
            return Err(format!(
                "{}: --window, --t-unit and --keep-spikes are for records of one input and one output",
                path.display()
            ));
        }
        if let Some(hz) = self.sample_rate.filter(|hz| !(hz.is_finite() && *hz > 0.0)) {
            return Err(format!("--sample-rate {}: must be a positive number of Hz", record::for_people(hz)));
        }
        let opts = MimoOptions {
            sample_rate_hz: self.sample_rate,
            u_unit: self.u_unit.unwrap_or(VoltUnit::V),
            y_unit: self.y_unit.unwrap_or(LengthUnit::Um),
            infer_y_unit: self.y_unit.is_none(),
            period_samples: self.period_samples,
            only: None,
            columns,
        };
        let rec = MimoRecord::read(path, &opts).map_err(|e| e.to_string())?;
        for note in &rec.notes {
            eprintln!("{}: {note}", rec.source);
        }
        Ok(rec)
    }

    /// Whether `--window` was given.
    pub fn window_given(&self) -> bool {
        self.window.is_some()
    }

    /// `--window` in samples of `r`, checked against the record.
    pub fn window(&self, r: &record::Record) -> Result<Option<(usize, usize)>, String> {
        let Some(text) = &self.window else { return Ok(None) };
        let parsed = text
            .split_once(':')
            .and_then(|(a, b)| Some((a.trim().parse::<f64>().ok()?, b.trim().parse::<f64>().ok()?)));
        let Some((a, b)) = parsed.filter(|(a, b)| a.is_finite() && b.is_finite()) else {
            return Err(format!(
                "--window {:?}: expected START:END in seconds, e.g. 2.5:10",
                record::excerpt(text)
            ));
        };
        let t_end = r.t0 + r.len() as f64 * r.ts;
        let k = |t: f64| ((t - r.t0) / r.ts).round();
        let (s, e) = (k(a), k(b));
        if !(s >= 0.0 && e <= r.len() as f64 && e > s) {
            let p = record::for_people;
            return Err(format!(
                "{}: --window {}:{} is not a part of the record, which runs from {} to {} s",
                r.source,
                p(a),
                p(b),
                p(r.t0),
                p(t_end)
            ));
        }
        Ok(Some((s as usize, e as usize)))
    }
}

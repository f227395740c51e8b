//! The flags every command that reads a record takes, and the one way to read it
//! ([`boucwen_lab::record::import`]).

use boucwen_lab::record::{self, ColumnMap, ImportOptions, Imported, LengthUnit, TimeUnit, VoltUnit};
use std::path::Path;

/// How to read a record that does not say everything itself.
#[derive(clap::Args, Clone, Debug)]
pub struct RecordArgs {
    /// Which column is which: t=NAME|N,u=NAME|N,y=NAME|N[,d=NAME|N] (names case-insensitive,
    /// or positions from 1); needed for a file without a header, or with other names.
    #[arg(long, value_name = "SPEC")]
    columns: Option<ColumnMap>,
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
        let opts = ImportOptions {
            columns: self.columns.clone(),
            sample_rate_hz: self.sample_rate,
            t_unit: self.t_unit,
            u_unit: self.u_unit,
            y_unit: self.y_unit,
            keep_spikes: self.keep_spikes,
        };
        record::import(path, &opts).map_err(|e| e.to_string())
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

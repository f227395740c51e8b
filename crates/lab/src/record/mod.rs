//! Measured records on disk: reading them as they come, writing them in one format.
//!
//! A record is one experiment sampled uniformly at `Ts`: the command `u[k]` (V) applied
//! over the interval `[t_k, t_k + Ts)`, the displacement `y[k]` (µm) measured at its end,
//! and optionally the reference `d[k]` (µm) a tracking run was following. In memory it is
//! a [`Record`]: `t_k = t0 + k·Ts`, so time is not stored per sample. It serves any
//! hysteretic actuator (a piezo stack or bimorph, a magnetostrictive or shape-memory
//! actuator): `u` is what drives it, `y` what it does.
//!
//! ## Reading ([`import`], [`import_text`]; [`Record::read`], [`Record::parse`])
//! ```text
//! # comment lines start with '#' or '%', anywhere in the file
//! Time (s)   Voltage        disp_mm
//! 0          0              0.000012
//! 0.001      0.0627905195   0.000419
//! ```
//! - **Separators**: tab, semicolon, comma or runs of spaces, found from the table's first
//!   line (a tab before a semicolon before a comma, since a comma may be a decimal mark).
//!   A trailing separator on data rows is tolerated. Fields may be quoted (`"Time (s)"`); a
//!   separator between quotes belongs to the field.
//! - **Decimal commas**: under a separator other than the comma, numbers may be written
//!   `0,25` or `-1,5e-3` (a spreadsheet's export in many locales); which mark the file uses
//!   comes from its first number with a fraction ([`ImportInfo::decimal_comma`]).
//! - **Preamble**: lines before the table that belong to no table (an instrument's
//!   `LabVIEW Measurement`, `Date<TAB>2024/05/01`, …) are skipped and said
//!   ([`ImportInfo::preamble`]). The table starts at the first run of three rows of as many
//!   numbers, and its header is the line just before if it names as many fields or more;
//!   nothing is skipped when the first line already has the table's shape or a row of
//!   numbers comes before the run, so a malformed row is an error at that row.
//! - **Header or not**: a first line with a field that is not a number names the columns.
//!   Names are matched case-insensitively, with a unit in brackets or after `_`/space/comma
//!   stripped: `t`, `time`, `timestamp`, `sec`, `x_value`; `u`, `v`, `voltage`, `volt`, `input`,
//!   `drive`, `command`, `vin`; `y`, `disp`, `displacement`, `position`, `pos`,
//!   `deflection`, `output`; `d`, `ref`, `reference`, `target`, `setpoint`. A unit the header
//!   states (`time_ms`, `Voltage (mV)`, `disp [mm]`) is applied unless a flag says otherwise.
//!   Without `--columns` every named column must be one of these (a typo must not silently
//!   drop a signal); unnamed columns (an empty first column, a pandas index), sample
//!   counters (`index`, `sample`, `Sample No.`, `n`, `k`), columns empty on every row, and
//!   trailing names no row fills (an instrument's `Comment`) are ignored.
//! - **Time unit**: the header's (`Time (ms)`), else `--t-unit s|ms|us`, else s; times
//!   written as whole numbers at least 1 apart with no unit stated are refused with the flag
//!   (a millisecond axis read as seconds would make every frequency 1000 times too low).
//!   A file without a header needs `--columns`.
//! - **`--columns t=NAME|N,u=NAME|N,y=NAME|N[,d=NAME|N]`** ([`ColumnMap`]): names
//!   (case-insensitive) or positions counting from 1; roles left out are found by name;
//!   other columns are ignored.
//! - **Time**: a time column (s), or `--sample-rate HZ` for a record without one (it then
//!   starts at `t = 0`). Given both, they must agree within 1 %.
//! - **Units**: `--u-unit V|mV|kV` (default V), `--y-unit m|mm|um|nm` (default µm, also
//!   for `d`). An output that spans less than 1 nm or more than 10 mm as read is refused with
//!   the unit that would make it plausible and the flag ([`MIN_SPAN_UM`], [`MAX_SPAN_UM`]).
//!   Subnormal values (below `2.2·10⁻³⁰⁸`) are read as 0.
//!   A name of several words takes the role its words name if they name only one
//!   (`Piezo Voltage`, `Measured Position (nm)`), behind a column named exactly; a name that
//!   is only a unit takes its quantity's role (`s`, `ms`; `V`, `mV`; `um`, `nm`, `mm`).
//! - **Spikes**: isolated samples of `y` far from both their neighbours' cubic and their
//!   median (a sensor's dropouts) are replaced and reported ([`spikes`],
//!   [`ImportInfo::spikes`]); [`ImportOptions::keep_spikes`] (`--keep-spikes`) keeps them.
//! - **Rows**: as many fields as the header (or the first row), except a last row the file
//!   stops inside (fewer fields, no line end after it: a logger stopped mid-write), which is
//!   left out and said ([`ImportInfo::cut_short`]); each value one that Rust's `f64` parser
//!   accepts (`1`, `-0.5`, `1e-3`, `+2.`), or with a decimal comma. `NaN` and `inf` are
//!   rejected, except a few missing samples of `y` (`NaN` or empty: a sensor out of range for
//!   a sample or two): runs of at most two, with two samples present on each side, at most
//!   1 % of the samples, are filled by the cubic through those four and said
//!   ([`ImportInfo::missing`]).
//! - **Text**: UTF-8, with or without a byte-order mark; LF or CRLF line ends.
//! - **Errors** are one line naming the file and the line (counting every line from 1, the
//!   header and comments included), and the column where one is at fault:
//!   `data.csv:17: column "y": "abc" is not a number`. They quote at most
//!   [`EXCERPT_CHARS`] characters of an offending field. Unknown or ambiguous columns name
//!   the columns found and the flag to use. See [`RecordError`].
//!
//! ## Limits
//! Values beyond what a bench can produce are taken as a unit or column mistake and
//! rejected:
//!
//! | quantity | accepted |
//! |---|---|
//! | `u` | `|u| ≤` [`U_LIMIT_V`] = 1000 V |
//! | `y`, `d` | `|y| ≤` [`Y_LIMIT_UM`] = 10⁵ µm (10 cm) |
//! | `t` | finite, strictly increasing; any origin (e.g. Unix time) |
//! | `Ts` | [`TS_MIN_S`] = 1 µs to [`TS_MAX_S`] = 10 s |
//! | samples | at least [`MIN_SAMPLES`] = 2 (the interval needs two); fitting needs more, see [`Record::validate_for_fit`] |
//!
//! ## Sample interval and uniform sampling
//! With `N` samples, `Ts = (t_{N-1} − t_0)/(N − 1)`, which averages the rounding of `t`
//! as written; of the decimals within that rounding (half of the ends' last-digit units,
//! and `f64`'s at their magnitude, over `N − 1`) the one with the fewest significant digits
//! is taken, so a Unix-time axis of a 1 kHz record gives 0.001 s. Sampling is uniform if every step `Δt_k = t_k − t_{k−1}` satisfies
//! ```text
//! |Δt_k − Δt_med| ≤ 0.01·Δt_med + min(r_k, 0.5·Δt_med) + 4ε·(|t_k| + |t_{k−1}|)
//! ```
//! where `Δt_med` is the median step ([`UNIFORM_TOLERANCE`] = 1 %), `r_k` is the
//! resolution at which the two times are written (the mean of their last-digit units:
//! `0.0003` has `10⁻⁴`, `1.5e-3` has `10⁻⁴`; a value rounded to that digit is off by at most
//! half of it, so their difference by at most `r_k`), and `ε` is the `f64` epsilon. So `t`
//! written with few decimals (3 kHz with four decimals gives steps of 0.0003 and 0.0004)
//! is accepted, while a dropped sample (a step of `2·Ts`) is always caught.
//!
//! ## Writing
//! [`Record::write`] writes the project's own form: comma-separated, header `t,u,y[,d]`,
//! in s, V and µm. It and [`write_columns`] write to a temporary file in the target's
//! directory and rename it over the target, so an error or a crash never leaves a
//! half-written file. Values are written in Rust's shortest form that reads back to the
//! same `f64` (`u`, `y`, `d` round-trip exactly). Time is written as `t0 + k·Ts` rounded to
//! `10⁻⁹·Ts` or finer, so the interval read back agrees to about `10⁻⁹/(N − 1)` relative.

mod error;
mod import;
pub mod mimo;
pub mod npy;
mod replay;
mod select;
pub mod spikes;
mod write;

pub use error::{At, EXCERPT_CHARS, ErrorKind, RecordError, excerpt, for_people};
pub use import::{
    ColumnMap, ColumnRef, ImportInfo, ImportOptions, Imported, LengthUnit, MAX_SPAN_UM, MIN_SPAN_UM,
    MissingNote, OptionError, Preamble, Separator, SpikeNote, TimeSource, TimeUnit, VoltUnit, import,
    import_text,
};
pub use replay::{REPLAY_TOLERANCE_V, Replay, ReplayError};
pub use write::{write_atomic, write_columns};

/// Largest accepted `|u|`, V.
pub const U_LIMIT_V: f64 = 1000.0;
/// Largest accepted `|y|` and `|d|`, µm (10 cm).
pub const Y_LIMIT_UM: f64 = 1e5;
/// Smallest accepted sample interval, s.
pub const TS_MIN_S: f64 = 1e-6;
/// Largest accepted sample interval, s.
pub const TS_MAX_S: f64 = 10.0;
/// Relative deviation of a time step from the median step allowed on top of the
/// resolution of `t` as written (see the module docs).
pub const UNIFORM_TOLERANCE: f64 = 0.01;
/// Fewest samples a record can have: two, to define the sample interval.
pub const MIN_SAMPLES: usize = 2;
/// Smallest standard deviation of `u` that counts as excitation, V
/// ([`Record::check_excitation`]).
pub const MIN_EXCITATION_STD_V: f64 = 1e-3;

/// One uniformly sampled experiment: `u[k]` applied over `[t0 + k·Ts, t0 + (k+1)·Ts)`,
/// `y[k]` measured at its end, and optionally the reference `d[k]`.
///
/// Build one with [`Record::new`], [`Record::read`] or [`Record::parse`]; all three check
/// the limits of the module docs, so a `Record` from them is valid. The fields are public
/// for reading; [`Record::write`] checks again what it writes.
///
/// ```
/// use boucwen_lab::record::Record;
/// let text = "# bench run 3\r\nt,y,u\r\n0.000,0.1,0\r\n0.001,0.4,0.5\r\n0.002,0.2,-0.5\r\n";
/// let r = Record::parse(text, "run3.csv")?;
/// assert_eq!((r.len(), r.u[1], r.y[1]), (3, 0.5, 0.4));
/// assert!((r.ts - 1e-3).abs() < 1e-15);
/// assert!(r.d.is_none());
/// # Ok::<(), boucwen_lab::record::RecordError>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    /// Where the record came from (the file, or a name given by the caller), for messages.
    pub source: String,
    /// Sample interval `Ts`, s.
    pub ts: f64,
    /// Time of the first sample, s.
    pub t0: f64,
    /// Command, V.
    pub u: Vec<f64>,
    /// Measured displacement, µm.
    pub y: Vec<f64>,
    /// Reference displacement, µm, if the experiment had one.
    pub d: Option<Vec<f64>>,
}

/// The columns of a record, in the order they are written.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Col {
    T,
    U,
    Y,
    D,
}

impl Col {
    fn name(self) -> &'static str {
        match self {
            Col::T => "t",
            Col::U => "u",
            Col::Y => "y",
            Col::D => "d",
        }
    }

    /// The largest accepted magnitude and its unit (`t` has none beyond finiteness).
    fn limit(self) -> Option<(f64, &'static str)> {
        match self {
            Col::T => None,
            Col::U => Some((U_LIMIT_V, "V")),
            Col::Y | Col::D => Some((Y_LIMIT_UM, "µm")),
        }
    }
}

/// Checks one value of column `col`: finite and within the column's limit.
fn check_value(col: Col, v: f64, text: &str) -> Result<(), ErrorKind> {
    if !v.is_finite() {
        return Err(ErrorKind::NotFinite { column: col.name().into(), text: excerpt(text) });
    }
    if let Some((limit, unit)) = col.limit() {
        if v.abs() > limit {
            return Err(ErrorKind::OutOfRange { column: col.name().into(), value: v, limit, unit });
        }
    }
    Ok(())
}

impl Record {
    /// A record from samples, checked against the limits of the module docs (errors name
    /// `source` and the sample).
    ///
    /// ```
    /// use boucwen_lab::record::Record;
    /// let r = Record::new("sim", 0.0, 1e-3, vec![0.0, 1.0, 0.0], vec![0.0, 2.0, 1.0], None)?;
    /// assert_eq!(r.time(2), 2e-3);
    /// let bad = Record::new("sim", 0.0, 1e-3, vec![0.0, 1e4], vec![0.0, 0.0], None).unwrap_err();
    /// assert_eq!(bad.to_string(), r#"sim: sample 1: column "u": 10000 is beyond ±1000 V"#);
    /// # Ok::<(), boucwen_lab::record::RecordError>(())
    /// ```
    pub fn new(
        source: &str,
        t0: f64,
        ts: f64,
        u: Vec<f64>,
        y: Vec<f64>,
        d: Option<Vec<f64>>,
    ) -> Result<Self, RecordError> {
        let r = Record { source: source.to_owned(), ts, t0, u, y, d };
        r.validate()?;
        Ok(r)
    }

    /// Checks the record against the limits of the module docs: lengths, at least
    /// [`MIN_SAMPLES`] samples, `t0` finite, `Ts` in range, every value finite and in range.
    pub fn validate(&self) -> Result<(), RecordError> {
        let err = |at, kind| Err(RecordError::new(&self.source, at, kind));
        let n = self.u.len();
        let mut columns = vec![(Col::U, &self.u), (Col::Y, &self.y)];
        if let Some(d) = &self.d {
            columns.push((Col::D, d));
        }
        for (col, x) in &columns {
            if x.len() != n {
                let kind = ErrorKind::LengthMismatch { column: col.name().into(), len: x.len(), expected: n };
                return err(None, kind);
            }
        }
        if n < MIN_SAMPLES {
            return err(None, ErrorKind::TooFewSamples { found: n, needed: MIN_SAMPLES });
        }
        if let Err(kind) = check_value(Col::T, self.t0, &self.t0.to_string()) {
            return err(Some(At::Sample(0)), kind);
        }
        if !(TS_MIN_S..=TS_MAX_S).contains(&self.ts) {
            return err(None, ErrorKind::SampleInterval(self.ts));
        }
        for (col, x) in &columns {
            for (k, &v) in x.iter().enumerate() {
                if let Err(kind) = check_value(*col, v, &v.to_string()) {
                    return err(Some(At::Sample(k)), kind);
                }
            }
        }
        Ok(())
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.u.len()
    }

    /// Whether the record has no samples (never, for a record built by this module).
    pub fn is_empty(&self) -> bool {
        self.u.is_empty()
    }

    /// Time of sample `k`: `t0 + k·Ts`, s.
    pub fn time(&self, k: usize) -> f64 {
        self.t0 + k as f64 * self.ts
    }

    /// Length of the record, `N·Ts`, s.
    pub fn duration_s(&self) -> f64 {
        self.len() as f64 * self.ts
    }

    /// Checks that `u` excites the plant: its standard deviation is at least
    /// [`MIN_EXCITATION_STD_V`] (1 mV). A constant command identifies nothing.
    ///
    /// ```
    /// use boucwen_lab::record::Record;
    /// let r = Record::new("flat.csv", 0.0, 1e-3, vec![2.0; 4], vec![0.0, 1.0, 2.0, 3.0], None)?;
    /// assert!(r.check_excitation().unwrap_err().to_string().starts_with("flat.csv: no excitation"));
    /// # Ok::<(), boucwen_lab::record::RecordError>(())
    /// ```
    pub fn check_excitation(&self) -> Result<(), RecordError> {
        let n = self.u.len().max(1) as f64;
        let mean = self.u.iter().sum::<f64>() / n;
        let var = self.u.iter().map(|&x| (x - mean) * (x - mean)).sum::<f64>() / n;
        let std_v = var.sqrt();
        if std_v >= MIN_EXCITATION_STD_V {
            Ok(())
        } else {
            Err(RecordError::new(&self.source, None, ErrorKind::NoExcitation { std_v }))
        }
    }

    /// Checks that the record can be fitted: at least `min_samples` samples and an
    /// excited input ([`Record::check_excitation`]).
    pub fn validate_for_fit(&self, min_samples: usize) -> Result<(), RecordError> {
        if self.len() < min_samples {
            let kind = ErrorKind::TooFewSamples { found: self.len(), needed: min_samples };
            return Err(RecordError::new(&self.source, None, kind));
        }
        self.check_excitation()
    }
}

#[cfg(test)]
mod tests;

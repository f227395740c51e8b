//! Measured records on disk: the one CSV format every boucwen tool reads and writes.
//!
//! A record is one experiment sampled uniformly at `Ts`: the command `u[k]` (V) applied
//! over the interval `[t_k, t_k + Ts)`, the displacement `y[k]` (µm) measured at its end,
//! and optionally the reference `d[k]` (µm) a tracking run was following. In memory it is
//! a [`Record`]: `t_k = t0 + k·Ts`, so time is not stored per sample.
//!
//! ## The format
//! ```text
//! # comment lines start with '#', anywhere in the file
//! t,u,y,d
//! 0,0,0.012,0
//! 0.001,0.0627905195,0.419,0.5
//! ```
//! - **Header**: the first line that is neither blank nor a comment names the columns,
//!   separated by commas. `t` (s), `u` (V) and `y` (µm) are required, `d` (µm) is
//!   optional, in any order. Names are exact and lower case; an unknown name (`Y`, `u_V`,
//!   a fifth column) is an error, so a typo cannot silently drop a signal. A column may
//!   appear only once. A file whose first line is numbers has no header and is rejected.
//! - **Rows**: one per sample, as many fields as the header, each a decimal number in
//!   any form Rust's `f64` parser accepts (`1`, `-0.5`, `1e-3`, `+2.`). Surrounding spaces
//!   are ignored. `NaN` and `inf` are rejected.
//! - **Text**: UTF-8, with or without a byte-order mark; LF or CRLF line ends; blank lines
//!   and comment lines (first non-space character `#`) are skipped anywhere. Fields are
//!   separated by commas only (no quoting, no tabs or semicolons).
//! - **Errors** name the file and the line (counting every line from 1, the header and
//!   comments included), and the column where one is at fault:
//!   `data.csv:17: column "y": "abc" is not a number`. See [`RecordError`].
//!
//! ## Limits
//! Values beyond what a bench with a bimorph can produce are taken as a unit or column
//! mistake and rejected:
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
//! as written. Sampling is uniform if every step `Δt_k = t_k − t_{k−1}` satisfies
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
//! [`Record::write`] and [`write_columns`] write to a temporary file in the target's
//! directory and rename it over the target, so an error or a crash never leaves a
//! half-written file. Values are written in Rust's shortest form that reads back to the
//! same `f64` (`u`, `y`, `d` round-trip exactly). Time is written as `t0 + k·Ts` rounded to
//! `10⁻⁹·Ts` or finer, so the interval read back agrees to about `10⁻⁹/(N − 1)` relative.

use std::fmt;
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

mod replay;
pub use replay::{REPLAY_TOLERANCE_V, Replay, ReplayError};

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

/// Where in its source an error is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum At {
    /// A line of a file, counting from 1 (header and comments included).
    Line(usize),
    /// A sample of an in-memory record or column, counting from 0.
    Sample(usize),
}

/// A record or table that cannot be read, built or written.
///
/// Its `Display` is one line: the source, the place, the column, and what is wrong.
///
/// ```
/// use boucwen_lab::record::Record;
/// let err = Record::parse("t,u,y\n0,0,0\n0.001,0,abc\n", "data.csv").unwrap_err();
/// assert_eq!(err.to_string(), r#"data.csv:3: column "y": "abc" is not a number"#);
/// ```
#[derive(Debug)]
pub struct RecordError {
    /// The file, or the name the caller gave the in-memory source.
    pub source: String,
    /// The line or sample at fault, if the error is at one place.
    pub at: Option<At>,
    /// What is wrong.
    pub kind: ErrorKind,
}

/// What is wrong with a record or table; part of a [`RecordError`].
#[derive(Debug)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The file could not be read or written.
    Io(std::io::Error),
    /// The file is not UTF-8 text.
    NotUtf8,
    /// The file holds no header (it is empty, blank or only comments).
    Empty,
    /// The first line is data, not column names.
    MissingHeader {
        /// The first field of that line.
        first_field: String,
    },
    /// A header field is empty (e.g. `t,,y`).
    EmptyColumnName {
        /// Its position in the header, counting from 1.
        position: usize,
    },
    /// A column name that is not `t`, `u`, `y` or `d`.
    UnknownColumn(String),
    /// A column named twice.
    DuplicateColumn(String),
    /// A required column is absent.
    MissingColumn(&'static str),
    /// A row with more or fewer fields than the header.
    FieldCount {
        /// Fields in the header.
        expected: usize,
        /// Fields in the row.
        found: usize,
    },
    /// A field that is not a number.
    NotANumber {
        /// The column.
        column: String,
        /// The field as written.
        text: String,
    },
    /// A value that is NaN or infinite.
    NotFinite {
        /// The column.
        column: String,
        /// The value as written.
        text: String,
    },
    /// A value beyond the physical limit of its column.
    OutOfRange {
        /// The column.
        column: String,
        /// The value.
        value: f64,
        /// The largest accepted magnitude.
        limit: f64,
        /// The unit of both.
        unit: &'static str,
    },
    /// `t` does not increase from the previous row to this one.
    TimeNotIncreasing {
        /// The previous row's time, s.
        previous: f64,
        /// This row's time, s.
        t: f64,
    },
    /// The step to this row departs from the median step by more than the tolerance.
    NonUniform {
        /// This step, s.
        dt: f64,
        /// The median step, s.
        median: f64,
        /// The largest accepted departure, s.
        tolerance: f64,
    },
    /// The sample interval is outside [`TS_MIN_S`], [`TS_MAX_S`] (or not finite).
    SampleInterval(f64),
    /// Fewer samples than needed.
    TooFewSamples {
        /// Samples present.
        found: usize,
        /// Samples needed.
        needed: usize,
    },
    /// A column's length differs from the first column's.
    LengthMismatch {
        /// The column.
        column: String,
        /// Its length.
        len: usize,
        /// The first column's length.
        expected: usize,
    },
    /// `u` is (nearly) constant: its standard deviation is below [`MIN_EXCITATION_STD_V`].
    NoExcitation {
        /// The standard deviation of `u`, V.
        std_v: f64,
    },
    /// A column name that cannot be written (empty, has a comma, quote or line break,
    /// surrounding spaces, or starts with `#`).
    BadColumnName(String),
    /// No columns were given to write.
    NoColumns,
}

impl fmt::Display for RecordError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.at {
            Some(At::Line(line)) => write!(f, "{}:{line}: {}", self.source, self.kind),
            Some(At::Sample(k)) => write!(f, "{}: sample {k}: {}", self.source, self.kind),
            None => write!(f, "{}: {}", self.source, self.kind),
        }
    }
}

impl fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ErrorKind::Io(e) => write!(f, "{e}"),
            ErrorKind::NotUtf8 => write!(f, "not UTF-8 text"),
            ErrorKind::Empty => write!(f, "no header: the file is empty or only comments"),
            ErrorKind::MissingHeader { first_field } => write!(
                f,
                "no header: the first line starts with the number {first_field:?}; \
                 it must name the columns (t,u,y and optionally d)"
            ),
            ErrorKind::EmptyColumnName { position } => write!(f, "header field {position} is empty"),
            ErrorKind::UnknownColumn(name) => {
                write!(f, "unknown column {name:?} (a record has t, u, y and optionally d")?;
                if name.contains(['\t', ';']) {
                    write!(f, "; fields must be separated by commas")?;
                }
                write!(f, ")")
            }
            ErrorKind::DuplicateColumn(name) => write!(f, "column {name:?} appears twice"),
            ErrorKind::MissingColumn(name) => write!(f, "missing column {name:?}"),
            ErrorKind::FieldCount { expected, found } => {
                write!(f, "{found} fields, but the header has {expected}")
            }
            ErrorKind::NotANumber { column, text } if text.is_empty() => {
                write!(f, "column {column:?}: empty field")
            }
            ErrorKind::NotANumber { column, text } => {
                write!(f, "column {column:?}: {text:?} is not a number")
            }
            ErrorKind::NotFinite { column, text } => {
                write!(f, "column {column:?}: {text:?} is not finite")
            }
            ErrorKind::OutOfRange { column, value, limit, unit } => {
                write!(f, "column {column:?}: {value} is beyond ±{limit} {unit}")
            }
            ErrorKind::TimeNotIncreasing { previous, t } => {
                write!(f, "column \"t\": {t} does not increase from the previous row's {previous}")
            }
            ErrorKind::NonUniform { dt, median, tolerance } => write!(
                f,
                "column \"t\": step {dt:e} s departs from the median step {median:e} s by more \
                 than {tolerance:e} s (non-uniform sampling or a dropped sample)"
            ),
            ErrorKind::SampleInterval(ts) => {
                write!(f, "sample interval {ts:e} s is outside {TS_MIN_S:e} s to {TS_MAX_S} s")
            }
            ErrorKind::TooFewSamples { found, needed } => {
                write!(f, "too few samples: {found}, at least {needed} needed")
            }
            ErrorKind::LengthMismatch { column, len, expected } => {
                write!(f, "column {column:?} has {len} samples, the first column {expected}")
            }
            ErrorKind::NoExcitation { std_v } => write!(
                f,
                "no excitation: u is constant (standard deviation {std_v:e} V, below \
                 {MIN_EXCITATION_STD_V:e} V)"
            ),
            ErrorKind::BadColumnName(name) => write!(f, "column name {name:?} cannot be written"),
            ErrorKind::NoColumns => write!(f, "no columns to write"),
        }
    }
}

impl std::error::Error for RecordError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.kind {
            ErrorKind::Io(e) => Some(e),
            _ => None,
        }
    }
}

impl RecordError {
    fn new(source: &str, at: Option<At>, kind: ErrorKind) -> Self {
        Self { source: source.to_owned(), at, kind }
    }
}

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
    fn from_name(name: &str) -> Option<Col> {
        match name {
            "t" => Some(Col::T),
            "u" => Some(Col::U),
            "y" => Some(Col::Y),
            "d" => Some(Col::D),
            _ => None,
        }
    }

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
        return Err(ErrorKind::NotFinite { column: col.name().into(), text: text.into() });
    }
    if let Some((limit, unit)) = col.limit() {
        if v.abs() > limit {
            return Err(ErrorKind::OutOfRange { column: col.name().into(), value: v, limit, unit });
        }
    }
    Ok(())
}

/// The unit of the last digit of a decimal number as written: `0.0003` → 1e-4,
/// `1.5e-3` → 1e-4, `12` → 1.
fn last_digit_unit(text: &str) -> f64 {
    let (mantissa, exp) = match text.find(['e', 'E']) {
        Some(i) => (&text[..i], text[i + 1..].parse::<i32>().unwrap_or(0)),
        None => (text, 0),
    };
    let decimals = mantissa.find('.').map_or(0, |i| mantissa.len() - i - 1);
    10f64.powi(exp.saturating_sub(decimals as i32))
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

    /// Reads a record file (see the module docs for the format).
    pub fn read(path: impl AsRef<Path>) -> Result<Self, RecordError> {
        let path = path.as_ref();
        let source = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|e| RecordError::new(&source, None, ErrorKind::Io(e)))?;
        let text = std::str::from_utf8(&bytes).map_err(|e| {
            let line = 1 + bytes[..e.valid_up_to()].iter().filter(|&&b| b == b'\n').count();
            RecordError::new(&source, Some(At::Line(line)), ErrorKind::NotUtf8)
        })?;
        Self::parse(text, &source)
    }

    /// Parses record text; `source` names it in errors (usually the file name).
    pub fn parse(text: &str, source: &str) -> Result<Self, RecordError> {
        let err = |line: usize, kind| RecordError::new(source, Some(At::Line(line)), kind);
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut lines = text
            .split('\n')
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));

        // Header.
        let Some((header_line, header)) = lines.next() else {
            return Err(RecordError::new(source, None, ErrorKind::Empty));
        };
        let mut slots: Vec<Col> = Vec::new();
        for (i, name) in header.split(',').map(str::trim).enumerate() {
            if name.parse::<f64>().is_ok() {
                return Err(err(header_line, ErrorKind::MissingHeader { first_field: name.into() }));
            }
            if name.is_empty() {
                return Err(err(header_line, ErrorKind::EmptyColumnName { position: i + 1 }));
            }
            let Some(col) = Col::from_name(name) else {
                return Err(err(header_line, ErrorKind::UnknownColumn(name.into())));
            };
            if slots.contains(&col) {
                return Err(err(header_line, ErrorKind::DuplicateColumn(name.into())));
            }
            slots.push(col);
        }
        for required in [Col::T, Col::U, Col::Y] {
            if !slots.contains(&required) {
                return Err(err(header_line, ErrorKind::MissingColumn(required.name())));
            }
        }
        let has_d = slots.contains(&Col::D);

        // Rows: values into columns, with the time's written resolution and line number.
        let rows_hint = text.bytes().filter(|&b| b == b'\n').count();
        let mut t = Vec::with_capacity(rows_hint);
        let mut t_unit = Vec::with_capacity(rows_hint);
        let mut line_of = Vec::with_capacity(rows_hint);
        let mut u = Vec::with_capacity(rows_hint);
        let mut y = Vec::with_capacity(rows_hint);
        let mut d = Vec::with_capacity(if has_d { rows_hint } else { 0 });
        for (line_no, line) in lines {
            let mut fields = 0;
            for (j, field) in line.split(',').enumerate() {
                fields = j + 1;
                let Some(&col) = slots.get(j) else {
                    let found = line.split(',').count();
                    return Err(err(line_no, ErrorKind::FieldCount { expected: slots.len(), found }));
                };
                let field = field.trim();
                let v: f64 = field.parse().map_err(|_| {
                    err(line_no, ErrorKind::NotANumber { column: col.name().into(), text: field.into() })
                })?;
                check_value(col, v, field).map_err(|kind| err(line_no, kind))?;
                match col {
                    Col::T => {
                        if let Some(&previous) = t.last() {
                            if v <= previous {
                                return Err(err(line_no, ErrorKind::TimeNotIncreasing { previous, t: v }));
                            }
                        }
                        t.push(v);
                        t_unit.push(last_digit_unit(field));
                    }
                    Col::U => u.push(v),
                    Col::Y => y.push(v),
                    Col::D => d.push(v),
                }
            }
            if fields < slots.len() {
                return Err(err(line_no, ErrorKind::FieldCount { expected: slots.len(), found: fields }));
            }
            line_of.push(line_no);
        }

        let n = t.len();
        if n < MIN_SAMPLES {
            return Err(RecordError::new(
                source,
                None,
                ErrorKind::TooFewSamples { found: n, needed: MIN_SAMPLES },
            ));
        }
        let mut steps: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        let mid = steps.len() / 2;
        let median = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
        for k in 1..n {
            let dt = t[k] - t[k - 1];
            let written = (0.5 * (t_unit[k] + t_unit[k - 1])).min(0.5 * median);
            let roundoff = 4.0 * f64::EPSILON * (t[k].abs() + t[k - 1].abs());
            let tolerance = UNIFORM_TOLERANCE * median + written + roundoff;
            if (dt - median).abs() > tolerance {
                return Err(err(line_of[k], ErrorKind::NonUniform { dt, median, tolerance }));
            }
        }
        let ts = (t[n - 1] - t[0]) / (n - 1) as f64;
        if !(TS_MIN_S..=TS_MAX_S).contains(&ts) {
            return Err(RecordError::new(source, None, ErrorKind::SampleInterval(ts)));
        }
        Ok(Record { source: source.to_owned(), ts, t0: t[0], u, y, d: has_d.then_some(d) })
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

    /// Writes the record atomically: columns `t,u,y` (and `d` if present), see the module
    /// docs. The record is validated first; errors name `path`.
    pub fn write(&self, path: impl AsRef<Path>) -> Result<(), RecordError> {
        let path = path.as_ref();
        self.validate().map_err(|e| RecordError { source: path.display().to_string(), ..e })?;
        // Time rounded to 1e-9·Ts or finer, trailing zeros dropped.
        let decimals = ((-self.ts.log10()).ceil() + 9.0).clamp(0.0, 20.0) as usize;
        let mut header = vec!["t", "u", "y"];
        if self.d.is_some() {
            header.push("d");
        }
        let mut text = String::with_capacity(self.len() * 48);
        text.push_str(&header.join(","));
        text.push('\n');
        let mut time = String::new();
        for k in 0..self.len() {
            use std::fmt::Write as _;
            time.clear();
            let _ = write!(time, "{:.*}", decimals, self.time(k));
            let trimmed =
                if time.contains('.') { time.trim_end_matches('0').trim_end_matches('.') } else { &time };
            let _ = write!(text, "{trimmed},{},{}", self.u[k], self.y[k]);
            if let Some(d) = &self.d {
                let _ = write!(text, ",{}", d[k]);
            }
            text.push('\n');
        }
        write_atomic(path, text.as_bytes())
    }
}

/// Writes a table of named columns atomically, for the CSVs that are not records (the
/// sweep's results, spectra). Every column must have the same length and only finite
/// values; names must be non-empty, unique, free of commas, quotes, line breaks and
/// surrounding spaces, and not start with `#`. Values are written in Rust's shortest
/// round-trip form.
///
/// ```
/// use boucwen_lab::record::write_columns;
/// let dir = std::env::temp_dir().join(format!("boucwen-doc-{}", std::process::id()));
/// std::fs::create_dir_all(&dir).unwrap();
/// let path = dir.join("gain.csv");
/// write_columns(&path, &[("f_hz", &[10.0, 20.0]), ("gain_db", &[-0.5, -3.25])])?;
/// assert_eq!(std::fs::read_to_string(&path).unwrap(), "f_hz,gain_db\n10,-0.5\n20,-3.25\n");
/// # std::fs::remove_dir_all(&dir).unwrap();
/// # Ok::<(), boucwen_lab::record::RecordError>(())
/// ```
pub fn write_columns(path: impl AsRef<Path>, columns: &[(&str, &[f64])]) -> Result<(), RecordError> {
    let path = path.as_ref();
    let source = path.display().to_string();
    let err = |at, kind| RecordError::new(&source, at, kind);
    let Some(&(_, first)) = columns.first() else {
        return Err(err(None, ErrorKind::NoColumns));
    };
    let n = first.len();
    for (i, &(name, values)) in columns.iter().enumerate() {
        let bad_name = name.is_empty()
            || name.trim() != name
            || name.starts_with('#')
            || name.contains([',', '"', '\n', '\r']);
        if bad_name {
            return Err(err(None, ErrorKind::BadColumnName(name.into())));
        }
        if columns[..i].iter().any(|&(other, _)| other == name) {
            return Err(err(None, ErrorKind::DuplicateColumn(name.into())));
        }
        if values.len() != n {
            let kind = ErrorKind::LengthMismatch { column: name.into(), len: values.len(), expected: n };
            return Err(err(None, kind));
        }
        if let Some(k) = values.iter().position(|v| !v.is_finite()) {
            let kind = ErrorKind::NotFinite { column: name.into(), text: values[k].to_string() };
            return Err(err(Some(At::Sample(k)), kind));
        }
    }
    let mut text = String::with_capacity((n + 1) * columns.len() * 20);
    let names: Vec<&str> = columns.iter().map(|&(name, _)| name).collect();
    text.push_str(&names.join(","));
    text.push('\n');
    for k in 0..n {
        use std::fmt::Write as _;
        for (j, &(_, values)) in columns.iter().enumerate() {
            if j > 0 {
                text.push(',');
            }
            let _ = write!(text, "{}", values[k]);
        }
        text.push('\n');
    }
    write_atomic(path, text.as_bytes())
}

/// Distinguishes temporary files of concurrent writers in one process.
static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to a temporary file beside `path`, syncs it, and renames it over `path`;
/// on any error the temporary file is removed and `path` is untouched. The writer of
/// [`Record::write`] and [`write_columns`], public for the project's other outputs
/// (figures, reports); errors are [`ErrorKind::Io`] naming `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), RecordError> {
    let io_err = |e| RecordError::new(&path.display().to_string(), None, ErrorKind::Io(e));
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let Some(name) = path.file_name() else {
        return Err(io_err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file name")));
    };
    let tmp = dir.join(format!(
        ".{}.{}-{}.tmp",
        name.to_string_lossy(),
        std::process::id(),
        TEMP_COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io_err)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_err(text: &str) -> RecordError {
        Record::parse(text, "data.csv").expect_err("the text must be rejected")
    }

    /// A temporary directory unique to one test, removed at drop.
    struct TempDir(std::path::PathBuf);

    impl TempDir {
        fn new(tag: &str) -> Self {
            let dir = std::env::temp_dir().join(format!("boucwen-record-{tag}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }
        fn entries(&self) -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(&self.0)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    #[test]
    fn parses_columns_in_any_order_with_reference() {
        let r = Record::parse("d,y,t,u\n1,2,0.5,3\n4,5,0.502,6\n7,8,0.504,9\n", "x.csv").unwrap();
        assert_eq!(r.u, [3.0, 6.0, 9.0]);
        assert_eq!(r.y, [2.0, 5.0, 8.0]);
        assert_eq!(r.d.as_deref(), Some(&[1.0, 4.0, 7.0][..]));
        assert_eq!(r.t0, 0.5);
        assert!((r.ts - 0.002).abs() < 1e-15);
        assert_eq!(r.source, "x.csv");
    }

    #[test]
    fn crlf_bom_whitespace_comments_blank_lines() {
        let text = "\u{feff}# bench 2024-05-01\r\n  t , u ,y \r\n\r\n0, 0.5 ,1\r\n# pause\r\n 0.001 ,-0.5,2 \r\n0.002,0,3\r\n\r\n\r\n";
        let r = Record::parse(text, "x.csv").unwrap();
        assert_eq!(r.u, [0.5, -0.5, 0.0]);
        assert_eq!(r.y, [1.0, 2.0, 3.0]);
        assert!((r.ts - 1e-3).abs() < 1e-15);
    }

    #[test]
    fn empty_file() {
        for text in ["", "\n\n  \r\n", "# only a comment\n"] {
            let e = parse_err(text);
            assert!(matches!(e.kind, ErrorKind::Empty), "{e}");
            assert_eq!(e.to_string(), "data.csv: no header: the file is empty or only comments");
        }
    }

    #[test]
    fn missing_header() {
        let e = parse_err("0,0,0\n0.001,1,1\n");
        assert!(matches!(e.kind, ErrorKind::MissingHeader { .. }));
        assert!(e.to_string().starts_with("data.csv:1: no header"), "{e}");
    }

    #[test]
    fn missing_required_column() {
        let e = parse_err("t,u\n0,0\n0.001,1\n");
        assert!(matches!(e.kind, ErrorKind::MissingColumn("y")));
        assert_eq!(e.to_string(), r#"data.csv:1: missing column "y""#);
    }

    #[test]
    fn duplicate_column() {
        let e = parse_err("# c\nt,u,y,u\n0,0,0,0\n");
        assert_eq!(e.to_string(), r#"data.csv:2: column "u" appears twice"#);
    }

    #[test]
    fn unknown_and_empty_column_names() {
        let e = parse_err("t,u,Y\n0,0,0\n0.001,1,1\n");
        assert_eq!(
            e.to_string(),
            r#"data.csv:1: unknown column "Y" (a record has t, u, y and optionally d)"#
        );
        let e = parse_err("t\tu\ty\n0\t0\t0\n");
        assert!(e.to_string().ends_with("fields must be separated by commas)"), "{e}");
        let e = parse_err("t,,y\n");
        assert_eq!(e.to_string(), "data.csv:1: header field 2 is empty");
    }

    #[test]
    fn non_numeric_value() {
        let e = parse_err("t,u,y\n0,0,0\n0.001,0,abc\n");
        assert_eq!(e.to_string(), r#"data.csv:3: column "y": "abc" is not a number"#);
        let e = parse_err("t,u,y\n0,,0\n");
        assert_eq!(e.to_string(), r#"data.csv:2: column "u": empty field"#);
    }

    #[test]
    fn non_finite_values() {
        for (bad, col) in [("NaN", "u"), ("inf", "y"), ("-infinity", "t")] {
            let row = match col {
                "u" => format!("0.001,{bad},0"),
                "y" => format!("0.001,0,{bad}"),
                _ => format!("{bad},0,0"),
            };
            let e = parse_err(&format!("t,u,y\n0,0,0\n{row}\n"));
            assert!(matches!(e.kind, ErrorKind::NotFinite { .. }), "{e}");
            assert_eq!(e.to_string(), format!(r#"data.csv:3: column "{col}": "{bad}" is not finite"#));
        }
    }

    #[test]
    fn values_beyond_physical_range() {
        let e = parse_err("t,u,y\n0,0,0\n0.001,1000.5,0\n");
        assert_eq!(e.to_string(), r#"data.csv:3: column "u": 1000.5 is beyond ±1000 V"#);
        let e = parse_err("t,u,y,d\n0,0,0,0\n0.001,0,0,-2e5\n");
        assert_eq!(e.to_string(), r#"data.csv:3: column "d": -200000 is beyond ±100000 µm"#);
        // At the limits is accepted.
        Record::parse("t,u,y\n0,-1000,1e5\n0.001,1000,-1e5\n", "x").unwrap();
    }

    #[test]
    fn ragged_rows() {
        let e = parse_err("t,u,y\n0,0,0\n0.001,0\n");
        assert_eq!(e.to_string(), "data.csv:3: 2 fields, but the header has 3");
        let e = parse_err("t,u,y\n0,0,0,7,8\n");
        assert_eq!(e.to_string(), "data.csv:2: 5 fields, but the header has 3");
    }

    #[test]
    fn time_not_increasing() {
        let e = parse_err("t,u,y\n0,0,0\n0.001,0,0\n0.001,0,0\n");
        assert!(matches!(e.kind, ErrorKind::TimeNotIncreasing { .. }));
        assert_eq!(
            e.to_string(),
            r#"data.csv:4: column "t": 0.001 does not increase from the previous row's 0.001"#
        );
        let e = parse_err("t,u,y\n0.002,0,0\n0.001,0,0\n");
        assert!(e.to_string().starts_with("data.csv:3: column \"t\""), "{e}");
    }

    #[test]
    fn non_uniform_sampling_and_dropped_sample() {
        // A dropped sample (the step at line 5 is 2 ms).
        let e = parse_err("t,u,y\n0.000,0,0\n0.001,0,0\n0.002,0,0\n0.004,0,0\n0.005,0,0\n");
        assert!(matches!(e.kind, ErrorKind::NonUniform { .. }), "{e}");
        assert!(e.to_string().starts_with("data.csv:5: column \"t\": step 2e-3 s"), "{e}");
        // Jitter of 2 % with times written to 1 µs is too much.
        let e = parse_err("t,u,y\n0.000000,0,0\n0.001000,0,0\n0.002020,0,0\n0.003020,0,0\n");
        assert!(e.to_string().starts_with("data.csv:4:"), "{e}");
        // Jitter of 0.5 % is within the tolerance.
        Record::parse("t,u,y\n0.000000,0,0\n0.001000,0,0\n0.002005,0,0\n0.003005,0,0\n", "x").unwrap();
    }

    #[test]
    fn times_rounded_when_written_are_uniform() {
        // 3 kHz written with four decimals: steps of 0.0003 and 0.0004 s.
        let mut text = String::from("t,u,y\n");
        for k in 0..3000 {
            text.push_str(&format!("{:.4},0,0\n", k as f64 / 3000.0));
        }
        let r = Record::parse(&text, "x").unwrap();
        assert!((r.ts - 1.0 / 3000.0).abs() < 1e-4 / 2999.0);
        // 1024 Hz written with six decimals, starting at a Unix time.
        let mut text = String::from("t,u,y\n");
        for k in 0..1024 {
            text.push_str(&format!("{:.6},0,0\n", 1.7e9 + k as f64 / 1024.0));
        }
        let r = Record::parse(&text, "x").unwrap();
        assert!((r.ts - 1.0 / 1024.0).abs() < 1e-6);
        assert_eq!(r.t0, 1.7e9);
    }

    #[test]
    fn too_few_samples() {
        let e = parse_err("t,u,y\n0,0,0\n");
        assert_eq!(e.to_string(), "data.csv: too few samples: 1, at least 2 needed");
        let e = parse_err("t,u,y\n");
        assert!(matches!(e.kind, ErrorKind::TooFewSamples { found: 0, needed: 2 }));
        let r = Record::parse("t,u,y\n0,0,0\n0.001,1,0\n0.002,0,0\n", "x.csv").unwrap();
        let e = r.validate_for_fit(100).unwrap_err();
        assert_eq!(e.to_string(), "x.csv: too few samples: 3, at least 100 needed");
        assert!(r.validate_for_fit(3).is_ok());
    }

    #[test]
    fn sample_interval_limits() {
        let e = parse_err("t,u,y\n0,0,0\n20,0,0\n");
        assert_eq!(e.to_string(), "data.csv: sample interval 2e1 s is outside 1e-6 s to 10 s");
        let e = parse_err("t,u,y\n0,0,0\n1e-7,0,0\n");
        assert!(matches!(e.kind, ErrorKind::SampleInterval(_)));
        Record::parse("t,u,y\n0,0,0\n1e-6,0,0\n", "x").unwrap();
    }

    #[test]
    fn no_excitation() {
        let r = Record::parse("t,u,y\n0,1.5,0\n0.001,1.5,1\n0.002,1.5004,2\n", "flat.csv").unwrap();
        let e = r.check_excitation().unwrap_err();
        assert!(matches!(e.kind, ErrorKind::NoExcitation { .. }));
        assert!(e.to_string().starts_with("flat.csv: no excitation: u is constant"), "{e}");
        let r = Record::parse("t,u,y\n0,0,0\n0.001,0.01,1\n0.002,-0.01,2\n", "x").unwrap();
        r.check_excitation().unwrap();
    }

    #[test]
    fn not_utf8_names_the_line() {
        let dir = TempDir::new("utf8");
        let path = dir.0.join("bin.csv");
        std::fs::write(&path, b"t,u,y\n0,0,0\n0.001,\xff,0\n").unwrap();
        let e = Record::read(&path).unwrap_err();
        assert_eq!(e.to_string(), format!("{}:3: not UTF-8 text", path.display()));
        let missing = dir.0.join("missing.csv");
        let e = Record::read(&missing).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::Io(_)));
        assert!(e.to_string().starts_with(&format!("{}: ", missing.display())), "{e}");
    }

    #[test]
    fn new_checks_lengths_and_values() {
        let e = Record::new("sim", 0.0, 1e-3, vec![0.0; 3], vec![0.0; 2], None).unwrap_err();
        assert_eq!(e.to_string(), r#"sim: column "y" has 2 samples, the first column 3"#);
        let e = Record::new("sim", 0.0, 1e-3, vec![0.0; 2], vec![0.0, f64::NAN], None).unwrap_err();
        assert_eq!(e.to_string(), r#"sim: sample 1: column "y": "NaN" is not finite"#);
        let e = Record::new("sim", 0.0, 0.0, vec![0.0; 2], vec![0.0; 2], None).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::SampleInterval(_)));
    }

    /// A record with awkward values: irrational interval, offset start, tiny and large values.
    fn awkward(n: usize, with_d: bool) -> Record {
        let ts = 1.0 / 3000.0;
        let u: Vec<f64> = (0..n).map(|k| 3.0 * (0.7 * k as f64).sin() + 1e-17 * k as f64).collect();
        let y: Vec<f64> = (0..n).map(|k| 123.456789 * (0.3 * k as f64).cos() / 7.0).collect();
        let d = with_d.then(|| (0..n).map(|k| -(k as f64) / 3.0).collect());
        Record::new("mem", 12.345678901, ts, u, y, d).unwrap()
    }

    #[test]
    fn round_trip() {
        let dir = TempDir::new("roundtrip");
        for with_d in [false, true] {
            let r = awkward(5000, with_d);
            let path = dir.0.join("r.csv");
            r.write(&path).unwrap();
            let back = Record::read(&path).unwrap();
            assert_eq!(back.u, r.u, "u round-trips exactly");
            assert_eq!(back.y, r.y, "y round-trips exactly");
            assert_eq!(back.d, r.d, "d round-trips exactly");
            assert!((back.ts - r.ts).abs() <= 1e-9 * r.ts, "{} vs {}", back.ts, r.ts);
            assert!((back.t0 - r.t0).abs() <= 1e-9 * r.ts);
            assert_eq!(back.source, path.display().to_string());
        }
        assert_eq!(dir.entries(), ["r.csv"], "no temporary file left");
    }

    #[test]
    fn writer_time_column_is_short_and_exact_enough() {
        let r = Record::new("m", 0.0, 1e-3, vec![0.0, 1.0, 2.0], vec![0.5; 3], None).unwrap();
        let dir = TempDir::new("short");
        let path = dir.0.join("s.csv");
        r.write(&path).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "t,u,y\n0,0,0.5\n0.001,1,0.5\n0.002,2,0.5\n");
    }

    #[test]
    fn write_errors_leave_nothing_behind() {
        let dir = TempDir::new("atomic");
        let path = dir.0.join("t.csv");
        write_columns(&path, &[("a", &[1.0, 2.0])]).unwrap();
        // Bad inputs: the existing file stays as it was.
        let e = write_columns(&path, &[("a", &[1.0]), ("b", &[1.0, 2.0])]).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(r#"{}: column "b" has 2 samples, the first column 1"#, path.display())
        );
        let e = write_columns(&path, &[("a", &[1.0, f64::INFINITY])]).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(r#"{}: sample 1: column "a": "inf" is not finite"#, path.display())
        );
        for bad in ["", "a,b", " a", "#a", "a\"", "x\ny"] {
            let e = write_columns(&path, &[(bad, &[1.0])]).unwrap_err();
            assert!(matches!(e.kind, ErrorKind::BadColumnName(_)), "{bad:?}: {e}");
        }
        let e = write_columns(&path, &[("a", &[1.0]), ("a", &[1.0])]).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::DuplicateColumn(_)));
        assert!(matches!(write_columns(&path, &[]).unwrap_err().kind, ErrorKind::NoColumns));
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "a\n1\n2\n");
        // A directory in the way of the rename: an I/O error, the temporary file removed.
        let blocked = dir.0.join("sub");
        std::fs::create_dir(&blocked).unwrap();
        std::fs::write(blocked.join("x"), "keep").unwrap();
        let e = write_columns(&blocked, &[("a", &[1.0])]).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::Io(_)), "{e}");
        assert!(e.to_string().starts_with(&blocked.display().to_string()));
        // Into a directory that does not exist.
        let e = write_columns(dir.0.join("nope").join("x.csv"), &[("a", &[1.0])]).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::Io(_)));
        assert_eq!(dir.entries(), ["sub", "t.csv"], "no temporary file left");
        // An invalid record is not written.
        let mut r = awkward(10, false);
        r.y[3] = f64::NAN;
        let e = r.write(dir.0.join("bad.csv")).unwrap_err();
        assert!(e.to_string().starts_with(&format!("{}: sample 3:", dir.0.join("bad.csv").display())), "{e}");
        assert_eq!(dir.entries(), ["sub", "t.csv"]);
    }

    #[test]
    fn large_file_parses() {
        // 100k rows at 10 kHz with a reference; no timing assertion (benches do timing).
        let r = awkward(100_000, true);
        let dir = TempDir::new("large");
        let path = dir.0.join("big.csv");
        r.write(&path).unwrap();
        let back = Record::read(&path).unwrap();
        assert_eq!(back.len(), 100_000);
        assert_eq!(back.y, r.y);
    }

    #[test]
    fn last_digit_units() {
        assert_eq!(last_digit_unit("0.0003"), 1e-4);
        assert_eq!(last_digit_unit("1.5e-3"), 1e-4);
        assert_eq!(last_digit_unit("12"), 1.0);
        assert_eq!(last_digit_unit("-2.50E+2"), 1.0);
    }
}

//! What can be wrong with a record or table, and where: [`RecordError`].

use super::{MIN_EXCITATION_STD_V, TS_MAX_S, TS_MIN_S};
use std::fmt;

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
    /// The first line is data, not column names, and no columns were named.
    MissingHeader {
        /// Fields in that line.
        fields: usize,
    },
    /// A header field is empty (e.g. `t,,y`) where a name is needed.
    EmptyColumnName {
        /// Its position in the header, counting from 1.
        position: usize,
    },
    /// A named column that is none of the record's signals (without `--columns`).
    UnknownColumn {
        /// The name (a short excerpt).
        name: String,
        /// The columns found.
        found: String,
    },
    /// `--columns` names a column the file does not have.
    ColumnNotFound {
        /// The role.
        role: &'static str,
        /// The column as given.
        given: String,
        /// The columns found.
        found: String,
    },
    /// More than one column could be this role.
    AmbiguousColumn {
        /// The role.
        role: &'static str,
        /// The columns found.
        found: String,
    },
    /// No time column and no sample rate.
    NoTime {
        /// The columns found.
        found: String,
    },
    /// A time column named in `--columns` and a sample rate given too.
    TimeTwice,
    /// The time column's sample rate differs from the one given.
    RateMismatch {
        /// From the time column, Hz.
        from_time_hz: f64,
        /// Given, Hz.
        given_hz: f64,
    },
    /// The output spans less than [`super::MIN_SPAN_UM`] or more than
    /// [`super::MAX_SPAN_UM`] as read: likely a unit mistake.
    OutputSpan {
        /// The span as read, µm.
        span_um: f64,
        /// The unit it was read in.
        read_in: &'static str,
        /// The unit that gives a plausible span, if one does.
        likely: Option<&'static str>,
    },
    /// The times are whole numbers at least 1 apart and nothing says their unit: seconds
    /// would make a 1 kHz record sampled every second, so the unit must be given.
    TimeUnitUnstated {
        /// The time column (its name or position).
        column: String,
        /// The interval as read.
        step: f64,
    },
    /// A column named twice.
    DuplicateColumn(String),
    /// A required column is absent.
    MissingColumn {
        /// The role.
        role: &'static str,
        /// The columns found.
        found: String,
    },
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
            Some(At::Line(line)) => {
                write!(f, "{}:{line}: {}", self.source, self.kind)?;
                // Read from a file: the likely mistake is the unit, and the flag fixes it.
                match &self.kind {
                    ErrorKind::OutOfRange { column, .. } if column == "u" => {
                        write!(f, " (if u is in mV, give --u-unit mV)")
                    }
                    ErrorKind::OutOfRange { column, .. } if column == "y" || column == "d" => {
                        write!(f, " (if {column} is in nm, give --y-unit nm)")
                    }
                    _ => Ok(()),
                }
            }
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
            ErrorKind::MissingHeader { fields } => write!(
                f,
                "no header: the first line is {fields} numbers; name the columns with --columns \
                 (e.g. t=1,u=2,y=3, or u=1,y=2 with --sample-rate HZ)"
            ),
            ErrorKind::EmptyColumnName { position } => write!(f, "header field {position} is empty"),
            ErrorKind::UnknownColumn { name, found } => write!(
                f,
                "column {name:?} is not one of t, u, y, d (columns found: {found}); choose the columns \
                 with --columns t=NAME|N,u=NAME|N,y=NAME|N"
            ),
            ErrorKind::ColumnNotFound { role, given, found } => {
                write!(f, "--columns {role}={given}: no such column (columns found: {found})")
            }
            ErrorKind::AmbiguousColumn { role, found } => write!(
                f,
                "more than one column could be {role} (columns found: {found}); choose with --columns {role}=NAME|N"
            ),
            ErrorKind::NoTime { found } => write!(
                f,
                "no time column (columns found: {found}); give --sample-rate HZ, or name it with --columns t=NAME|N"
            ),
            ErrorKind::TimeTwice => {
                write!(f, "--columns names a time column and --sample-rate is given too; give one of them")
            }
            ErrorKind::RateMismatch { from_time_hz, given_hz } => write!(
                f,
                "the time column gives a sample rate of {from_time_hz:.6} Hz, --sample-rate says {} Hz",
                for_people(*given_hz)
            ),
            ErrorKind::OutputSpan { span_um, read_in, likely } => {
                let read =
                    if *read_in == "um" { "µm".to_string() } else { format!("µm (read in {read_in})") };
                let what = if *span_um < super::MIN_SPAN_UM { "less than 1 nm" } else { "more than 10 mm" };
                write!(f, "column \"y\": the output spans {span_um:.3e} {read}, {what}")?;
                match likely {
                    Some(u) => write!(f, "; if y is in {u}, give --y-unit {u}"),
                    None => {
                        write!(f, "; no unit of --y-unit (m, mm, um, nm) makes it an actuator's displacement")
                    }
                }
            }
            ErrorKind::TimeUnitUnstated { column, step } => {
                let step = for_people(*step);
                write!(
                    f,
                    "column {column:?}: the times are whole numbers {step} apart and the header gives no unit; \
                     if t is in ms, give --t-unit ms (us for µs; s if it really is sampled every {step} s)"
                )
            }
            ErrorKind::DuplicateColumn(name) => write!(f, "column {name:?} appears twice"),
            ErrorKind::MissingColumn { role, found } => write!(
                f,
                "no column for {role} (columns found: {found}); name it with --columns {role}=NAME|N"
            ),
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
                write!(
                    f,
                    "column {column:?}: {} is beyond ±{} {unit}",
                    for_people(*value),
                    for_people(*limit)
                )
            }
            ErrorKind::TimeNotIncreasing { previous, t } => {
                write!(
                    f,
                    "column \"t\": {} does not increase from the previous row's {}",
                    for_people(*t),
                    for_people(*previous)
                )
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
    pub(super) fn new(source: &str, at: Option<At>, kind: ErrorKind) -> Self {
        Self { source: source.to_owned(), at, kind }
    }
}

/// A number as a message shows it to people: as Rust writes it (the shortest form that
/// reads back to it) from `10⁻⁴` to `10¹⁵` in size, in scientific notation beyond (`1e300`,
/// not 301 digits; `1.5e-9`, not `0.0000000015`), so a Unix time reads as written.
///
/// ```
/// use boucwen_lab::record::for_people;
/// assert_eq!(for_people(1e300), "1e300");
/// assert_eq!(for_people(-2.5e-7), "-2.5e-7");
/// assert_eq!(for_people(1_700_000_000.125), "1700000000.125");
/// assert_eq!((for_people(0.001), for_people(0.0)), ("0.001".to_string(), "0".to_string()));
/// ```
pub fn for_people(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-4..1e15).contains(&x.abs()) {
        x.to_string()
    } else {
        format!("{x:e}")
    }
}

/// Longest part of an offending field quoted in a message, in characters.
pub const EXCERPT_CHARS: usize = 24;

/// `text` as quoted in a message: at most [`EXCERPT_CHARS`] characters, then `…`; control
/// characters, the line and paragraph separators U+2028 and U+2029 (which break a line in
/// an editor, a browser or a log viewer, though they are not control characters) and the
/// bidirectional controls (which reorder what follows them) shown as `?`: a message stays
/// one printable line, in the order written.
///
/// ```
/// use boucwen_lab::record::excerpt;
/// assert_eq!(excerpt("disp\u{2028}[mm]\t"), "disp?[mm]?");
/// ```
pub fn excerpt(text: &str) -> String {
    excerpt_n(text, EXCERPT_CHARS)
}

/// Whether `c` is shown as `?` in a message (see [`excerpt`]).
fn unprintable(c: char) -> bool {
    c.is_control()
        || matches!(c, '\u{2028}' | '\u{2029}' | '\u{200e}' | '\u{200f}' | '\u{061c}')
        || ('\u{202a}'..='\u{202e}').contains(&c)
        || ('\u{2066}'..='\u{2069}').contains(&c)
}

/// [`excerpt`] of at most `n` characters.
pub(super) fn excerpt_n(text: &str, n: usize) -> String {
    let mut out: String = text.chars().take(n).map(|c| if unprintable(c) { '?' } else { c }).collect();
    if text.chars().nth(n).is_some() {
        out.push('…');
    }
    out
}

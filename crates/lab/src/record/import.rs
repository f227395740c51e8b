//! Reading records as they come from a bench: [`import`] and [`import_text`].
//!
//! Every command that reads a record reads it here ([`Record::read`] and
//! [`Record::parse`] are `import` with the default [`ImportOptions`]). What is accepted is in
//! the module docs of [`crate::record`]; what the caller can say about a file that does
//! not say it itself is in [`ImportOptions`] (the CLI's `--columns`, `--sample-rate`,
//! `--u-unit`, `--y-unit`).

use super::error::{excerpt, excerpt_n};
use super::{At, Col, ErrorKind, MIN_SAMPLES, Record, RecordError, TS_MAX_S, TS_MIN_S, UNIFORM_TOLERANCE};
use std::fmt;
use std::path::Path;
use std::str::FromStr;

/// Smallest span of the output (µm) taken as a displacement: below it, the values are
/// likely in another unit (metres, millimetres) or the sensor shows nothing.
pub const MIN_SPAN_UM: f64 = 1e-3;
/// Largest span of the output (µm) taken as an actuator's displacement: 10 mm.
pub const MAX_SPAN_UM: f64 = 1e4;

/// The unit of the input column `u` (`--u-unit`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VoltUnit {
    /// Volts (the default).
    V,
    /// Millivolts.
    MilliV,
    /// Kilovolts.
    KiloV,
}

impl VoltUnit {
    /// Volts per unit.
    pub fn volts(self) -> f64 {
        match self {
            VoltUnit::V => 1.0,
            VoltUnit::MilliV => 1e-3,
            VoltUnit::KiloV => 1e3,
        }
    }
    /// The name as the flag takes it.
    pub fn name(self) -> &'static str {
        match self {
            VoltUnit::V => "V",
            VoltUnit::MilliV => "mV",
            VoltUnit::KiloV => "kV",
        }
    }
}

/// The unit of the output and reference columns `y`, `d` (`--y-unit`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LengthUnit {
    /// Metres.
    M,
    /// Millimetres.
    Mm,
    /// Micrometres (the default).
    Um,
    /// Nanometres.
    Nm,
}

impl LengthUnit {
    /// Micrometres per unit.
    pub fn micrometres(self) -> f64 {
        match self {
            LengthUnit::M => 1e6,
            LengthUnit::Mm => 1e3,
            LengthUnit::Um => 1.0,
            LengthUnit::Nm => 1e-3,
        }
    }
    /// The name as the flag takes it.
    pub fn name(self) -> &'static str {
        match self {
            LengthUnit::M => "m",
            LengthUnit::Mm => "mm",
            LengthUnit::Um => "um",
            LengthUnit::Nm => "nm",
        }
    }
    const ALL: [LengthUnit; 4] = [LengthUnit::M, LengthUnit::Mm, LengthUnit::Um, LengthUnit::Nm];
}

/// The unit of the time column `t` (`--t-unit`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimeUnit {
    /// Seconds (the default).
    S,
    /// Milliseconds.
    Ms,
    /// Microseconds.
    Us,
}

impl TimeUnit {
    /// Seconds per unit.
    pub fn seconds(self) -> f64 {
        match self {
            TimeUnit::S => 1.0,
            TimeUnit::Ms => 1e-3,
            TimeUnit::Us => 1e-6,
        }
    }
    /// The name as the flag takes it.
    pub fn name(self) -> &'static str {
        match self {
            TimeUnit::S => "s",
            TimeUnit::Ms => "ms",
            TimeUnit::Us => "us",
        }
    }
}

impl FromStr for TimeUnit {
    type Err = OptionError;
    fn from_str(s: &str) -> Result<Self, OptionError> {
        match s.trim().to_lowercase().as_str() {
            "s" => Ok(TimeUnit::S),
            "ms" => Ok(TimeUnit::Ms),
            "us" | "µs" | "μs" => Ok(TimeUnit::Us),
            _ => Err(OptionError { flag: "--t-unit", value: excerpt(s), expected: "s, ms or us" }),
        }
    }
}

/// A flag's value that cannot be read (`--columns`, `--t-unit`, `--u-unit`, `--y-unit`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OptionError {
    /// The flag.
    pub flag: &'static str,
    /// The value given (a short excerpt).
    pub value: String,
    /// What was expected.
    pub expected: &'static str,
}

impl fmt::Display for OptionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {:?}: expected {}", self.flag, self.value, self.expected)
    }
}

impl std::error::Error for OptionError {}

impl FromStr for VoltUnit {
    type Err = OptionError;
    fn from_str(s: &str) -> Result<Self, OptionError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "v" => Ok(VoltUnit::V),
            "mv" => Ok(VoltUnit::MilliV),
            "kv" => Ok(VoltUnit::KiloV),
            _ => Err(OptionError { flag: "--u-unit", value: excerpt(s), expected: "V, mV or kV" }),
        }
    }
}

impl FromStr for LengthUnit {
    type Err = OptionError;
    fn from_str(s: &str) -> Result<Self, OptionError> {
        match s.trim().to_lowercase().as_str() {
            "m" => Ok(LengthUnit::M),
            "mm" => Ok(LengthUnit::Mm),
            "um" | "µm" | "μm" => Ok(LengthUnit::Um),
            "nm" => Ok(LengthUnit::Nm),
            _ => Err(OptionError { flag: "--y-unit", value: excerpt(s), expected: "m, mm, um or nm" }),
        }
    }
}

/// A column as the user names it: by its header name (case-insensitive) or by its
/// position, counting from 1.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ColumnRef {
    /// A header name.
    Name(String),
    /// A position, from 1.
    Index(usize),
}

impl fmt::Display for ColumnRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ColumnRef::Name(n) => write!(f, "{n}"),
            ColumnRef::Index(i) => write!(f, "{i}"),
        }
    }
}

/// Which column holds which signal (`--columns t=NAME|N,u=NAME|N,y=NAME|N[,d=NAME|N]`).
/// A role left out is looked for by its usual names (see the module docs of
/// [`crate::record`]); columns no role names are ignored.
///
/// ```
/// use boucwen_lab::record::{ColumnMap, ColumnRef};
/// let m: ColumnMap = "u=Voltage,y=3".parse()?;
/// assert_eq!(m.u, Some(ColumnRef::Name("Voltage".into())));
/// assert_eq!(m.y, Some(ColumnRef::Index(3)));
/// assert!("u=0".parse::<ColumnMap>().is_err());
/// # Ok::<(), boucwen_lab::record::OptionError>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ColumnMap {
    /// Time (s).
    pub t: Option<ColumnRef>,
    /// Input (V, or `--u-unit`).
    pub u: Option<ColumnRef>,
    /// Output (µm, or `--y-unit`).
    pub y: Option<ColumnRef>,
    /// Reference (the output's unit).
    pub d: Option<ColumnRef>,
}

impl ColumnMap {
    fn get(&self, col: Col) -> Option<&ColumnRef> {
        match col {
            Col::T => self.t.as_ref(),
            Col::U => self.u.as_ref(),
            Col::Y => self.y.as_ref(),
            Col::D => self.d.as_ref(),
        }
    }
}

impl FromStr for ColumnMap {
    type Err = OptionError;
    fn from_str(s: &str) -> Result<Self, OptionError> {
        let bad = |expected| OptionError { flag: "--columns", value: excerpt(s), expected };
        let mut m = ColumnMap::default();
        for part in s.split(',') {
            let Some((role, col)) = part.split_once('=') else {
                return Err(bad("ROLE=NAME or ROLE=N, comma-separated (e.g. t=time,u=2,y=disp)"));
            };
            let (role, col) = (role.trim().to_ascii_lowercase(), col.trim());
            if col.is_empty() {
                return Err(bad("a column name or a position after each '='"));
            }
            let r = match col.parse::<usize>() {
                Ok(0) => return Err(bad("positions counting from 1")),
                Ok(i) => ColumnRef::Index(i),
                Err(_) => ColumnRef::Name(col.to_string()),
            };
            let slot = match role.as_str() {
                "t" => &mut m.t,
                "u" => &mut m.u,
                "y" => &mut m.y,
                "d" => &mut m.d,
                _ => return Err(bad("roles t, u, y and d")),
            };
            if slot.replace(r).is_some() {
                return Err(bad("each role once"));
            }
        }
        Ok(m)
    }
}

/// What the caller knows about a file that the file does not say.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImportOptions {
    /// Which column is which (`None`: found by the header's names).
    pub columns: Option<ColumnMap>,
    /// The sample rate (Hz) of a record without a time column.
    pub sample_rate_hz: Option<f64>,
    /// The unit of `t` (`None`: the header's, else s; whole-number times with no unit
    /// stated are refused, see [`ErrorKind::TimeUnitUnstated`]).
    pub t_unit: Option<TimeUnit>,
    /// The unit of `u` (`None`: the header's, else V).
    pub u_unit: Option<VoltUnit>,
    /// The unit of `y` and `d` (`None`: the header's, else µm).
    pub y_unit: Option<LengthUnit>,
    /// Keep isolated spikes of `y` as read (by default they are repaired: [`super::spikes`]).
    pub keep_spikes: bool,
}

/// How fields are separated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Separator {
    /// `,`
    Comma,
    /// A tab.
    Tab,
    /// `;`
    Semicolon,
    /// Runs of spaces (and tabs).
    Whitespace,
}

impl Separator {
    /// A name for messages and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Separator::Comma => "comma",
            Separator::Tab => "tab",
            Separator::Semicolon => "semicolon",
            Separator::Whitespace => "whitespace",
        }
    }
}

/// Where the sample times came from.
#[derive(Clone, Debug, PartialEq)]
pub enum TimeSource {
    /// A column of the file (its name or position).
    Column(String),
    /// `--sample-rate` (Hz), the record starting at `t = 0`.
    SampleRate(f64),
}

/// How a file was read: for the user to check, and for the JSON.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportInfo {
    /// The separator found.
    pub separator: Separator,
    /// Whether numbers were written with a decimal comma (`0,25`; with a separator other
    /// than the comma).
    pub decimal_comma: bool,
    /// Lines before the table that belong to no table (an instrument's preamble), skipped.
    pub preamble: Option<Preamble>,
    /// The last line, left out: the file stops inside it (fewer fields than the header, no
    /// line end after it).
    pub cut_short: Option<usize>,
    /// Samples of `y` the file leaves missing (`NaN` or empty), filled.
    pub missing: Option<MissingNote>,
    /// Whether the file had a header row.
    pub header: bool,
    /// Each signal read and the column it came from (its header name, or its position).
    pub columns: Vec<(&'static str, String)>,
    /// The unit `t` was read in.
    pub t_unit: TimeUnit,
    /// The unit `u` was read in.
    pub u_unit: VoltUnit,
    /// The unit `y` (and `d`) was read in.
    pub y_unit: LengthUnit,
    /// Where the times came from.
    pub time: TimeSource,
    /// The isolated spikes of `y` repaired ([`super::spikes`]), if any.
    pub spikes: Option<SpikeNote>,
}

/// Lines before the table, skipped: an instrument's preamble (`LabVIEW Measurement`,
/// `Date<TAB>2024/05/01`, …).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Preamble {
    /// How many lines were skipped (neither blank nor comments).
    pub lines: usize,
    /// The line (from 1) where the table starts: its header, or its first row.
    pub table_line: usize,
}

/// Samples of `y` missing from the file (`NaN` or an empty field: a sensor out of range for
/// a sample or two), filled by the cubic through the two samples on each side of each run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MissingNote {
    /// How many samples were filled.
    pub count: usize,
    /// The time of the first (s, the record's axis).
    pub first_s: f64,
}

/// Fills the missing (NaN) samples of `y` at `at` (ascending) if they are a few isolated
/// ones: runs of at most [`super::spikes::MAX_RUN`] samples, each with two present samples
/// on both sides, at most [`super::spikes::MAX_SHARE`] of the samples in all. Each is the
/// cubic through the two samples on each side of its run. `None` (and `y` unchanged) if
/// they are not.
fn fill_missing(y: &mut [f64], at: impl Iterator<Item = usize>) -> Option<usize> {
    let at: Vec<usize> = at.collect();
    let n = y.len();
    if at.len() as f64 > super::spikes::MAX_SHARE * n as f64 {
        return None;
    }
    // Runs of consecutive indices: (first, last).
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for &k in &at {
        match runs.last_mut() {
            Some(r) if r.1 + 1 == k => r.1 = k,
            _ => runs.push((k, k)),
        }
    }
    let present = |k: usize| y.get(k).is_some_and(|v| v.is_finite());
    let isolated = |&(a, b): &(usize, usize)| {
        b - a < super::spikes::MAX_RUN
            && a >= 2
            && present(a - 2)
            && present(a - 1)
            && present(b + 1)
            && present(b + 2)
    };
    if !runs.iter().all(isolated) {
        return None;
    }
    for (a, b) in runs {
        // Lagrange through (a−2, a−1, b+1, b+2).
        let xs = [a - 2, a - 1, b + 1, b + 2].map(|k| k as f64);
        let ys = [y[a - 2], y[a - 1], y[b + 1], y[b + 2]];
        for (k, v) in y.iter_mut().enumerate().take(b + 1).skip(a) {
            let x = k as f64;
            *v = (0..4)
                .map(|i| {
                    let w: f64 = (0..4).filter(|&j| j != i).map(|j| (x - xs[j]) / (xs[i] - xs[j])).product();
                    w * ys[i]
                })
                .sum();
        }
    }
    Some(at.len())
}

/// Isolated spikes of `y` the importer repaired.
#[derive(Clone, Debug, PartialEq)]
pub struct SpikeNote {
    /// How many samples were replaced.
    pub count: usize,
    /// The smallest and the largest departure from their replacement (µm).
    pub departure_um: [f64; 2],
    /// The time of the first (s, the record's axis).
    pub first_s: f64,
}

impl SpikeNote {
    /// One clause: "y: 15 isolated spikes (20.3 to 59.6 µm off their neighbours, the first
    /// at 1.234 s) replaced …".
    pub fn describe(&self) -> String {
        format!(
            "y: {} isolated spike{} ({:.3} to {:.3} µm off {} neighbours, the first at {} s) replaced by the cubic through \
             {} neighbours (a sensor's dropouts, not the actuator; --keep-spikes keeps them)",
            self.count,
            if self.count == 1 { "" } else { "s" },
            self.departure_um[0],
            self.departure_um[1],
            if self.count == 1 { "its" } else { "their" },
            {
                let t = format!("{:.6}", self.first_s);
                t.trim_end_matches('0').trim_end_matches('.').to_string()
            },
            if self.count == 1 { "its" } else { "their" },
        )
    }
}

impl ImportInfo {
    /// One line: "comma-separated with a header; t = time, u = Voltage (mV), y = disp (mm)".
    pub fn describe(&self) -> String {
        let cols: Vec<String> = self
            .columns
            .iter()
            .map(|(role, from)| {
                let unit = match *role {
                    "t" if self.t_unit != TimeUnit::S => format!(" in {}", self.t_unit.name()),
                    "u" if self.u_unit != VoltUnit::V => format!(" in {}", self.u_unit.name()),
                    "y" | "d" if self.y_unit != LengthUnit::Um => format!(" in {}", self.y_unit.name()),
                    _ => String::new(),
                };
                format!("{role} = {from}{unit}")
            })
            .collect();
        let time = match &self.time {
            TimeSource::Column(_) => String::new(),
            TimeSource::SampleRate(hz) => {
                format!("; times from --sample-rate {} Hz", super::for_people(*hz))
            }
        };
        let spikes = self.spikes.as_ref().map_or(String::new(), |s| format!("; {}", s.describe()));
        let preamble = self.preamble.map_or(String::new(), |p| {
            format!(
                " from line {} ({} line{} before it skipped: they belong to no table)",
                p.table_line,
                p.lines,
                if p.lines == 1 { "" } else { "s" }
            )
        });
        let missing = self.missing.map_or(String::new(), |m| {
            let t = format!("{:.6}", m.first_s);
            format!(
                "; y: {} missing sample{} (NaN or empty, the first at {} s) filled by the cubic through {} neighbours",
                m.count,
                if m.count == 1 { "" } else { "s" },
                t.trim_end_matches('0').trim_end_matches('.'),
                if m.count == 1 { "its" } else { "their" }
            )
        });
        let cut = self
            .cut_short
            .map_or(String::new(), |line| format!("; line {line} left out: the file stops inside it"));
        format!(
            "{}-separated{}, {}{preamble}; {}{time}{cut}{missing}{spikes}",
            self.separator.name(),
            if self.decimal_comma { " with decimal commas" } else { "" },
            if self.header { "with a header" } else { "no header" },
            cols.join(", ")
        )
    }
}

/// A record and how it was read.
#[derive(Clone, Debug, PartialEq)]
pub struct Imported {
    /// The record (t in s, u in V, y and d in µm).
    pub record: Record,
    /// How it was read.
    pub info: ImportInfo,
}

/// Reads a record file as it comes (see the module docs of [`crate::record`]). The file is
/// read line by line, never whole: what stays in memory is the record (and, while reading,
/// the times of a time column and the unit of their last digits).
pub fn import(path: impl AsRef<Path>, opts: &ImportOptions) -> Result<Imported, RecordError> {
    let path = path.as_ref();
    let source = path.display().to_string();
    let io = |e| RecordError::new(&source, None, ErrorKind::Io(e));
    let file = std::fs::File::open(path).map_err(io)?;
    let bytes = file.metadata().map_err(io)?.len();
    import_from(std::io::BufReader::with_capacity(1 << 16, file), bytes, &source, opts)
}

impl Record {
    /// Reads a record file with the default [`ImportOptions`] (see the module docs).
    pub fn read(path: impl AsRef<Path>) -> Result<Self, RecordError> {
        import(path, &ImportOptions::default()).map(|i| i.record)
    }

    /// Parses record text with the default [`ImportOptions`]; `source` names it in errors
    /// (usually the file name).
    pub fn parse(text: &str, source: &str) -> Result<Self, RecordError> {
        import_text(text, source, &ImportOptions::default()).map(|i| i.record)
    }
}

/// Splits a line into its fields, trimmed, each stripped of one pair of surrounding double
/// quotes; a separator between quotes belongs to the field (`"Time, s",Voltage`). Runs of
/// whitespace are one separator.
fn fields(line: &str, sep: Separator) -> Vec<&str> {
    let is_sep = |c: char| match sep {
        Separator::Comma => c == ',',
        Separator::Tab => c == '\t',
        Separator::Semicolon => c == ';',
        Separator::Whitespace => c.is_whitespace(),
    };
    let mut out = Vec::new();
    let (mut start, mut quoted) = (0, false);
    for (i, c) in line.char_indices() {
        if c == '"' {
            quoted = !quoted;
        } else if !quoted && is_sep(c) {
            out.push(&line[start..i]);
            start = i + c.len_utf8();
        }
    }
    out.push(&line[start..]);
    if sep == Separator::Whitespace {
        out.retain(|f| !f.trim().is_empty());
    }
    out.into_iter().map(unquote).collect()
}

/// `" \"Time (s)\" "` → `Time (s)`: trimmed, one pair of surrounding quotes removed.
fn unquote(field: &str) -> &str {
    let f = field.trim();
    match f.strip_prefix('"').and_then(|f| f.strip_suffix('"')) {
        Some(inner) => inner.trim(),
        None => f,
    }
}

/// The separator of one line: a tab, else a semicolon (never part of a number, while a comma
/// may be a decimal comma), else a comma (unless the line is numbers with decimal commas
/// between spaces), else runs of spaces. Quoted text does not count.
fn separator_of(line: &str) -> Separator {
    let mut quoted = false;
    let (mut tab, mut semicolon, mut comma) = (false, false, false);
    for c in line.chars() {
        match c {
            '"' => quoted = !quoted,
            '\t' if !quoted => tab = true,
            ';' if !quoted => semicolon = true,
            ',' if !quoted => comma = true,
            _ => {}
        }
    }
    // Numbers with decimal commas between spaces: `0,001  0,25  12,5`.
    let spaced_commas = || {
        let f: Vec<&str> = line.split_whitespace().collect();
        f.len() >= 2 && f.iter().all(|x| number(x, true).is_some()) && f.iter().any(|x| has_decimal_comma(x))
    };
    if tab {
        Separator::Tab
    } else if semicolon {
        Separator::Semicolon
    } else if comma && !spaced_commas() {
        Separator::Comma
    } else {
        Separator::Whitespace
    }
}

/// A field as a number: Rust's `f64` syntax, or with `decimal_comma` one comma standing for
/// the point (`-0,25`, `1,5e-3`).
fn number(field: &str, decimal_comma: bool) -> Option<f64> {
    if decimal_comma && field.contains(',') {
        if field.contains('.') || field.matches(',').count() > 1 {
            return None;
        }
        return field.replacen(',', ".", 1).parse().ok();
    }
    field.parse().ok()
}

/// Whether a field is written with a decimal comma (`0,25`, `-12,5e-3`): digits on both
/// sides of one comma, no point.
fn has_decimal_comma(field: &str) -> bool {
    let Some((int, frac)) = field.split_once(',') else { return false };
    let int = int.trim_start_matches(['+', '-']);
    !field.contains('.')
        && !frac.contains(',')
        && !int.is_empty()
        && int.bytes().all(|b| b.is_ascii_digit())
        && frac.bytes().next().is_some_and(|b| b.is_ascii_digit())
        && frac.parse::<f64>().is_ok()
}

/// Lines (neither blank nor comments) the layout is found in: a preamble and the table's
/// first rows are among them.
const LAYOUT_LINES: usize = 4096;

/// Consecutive numeric rows that make a table: the first line of such a run starts the data.
const TABLE_RUN: usize = 3;

/// Where the table starts in the lines that are neither blank nor comments, found before
/// anything is read.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Layout {
    /// The index (into those lines) of the header, or of the first row without one.
    start: usize,
    /// The table's separator.
    sep: Separator,
    /// Whether numbers are written with a decimal comma (a separator other than the comma);
    /// `None` if no number with a fraction was among the lines looked at.
    decimal_comma: Option<bool>,
}

/// The table's layout: the separator, the decimal comma, and the lines before the header
/// that belong to no table (an instrument's preamble: `LabVIEW Measurement`,
/// `Date<TAB>2024/05/01`, …).
///
/// The data start at the first run of [`TABLE_RUN`] rows (fewer at the end of the file)
/// that are all numbers, at least two per row, as many per row, under the separator of the
/// run's first row. The line just before it is the header if it has as many fields (or
/// more). Lines before the header are a preamble only if the first line does not have the
/// table's shape itself, the run is whole, and none of them is a row of numbers: a malformed
/// row after a normal header is an error at that row, never a reason to skip lines.
fn layout(lines: &[(usize, &str)]) -> Layout {
    // While looking for the run a comma inside a field may be a decimal one; which it is
    // comes from the first number written with a fraction.
    let lenient = |sep: Separator| sep != Separator::Comma;
    let used = |f: &[&str]| f.iter().rposition(|x| !x.is_empty()).map_or(0, |i| i + 1);
    let row_width = |line: &str, sep: Separator| -> Option<usize> {
        let f = fields(line, sep);
        let n = used(&f);
        (n >= 2 && f[..n].iter().all(|x| number(x, lenient(sep)).is_some())).then_some(n)
    };
    let width_of = |line: &str, sep: Separator| used(&fields(line, sep));
    let with_comma = |from: &[(usize, &str)], sep: Separator| {
        if sep == Separator::Comma {
            return Some(false);
        }
        from.iter()
            .flat_map(|(_, l)| fields(l, sep))
            .find(|f| f.contains(['.', ',']) && number(f, true).is_some())
            .map(has_decimal_comma)
    };
    let first_sep = separator_of(lines[0].1);
    let plain = |sep: Separator| Layout { start: 0, sep, decimal_comma: with_comma(lines, sep) };
    for i in 0..lines.len() {
        let sep = separator_of(lines[i].1);
        let Some(w) = row_width(lines[i].1, sep) else { continue };
        let run = &lines[i..lines.len().min(i + TABLE_RUN)];
        if !run.iter().all(|(_, l)| row_width(l, sep) == Some(w)) {
            continue;
        }
        if i <= 1 || width_of(lines[0].1, sep) == w {
            // The first line is the header or the first row: no preamble.
            return plain(sep);
        }
        if run.len() < TABLE_RUN || lines[..i].iter().any(|(_, l)| row_width(l, separator_of(l)).is_some()) {
            // A short table, or a row of numbers before the run: not a preamble; read it
            // all (and fail where a row is malformed).
            return plain(first_sep);
        }
        // The header names the rows' fields, and perhaps more (`X_Value<TAB>Voltage<TAB>
        // Displacement<TAB>Comment` over rows of three numbers).
        let start = if width_of(lines[i - 1].1, sep) >= w { i - 1 } else { i };
        return Layout { start, sep, decimal_comma: with_comma(&lines[i..], sep) };
    }
    plain(first_sep)
}

fn is_comment(line: &str) -> bool {
    line.starts_with('#') || line.starts_with('%')
}

/// The role a header name stands for, and a unit it states (`disp_mm`, `Voltage (V)`,
/// `time [ms]`): (role, volts-or-micrometres-or-seconds per unit, whether the name itself
/// is the role's). A name of several words (`Piezo Voltage`, `Measured Position`) takes the
/// role its words name if they name only one, behind a column named exactly; a name that is
/// only a unit (`V`, `um`, `ms`) takes the role of that unit's quantity.
fn recognise(name: &str) -> (Option<Col>, Option<f64>, bool) {
    let lower = name.trim().to_lowercase();
    let (base, unit) = split_unit(&lower);
    let exact = role_of(base).is_some();
    let role = role_of(base).or_else(|| {
        let mut roles = base.split([' ', '_', '-', '.']).filter_map(role_of);
        let first = roles.next()?;
        roles.all(|r| r == first).then_some(first)
    });
    let (role, unit) = match (role, unit) {
        (Some(r), u) => (Some(r), u),
        (None, None) if TIME_UNITS.contains(&base) => (Some(Col::T), Some(base)),
        (None, None) if base.parse::<LengthUnit>().is_ok() && base != "m" => (Some(Col::Y), Some(base)),
        (None, None) if base.parse::<VoltUnit>().is_ok() => (Some(Col::U), Some(base)),
        _ => (None, unit),
    };
    let exact = exact || (role.is_some() && unit == Some(base));
    let scale = role.zip(unit).and_then(|(r, u)| unit_scale(r, u));
    (role, scale, exact)
}

/// The unit a header name states for the role `col` it was given for with `--columns`,
/// whatever the name (`Zeit [ms]` for `t`, `Spannung (mV)` for `u`; a name that is only a
/// unit, `ms`): seconds, volts or micrometres per unit. `None` if it states none of that
/// role's units.
fn stated_scale(name: &str, col: Col) -> Option<f64> {
    let lower = name.trim().to_lowercase();
    let (base, unit) = split_unit(&lower);
    // "m" alone names a column more often than it states metres.
    unit.or((base != "m").then_some(base)).and_then(|u| unit_scale(col, u))
}

/// Seconds, volts or micrometres per `unit` for the role `col` (`None`: not one of its
/// units).
fn unit_scale(col: Col, unit: &str) -> Option<f64> {
    match col {
        Col::T => match unit {
            "s" => Some(1.0),
            "ms" => Some(1e-3),
            "us" | "µs" | "μs" => Some(1e-6),
            _ => None,
        },
        Col::U => unit.parse::<VoltUnit>().ok().map(VoltUnit::volts),
        Col::Y | Col::D => unit.parse::<LengthUnit>().ok().map(LengthUnit::micrometres),
    }
}

/// Units of a time column.
const TIME_UNITS: [&str; 5] = ["s", "ms", "us", "µs", "μs"];

/// The role one word of a header names.
fn role_of(word: &str) -> Option<Col> {
    match word {
        "t" | "time" | "times" | "timestamp" | "sec" | "seconds" | "x_value" => Some(Col::T),
        "u" | "v" | "volt" | "volts" | "voltage" | "input" | "drive" | "command" | "cmd" | "vin"
        | "excitation" => Some(Col::U),
        "y" | "disp" | "displacement" | "position" | "pos" | "deflection" | "output" | "out" | "stroke"
        | "sensor" | "laser" | "lvdt" => Some(Col::Y),
        "d" | "ref" | "reference" | "target" | "setpoint" | "desired" => Some(Col::D),
        _ => None,
    }
}

/// Whether a header name is a sample counter (`index`, `Sample No.`, `k`), which carries no
/// signal.
fn is_index(name: &str) -> bool {
    let lower = name.trim().to_lowercase();
    let words: Vec<&str> = lower.split([' ', '_', '-', '.']).filter(|w| !w.is_empty()).collect();
    match words.as_slice() {
        [w] => {
            ["index", "idx", "i", "k", "n", "no", "nr", "sample", "samples", "point", "points"].contains(w)
        }
        [a, b] => ["sample", "point"].contains(a) && ["no", "nr", "number", "index", "#"].contains(b),
        _ => false,
    }
}

/// `"disp (mm)"` → `("disp", Some("mm"))`, `"time_s"` → `("time", Some("s"))`, `"voltage, mv"`
/// → `("voltage", Some("mv"))`, `"y"` → `("y", None)`.
fn split_unit(name: &str) -> (&str, Option<&str>) {
    const UNITS: [&str; 14] =
        ["s", "ms", "us", "µs", "μs", "v", "mv", "kv", "m", "mm", "um", "µm", "μm", "nm"];
    if let Some(open) = name.rfind(['(', '[']) {
        if name.ends_with([')', ']']) && open + 1 < name.len() - 1 {
            let unit = name[open + 1..name.len() - 1].trim();
            return (name[..open].trim_end_matches([' ', '_', '/']), Some(unit));
        }
    }
    if let Some(cut) = name.rfind(['_', ' ', '/']) {
        let unit = &name[cut + 1..];
        if UNITS.contains(&unit) && cut > 0 {
            return (name[..cut].trim_end_matches([' ', ',']), Some(unit));
        }
    }
    (name, None)
}

/// Most columns a message lists.
const LISTED_COLUMNS: usize = 8;

/// The columns found, for messages: `time, Voltage, disp` or `1, 2, 3`; at most
/// [`LISTED_COLUMNS`] of them, then how many there are.
fn found_list(names: Option<&[String]>, count: usize) -> String {
    let mut list: Vec<String> = match names {
        Some(names) => names
            .iter()
            .take(LISTED_COLUMNS)
            .enumerate()
            .map(|(i, n)| if n.is_empty() { format!("{} (unnamed)", i + 1) } else { excerpt_n(n, 16) })
            .collect(),
        None => (1..=count.min(LISTED_COLUMNS)).map(|i| i.to_string()).collect(),
    };
    if count > LISTED_COLUMNS {
        list.push(format!("… {count} in all"));
    }
    list.join(", ")
}

/// The unit that brings an output span (µm, as read) between [`MIN_SPAN_UM`] and
/// [`MAX_SPAN_UM`], nearest the middle of that range on a log scale, if one does.
pub(crate) fn likely_unit(span_as_read: f64, read_in: LengthUnit) -> Option<LengthUnit> {
    let raw = span_as_read / read_in.micrometres();
    let mid = (MIN_SPAN_UM * MAX_SPAN_UM).sqrt().ln();
    LengthUnit::ALL
        .into_iter()
        .filter(|&u| u != read_in)
        .map(|u| (u, raw * u.micrometres()))
        .filter(|&(_, s)| (MIN_SPAN_UM..=MAX_SPAN_UM).contains(&s))
        .min_by(|a, b| (a.1.ln() - mid).abs().total_cmp(&(b.1.ln() - mid).abs()))
        .map(|(u, _)| u)
}

/// Parses record text as it comes; `source` names it in errors.
///
/// ```
/// use boucwen_lab::record::{ImportOptions, import_text};
/// // No header, whitespace-separated, no time column, the output in metres.
/// let text = "0.0  1.0e-6\n0.5  3.0e-6\n-0.5 -1.0e-6\n";
/// let opts = ImportOptions {
///     columns: Some("u=1,y=2".parse()?),
///     sample_rate_hz: Some(1000.0),
///     y_unit: Some("m".parse()?),
///     ..ImportOptions::default()
/// };
/// let r = import_text(text, "bench.txt", &opts)?.record;
/// assert_eq!(r.y, [1.0, 3.0, -1.0]);
/// assert_eq!(r.ts, 1e-3);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn import_text(text: &str, source: &str, opts: &ImportOptions) -> Result<Imported, RecordError> {
    import_from(text.as_bytes(), text.len() as u64, source, opts)
}

/// The lines of a record's text, numbered from 1, read one at a time into one buffer:
/// trimmed, the byte-order mark skipped, blank lines and comments passed over.
struct LineReader<'s, R> {
    reader: R,
    buf: Vec<u8>,
    line_no: usize,
    source: &'s str,
}

impl<R: std::io::BufRead> LineReader<'_, R> {
    /// The next line that is neither blank nor a comment: its number, its text (trimmed),
    /// and whether a line end follows it (only a file's last line may lack one; a `\r`
    /// counts). `None` at the end.
    fn next_content(&mut self) -> Result<Option<(usize, &str, bool)>, RecordError> {
        loop {
            self.buf.clear();
            let read = self
                .reader
                .read_until(b'\n', &mut self.buf)
                .map_err(|e| RecordError::new(self.source, None, ErrorKind::Io(e)))?;
            if read == 0 {
                return Ok(None);
            }
            self.line_no += 1;
            if self.line_no == 1 && self.buf.starts_with("\u{feff}".as_bytes()) {
                self.buf.drain(..3);
            }
            let Ok(text) = std::str::from_utf8(&self.buf) else {
                return Err(RecordError::new(self.source, Some(At::Line(self.line_no)), ErrorKind::NotUtf8));
            };
            let line = text.trim();
            if !line.is_empty() && !is_comment(line) {
                break;
            }
        }
        let ended = matches!(self.buf.last(), Some(b'\n' | b'\r'));
        // (Checked above; borrowed again after the loop.)
        let line = std::str::from_utf8(&self.buf).unwrap_or_default().trim();
        Ok(Some((self.line_no, line, ended)))
    }
}

/// The table's lines: those read ahead (the layout's) first, then the rest as they come.
struct TableLines<'s, R> {
    ahead: std::collections::VecDeque<(usize, String, bool)>,
    current: String,
    rest: LineReader<'s, R>,
}

impl<R: std::io::BufRead> TableLines<'_, R> {
    /// The next line (number, text, whether a line end follows it).
    fn next_line(&mut self) -> Result<Option<(usize, &str, bool)>, RecordError> {
        match self.ahead.pop_front() {
            Some((no, text, ended)) => {
                self.current = text;
                Ok(Some((no, &self.current, ended)))
            }
            None => self.rest.next_content(),
        }
    }
}

/// The sample rows' line numbers: the first row's, and each row whose line does not follow
/// the previous row's (comments or blank lines between them), so a file of rows on
/// consecutive lines costs nothing per row.
#[derive(Default)]
struct LineMap(Vec<(usize, usize)>);

impl LineMap {
    fn push(&mut self, sample: usize, line: usize) {
        let follows = self.0.last().is_some_and(|&(k, l)| l + (sample - k) == line);
        if !follows {
            self.0.push((sample, line));
        }
    }
    fn line(&self, sample: usize) -> usize {
        let i = self.0.partition_point(|&(k, _)| k <= sample);
        self.0.get(i.wrapping_sub(1)).map_or(0, |&(k, l)| l + (sample - k))
    }
}

/// [`import_text`] on a reader of `bytes` bytes (an estimate, for the storage reserved).
fn import_from(
    reader: impl std::io::BufRead,
    bytes: u64,
    source: &str,
    opts: &ImportOptions,
) -> Result<Imported, RecordError> {
    let err = |line: usize, kind| RecordError::new(source, Some(At::Line(line)), kind);
    let whole = |kind| RecordError::new(source, None, kind);
    let mut rest = LineReader { reader, buf: Vec::new(), line_no: 0, source };
    // The layout from the first lines (a preamble is a few dozen), the rest read as it comes.
    let mut read_ahead: Vec<(usize, String, bool)> = Vec::new();
    while read_ahead.len() < LAYOUT_LINES {
        match rest.next_content()? {
            Some((no, text, ended)) => read_ahead.push((no, text.to_string(), ended)),
            None => break,
        }
    }
    if read_ahead.is_empty() {
        return Err(whole(ErrorKind::Empty));
    }
    let head: Vec<(usize, &str)> = read_ahead.iter().map(|(no, t, _)| (*no, t.as_str())).collect();
    let Layout { start, sep, decimal_comma } = layout(&head);
    // Without a fraction among those lines, a comma under another separator is a decimal one.
    let dc = decimal_comma.unwrap_or(sep != Separator::Comma);
    let mut saw_comma = false;
    let preamble = (start > 0).then(|| Preamble { lines: start, table_line: head[start].0 });
    // The rows read ahead, for the checks that look at more than one row.
    let head_rows: Vec<(usize, &str)> = head[start..].to_vec();
    let (first_line, first) = head_rows[0];
    let first_fields = fields(first, sep);
    let header = first_fields.iter().any(|f| !f.is_empty() && number(f, dc).is_none());
    let mut names: Option<Vec<String>> = header.then(|| first_fields.iter().map(|s| s.to_string()).collect());
    let mut width = first_fields.len();
    let rows_ahead = &head_rows[usize::from(header)..];
    if header {
        // A header may name trailing columns that no row has (an instrument's `Comment`
        // over rows of numbers only): they are left out if they name no signal.
        if let (Some(n), Some((_, row))) = (names.as_mut(), rows_ahead.first()) {
            let row_width = fields(row, sep).len();
            if row_width < width && n[row_width..].iter().all(|x| recognise(x).0.is_none()) {
                n.truncate(row_width);
                width = row_width;
            }
        }
    }
    let found = || found_list(names.as_deref(), width);

    // Which column is which, and the units the header states.
    let mut slot: [Option<usize>; 4] = [None; 4];
    let mut scale_from_header: [Option<f64>; 4] = [None; 4];
    let roles = [Col::T, Col::U, Col::Y, Col::D];
    let recognised: Vec<(Option<Col>, Option<f64>, bool)> =
        names.as_ref().map_or_else(Vec::new, |n| n.iter().map(|s| recognise(s)).collect());
    let given = opts.columns.clone().unwrap_or_default();
    // Named columns that are none of the record's (without --columns): refused if a row fills
    // them.
    let mut unnamed_roles: Vec<usize> = Vec::new();
    for (r, &col) in roles.iter().enumerate() {
        let Some(want) = given.get(col) else { continue };
        let idx = match want {
            ColumnRef::Index(i) if *i <= width => i - 1,
            ColumnRef::Index(_) => {
                return Err(err(
                    first_line,
                    ErrorKind::ColumnNotFound { role: col.name(), given: want.to_string(), found: found() },
                ));
            }
            ColumnRef::Name(name) => {
                let lname = name.to_lowercase();
                let matches: Vec<usize> = names
                    .iter()
                    .flatten()
                    .enumerate()
                    .filter(|(_, n)| n.to_lowercase() == lname)
                    .map(|(i, _)| i)
                    .collect();
                match matches.as_slice() {
                    [i] => *i,
                    [] => {
                        return Err(err(
                            first_line,
                            ErrorKind::ColumnNotFound {
                                role: col.name(),
                                given: excerpt(name),
                                found: found(),
                            },
                        ));
                    }
                    _ => {
                        return Err(err(
                            first_line,
                            ErrorKind::AmbiguousColumn { role: col.name(), found: found() },
                        ));
                    }
                }
            }
        };
        if let Some(r2) = slot.iter().position(|s| *s == Some(idx)) {
            let kind = ErrorKind::DuplicateColumn(format!(
                "{} (given for {} and {})",
                idx + 1,
                roles[r2].name(),
                col.name()
            ));
            return Err(err(first_line, kind));
        }
        slot[r] = Some(idx);
        // The unit is the header's whatever picks the column: a name --columns gives for a
        // role may be one the importer does not know (`Zeit [ms]`), its unit still holds.
        scale_from_header[r] = names.as_ref().and_then(|n| stated_scale(&n[idx], col));
    }
    if header {
        // Roles not given are found by their names.
        for (r, &col) in roles.iter().enumerate() {
            if slot[r].is_some() {
                continue;
            }
            let hits_by = |exact: bool| -> Vec<usize> {
                recognised
                    .iter()
                    .enumerate()
                    .filter(|(i, (c, _, e))| *c == Some(col) && *e == exact && !slot.contains(&Some(*i)))
                    .map(|(i, _)| i)
                    .collect()
            };
            // A column named exactly for the role comes before one whose words name it.
            let hits = match hits_by(true) {
                exact if !exact.is_empty() => exact,
                _ => hits_by(false),
            };
            match hits.as_slice() {
                [] => {}
                [i] => {
                    slot[r] = Some(*i);
                    scale_from_header[r] = recognised[*i].1;
                }
                _ => {
                    return Err(err(
                        first_line,
                        ErrorKind::AmbiguousColumn { role: col.name(), found: found() },
                    ));
                }
            }
        }
        if opts.columns.is_none() {
            // Without --columns every named column must be one of the record's: a typo must
            // not silently drop a signal. A column empty on every row (an instrument's
            // `Comment`) carries none.
            // Checked on the rows read ahead now, on the others as they are read.
            let names = names.as_deref().unwrap_or_default();
            unnamed_roles = (0..width)
                .filter(|&i| !names[i].is_empty() && !slot.contains(&Some(i)) && !is_index(&names[i]))
                .collect();
            let filled = |i: usize, l: &str| fields(l, sep).get(i).is_some_and(|f| !f.is_empty());
            if let Some(&i) = unnamed_roles.iter().find(|&&i| rows_ahead.iter().any(|(_, l)| filled(i, l))) {
                let kind = ErrorKind::UnknownColumn { name: excerpt(&names[i]), found: found() };
                return Err(err(first_line, kind));
            }
        }
    } else if opts.columns.is_none() {
        return Err(err(first_line, ErrorKind::MissingHeader { fields: width }));
    }
    for (r, col) in [(1, Col::U), (2, Col::Y)] {
        if slot[r].is_none() {
            return Err(err(first_line, ErrorKind::MissingColumn { role: col.name(), found: found() }));
        }
    }
    let time_col = slot[0];
    if time_col.is_none() && opts.sample_rate_hz.is_none() {
        return Err(err(first_line, ErrorKind::NoTime { found: found() }));
    }
    if let (Some(_), Some(_), Some(_)) = (given.t.as_ref(), opts.sample_rate_hz, time_col) {
        return Err(whole(ErrorKind::TimeTwice));
    }
    let u_scale = opts.u_unit.map(VoltUnit::volts).or(scale_from_header[1]).unwrap_or(1.0);
    let y_scale = opts.y_unit.map(LengthUnit::micrometres).or(scale_from_header[2]).unwrap_or(1.0);
    let t_stated = opts.t_unit.map(TimeUnit::seconds).or(scale_from_header[0]);
    let t_scale = t_stated.unwrap_or(1.0);
    let time_unit = [TimeUnit::S, TimeUnit::Ms, TimeUnit::Us]
        .into_iter()
        .find(|u| u.seconds() == t_scale)
        .unwrap_or(TimeUnit::S);
    let u_unit = [VoltUnit::V, VoltUnit::MilliV, VoltUnit::KiloV]
        .into_iter()
        .find(|u| u.volts() == u_scale)
        .unwrap_or(VoltUnit::V);
    let y_unit = LengthUnit::ALL.into_iter().find(|u| u.micrometres() == y_scale).unwrap_or(LengthUnit::Um);

    // The columns to read, in file order.
    let mut wanted: Vec<(usize, Col, f64)> = roles
        .iter()
        .zip(slot)
        .filter_map(|(&col, s)| {
            let scale = match col {
                Col::T => t_scale,
                Col::U => u_scale,
                Col::Y | Col::D => y_scale,
            };
            s.map(|i| (i, col, scale))
        })
        .collect();
    wanted.sort_by_key(|w| w.0);
    let has_d = slot[3].is_some();

    // Rows. The storage is reserved for the rows the file's size suggests (at the length of
    // the rows read ahead).
    let row_bytes = rows_ahead.iter().map(|(_, l)| l.len() + 1).sum::<usize>().max(1) as f64
        / rows_ahead.len().max(1) as f64;
    let rows_hint = ((bytes as f64 / row_bytes) * 1.02) as usize + 16;
    let mut t = Vec::with_capacity(if time_col.is_some() { rows_hint } else { 0 });
    // The unit of each time's last digit, as its power of ten (`t_scale` applies to all).
    let mut t_digit: Vec<i16> = Vec::with_capacity(t.capacity());
    let mut line_of = LineMap::default();
    let mut u = Vec::with_capacity(rows_hint);
    let mut y = Vec::with_capacity(rows_hint);
    let mut d = Vec::with_capacity(if has_d { rows_hint } else { 0 });
    let mut cut_short = None;
    // Samples of y the file leaves missing, and the first one's line and text.
    let mut missing: Vec<usize> = Vec::new();
    let mut first_missing: Option<(usize, String)> = None;
    let unknown = |i: usize| -> RecordError {
        let names = names.as_deref().unwrap_or_default();
        err(
            first_line,
            ErrorKind::UnknownColumn { name: excerpt(&names[i]), found: found_list(Some(names), width) },
        )
    };
    let mut lines = TableLines {
        ahead: read_ahead.into_iter().skip(start + usize::from(header)).collect(),
        current: String::new(),
        rest,
    };
    while let Some((line_no, line, ended)) = lines.next_line()? {
        let f = fields(line, sep);
        // A trailing separator on data rows only is tolerated.
        let n_fields =
            if f.len() > width && f[width..].iter().all(|x| x.is_empty()) { width } else { f.len() };
        if n_fields != width {
            if n_fields < width && !ended {
                // The file stops inside its last row (a logger stopped mid-write).
                cut_short = Some(line_no);
                break;
            }
            return Err(err(line_no, ErrorKind::FieldCount { expected: width, found: f.len() }));
        }
        if let Some(&i) = unnamed_roles.iter().find(|&&i| !f[i].is_empty()) {
            return Err(unknown(i));
        }
        for &(i, col, scale) in &wanted {
            let field = f[i];
            if col == Col::Y && (field.is_empty() || field.eq_ignore_ascii_case("nan")) {
                // A sensor's missing sample: filled below if it is one of a few.
                missing.push(y.len());
                if first_missing.is_none() {
                    first_missing = Some((line_no, excerpt(field)));
                }
                y.push(f64::NAN);
                continue;
            }
            saw_comma |= dc && field.contains(',');
            let raw: f64 = number(field, dc).ok_or_else(|| {
                err(line_no, ErrorKind::NotANumber { column: col.name().into(), text: excerpt(field) })
            })?;
            if !raw.is_finite() {
                return Err(err(
                    line_no,
                    ErrorKind::NotFinite { column: col.name().into(), text: excerpt(field) },
                ));
            }
            let mut v = raw * scale;
            // Subnormal values are zero in any physical unit, and slow every later step.
            if v != 0.0 && v.abs() < f64::MIN_POSITIVE {
                v = 0.0;
            }
            super::check_value(col, v, field).map_err(|kind| err(line_no, kind))?;
            match col {
                Col::T => {
                    if let Some(&previous) = t.last() {
                        if v <= previous {
                            return Err(err(line_no, ErrorKind::TimeNotIncreasing { previous, t: v }));
                        }
                    }
                    t.push(v);
                    t_digit.push(last_digit_exp(field, dc));
                }
                Col::U => u.push(v),
                Col::Y => y.push(v),
                Col::D => d.push(v),
            }
        }
        line_of.push(u.len() - 1, line_no);
    }
    let n = u.len();
    if n < MIN_SAMPLES {
        return Err(whole(ErrorKind::TooFewSamples { found: n, needed: MIN_SAMPLES }));
    }
    let filled = if missing.is_empty() {
        None
    } else if let Some(count) = fill_missing(&mut y, missing.iter().copied()) {
        Some(count)
    } else {
        let (line_no, text) = first_missing.unwrap_or_default();
        let kind = if text.is_empty() {
            ErrorKind::NotANumber { column: "y".into(), text }
        } else {
            ErrorKind::NotFinite { column: "y".into(), text }
        };
        return Err(err(line_no, kind));
    };
    let t_unit = |k: usize| 10f64.powi(i32::from(t_digit[k])) * t_scale;
    let (t0, ts, time) = match time_col {
        Some(i) => {
            // The median step, without a copy of the steps.
            let median = super::select::nth(n - 1, (n - 1) / 2, |k| t[k + 1] - t[k]);
            for k in 1..n {
                let dt = t[k] - t[k - 1];
                let written = (0.5 * (t_unit(k) + t_unit(k - 1))).min(0.5 * median);
                let roundoff = 4.0 * f64::EPSILON * (t[k].abs() + t[k - 1].abs());
                let tolerance = UNIFORM_TOLERANCE * median + written + roundoff;
                if (dt - median).abs() > tolerance {
                    return Err(err(line_of.line(k), ErrorKind::NonUniform { dt, median, tolerance }));
                }
            }
            // The ends as written are each off by half their last digit's unit (and by f64's
            // rounding at their magnitude), shared over N − 1 steps: the plainest decimal
            // within that is the interval (a Unix-time axis of a 1 kHz record reads 0.001 s,
            // not 0.0010000000181).
            let spread =
                0.5 * (t_unit(0) + t_unit(n - 1)) + 4.0 * f64::EPSILON * (t[0].abs() + t[n - 1].abs());
            let ts = plainest((t[n - 1] - t[0]) / (n - 1) as f64, spread / (n - 1) as f64);
            let name = names.as_ref().map_or_else(|| (i + 1).to_string(), |n| excerpt(&n[i]));
            if t_stated.is_none() && ts >= 1.0 && (0..n).all(|k| t_unit(k) >= 1.0) {
                return Err(whole(ErrorKind::TimeUnitUnstated { column: name, step: ts }));
            }
            if let Some(hz) = opts.sample_rate_hz {
                if (hz * ts - 1.0).abs() > UNIFORM_TOLERANCE {
                    return Err(whole(ErrorKind::RateMismatch { from_time_hz: 1.0 / ts, given_hz: hz }));
                }
            }
            (t[0], ts, TimeSource::Column(name))
        }
        None => {
            let hz = opts.sample_rate_hz.unwrap_or(f64::NAN);
            (0.0, 1.0 / hz, TimeSource::SampleRate(hz))
        }
    };
    // The times are the interval now.
    drop((t, t_digit, line_of));
    if !(TS_MIN_S..=TS_MAX_S).contains(&ts) {
        return Err(whole(ErrorKind::SampleInterval(ts)));
    }
    // An output that spans less than a nanometre or more than 10 mm as read is likely in
    // another unit.
    let (lo, hi) = y.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let span = hi - lo;
    if span > 0.0 && !(MIN_SPAN_UM..=MAX_SPAN_UM).contains(&span) {
        let kind = ErrorKind::OutputSpan {
            span_um: span,
            read_in: y_unit.name(),
            likely: likely_unit(span, y_unit).map(LengthUnit::name),
        };
        return Err(whole(kind));
    }
    let columns = roles
        .iter()
        .zip(slot)
        .filter_map(|(col, s)| {
            let i = s?;
            let from = match &names {
                Some(n) if !n[i].is_empty() => format!("{:?}", excerpt(&n[i])),
                _ => format!("column {}", i + 1),
            };
            Some((col.name(), from))
        })
        .collect();

    let missing = filled.map(|count| MissingNote { count, first_s: t0 + missing[0] as f64 * ts });
    let spikes = if opts.keep_spikes { None } else { super::spikes::repair(&mut y) }.map(|s| SpikeNote {
        count: s.indices.len(),
        departure_um: [s.min_departure, s.max_departure],
        first_s: t0 + s.indices[0] as f64 * ts,
    });
    let record = Record { source: source.to_owned(), ts, t0, u, y, d: has_d.then_some(d) };
    Ok(Imported {
        record,
        info: ImportInfo {
            separator: sep,
            decimal_comma: decimal_comma.unwrap_or(saw_comma),
            preamble,
            cut_short,
            missing,
            header,
            columns,
            t_unit: time_unit,
            u_unit,
            y_unit,
            time,
            spikes,
        },
    })
}

/// The decimal with the fewest significant digits within `tolerance` of `x` (`x` itself if
/// none with fewer than 17 is).
fn plainest(x: f64, tolerance: f64) -> f64 {
    (1..17)
        .filter_map(|digits| format!("{x:.*e}", digits - 1).parse::<f64>().ok())
        .find(|r| (r - x).abs() <= tolerance)
        .unwrap_or(x)
}

/// The unit of the last digit of a decimal number as written: `0.0003` → 1e-4,
/// `1.5e-3` → 1e-4, `12` → 1.
#[cfg(test)]
pub(super) fn last_digit_unit(text: &str) -> f64 {
    10f64.powi(i32::from(last_digit_exp(text, false)))
}

/// The power of ten of [`last_digit_unit`] (with `decimal_comma`, a comma is the decimal
/// mark), within ±400 (beyond, the unit is 0 or infinite in `f64` all the same).
fn last_digit_exp(text: &str, decimal_comma: bool) -> i16 {
    let (mantissa, exp) = match text.find(['e', 'E']) {
        Some(i) => (&text[..i], text[i + 1..].parse::<i32>().unwrap_or(0)),
        None => (text, 0),
    };
    let mark = if decimal_comma { mantissa.find(['.', ',']) } else { mantissa.find('.') };
    let decimals = mark.map_or(0, |i| mantissa.len() - i - 1);
    exp.saturating_sub(decimals.min(400) as i32).clamp(-400, 400) as i16
}

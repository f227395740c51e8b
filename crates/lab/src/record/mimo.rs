//! Records with several inputs and outputs under periodic drives: [`MimoRecord`].
//!
//! A MIMO record is a set of amplitude **levels**; each level holds `R` **realisations**
//! (multisines with new random phases) of `P` steady-state **periods** of `N` samples, on
//! `m` input and `p` output channels. The fit and the diagnosis use it as one object:
//! periods are averaged (their spread is the noise), realisations are kept apart (their
//! spread is the nonlinear distortion, and a realisation left out validates a model).
//!
//! ## Sources
//! - **A folder of NumPy files** ([`MimoRecord::read_npy_folder`]): `u_TAG.npy` with
//!   `y_TAG.npy` (or members `u_TAG`, `y_TAG` of `.npz` archives in the folder), one level per
//!   `TAG`, e.g. `u_100mV_train.npy`. Arrays of shape `(N, channel, R, P)` as the Fine Steering
//!   Mirror benchmark ships them, or `(N, channel, R)` (`P = 1`) or `(N, channel)`. The level's
//!   amplitude is the number and unit the tag starts with (`100mV` → 0.1 V); levels are sorted by
//!   it. The files carry no sample rate and no units: [`MimoOptions`] gives them.
//! - **A CSV table** ([`MimoRecord::read_csv`]): a header `t,u1,u2,u3,y1,y2,y3` (a time
//!   column named `t` or `time`, inputs `u1..`, outputs `y1..`, in any order), separated by
//!   commas, semicolons, tabs or spaces; one level, one realisation, the rows cut into
//!   [`MimoOptions::period_samples`] periods (the whole table is one period without it).
//!
//! Inputs are kept in V and outputs in µm, whatever the files' units.

use super::import::{ColumnRef, LengthUnit, VoltUnit};
use super::npy::{self, NpyArray, NpyError};
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

/// Most samples in one MIMO record (all levels, channels, realisations and periods): 2³⁰.
pub const MAX_TOTAL_SAMPLES: usize = 1 << 30;

/// What the files of a MIMO record do not say themselves.
#[derive(Clone, Debug, PartialEq)]
pub struct MimoOptions {
    /// Sample rate, Hz (a CSV's time column overrides it; it must then agree within 1 %).
    pub sample_rate_hz: Option<f64>,
    /// Unit of the input files.
    pub u_unit: VoltUnit,
    /// Unit of the output files.
    pub y_unit: LengthUnit,
    /// `y_unit` was not given: when the outputs as read in it span less than
    /// [`super::MIN_SPAN_UM`] or more than [`super::MAX_SPAN_UM`] (the importer's plausible
    /// displacements), they are read in the unit that brings them in, and
    /// [`MimoRecord::notes`] says so (NumPy files carry no unit).
    pub infer_y_unit: bool,
    /// Samples per period of a CSV table (`None`: the whole table is one period).
    pub period_samples: Option<usize>,
    /// Only levels whose tag contains this text (e.g. `"train"`).
    pub only: Option<String>,
    /// Which CSV columns are the time, the inputs and the outputs (`None`: the header's
    /// names `t`, `u1..`, `y1..`).
    pub columns: Option<MimoColumns>,
}

/// `--columns t=NAME|N,u=NAME|N,NAME|N,…,y=NAME|N,…`: the CSV columns of a record with
/// several inputs and outputs, by header name (case-insensitive) or position (from 1). The
/// names after `u=` up to the next `ROLE=` are the inputs, in order; likewise the outputs.
///
/// ```
/// use boucwen_lab::record::mimo::MimoColumns;
/// use boucwen_lab::record::ColumnRef;
/// let c: MimoColumns = "t=time,u=u1,u2,u3,y=4,5".parse()?;
/// assert_eq!(c.u.len(), 3);
/// assert_eq!(c.y, vec![ColumnRef::Index(4), ColumnRef::Index(5)]);
/// assert!("u=a,b".parse::<MimoColumns>().is_err()); // no output
/// # Ok::<(), String>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MimoColumns {
    /// The time column.
    pub t: Option<ColumnRef>,
    /// The input columns, in order.
    pub u: Vec<ColumnRef>,
    /// The output columns, in order.
    pub y: Vec<ColumnRef>,
}

impl MimoColumns {
    /// Whether the spec names more than one input or output (a one-input one-output spec is
    /// the importer's `--columns`).
    pub fn is_mimo(&self) -> bool {
        self.u.len() > 1 || self.y.len() > 1
    }
}

impl std::str::FromStr for MimoColumns {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = |what: &str| format!("--columns {s:?}: {what}");
        let mut m = MimoColumns::default();
        let mut role: Option<char> = None;
        for part in s.split(',') {
            let (r, col) = match part.split_once('=') {
                Some((r, c)) => {
                    let r = match r.trim().to_ascii_lowercase().as_str() {
                        "t" => 't',
                        "u" => 'u',
                        "y" => 'y',
                        _ => return Err(bad("roles are t, u and y (e.g. t=time,u=u1,u2,y=y1,y2)")),
                    };
                    let taken = match r {
                        't' => m.t.is_some(),
                        'u' => !m.u.is_empty(),
                        _ => !m.y.is_empty(),
                    };
                    if taken {
                        return Err(bad("each role once"));
                    }
                    (r, c.trim())
                }
                None => match role {
                    Some(r @ ('u' | 'y')) => (r, part.trim()),
                    _ => return Err(bad("a list of columns follows u= or y= only")),
                },
            };
            role = Some(r);
            let c = match col.parse::<usize>() {
                Ok(0) => return Err(bad("positions count from 1")),
                Ok(i) => ColumnRef::Index(i),
                Err(_) if col.is_empty() => return Err(bad("an empty column name")),
                Err(_) => ColumnRef::Name(col.to_string()),
            };
            match r {
                't' => m.t = Some(c),
                'u' => m.u.push(c),
                _ => m.y.push(c),
            }
        }
        if m.u.is_empty() || m.y.is_empty() {
            return Err(bad("needs u= and y= columns"));
        }
        Ok(m)
    }
}

impl Default for MimoOptions {
    fn default() -> Self {
        Self {
            sample_rate_hz: None,
            u_unit: VoltUnit::V,
            y_unit: LengthUnit::Um,
            infer_y_unit: false,
            period_samples: None,
            only: None,
            columns: None,
        }
    }
}

impl MimoOptions {
    /// The Fine Steering Mirror benchmark as shipped: 6400 Hz, inputs in V, outputs in m.
    pub fn fine_steering_mirror() -> Self {
        Self { sample_rate_hz: Some(6400.0), y_unit: LengthUnit::M, ..Self::default() }
    }
}

/// Samples of one signal kind (inputs or outputs) of one level: `[r][p][c][k]`, the samples
/// of one channel of one period contiguous.
#[derive(Clone, Debug, PartialEq)]
pub struct Signals {
    /// Channels.
    pub channels: usize,
    /// Realisations `R`.
    pub realisations: usize,
    /// Periods `P` per realisation.
    pub periods: usize,
    /// Samples `N` per period.
    pub samples: usize,
    data: Vec<f64>,
}

impl Signals {
    /// From samples laid out `[r][p][c][k]`; `None` if the length does not match.
    pub fn new(
        channels: usize,
        realisations: usize,
        periods: usize,
        samples: usize,
        data: Vec<f64>,
    ) -> Option<Self> {
        let n = channels.checked_mul(realisations)?.checked_mul(periods)?.checked_mul(samples)?;
        (n == data.len() && n > 0).then_some(Self { channels, realisations, periods, samples, data })
    }

    /// One period of one channel of one realisation (empty out of range).
    pub fn get(&self, r: usize, p: usize, c: usize) -> &[f64] {
        if r >= self.realisations || p >= self.periods || c >= self.channels {
            return &[];
        }
        let at = ((r * self.periods + p) * self.channels + c) * self.samples;
        &self.data[at..at + self.samples]
    }

    /// The mean over periods of one channel of one realisation.
    pub fn mean_period(&self, r: usize, c: usize) -> Vec<f64> {
        let mut m = vec![0.0; self.samples];
        for p in 0..self.periods {
            for (a, b) in m.iter_mut().zip(self.get(r, p, c)) {
                *a += b;
            }
        }
        let w = 1.0 / self.periods.max(1) as f64;
        m.iter_mut().for_each(|a| *a *= w);
        m
    }

    /// The mean period of every channel of realisation `r`, channels-major (`[c][k]`).
    pub fn mean_channels(&self, r: usize) -> Vec<f64> {
        (0..self.channels).flat_map(|c| self.mean_period(r, c)).collect()
    }

    /// All samples, `[r][p][c][k]`.
    pub fn as_slice(&self) -> &[f64] {
        &self.data
    }

    /// Every sample times `k`.
    pub fn scale(&mut self, k: f64) {
        self.data.iter_mut().for_each(|v| *v *= k);
    }

    /// From an array of shape `(N, C, R, P)`, `(N, C, R)` or `(N, C)` in C order, scaled.
    fn from_array(a: &NpyArray, scale: f64) -> Option<Self> {
        let s = &a.shape;
        let (n, c, r, p) = match s.len() {
            2 => (s[0], s[1], 1, 1),
            3 => (s[0], s[1], s[2], 1),
            4 => (s[0], s[1], s[2], s[3]),
            _ => return None,
        };
        let total = n.checked_mul(c)?.checked_mul(r)?.checked_mul(p)?;
        if total != a.data.len() || total == 0 {
            return None;
        }
        let mut data = vec![0.0; total];
        for k in 0..n {
            for ci in 0..c {
                for ri in 0..r {
                    for pi in 0..p {
                        let src = ((k * c + ci) * r + ri) * p + pi;
                        data[((ri * p + pi) * c + ci) * n + k] = a.data[src] * scale;
                    }
                }
            }
        }
        Self::new(c, r, p, n, data)
    }
}

/// One amplitude level: inputs (V) and outputs (µm) of the same realisations and periods.
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    /// The tag the files name it by (`100mV_train`).
    pub tag: String,
    /// The amplitude the tag states, V (`None` when it states none).
    pub amplitude_v: Option<f64>,
    /// Inputs, V.
    pub u: Signals,
    /// Outputs, µm.
    pub y: Signals,
}

/// A record of several inputs and outputs at one or more amplitude levels.
#[derive(Clone, Debug, PartialEq)]
pub struct MimoRecord {
    /// Where it came from.
    pub source: String,
    /// Sample rate, Hz (1 when [`Self::rate_given`] is false: frequencies are then in cycles
    /// per sample).
    pub sample_rate_hz: f64,
    /// Whether the sample rate was given (an option or a time column); NumPy files carry none.
    pub rate_given: bool,
    /// The levels, by rising amplitude.
    pub levels: Vec<Level>,
    /// What the reader decided that the files do not say (a unit, no sample rate).
    pub notes: Vec<String>,
}

/// A MIMO record that cannot be read or built.
#[derive(Debug)]
#[non_exhaustive]
pub enum MimoError {
    /// A NumPy file or archive that cannot be read.
    Npy(NpyError),
    /// A file or folder that cannot be read.
    Io {
        /// The path.
        path: String,
        /// The error.
        error: std::io::Error,
    },
    /// Anything else wrong with the record: the source and what.
    Invalid {
        /// The file, folder or level.
        source: String,
        /// What is wrong.
        what: String,
    },
}

impl fmt::Display for MimoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Npy(e) => write!(f, "{e}"),
            Self::Io { path, error } => write!(f, "{path}: {error}"),
            Self::Invalid { source, what } => write!(f, "{source}: {what}"),
        }
    }
}

impl std::error::Error for MimoError {}

impl From<NpyError> for MimoError {
    fn from(e: NpyError) -> Self {
        Self::Npy(e)
    }
}

fn invalid(source: &str, what: impl Into<String>) -> MimoError {
    MimoError::Invalid { source: source.to_string(), what: what.into() }
}

/// The amplitude a tag starts with, in V: `100mV_train` → 0.1, `2V` → 2.
pub fn tag_amplitude_v(tag: &str) -> Option<f64> {
    let end = tag.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(tag.len());
    let value: f64 = tag[..end].parse().ok()?;
    let rest = tag[end..].to_ascii_lowercase();
    let scale = if rest.starts_with("mv") {
        1e-3
    } else if rest.starts_with("kv") {
        1e3
    } else if rest.starts_with('v') {
        1.0
    } else {
        return None;
    };
    Some(value * scale)
}

impl MimoRecord {
    /// Inputs `m`, outputs `p`, samples per period `N` (of the first level; all agree).
    pub fn dims(&self) -> (usize, usize, usize) {
        self.levels.first().map_or((0, 0, 0), |l| (l.u.channels, l.y.channels, l.u.samples))
    }

    /// Checks that every level has the same channels and period, and finite values.
    pub fn validate(&self) -> Result<(), MimoError> {
        let first = self.levels.first().ok_or_else(|| invalid(&self.source, "no level"))?;
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(invalid(&self.source, format!("sample rate {} Hz", self.sample_rate_hz)));
        }
        for l in &self.levels {
            let src = format!("{} ({})", self.source, l.tag);
            if l.u.channels != first.u.channels || l.y.channels != first.y.channels {
                return Err(invalid(&src, "channel counts differ between levels"));
            }
            if l.u.samples != first.u.samples || l.y.samples != l.u.samples {
                return Err(invalid(&src, "period lengths differ"));
            }
            if l.u.realisations != l.y.realisations || l.u.periods != l.y.periods {
                return Err(invalid(&src, "inputs and outputs have different realisations or periods"));
            }
            if let Some(i) = l.u.as_slice().iter().chain(l.y.as_slice()).position(|v| !v.is_finite()) {
                return Err(invalid(&src, format!("value {i} is not finite")));
            }
        }
        Ok(())
    }

    /// Reads a record of several inputs and outputs: a folder of `u_TAG`/`y_TAG` NumPy files
    /// ([`Self::read_npy_folder`]), one `.npz` archive with such members, or a CSV table
    /// ([`Self::read_csv`]).
    pub fn read(path: impl AsRef<Path>, opts: &MimoOptions) -> Result<Self, MimoError> {
        let path = path.as_ref();
        if path.is_dir() {
            Self::read_npy_folder(path, opts)
        } else if path.extension().is_some_and(|x| x == "npz" || x == "npy") {
            Self::read_npy_files(path.display().to_string(), &[path.to_path_buf()], opts)
        } else {
            Self::read_csv(path, opts)
        }
    }

    /// Whether `path` is read as a record of several inputs and outputs whatever its
    /// columns: a folder, or a NumPy file.
    pub fn is_numpy(path: impl AsRef<Path>) -> bool {
        let path = path.as_ref();
        path.is_dir() || path.extension().is_some_and(|x| x == "npz" || x == "npy")
    }

    /// Reads every `u_TAG`/`y_TAG` pair of `.npy` files (and of `.npz` members) in `dir`.
    ///
    /// ```no_run
    /// use boucwen_lab::record::mimo::{MimoOptions, MimoRecord};
    /// let rec = MimoRecord::read_npy_folder("fine-steering-mirror", &MimoOptions::fine_steering_mirror())?;
    /// assert_eq!(rec.dims(), (3, 3, 8192));
    /// # Ok::<(), boucwen_lab::record::mimo::MimoError>(())
    /// ```
    pub fn read_npy_folder(dir: impl AsRef<Path>, opts: &MimoOptions) -> Result<Self, MimoError> {
        let dir = dir.as_ref();
        let source = dir.display().to_string();
        let io = |error| MimoError::Io { path: source.clone(), error };
        let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "npy" || x == "npz"))
            .collect();
        paths.sort();
        Self::read_npy_files(source, &paths, opts)
    }

    /// The `u_TAG`/`y_TAG` pairs among `paths` (`.npy` files named so, members of `.npz`
    /// archives named so; a lone `.npy` file `u_TAG.npy` brings its `y_TAG.npy` beside it).
    fn read_npy_files(source: String, paths: &[PathBuf], opts: &MimoOptions) -> Result<Self, MimoError> {
        let fs = opts.sample_rate_hz.unwrap_or(1.0);
        let mut paths = paths.to_vec();
        if let [one] = paths.as_slice() {
            let stem = one.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            if one.extension().is_some_and(|x| x == "npy") {
                let other = match stem.strip_prefix("u_") {
                    Some(tag) => format!("y_{tag}.npy"),
                    None => match stem.strip_prefix("y_") {
                        Some(tag) => format!("u_{tag}.npy"),
                        None => {
                            return Err(invalid(
                                &source,
                                "a NumPy file of a record is named u_TAG.npy or y_TAG.npy",
                            ));
                        }
                    },
                };
                paths.push(one.with_file_name(other));
            }
        }
        let mut u: BTreeMap<String, (String, NpyArray)> = BTreeMap::new();
        let mut y: BTreeMap<String, (String, NpyArray)> = BTreeMap::new();
        let mut put = |name: &str, from: String, a: NpyArray| {
            if name == "u" || name == "y" {
                let side = if name == "u" { &mut u } else { &mut y };
                side.insert(String::new(), (from, a));
            } else if let Some(tag) = name.strip_prefix("u_") {
                u.insert(tag.to_string(), (from, a));
            } else if let Some(tag) = name.strip_prefix("y_") {
                y.insert(tag.to_string(), (from, a));
            }
        };
        for p in &paths {
            let stem = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            let wanted = |tag: &str| opts.only.as_deref().is_none_or(|o| tag.contains(o));
            if p.extension().is_some_and(|x| x == "npy") {
                if (stem.starts_with("u_") || stem.starts_with("y_")) && wanted(&stem[2..]) {
                    put(&stem, p.display().to_string(), npy::read_npy(p)?);
                }
            } else {
                for (name, a) in npy::read_npz(p)? {
                    let tag = name.get(2..).unwrap_or("");
                    if name == "u"
                        || name == "y"
                        || ((name.starts_with("u_") || name.starts_with("y_")) && wanted(tag))
                    {
                        put(&name, format!("{}:{name}", p.display()), a);
                    }
                }
            }
        }
        let mut levels = Vec::new();
        let mut total = 0usize;
        for (tag, (ufrom, ua)) in u {
            let Some((yfrom, ya)) = y.remove(&tag) else {
                return Err(invalid(&ufrom, format!("no y_{tag} beside u_{tag}")));
            };
            total = total.saturating_add(ua.data.len()).saturating_add(ya.data.len());
            if total > MAX_TOTAL_SAMPLES {
                return Err(invalid(&source, format!("more than {MAX_TOTAL_SAMPLES} samples")));
            }
            let shape_err = |from: &str, a: &NpyArray| {
                invalid(from, format!("shape {:?} is not (N, channel[, realisation[, period]])", a.shape))
            };
            let us = Signals::from_array(&ua, opts.u_unit.volts()).ok_or_else(|| shape_err(&ufrom, &ua))?;
            let ys =
                Signals::from_array(&ya, opts.y_unit.micrometres()).ok_or_else(|| shape_err(&yfrom, &ya))?;
            levels.push(Level { amplitude_v: tag_amplitude_v(&tag), tag, u: us, y: ys });
        }
        if let Some((tag, (from, _))) = y.into_iter().next() {
            return Err(invalid(&from, format!("no u_{tag} beside y_{tag}")));
        }
        if levels.is_empty() {
            return Err(invalid(&source, "no u_TAG.npy / y_TAG.npy pair"));
        }
        levels.sort_by(|a, b| {
            a.amplitude_v.unwrap_or(f64::INFINITY).total_cmp(&b.amplitude_v.unwrap_or(f64::INFINITY))
        });
        let mut rec = Self {
            source,
            sample_rate_hz: fs,
            rate_given: opts.sample_rate_hz.is_some(),
            levels,
            notes: vec![],
        };
        if !rec.rate_given {
            rec.notes.push(
                "no sample rate (NumPy files carry none; give --sample-rate HZ): the model runs per sample, frequencies in cycles per sample".into(),
            );
        }
        rec.validate()?;
        rec.infer_y_unit(opts);
        Ok(rec)
    }

    /// [`MimoOptions::infer_y_unit`].
    fn infer_y_unit(&mut self, opts: &MimoOptions) {
        if !opts.infer_y_unit {
            return;
        }
        let (lo, hi) = self
            .levels
            .iter()
            .flat_map(|l| l.y.as_slice())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        let span = hi - lo;
        if span.is_nan() || span <= 0.0 || (super::MIN_SPAN_UM..=super::MAX_SPAN_UM).contains(&span) {
            return;
        }
        if let Some(unit) = super::import::likely_unit(span, opts.y_unit) {
            let k = unit.micrometres() / opts.y_unit.micrometres();
            for l in &mut self.levels {
                l.y.scale(k);
            }
            self.notes.push(format!(
                "outputs read in {} (in {} they would span {:.3e} µm, outside {}…{} µm); give --y-unit to say otherwise",
                unit.name(),
                opts.y_unit.name(),
                span,
                super::for_people(super::MIN_SPAN_UM),
                super::for_people(super::MAX_SPAN_UM)
            ));
        }
    }

    /// Reads a CSV table `t,u1,..,um,y1,..,yp` as one level of one realisation.
    pub fn read_csv(path: impl AsRef<Path>, opts: &MimoOptions) -> Result<Self, MimoError> {
        let path = path.as_ref();
        let source = path.display().to_string();
        let text =
            std::fs::read_to_string(path).map_err(|error| MimoError::Io { path: source.clone(), error })?;
        Self::parse_csv(&text, &source, opts)
    }

    /// [`Self::read_csv`] from text; `source` names it in errors.
    ///
    /// ```
    /// use boucwen_lab::record::mimo::{MimoOptions, MimoRecord};
    /// let text = "t,u1,u2,y1,y2\n0,0,1,0.5,0\n0.5,1,0,0,0.5\n1,0,-1,-0.5,0\n1.5,-1,0,0,-0.5\n";
    /// let opts = MimoOptions { period_samples: Some(2), ..MimoOptions::default() };
    /// let r = MimoRecord::parse_csv(text, "run.csv", &opts)?;
    /// assert_eq!((r.dims(), r.sample_rate_hz, r.levels[0].u.periods), ((2, 2, 2), 2.0, 2));
    /// assert_eq!(r.levels[0].y.get(0, 1, 0), &[-0.5, 0.0]);
    /// # Ok::<(), boucwen_lab::record::mimo::MimoError>(())
    /// ```
    pub fn parse_csv(text: &str, source: &str, opts: &MimoOptions) -> Result<Self, MimoError> {
        let mut lines = text.lines().enumerate().filter(|(_, l)| {
            let t = l.trim();
            !t.is_empty() && !t.starts_with('#') && !t.starts_with('%')
        });
        let (_, header) = lines.next().ok_or_else(|| invalid(source, "empty"))?;
        let header = header.trim_start_matches('\u{feff}');
        let sep = [('\t', "tab"), (';', ";"), (',', ",")]
            .into_iter()
            .find(|(c, _)| header.contains(*c))
            .map(|(c, _)| c);
        let split = |l: &str| -> Vec<String> {
            match sep {
                Some(c) => l.split(c).map(|f| f.trim().trim_matches('"').to_string()).collect(),
                None => l.split_whitespace().map(str::to_string).collect(),
            }
        };
        let names = split(header);
        let mut t_col = None;
        let mut u_cols: Vec<(usize, usize)> = Vec::new();
        let mut y_cols: Vec<(usize, usize)> = Vec::new();
        if let Some(c) = &opts.columns {
            let find = |r: &ColumnRef| -> Result<usize, MimoError> {
                let i = match r {
                    ColumnRef::Index(i) => Some(i - 1).filter(|&i| i < names.len()),
                    ColumnRef::Name(n) => names.iter().position(|h| h.eq_ignore_ascii_case(n)),
                };
                i.ok_or_else(|| {
                    invalid(
                        source,
                        format!("--columns names {r}: no such column (columns found: {})", names.join(", ")),
                    )
                })
            };
            t_col = c.t.as_ref().map(find).transpose()?;
            u_cols =
                c.u.iter().map(find).enumerate().map(|(k, i)| i.map(|i| (k, i))).collect::<Result<_, _>>()?;
            y_cols =
                c.y.iter().map(find).enumerate().map(|(k, i)| i.map(|i| (k, i))).collect::<Result<_, _>>()?;
        }
        for (i, n) in names.iter().enumerate().filter(|_| opts.columns.is_none()) {
            let l = n.to_ascii_lowercase();
            if l == "t" || l == "time" {
                t_col = Some(i);
            } else if let Some(k) = l.strip_prefix('u').and_then(|d| d.parse::<usize>().ok()) {
                u_cols.push((k, i));
            } else if let Some(k) = l.strip_prefix('y').and_then(|d| d.parse::<usize>().ok()) {
                y_cols.push((k, i));
            } else if !l.is_empty() {
                return Err(invalid(source, format!("column {n:?} is none of t, u1.., y1..")));
            }
        }
        u_cols.sort_unstable();
        y_cols.sort_unstable();
        if u_cols.is_empty() || y_cols.is_empty() {
            return Err(invalid(source, "needs columns u1.. and y1.."));
        }
        let mut t = Vec::new();
        let mut cols: Vec<Vec<f64>> = vec![Vec::new(); u_cols.len() + y_cols.len()];
        for (ln, line) in lines {
            let f = split(line);
            if f.len() < names.len() {
                return Err(invalid(
                    &format!("{source}:{}", ln + 1),
                    format!("{} fields, the header has {}", f.len(), names.len()),
                ));
            }
            let num = |i: usize| -> Result<f64, MimoError> {
                let v: f64 = f[i].parse().map_err(|_| {
                    invalid(
                        &format!("{source}:{}", ln + 1),
                        format!("column {:?}: {:?} is not a number", names[i], f[i]),
                    )
                })?;
                if v.is_finite() {
                    Ok(v)
                } else {
                    Err(invalid(
                        &format!("{source}:{}", ln + 1),
                        format!("column {:?} is not finite", names[i]),
                    ))
                }
            };
            if let Some(ti) = t_col {
                t.push(num(ti)?);
            }
            for (j, &(_, i)) in u_cols.iter().chain(&y_cols).enumerate() {
                let s = if j < u_cols.len() { opts.u_unit.volts() } else { opts.y_unit.micrometres() };
                cols[j].push(num(i)? * s);
            }
            if cols[0].len().saturating_mul(cols.len()) > MAX_TOTAL_SAMPLES {
                return Err(invalid(source, format!("more than {MAX_TOTAL_SAMPLES} samples")));
            }
        }
        let rows = cols[0].len();
        if rows < 2 {
            return Err(invalid(source, "fewer than two rows"));
        }
        let fs = match (t_col, opts.sample_rate_hz) {
            (Some(_), given) => {
                let dt = (t[rows - 1] - t[0]) / (rows - 1) as f64;
                if dt.is_nan() || dt <= 0.0 {
                    return Err(invalid(source, "time does not increase"));
                }
                let fs = 1.0 / dt;
                if let Some(g) = given.filter(|g| ((g - fs) / g).abs() > 0.01) {
                    return Err(invalid(source, format!("the time column gives {fs} Hz, the option {g} Hz")));
                }
                fs
            }
            (None, Some(g)) => g,
            (None, None) => return Err(invalid(source, "no time column and no sample rate")),
        };
        let n = opts.period_samples.unwrap_or(rows);
        if n == 0 || n > rows {
            return Err(invalid(source, format!("period of {n} samples in {rows} rows")));
        }
        let periods = rows / n;
        let build = |range: std::ops::Range<usize>| {
            let mut data = Vec::with_capacity(periods * range.len() * n);
            for p in 0..periods {
                for c in range.clone() {
                    data.extend_from_slice(&cols[c][p * n..(p + 1) * n]);
                }
            }
            Signals::new(range.len(), 1, periods, n, data)
        };
        let mu = u_cols.len();
        let u = build(0..mu).ok_or_else(|| invalid(source, "no samples"))?;
        let y = build(mu..cols.len()).ok_or_else(|| invalid(source, "no samples"))?;
        let mut rec = Self {
            source: source.to_string(),
            sample_rate_hz: fs,
            rate_given: true,
            levels: vec![Level { tag: "csv".into(), amplitude_v: None, u, y }],
            notes: vec![],
        };
        rec.validate()?;
        rec.infer_y_unit(opts);
        Ok(rec)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_from_npy_shape() {
        // (N=2, C=2, R=1, P=2): value = 1000k + 100c + 10r + p.
        let mut data = Vec::new();
        for k in 0..2 {
            for c in 0..2 {
                for p in 0..2 {
                    data.push((1000 * k + 100 * c + p) as f64);
                }
            }
        }
        let a = NpyArray { shape: vec![2, 2, 1, 2], data };
        let s = Signals::from_array(&a, 1.0).unwrap();
        assert_eq!(s.get(0, 1, 1), &[101.0, 1101.0]);
        assert_eq!(s.mean_period(0, 0), vec![0.5, 1000.5]);
    }

    #[test]
    fn tags() {
        assert_eq!(tag_amplitude_v("100mV_train"), Some(0.1));
        assert_eq!(tag_amplitude_v("2V"), Some(2.0));
        assert_eq!(tag_amplitude_v("train"), None);
    }
}

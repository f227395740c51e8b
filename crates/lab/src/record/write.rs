//! Writing records and tables atomically.

use super::{At, ErrorKind, Record, RecordError};
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

impl Record {
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

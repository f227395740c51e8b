//! Writing output files atomically: to a temporary file beside the target, then renamed,
//! so an interrupted or failed run never leaves a half-written file.

use std::io::Write;
use std::path::{Path, PathBuf};

/// An output that could not be written, naming the path.
#[derive(Debug)]
pub struct WriteError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub source: std::io::Error,
}

impl std::fmt::Display for WriteError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "cannot write {}: {}", self.path.display(), self.source)
    }
}

impl std::error::Error for WriteError {}

/// Writes `contents` to `path` atomically (temporary file in the same directory, then rename).
pub fn write_atomic(path: &Path, contents: &[u8]) -> Result<(), WriteError> {
    let err = |source| WriteError { path: path.to_path_buf(), source };
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(contents)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(err)
}

/// Creates a directory (and its parents), naming it on failure.
pub fn create_dir(path: &Path) -> Result<(), WriteError> {
    std::fs::create_dir_all(path).map_err(|source| WriteError { path: path.to_path_buf(), source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_replaces_and_names_failures() {
        let dir = std::env::temp_dir().join(format!("boucwen-io-{}", std::process::id()));
        create_dir(&dir).unwrap();
        let p = dir.join("a.csv");
        write_atomic(&p, b"x\n1\n").unwrap();
        write_atomic(&p, b"x\n2\n").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "x\n2\n");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "no temporary file left");
        let bad = dir.join("missing-dir").join("b.csv");
        let e = write_atomic(&bad, b"x").unwrap_err();
        assert!(e.to_string().contains("missing-dir"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

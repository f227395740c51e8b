//! What importing a long record costs in memory (issue 29, item 8): the file is read line by
//! line, never whole, and per row only what the record keeps (`u`, `y`) and, while reading,
//! the time and the power of ten of its last digit. Measured as the growth of this
//! process's peak resident memory (`VmHWM`), in a test binary of its own so nothing else
//! runs meanwhile.
//!
//! The importer held the file's text (about 28 bytes a row here), five `f64` a row (t, the
//! unit of t's last digit, the row's line, u, y) and, in the spike repair, a copy of `y`:
//! about 80 bytes a row. Now: about 26.

use boucwen_lab::record::{ImportOptions, import};
use std::io::Write;

/// Peak resident memory of this process, kB (`None` off Linux).
fn peak_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines().find_map(|l| l.strip_prefix("VmHWM:"))?.trim().trim_end_matches("kB").trim().parse().ok()
}

#[test]
fn importing_a_long_record_costs_about_the_record() {
    const ROWS: usize = 1_000_000;
    let dir = std::env::temp_dir().join(format!("boucwen-import-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("long.csv");
    {
        let mut out = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        writeln!(out, "t,u,y").unwrap();
        for k in 0..ROWS {
            let t = k as f64 * 1e-3;
            let u = (std::f64::consts::TAU * 23.0 * t).sin();
            writeln!(out, "{t:.3},{u:.6},{:.4}", 20.0 * u + 0.001 * (k % 7) as f64).unwrap();
        }
    }
    let bytes = std::fs::metadata(&path).unwrap().len();
    let Some(before) = peak_kb() else {
        std::fs::remove_dir_all(&dir).unwrap();
        eprintln!("no /proc/self/status: not measured");
        return;
    };
    let r = import(&path, &ImportOptions::default()).unwrap().record;
    let after = peak_kb().unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(r.len(), ROWS);
    let per_row = (after.saturating_sub(before) * 1024) as f64 / ROWS as f64;
    eprintln!("{bytes} bytes of CSV, peak memory grew by {per_row:.1} bytes a row");
    // u and y are 16 bytes a row, the times 8 more and their digits 2 while reading.
    assert!(per_row < 40.0, "{per_row:.1} bytes a row");
}

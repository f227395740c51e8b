//! Peak memory of `boucwen identify` and `boucwen diagnose` on a long record (issue 29,
//! item 8): writes a record of `--samples` samples (default 10⁷: 23 Hz sine on the on-chip
//! actuator's model at 1 kHz, 2.8 hours, about 280 MB of CSV) to a temporary directory,
//! runs the `boucwen` built with this bench (the `bench` profile) on it, and prints each
//! command's time and peak resident memory (`/usr/bin/time -v`'s maximum resident set
//! size; without it, the largest `VmHWM` seen in `/proc/PID/status` while it runs).
//!
//! ```text
//! cargo bench -p boucwen-cli --bench memory
//! cargo bench -p boucwen-cli --bench memory -- --samples 1000000 --commands identify
//! BOUCWEN_BIN=/path/to/another/boucwen cargo bench -p boucwen-cli --bench memory
//! ```
//!
//! The record is written, not simulated (the virtual bimorph takes a minute for 10⁷
//! samples): the core's extended model with a resonance near 70 Hz and a seeded noise of
//! ±10 nm, in the project's CSV layout (`t,u,y`, times to the ms).

use boucwen_core::model::{BoucWenParams, ExtendedParams, Model};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn main() {
    let mut samples: usize = 10_000_000;
    let mut commands = vec!["identify".to_string(), "diagnose".to_string()];
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--samples" => {
                samples = args.next().and_then(|v| v.parse::<f64>().ok()).map_or(samples, |v| v as usize)
            }
            "--commands" => {
                commands = args.next().map_or(commands, |v| v.split(',').map(String::from).collect())
            }
            // `cargo bench` passes --bench; filters are not used.
            _ => {}
        }
    }
    let bin = std::env::var("BOUCWEN_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_boucwen").to_string());
    let dir = std::env::temp_dir().join(format!("boucwen-memory-{}", std::process::id()));
    if let Err(e) = std::fs::create_dir_all(&dir) {
        eprintln!("memory: cannot create {}: {e}", dir.display());
        std::process::exit(1);
    }
    let path = dir.join("long.csv");
    let started = Instant::now();
    if let Err(e) = write_record(&path, samples) {
        eprintln!("memory: cannot write {}: {e}", path.display());
        let _ = std::fs::remove_dir_all(&dir);
        std::process::exit(1);
    }
    let size = std::fs::metadata(&path).map_or(0, |m| m.len());
    println!(
        "memory: {samples} samples, {:.0} MB of CSV written in {:.1} s; {bin}",
        size as f64 / 1e6,
        started.elapsed().as_secs_f64()
    );
    let mut failed = false;
    for c in &commands {
        match measure(&bin, c, &path) {
            Ok((time, peak_kb, ok)) => {
                println!(
                    "memory: boucwen {c}: {:.1} s, peak RSS {:.0} MB ({:.1} bytes per sample){}",
                    time.as_secs_f64(),
                    peak_kb as f64 / 1e3,
                    peak_kb as f64 * 1e3 / samples as f64,
                    if ok { "" } else { " (the command failed)" }
                );
                failed |= !ok;
            }
            Err(e) => {
                println!("memory: boucwen {c}: {e}");
                failed = true;
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    if failed {
        std::process::exit(1);
    }
}

/// The record: `t, u, y` at 1 kHz, `u` a 1 V sine at 23 Hz, `y` the model's output plus a
/// seeded noise.
fn write_record(path: &Path, samples: usize) -> std::io::Result<()> {
    let ts = 1e-3;
    let w0 = std::f64::consts::TAU * 70.0 * ts;
    let model = ExtendedParams {
        bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
        ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
    };
    let mut state = model.initial_state();
    let mut noise = 0x2545_F491_4F6C_DD1Du64;
    let mut out = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(path)?);
    writeln!(out, "t,u,y")?;
    for k in 0..samples {
        let t = k as f64 * ts;
        let u = (std::f64::consts::TAU * 23.0 * t).sin();
        noise ^= noise << 13;
        noise ^= noise >> 7;
        noise ^= noise << 17;
        let n = ((noise >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.02;
        let y = model.step(&mut state, u) + n;
        writeln!(out, "{t:.3},{u:.6},{y:.4}")?;
    }
    out.flush()
}

/// Runs `boucwen command path`: its wall time, peak RSS (kB) and whether it succeeded.
fn measure(bin: &str, command: &str, path: &Path) -> Result<(Duration, u64, bool), String> {
    let time = PathBuf::from("/usr/bin/time");
    let started = Instant::now();
    if time.exists() {
        let o = Command::new(&time)
            .arg("-v")
            .arg(bin)
            .arg(command)
            .arg(path)
            .stdout(Stdio::null())
            .output()
            .map_err(|e| format!("cannot run {}: {e}", time.display()))?;
        let elapsed = started.elapsed();
        let err = String::from_utf8_lossy(&o.stderr);
        let peak = err
            .lines()
            .find_map(|l| l.trim().strip_prefix("Maximum resident set size (kbytes):"))
            .and_then(|v| v.trim().parse().ok())
            .ok_or_else(|| format!("no maximum resident set size from {}", time.display()))?;
        return Ok((elapsed, peak, o.status.success()));
    }
    let mut child = Command::new(bin)
        .arg(command)
        .arg(path)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("cannot run {bin}: {e}"))?;
    let status = format!("/proc/{}/status", child.id());
    let mut peak = 0u64;
    loop {
        if let Ok(s) = std::fs::read_to_string(&status) {
            let hwm = s
                .lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok());
            peak = peak.max(hwm.unwrap_or(0));
        }
        match child.try_wait() {
            Ok(Some(s)) => return Ok((started.elapsed(), peak, s.success())),
            Ok(None) => std::thread::sleep(Duration::from_millis(5)),
            Err(e) => return Err(format!("waiting for {bin}: {e}")),
        }
    }
}

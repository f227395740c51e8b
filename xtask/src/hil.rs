//! `cargo xtask hil`: the firmware in QEMU with its UART on a pseudo-terminal, and
//! `boucwen hil --port PATH` driving the virtual bimorph against it, in lockstep (or
//! free-running with `--free-running`).
//!
//! QEMU prints `char device redirected to /dev/pts/N` when it puts the board's UART on a
//! pseudo-terminal; that path is handed to the CLI. QEMU runs with `-icount shift=0`
//! (one instruction per virtual nanosecond) and its default `sleep=on`: while the board
//! idles, its virtual clock follows the wall clock, so the host's latency shows in the
//! board's time. The emulated UART also takes its input one byte per turn of QEMU's main
//! loop, slower than a real line, and the board paces its transmitter at the baud rate:
//! a command takes 0.43 ms to leave it. A free-running run therefore finds most
//! measurements after the next tick on this machine (and QEMU's clock, dragged by a loaded
//! host, makes the board count tick overruns); lockstep, the default, takes the host's
//! latency out of the loop's result.

use crate::session::Session;
use crate::tools::{self, Board};
use std::path::PathBuf;
use std::process::{Command, Stdio};

/// Options passed through to `boucwen hil`.
pub struct Options {
    /// The board.
    pub board: Board,
    /// Per-byte fault rate, both directions.
    pub inject_faults: Option<f64>,
    /// End with the JSON line.
    pub json: bool,
    /// Samples to run.
    pub samples: u32,
    /// A free-running control run instead of lockstep.
    pub free_running: bool,
}

/// Builds the `boucwen` binary with the cargo that runs xtask; returns its path.
fn build_cli() -> Result<PathBuf, String> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    eprintln!("building the boucwen command");
    let status = Command::new(&cargo)
        .args(["build", "-p", "boucwen-cli", "--bin", "boucwen"])
        .current_dir(tools::root())
        .status()
        .map_err(|e| format!("cannot run {}: {e}", cargo.to_string_lossy()))?;
    if !status.success() {
        return Err(format!("building boucwen failed ({status})"));
    }
    let base =
        std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| tools::root().join("target"), PathBuf::from);
    let bin = base.join("debug").join("boucwen");
    if bin.exists() { Ok(bin) } else { Err(format!("no {} after the build", bin.display())) }
}

/// Runs the task; returns every failure.
pub fn run(opts: &Options) -> Vec<String> {
    let mut failures = Vec::new();
    if let Err(mut e) = tools::check(&[&tools::QEMU]) {
        failures.append(&mut e);
    }
    let elf = match tools::build_firmware(&opts.board.qemu_features(&[])) {
        Ok(e) => Some(e),
        Err(mut e) => {
            failures.append(&mut e);
            None
        }
    };
    let cli = match build_cli() {
        Ok(c) => Some(c),
        Err(e) => {
            failures.push(e);
            None
        }
    };
    let (Some(elf), Some(cli), true) = (elf, cli, failures.is_empty()) else {
        return failures;
    };

    let session = match Session::start(opts.board, &elf, false) {
        Ok(s) => s,
        Err(e) => return vec![e],
    };
    let pty = session.pty.clone();
    eprintln!("board on {pty}; running boucwen hil");

    let mut cmd = Command::new(&cli);
    cmd.args(["hil", "--port", &pty, "--samples", &opts.samples.to_string()]);
    if let Some(r) = opts.inject_faults {
        cmd.args(["--inject-faults", &r.to_string()]);
    }
    if opts.free_running {
        cmd.arg("--free-running");
    }
    if opts.json {
        cmd.arg("--json");
    }
    let out = cmd.stdin(Stdio::null()).stderr(Stdio::inherit()).output();
    drop(session);
    let out = match out {
        Ok(o) => o,
        Err(e) => return vec![format!("cannot run {}: {e}", cli.display())],
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    print!("{stdout}");
    if !out.status.success() {
        failures.push(format!("boucwen hil failed ({})", out.status));
    }
    if opts.json {
        match stdout.lines().last().map(serde_json::from_str::<serde_json::Value>) {
            Some(Ok(v)) => {
                let get = |k: &str| v.get(k).and_then(serde_json::Value::as_u64);
                match (get("samples"), get("samples_accounted")) {
                    (Some(n), Some(a)) if n == a && n == opts.samples as u64 => {}
                    (n, a) => failures.push(format!("JSON reports samples {n:?}, accounted {a:?}")),
                }
                if v.get("safe_state_ms").and_then(serde_json::Value::as_f64).is_none() {
                    failures.push("JSON reports no safe_state_ms: the board did not reach 0 V".into());
                }
            }
            _ => failures.push("boucwen hil --json did not end with a JSON line".into()),
        }
    }
    failures
}

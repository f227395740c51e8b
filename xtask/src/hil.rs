//! `cargo xtask hil`: the firmware in QEMU with UART0 on a pseudo-terminal, and
//! `boucwen hil --port PATH` driving the virtual bimorph against it.
//!
//! QEMU prints `char device redirected to /dev/pts/N (label serial0)` when it puts the
//! board's UART0 on a pseudo-terminal; that path is handed to the CLI. QEMU runs with
//! `-icount shift=0`, so the board's 1 kHz sample timer runs in virtual time: the emulated
//! UART takes its input one byte per turn of QEMU's main loop, which makes the link slower
//! than a real 460,800 baud line, and in virtual time the board still sees one sample per
//! millisecond (the wall clock runs a few times slower).

use crate::tools::{self, QEMU};
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// Options passed through to `boucwen hil`.
pub struct Options {
    /// Per-byte fault rate, both directions.
    pub inject_faults: Option<f64>,
    /// End with the JSON line.
    pub json: bool,
    /// Samples to run.
    pub samples: u32,
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
    if let Err(mut e) = tools::check(&[&QEMU]) {
        failures.append(&mut e);
    }
    let elf = match tools::build_firmware(None) {
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

    let mut qemu = tools::qemu_command(&elf, &[], "pty");
    let mut child = match qemu.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn() {
        Ok(c) => c,
        Err(e) => return vec![format!("cannot start {}: {e}", QEMU.path)],
    };
    // QEMU names the pseudo-terminal on stdout or stderr (depending on the version).
    let (tx, rx) = mpsc::channel::<String>();
    let mut readers = Vec::new();
    for stream in [
        child.stdout.take().map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
        child.stderr.take().map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
    ]
    .into_iter()
    .flatten()
    {
        let tx = tx.clone();
        readers.push(std::thread::spawn(move || {
            for line in BufReader::new(stream).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        }));
    }
    drop(tx);
    let mut pty = None;
    let mut qemu_lines = Vec::new();
    while let Ok(line) = rx.recv_timeout(Duration::from_secs(10)) {
        if let Some(at) = line.find("/dev/pts/") {
            let path: String = line[at..].chars().take_while(|c| !c.is_whitespace()).collect();
            pty = Some(path);
            break;
        }
        qemu_lines.push(line);
    }
    let Some(pty) = pty else {
        let _ = child.kill();
        let _ = child.wait();
        return vec![format!("QEMU did not report its pseudo-terminal; it said: {}", qemu_lines.join(" | "))];
    };
    eprintln!("board on {pty}; running boucwen hil");

    let mut cmd = Command::new(&cli);
    cmd.args(["hil", "--port", &pty, "--samples", &opts.samples.to_string()]);
    if let Some(r) = opts.inject_faults {
        cmd.args(["--inject-faults", &r.to_string()]);
    }
    if opts.json {
        cmd.arg("--json");
    }
    let out = cmd.stdin(Stdio::null()).stderr(Stdio::inherit()).output();
    let _ = child.kill();
    let _ = child.wait();
    for r in readers {
        let _ = r.join();
    }
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
            }
            _ => failures.push("boucwen hil --json did not end with a JSON line".into()),
        }
    }
    failures
}

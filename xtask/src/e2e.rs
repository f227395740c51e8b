//! `cargo xtask e2e`: from a measured record to a running board, and back, without
//! hardware: the firmware in QEMU on a pseudo-terminal and the `boucwen board` commands
//! run as a user runs them.
//!
//! For each actuator (`--actuator on-chip|bimorph|both`):
//! 1. `boucwen board excite` (a 1 V sine at 23 Hz, 5 s): the board drives the excitation,
//!    the record comes back sample by sample;
//! 2. `boucwen board design` on that record (20 µm at 23 Hz);
//! 3. `boucwen board load`: the parameters sent and read back bit for bit;
//! 4. `boucwen board run --reference sine:23Hz:20um --seconds 5`: the board runs its own
//!    loop, the telemetry streamed into a record;
//! 5. the same design in-process on the same actuator: the board's controller code on the
//!    on-chip actuator's model (`on-chip`), or on the virtual bimorph (`bimorph`, computed
//!    by `boucwen board run` itself). The run's RMSE must be within 20 % of it, and every
//!    sample logged.
//!
//! Actuators: `on-chip` is the board's own simulated actuator (the self-test's plant,
//! set over the link first), the run a `Simulated` run on the board; `bimorph` is the
//! virtual bimorph on the host, the board driving it over the serial link in lockstep.
//!
//! Then the crash test (on the on-chip actuator): a run of 30 s whose host is killed
//! (SIGKILL) after [`KILL_AFTER`] samples. The board's link goes through a relay here that
//! notes every telemetry frame it passes to the host; before the kill it holds the board's
//! output for [`DRAIN`], so the host has read all it was sent: the record must hold every
//! complete sample passed, exactly as sent, and the board, left without a host, must end
//! the run and ramp its drive to 0 V (`Safe{HostLost}`, the drive 0 V in its diagnostics).
//! (`cargo test`'s version of this test, against the board's state machine in a thread
//! ticking in real time, kills the host without warning and checks every sample sent
//! 300 ms before the kill.)
//!
//! Clocks: on the on-chip actuator QEMU's virtual clock never follows the wall clock
//! (`-icount shift=0,sleep=off`): nothing on the board waits for the host, its telemetry
//! leaves it at the line's rate of its own clock, and QEMU's serial port holds the board
//! when the host reads slower. The board's clock then runs at its own pace against the
//! wall's (about a third of it on an idle 2-core machine, less under load), so these runs
//! set the host timeout to [`HOST_TIMEOUT_MS`], and the host paces its keepalives by the
//! board's samples as well as its own clock (`boucwen_hal::board::KEEPALIVE_SAMPLES`): on
//! its own clock alone, a board slower than the wall had more keepalives to answer per
//! second of its own than its line could carry beside the telemetry, and dropped frames
//! (16 to 208 of 5,000 per stream; CI retried the streaming steps, then stopped gating on
//! them). Nothing is retried now. With the virtual bimorph the host is in the loop
//! (lockstep) and the clock follows the wall.
//!
//! With `--json` each actuator ends with a line `{actuator, samples_expected,
//! samples_logged, design_rmse_um, run_rmse_um, inprocess_rmse_um}`, the last line being
//! the last actuator's.

use crate::session::{Session, request_ok};
use crate::tools::{self, Board};
use boucwen_hal::transport::{self, Link, Port, SerialPort};
use boucwen_lab::design::board::{DesignFile, settle_samples};
use boucwen_link::device::Controller;
use boucwen_link::message::{PlantParams, SafeReason, command_flags};
use boucwen_link::plant::OnChipPlant;
use boucwen_link::{Decoder, Message, Packet};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The crash test: samples of the run before the host is killed.
const KILL_AFTER: usize = 1500;
/// The crash test: how long the host has to read what it was sent before the kill.
const DRAIN: Duration = Duration::from_millis(500);
/// Seconds of the identification record: as long as the run.
const EXCITE_SECONDS: &str = "5";
/// Seconds of the run.
const RUN_SECONDS: u32 = 5;
/// The board's host timeout in these runs, ms: the board's ticks run on QEMU's virtual
/// clock, which (see the module docs) skips ahead of the wall's when the board idles.
const HOST_TIMEOUT_MS: &str = "2000";
/// The run's tolerance against the same design in-process.
const TOLERANCE: f64 = 0.2;

/// Which actuator(s).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Which {
    /// The board's on-chip simulated actuator.
    OnChip,
    /// The virtual bimorph on the host, over the link.
    Bimorph,
    /// Both, on-chip first.
    Both,
}

/// The task's options.
pub struct Options {
    /// The board.
    pub board: Board,
    /// The actuators.
    pub actuator: Which,
    /// End each actuator with a JSON line.
    pub json: bool,
}

/// The on-chip actuator: the plant of the self-test's first case.
fn on_chip_plant() -> Result<PlantParams, String> {
    Ok(crate::qemu::scenario(&crate::qemu::CASES[0])?.1)
}

fn cli(bin: &Path, args: &[&str]) -> Result<String, String> {
    eprintln!("$ boucwen {}", args.join(" "));
    let out = Command::new(bin)
        .args(args)
        .stdin(Stdio::null())
        .stderr(Stdio::inherit())
        .output()
        .map_err(|e| format!("cannot run {}: {e}", bin.display()))?;
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    eprint!("{stdout}");
    if !out.status.success() {
        return Err(format!("boucwen {} failed ({})", args.join(" "), out.status));
    }
    Ok(stdout)
}

fn last_json(stdout: &str, what: &str) -> Result<serde_json::Value, String> {
    stdout
        .lines()
        .last()
        .and_then(|l| serde_json::from_str(l).ok())
        .ok_or_else(|| format!("{what} did not end with a JSON line"))
}

fn num(v: &serde_json::Value, key: &str, what: &str) -> Result<f64, String> {
    v.get(key).and_then(serde_json::Value::as_f64).ok_or_else(|| format!("{what}: no {key} in its JSON"))
}

/// Sets the board's on-chip actuator.
fn set_plant(pty: &str) -> Result<(), String> {
    let mut link = Link::new(transport::open_serial(pty, crate::BAUD).map_err(|e| e.to_string())?);
    link.flush_peer().map_err(|e| e.to_string())?;
    request_ok(&mut link, &Message::SetPlant(on_chip_plant()?))
}

/// The design's compensator on the on-chip actuator's model, in-process: RMSE after the
/// settling time, µm.
fn on_chip_in_process(design: &Path, samples: u32) -> Result<f64, String> {
    let d = DesignFile::read(design).map_err(|e| e.to_string())?;
    let (mut params, _) = d.board_params().map_err(|e| e.to_string())?;
    params.amplitude_um = 20.0;
    let mut c = Controller::new(&params).map_err(|e| e.to_string())?;
    let mut a = OnChipPlant::new(&on_chip_plant()?).map_err(|e| e.to_string())?;
    let settle = settle_samples(samples, params.fade_samples);
    let (mut y_prev, mut sq) = (None, 0.0);
    for k in 0..samples {
        let s = c.step(y_prev).map_err(|e| e.to_string())?;
        let y = a.step(s.out.u);
        y_prev = Some(y);
        if k >= settle {
            sq += (y as f64 - s.d as f64).powi(2);
        }
    }
    Ok((sq / (samples - settle) as f64).sqrt())
}

/// One actuator's excite → design → load → run; its JSON line.
fn flow(bin: &Path, pty: &str, which: Which, dir: &Path) -> Result<serde_json::Value, String> {
    let name = if which == Which::OnChip { "on-chip" } else { "bimorph" };
    let path = |f: &str| dir.join(format!("{name}-{f}")).display().to_string();
    let (rec, design, run) = (path("rec.csv"), path("design.json"), path("run.csv"));
    let actuator = ["--actuator", name];
    let port = ["--port", pty];
    let mut excite = vec!["board", "excite"];
    excite.extend(port);
    excite.extend(actuator);
    excite.extend(["--host-timeout-ms", HOST_TIMEOUT_MS]);
    excite.extend(["--sine", "23Hz:1V", "--seconds", EXCITE_SECONDS, "-o", &rec]);
    cli(bin, &excite)?;
    let d = last_json(
        &cli(
            bin,
            &[
                "board",
                "design",
                &rec,
                "-o",
                &design,
                "--amplitude",
                "20",
                "--host-timeout-ms",
                HOST_TIMEOUT_MS,
                "--json",
            ],
        )?,
        "design",
    )?;
    cli(bin, &["board", "load", "--port", pty, &design])?;
    let seconds = RUN_SECONDS.to_string();
    let mut r = vec!["board", "run"];
    r.extend(port);
    r.extend(actuator);
    r.extend(["--reference", "sine:23Hz:20um", "--seconds", &seconds, "-o", &run, "--json"]);
    let out = cli(bin, &r)?;
    let v = last_json(&out, "board run")?;
    let samples = RUN_SECONDS * 1000;
    let inprocess = match which {
        Which::OnChip => on_chip_in_process(Path::new(&design), samples)?,
        _ => num(&v, "inprocess_rmse_um", "board run")?,
    };
    Ok(serde_json::json!({
        "actuator": name,
        "samples_expected": v.get("samples_expected"),
        "samples_logged": v.get("samples_logged"),
        "design_rmse_um": num(&d, "design_rmse_um", "board design")?,
        "run_rmse_um": num(&v, "rmse_um", "board run")?,
        "inprocess_rmse_um": inprocess,
    }))
}

/// What the relay saw.
#[derive(Default)]
struct Relayed {
    /// Telemetry passed to the host (not the ramp): k, u, y.
    telemetry: Vec<(u32, f32, f32)>,
    /// `Safe` from the board: when, reason.
    safe: Vec<(Instant, u8)>,
}

/// Passes bytes between the board's pseudo-terminal and a new one for the host, noting
/// the telemetry it passes. Board to host can be held ([`Relay::hold`]: the board's
/// output waits, as behind a full line); once the host is gone ([`Relay::host_gone`]), what
/// the host does not take is dropped.
struct Relay {
    /// The host's end.
    pty: String,
    stop: Arc<AtomicBool>,
    hold: Arc<AtomicBool>,
    gone: Arc<AtomicBool>,
    seen: Arc<Mutex<Relayed>>,
    thread: Option<std::thread::JoinHandle<Result<SerialPort, String>>>,
    _slave: serialport::TTYPort,
}

impl Relay {
    fn start(board_pty: &str) -> Result<Self, String> {
        let mut board = transport::open_serial(board_pty, crate::BAUD).map_err(|e| e.to_string())?;
        let (mut host, slave) =
            serialport::TTYPort::pair().map_err(|e| format!("a pseudo-terminal pair: {e}"))?;
        let pty = serialport::SerialPort::name(&slave).ok_or("the relay's pseudo-terminal has no name")?;
        serialport::SerialPort::set_timeout(&mut host, Duration::from_micros(300))
            .map_err(|e| format!("the relay's pseudo-terminal: {e}"))?;
        let flag = || Arc::new(AtomicBool::new(false));
        let (stop, hold, gone) = (flag(), flag(), flag());
        let seen = Arc::new(Mutex::new(Relayed::default()));
        let (stop2, hold2, gone2, seen2) = (stop.clone(), hold.clone(), gone.clone(), seen.clone());
        let thread = std::thread::spawn(move || {
            let mut dec = Decoder::new();
            let mut buf = [0u8; 1024];
            let io = |e: std::io::Error| e.to_string();
            while !stop2.load(Ordering::Relaxed) {
                let n = if hold2.load(Ordering::Relaxed) {
                    0
                } else {
                    board.read_timeout(&mut buf, Duration::from_micros(300)).map_err(io)?
                };
                let mut rest = &buf[..n];
                while !rest.is_empty() && !stop2.load(Ordering::Relaxed) {
                    match std::io::Write::write(&mut host, rest) {
                        Ok(w) if w > 0 => rest = &rest[w..],
                        _ if gone2.load(Ordering::Relaxed) => break,
                        _ => {}
                    }
                }
                if n > 0 {
                    let now = Instant::now();
                    let mut s = seen2.lock().map_err(|_| "relay state poisoned")?;
                    for &b in &buf[..n] {
                        match dec.push(b) {
                            Some(Ok(Packet { msg: Message::Telemetry { k, u, y, flags }, .. }))
                                if flags & command_flags::SAFE_RAMP == 0 =>
                            {
                                s.telemetry.push((k, u, y))
                            }
                            Some(Ok(Packet { msg: Message::Safe { reason, .. }, .. })) => {
                                s.safe.push((now, reason))
                            }
                            _ => {}
                        }
                    }
                }
                let m = std::io::Read::read(&mut host, &mut buf).unwrap_or(0);
                if m > 0 {
                    board.write_all(&buf[..m]).map_err(io)?;
                }
            }
            Ok(board)
        });
        Ok(Relay { pty, stop, hold, gone, seen, thread: Some(thread), _slave: slave })
    }

    /// Holds (or releases) the board's output.
    fn hold(&self, on: bool) {
        self.hold.store(on, Ordering::Relaxed);
    }

    /// The host is gone: what it does not take is dropped from now on.
    fn host_gone(&self) {
        self.gone.store(true, Ordering::Relaxed);
    }

    /// Stops the relay; the board's port back.
    fn finish(mut self) -> Result<SerialPort, String> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(std::thread::JoinHandle::join) {
            Some(Ok(r)) => r,
            _ => Err("the relay thread failed".into()),
        }
    }
}

/// The rows of a record: its fields.
fn rows(path: &Path) -> Result<Vec<Vec<String>>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').map(str::to_owned).collect())
        .collect())
}

/// The host killed mid-run: checks the record and the board's safe state.
fn crash(bin: &Path, board_pty: &str, dir: &Path) -> Result<serde_json::Value, String> {
    let record = dir.join("killed-run.csv");
    let relay = Relay::start(board_pty)?;
    let args = [
        "board",
        "run",
        "--port",
        &relay.pty,
        "--actuator",
        "on-chip",
        "--reference",
        "sine:23Hz:20um",
        "--seconds",
        "30",
        "-o",
        &record.display().to_string(),
    ]
    .map(str::to_owned);
    eprintln!("$ boucwen {} (killed after {KILL_AFTER} samples of the run)", args.join(" "));
    let mut child = Command::new(bin)
        .args(&args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("cannot run {}: {e}", bin.display()))?;
    let started = Instant::now();
    let relayed = |relay: &Relay| -> Result<usize, String> {
        let s = relay.seen.lock().map_err(|_| "relay poisoned")?;
        Ok(s.telemetry.iter().rposition(|t| t.0 == 0).map_or(0, |i| s.telemetry.len() - i))
    };
    while relayed(&relay)? < KILL_AFTER {
        if started.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            return Err(format!("fewer than {KILL_AFTER} samples of the run within 60 s"));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    // The board's output held, the host reads what it was sent (DRAIN), and is killed
    // (SIGKILL: no handler runs): every sample relayed was received.
    relay.hold(true);
    std::thread::sleep(DRAIN);
    child.kill().map_err(|e| format!("killing the host: {e}"))?;
    let killed_at = Instant::now();
    let _ = child.wait();
    let tel = {
        let s = relay.seen.lock().map_err(|_| "relay poisoned")?;
        let first = s.telemetry.iter().rposition(|t| t.0 == 0).ok_or("no telemetry of the run")?;
        s.telemetry[first..].to_vec()
    };
    relay.host_gone();
    relay.hold(false);
    // The board, without its host: the ramp to 0 V.
    let deadline = killed_at + Duration::from_secs(30);
    let safe_at = loop {
        let s = relay.seen.lock().map_err(|_| "relay poisoned")?;
        if let Some(&(t, r)) = s.safe.iter().find(|(t, _)| *t > killed_at) {
            if r != SafeReason::HostLost as u8 {
                return Err(format!("after the kill the board went safe for reason {r}, not the lost host"));
            }
            break t;
        }
        drop(s);
        if Instant::now() > deadline {
            return Err("no safe state within 30 s of the host's kill".into());
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let port = relay.finish()?;
    let mut link = Link::new(port);
    let diag = crate::session::diagnostics(&mut link, 3)?;
    if diag.drive_v != 0.0 {
        return Err(format!("after the safe state the drive is {} V", diag.drive_v));
    }
    // Sample k is complete with the telemetry of k + 1: every complete sample relayed
    // before the kill must be in the record, as it was sent.
    let complete = tel.len() - 1;
    let rows = rows(&record)?;
    if rows.len() != complete {
        return Err(format!(
            "the record holds {} samples; the host received {complete} complete ones before it was killed",
            rows.len()
        ));
    }
    for (k, row) in rows.iter().enumerate() {
        let ok = row.len() == 5
            && row[1].parse::<f32>().ok().map(f32::to_bits) == Some(tel[k].1.to_bits())
            && row[2].parse::<f64>().ok() == Some(tel[k + 1].2 as f64);
        if !ok {
            return Err(format!("record row {k} {row:?} is not what the board sent"));
        }
    }
    let safe_ms = (safe_at - killed_at).as_secs_f64() * 1e3;
    eprintln!(
        "host killed with {complete} complete samples received: the record holds all {}, exactly as sent; the board ended the run and reached 0 V {safe_ms:.0} ms after the kill (host timeout {HOST_TIMEOUT_MS} ms of its clock)",
        rows.len()
    );
    Ok(serde_json::json!({
        "crash_samples_received": complete,
        "crash_samples_in_record": rows.len(),
        "safe_after_kill_ms": safe_ms,
    }))
}

/// Runs the task; returns every failure.
pub fn run(opts: &Options) -> Vec<String> {
    let mut failures = Vec::new();
    if let Err(mut e) = tools::check(&[&tools::QEMU]) {
        failures.append(&mut e);
    }
    let elf =
        tools::build_firmware(&opts.board.qemu_features(&[])).map_err(|mut e| failures.append(&mut e)).ok();
    let bin = crate::hil::build_cli().map_err(|e| failures.push(e)).ok();
    let (Some(elf), Some(bin), true) = (elf, bin, failures.is_empty()) else {
        return failures;
    };
    let dir = tools::root().join("target").join("e2e");
    if let Err(e) = std::fs::create_dir_all(&dir) {
        return vec![format!("{}: {e}", dir.display())];
    }
    let which: &[Which] = match opts.actuator {
        Which::Both => &[Which::OnChip, Which::Bimorph],
        Which::OnChip => &[Which::OnChip],
        Which::Bimorph => &[Which::Bimorph],
    };
    let mut lines = Vec::new();
    for &w in which {
        let go = || -> Result<(serde_json::Value, Option<serde_json::Value>), String> {
            // On the on-chip actuator nothing waits for the host: the board's clock is
            // QEMU's virtual one alone. With a host in the loop it follows the wall's.
            let session = Session::start(opts.board, &elf, w == Which::OnChip)?;
            eprintln!("{} on {}: {w:?}", opts.board.name(), session.pty);
            if w == Which::OnChip {
                set_plant(&session.pty)?;
            }
            let v = flow(&bin, &session.pty, w, &dir)?;
            let c = if w == Which::OnChip { Some(crash(&bin, &session.pty, &dir)?) } else { None };
            Ok((v, c))
        };
        match go() {
            Ok((v, crash)) => {
                let get = |k: &str| v.get(k).and_then(serde_json::Value::as_f64).unwrap_or(f64::NAN);
                let (expected, logged) = (get("samples_expected"), get("samples_logged"));
                let all = expected == logged && expected == (RUN_SECONDS * 1000) as f64;
                if !all {
                    failures.push(format!("{w:?}: {logged} of {expected} samples logged"));
                }
                let (run, inproc) = (get("run_rmse_um"), get("inprocess_rmse_um"));
                let within = (run - inproc).abs() <= TOLERANCE * inproc;
                if !within || run.is_nan() || inproc.is_nan() {
                    failures.push(format!(
                        "{w:?}: run RMSE {run:.4} µm, the same design in-process {inproc:.4} µm: more than {:.0} % apart",
                        TOLERANCE * 100.0
                    ));
                }
                if let Some(c) = crash {
                    lines.push(c);
                }
                lines.push(v);
            }
            Err(e) => failures.push(format!("{w:?}: {e}")),
        }
    }
    for l in &lines {
        if opts.json {
            println!("{l}");
        } else {
            eprintln!("{l}");
        }
    }
    failures
}

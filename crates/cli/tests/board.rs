//! `boucwen board` end to end without hardware: the board is the firmware's own state
//! machine (`boucwen_link::device::Device`) in a thread, ticking every millisecond, with
//! its on-chip simulated actuator, on one end of a pseudo-terminal; the commands run as a
//! user runs them, on the other end. (`cargo xtask e2e` does the same with the firmware in
//! QEMU.)
//!
//! * excite → record → design → load → run: every sample logged, the run's tracking error
//!   the same as the same design's on the same actuator in-process;
//! * the host killed mid-run: the record holds every sample the board sent before the kill
//!   (those the host had time to read: sent at least [`READ_SLACK`] earlier), each exactly
//!   as sent, and the board ramps its drive to 0 V on its own.

use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
use boucwen_core::signal::Oscillator;
use boucwen_lab::design::board::DesignFile;
use boucwen_link::analog::NoFrontEnd;
use boucwen_link::device::{Controller, Device, TimerRequest};
use boucwen_link::message::{PlantParams, SafeReason, command_flags};
use boucwen_link::plant::OnChipPlant;
use boucwen_link::{Decoder, Message, Packet};
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// How long the host may take to read and write what the board sent (a debug build on a
/// loaded two-core machine).
const READ_SLACK: Duration = Duration::from_millis(300);

/// The on-chip actuator: the self-test's plant of `cargo xtask qemu` (a resonance near
/// 70 Hz, a third harmonic of 23 Hz).
fn plant() -> PlantParams {
    let w0 = std::f64::consts::TAU * 70.0e-3;
    PlantParams {
        base: ExtendedParams {
            bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
            ar: [(2.0 * 0.97 * w0.cos()) as f32, -0.97 * 0.97, 0.0],
        },
        drive: Oscillator::new(23.0, 1e-3).unwrap(),
        branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }].into_iter().collect(),
    }
}

/// What the board did, for the checks.
#[derive(Default)]
struct Seen {
    /// Telemetry of runs (not the ramp): `(when, k, u, y)`.
    telemetry: Vec<(Instant, u32, f32, f32)>,
    /// The board's `Safe` messages: when, reason.
    safe: Vec<(Instant, u8)>,
    /// Runs started.
    runs: u32,
}

struct Board {
    pty: String,
    stop: Arc<AtomicBool>,
    seen: Arc<Mutex<Seen>>,
    device: Arc<Mutex<Device>>,
    thread: Option<std::thread::JoinHandle<()>>,
    _slave: TTYPort,
}

impl Board {
    fn start() -> Self {
        let (mut master, slave) = TTYPort::pair().expect("a pseudo-terminal pair");
        let pty = slave.name().expect("the pseudo-terminal's name");
        master.set_timeout(Duration::from_micros(200)).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let seen = Arc::new(Mutex::new(Seen::default()));
        let device = Arc::new(Mutex::new(Device::new()));
        // The actuator is the board's: configured at "manufacture".
        device
            .lock()
            .unwrap()
            .on_packet(Ok(Packet { seq: 0, msg: Message::SetPlant(plant()) }), &mut |_: &[u8]| {});
        let (stop2, seen2, dev2) = (stop.clone(), seen.clone(), device.clone());
        let thread = std::thread::spawn(move || {
            let mut dec = Decoder::new();
            let mut watch = Decoder::new();
            let mut next_tick = Instant::now();
            let mut buf = [0u8; 512];
            let mut out = Vec::new();
            while !stop2.load(Ordering::Relaxed) {
                let n = match master.read(&mut buf) {
                    Ok(n) => n,
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
                    Err(_) => 0,
                };
                out.clear();
                {
                    let mut dev = dev2.lock().unwrap();
                    let mut send = |b: &[u8]| out.extend_from_slice(b);
                    for &b in &buf[..n] {
                        if let Some(p) = dec.push(b) {
                            if let TimerRequest::Start { .. } = dev.on_packet(p, &mut send) {
                                seen2.lock().unwrap().runs += 1;
                            }
                        }
                    }
                    // The sample timer: every millisecond, whatever the host does.
                    while Instant::now() >= next_tick {
                        dev.on_tick(0, &mut NoFrontEnd, &|| 0, &mut send);
                        next_tick += Duration::from_millis(1);
                    }
                }
                if out.is_empty() {
                    continue;
                }
                let now = Instant::now();
                {
                    let mut s = seen2.lock().unwrap();
                    for &b in &out {
                        match watch.push(b) {
                            Some(Ok(Packet { msg: Message::Telemetry { k, u, y, flags }, .. }))
                                if flags & command_flags::SAFE_RAMP == 0 =>
                            {
                                s.telemetry.push((now, k, u, y))
                            }
                            Some(Ok(Packet { msg: Message::Safe { reason, .. }, .. })) => {
                                s.safe.push((now, reason))
                            }
                            _ => {}
                        }
                    }
                }
                // A host that is gone leaves the bytes unread; the board does not wait.
                let _ = master.write_all(&out);
            }
        });
        Board { pty, stop, seen, device, thread: Some(thread), _slave: slave }
    }
}

impl Drop for Board {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn boucwen(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_boucwen")).args(args).output().expect("run boucwen")
}

fn ok(args: &[&str]) -> String {
    let o = boucwen(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{args:?}: {err}");
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("boucwen-board-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn last_json(stdout: &str) -> serde_json::Value {
    serde_json::from_str(stdout.lines().last().expect("output")).expect("a JSON last line")
}

/// The data rows of a record: `(t, u, y, d, flags)` as written (`d`, `flags` if present).
fn rows(path: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').map(str::to_owned).collect())
        .collect()
}

/// The two tests each run a board in real time and `boucwen` beside it: one at a time, so
/// that on a 2-core machine neither starves the other's host.
static ONE_BOARD: Mutex<()> = Mutex::new(());

#[test]
fn excite_design_load_run_on_the_board() {
    let _one = ONE_BOARD.lock().unwrap_or_else(|e| e.into_inner());
    let board = Board::start();
    let dir = temp_dir("e2e");
    let (rec, design, run) = (dir.join("rec.csv"), dir.join("design.json"), dir.join("run.csv"));
    let p = board.pty.as_str();
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    ok(&[
        "board",
        "excite",
        "--port",
        p,
        "--actuator",
        "on-chip",
        "--sine",
        "23Hz:1V",
        "--seconds",
        "4",
        "-o",
        &s(&rec),
    ]);
    // The record is one the lab's importer reads; identify fits it.
    ok(&["identify", &s(&rec)]);
    let out = ok(&["board", "design", &s(&rec), "-o", &s(&design), "--amplitude", "20", "--json"]);
    let d = last_json(&out);
    assert_eq!(d["harmonics"], serde_json::json!([3]), "{out}");
    let design_rmse = d["design_rmse_um"].as_f64().unwrap();
    let out = ok(&["board", "load", "--port", p, &s(&design)]);
    assert!(out.contains("27 fields equal bit for bit"), "{out}");
    let out = ok(&[
        "board",
        "run",
        "--port",
        p,
        "--actuator",
        "on-chip",
        "--reference",
        "sine:23Hz:20um",
        "--seconds",
        "5",
        "-o",
        &s(&run),
        "--json",
    ]);
    let r = last_json(&out);
    assert_eq!(r["samples_expected"], 5000, "{out}");
    assert_eq!(r["samples_logged"], 5000, "{out}");
    let run_rmse = r["rmse_um"].as_f64().unwrap();
    // In-process: the design's compensator (the board's controller code) on the same
    // actuator (the board's plant model), every measurement used at the next step.
    let (params, _) = DesignFile::read(&design).unwrap().board_params().unwrap();
    let mut c = Controller::new(&params).unwrap();
    let mut a = OnChipPlant::new(&plant()).unwrap();
    let (mut y_prev, mut sq) = (None, 0.0);
    let settle = boucwen_lab::design::board::settle_samples(5000, params.fade_samples);
    for k in 0..5000 {
        let step = c.step(y_prev).unwrap();
        let y = a.step(step.out.u);
        y_prev = Some(y);
        if k >= settle {
            sq += (y as f64 - step.d as f64).powi(2);
        }
    }
    let inprocess = (sq / (5000 - settle) as f64).sqrt();
    eprintln!("run {run_rmse} µm, in-process {inprocess} µm, design {design_rmse} µm");
    assert!((run_rmse - inprocess).abs() <= 1e-9 * inprocess, "run {run_rmse}, in-process {inprocess}");
    // The design's prediction (on the model fitted to the record) is within 20 % of it.
    assert!(run_rmse < 1.0, "{out}");
    assert!((run_rmse - design_rmse).abs() <= 0.2 * run_rmse, "run {run_rmse}, design {design_rmse}");
    // Every row of the record is the board's telemetry, bit for bit.
    let rows = rows(&run);
    assert_eq!(rows.len(), 5000);
    let seen = board.seen.lock().unwrap();
    let tel: Vec<_> = seen.telemetry.iter().rev().take(5001).rev().collect();
    for (k, row) in rows.iter().enumerate() {
        assert_eq!(row[1].parse::<f32>().unwrap().to_bits(), tel[k].2.to_bits(), "u at {k}");
        assert_eq!(row[2].parse::<f64>().unwrap(), tel[k + 1].3 as f64, "y at {k}");
        assert_eq!(row[4], "0", "flags at {k}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_killed_host_leaves_every_sample_received_and_the_board_goes_safe() {
    let _one = ONE_BOARD.lock().unwrap_or_else(|e| e.into_inner());
    let board = Board::start();
    let dir = temp_dir("kill");
    let (rec, design, run) = (dir.join("rec.csv"), dir.join("design.json"), dir.join("run.csv"));
    let p = board.pty.as_str();
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    ok(&[
        "board",
        "excite",
        "--port",
        p,
        "--actuator",
        "on-chip",
        "--sine",
        "23:1",
        "--seconds",
        "3",
        "-o",
        &s(&rec),
    ]);
    ok(&["board", "design", &s(&rec), "-o", &s(&design), "--amplitude", "20"]);
    ok(&["board", "load", "--port", p, &s(&design)]);
    let runs_before = board.seen.lock().unwrap().runs;
    let mut child = Command::new(env!("CARGO_BIN_EXE_boucwen"))
        .args(["board", "run", "--port", p, "--actuator", "on-chip", "--reference", "sine:23:20um"])
        .args(["--seconds", "30", "-o", &s(&run)])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Kill it (SIGKILL: no handler runs) a second and a half into the run.
    let started = Instant::now();
    loop {
        let n = board.seen.lock().unwrap().telemetry.len();
        if board.seen.lock().unwrap().runs > runs_before && n > 0 {
            let first_of_run = board.seen.lock().unwrap().telemetry.iter().rposition(|t| t.1 == 0).unwrap();
            // ... and the host has been writing its record (it creates the file at the
            // first complete sample).
            if n - first_of_run >= 1500 && run.exists() {
                break;
            }
        }
        assert!(started.elapsed() < Duration::from_secs(30), "the run did not start");
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap();
    let killed_at = Instant::now();
    child.wait().unwrap();
    let (tel, _first) = {
        let seen = board.seen.lock().unwrap();
        let first = seen.telemetry.iter().rposition(|t| t.1 == 0).unwrap();
        (seen.telemetry[first..].to_vec(), first)
    };
    // Sample k is complete when the telemetry of k + 1 has arrived.
    let sent_in_time = tel.iter().filter(|t| t.0 + READ_SLACK <= killed_at).count().saturating_sub(1);
    let rows = rows(&run);
    assert!(
        rows.len() >= sent_in_time,
        "{} rows, {sent_in_time} samples sent {READ_SLACK:?} before the kill",
        rows.len()
    );
    assert!(rows.len() < tel.len(), "more rows than samples sent");
    for (k, row) in rows.iter().enumerate() {
        assert_eq!(row.len(), 5, "row {k} whole: {row:?}");
        assert_eq!(row[1].parse::<f32>().unwrap().to_bits(), tel[k].2.to_bits(), "u at {k}");
        assert_eq!(row[2].parse::<f64>().unwrap(), tel[k + 1].3 as f64, "y at {k}");
    }
    eprintln!(
        "killed after {} samples sent; the record holds {} ({} sent {READ_SLACK:?} before)",
        tel.len(),
        rows.len(),
        sent_in_time
    );
    // The board, with no host, ends the run and ramps to 0 V: within the host timeout
    // (250 ms) plus the ramp (at most 10 V at 100 V/s), with margin for the thread.
    let until = Instant::now() + Duration::from_secs(3);
    loop {
        let safe = board
            .seen
            .lock()
            .unwrap()
            .safe
            .iter()
            .any(|&(t, r)| t > killed_at && r == SafeReason::HostLost as u8);
        if safe {
            break;
        }
        assert!(Instant::now() < until, "no safe state after the host was killed");
        std::thread::sleep(Duration::from_millis(10));
    }
    let dev = board.device.lock().unwrap();
    assert_eq!(dev.drive_v(), 0.0);
    assert!(!dev.running());
    let _ = std::fs::remove_dir_all(&dir);
}

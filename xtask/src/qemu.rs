//! `cargo xtask qemu`: the firmware's self-test in QEMU, checked bit for bit against the
//! same computation on the host.
//!
//! The scenario (below) is encoded with the wire protocol into a frames file that the
//! firmware reads through semihosting; the host decodes the *same bytes* and runs the same
//! `boucwen_link::device::ClosedLoop` in `f32`. Every `u[k]` and `y[k]` the firmware
//! prints must equal the host's bit for bit.
//!
//! Instructions per control step: QEMU runs with `-icount shift=0` (one instruction per
//! nanosecond of virtual time); the firmware times each step with a 25 MHz CMSDK timer,
//! and calibrates that clock against a spin loop of known length (`clock` line). The mean
//! step is `(Σ step ticks − Σ empty ticks) · instructions per tick / N`.

use crate::elf;
use crate::session::Session;
use crate::tools::{self, Board};
use boucwen_core::compensator::{HarmonicSpec, PhaseRule, Saturation, harmonic_response};
use boucwen_core::controllers::{TuneOptions, tune};
use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
use boucwen_core::rls::RlsConfig;
use boucwen_hal::transport::{self, Link};
use boucwen_lab::design::{ReferenceSpec, controller_params, orc_params};
use boucwen_link::Packet;
use boucwen_link::analog::NoFrontEnd;
use boucwen_link::device::{Device, Reference};
use boucwen_link::message::{ControllerParams, Mode, OrcParams, PlantParams};
use boucwen_link::message::{Diagnostics, RunState, SafetyParams};
use boucwen_link::{self as wire, Decoder, Message};
use std::path::Path;
use std::time::Duration;
use std::time::Instant;

/// The sample interval of the scenario, s.
const TS: f64 = 1e-3;
/// Budget: instructions per control step.
pub const STEP_BUDGET_INSNS: f64 = 2000.0;
/// Budget: flash bytes.
pub const FLASH_BUDGET: u32 = 64 * 1024;
/// Budget: RAM bytes.
pub const RAM_BUDGET: u32 = 16 * 1024;

/// A self-test case: drive frequency and the plant's harmonic branches (order, `α_s`, `α_c`
/// in µm), all of which the compensator cancels.
pub struct Case {
    /// Name in the report.
    pub name: &'static str,
    /// Drive frequency, Hz.
    pub drive_hz: f64,
    /// The plant's harmonic branches.
    pub branches: &'static [(u32, f32, f32)],
    /// Run the odd-harmonic repetitive controller (tuned from the model) instead of the
    /// compensator (firmware feature `orc`).
    pub orc: bool,
    /// The compensator's preview `τ`, samples (0: none): its inverse works on the
    /// reference `τ` samples ahead.
    pub preview_samples: f64,
}

/// The cases run: the paper's 23 Hz with its third harmonic, the worst case the board
/// supports (two cancelled harmonics: the third and fifth of 14 Hz, the fifth on the
/// resonance), and the first with the reference previewed by 1.3 samples (a fractional
/// preview: the sine and the fade-in each evaluated at `k + τ`; the on-chip plant has no
/// input delay, so this case checks the computation bit for bit, not the tracking).
pub const CASES: [Case; 3] = [
    Case {
        name: "23 Hz, 3rd harmonic",
        drive_hz: 23.0,
        branches: &[(3, 0.10, -0.06)],
        orc: false,
        preview_samples: 0.0,
    },
    Case {
        name: "14 Hz, 3rd and 5th harmonics",
        drive_hz: 14.0,
        branches: &[(3, 0.05, 0.03), (5, 0.08, -0.04)],
        orc: false,
        preview_samples: 0.0,
    },
    Case {
        name: "23 Hz, 3rd harmonic, preview 1.3 samples",
        drive_hz: 23.0,
        branches: &[(3, 0.10, -0.06)],
        orc: false,
        preview_samples: 1.3,
    },
];

/// The case of `--orc`: Li et al.'s odd-harmonic repetitive controller on its PI, tuned by
/// the core's rule from the model, on the 23 Hz plant.
pub const ORC_CASE: Case = Case {
    name: "23 Hz, ORC on PI",
    drive_hz: 23.0,
    branches: &[(3, 0.10, -0.06)],
    orc: true,
    preview_samples: 0.0,
};

/// The self-test's actuator and controller for `case`: a plant in µm per volt with a
/// lightly damped resonance near 70 Hz, the Bouc–Wen loop of the core's tests and the
/// case's harmonic branches; the compensator inverts the plant's extended part exactly and
/// cancels every branch with the model's phase at `n·f`. Reference: 20 µm, faded in over
/// 0.5 s.
pub fn scenario(case: &Case) -> Result<(ControllerParams, PlantParams, Option<OrcParams>), String> {
    let w0 = std::f64::consts::TAU * 70.0 * TS;
    let ext = ExtendedParams::<f64, 2> {
        bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
        ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
    };
    let harmonics: Vec<HarmonicSpec<f64>> = case
        .branches
        .iter()
        .map(|&(order, _, _)| HarmonicSpec {
            order,
            response: harmonic_response(&ext, order, case.drive_hz, TS, PhaseRule::Model),
        })
        .collect();
    let reference = ReferenceSpec {
        freq_hz: case.drive_hz,
        amplitude_um: 20.0,
        fade_s: 0.5,
        preview_samples: case.preview_samples,
    };
    let controller = controller_params(
        &ext,
        &harmonics,
        RlsConfig::with_forgetting(0.999, 1e-2),
        Saturation::symmetric(10.0),
        5.0,
        reference,
        TS,
    )
    .map_err(|e| format!("{}: {e}", case.name))?;
    let plant = PlantParams {
        base: controller.model,
        drive: controller.drive,
        branches: case
            .branches
            .iter()
            .map(|&(order, alpha_s, alpha_c)| HarmonicBranch { order, alpha_s, alpha_c, ar: [] })
            .collect(),
    };
    let orc = if case.orc {
        let t = tune(&ext, controller.drive, TS, Saturation::symmetric(10.0), &TuneOptions::default())
            .map_err(|e| format!("{}: tuning: {e}", case.name))?;
        Some(orc_params(&t.pi.pi, &t.orc.orc).map_err(|e| format!("{}: {e}", case.name))?)
    } else {
        None
    };
    Ok((controller, plant, orc))
}

/// The frames file of a self-test of `case` for `samples` samples.
pub fn frames(case: &Case, samples: u32) -> Result<Vec<u8>, String> {
    let (c, p, orc) = scenario(case)?;
    let mut out = Vec::new();
    let mut msgs = vec![Message::SetController(c), Message::SetPlant(p)];
    msgs.extend(orc.map(Message::SetOrc));
    msgs.push(Message::Start { mode: Mode::Simulated, samples });
    for (seq, m) in msgs.iter().enumerate() {
        out.extend_from_slice(
            &wire::encode(seq as u16, m).map_err(|e| format!("encoding the scenario: {e}"))?,
        );
    }
    Ok(out)
}

/// The messages of the frames file (decoded back: the host runs what the board gets).
fn messages(frames: &[u8]) -> Result<Vec<Message>, String> {
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    for &b in frames {
        match dec.push(b) {
            Some(Ok(p)) => out.push(p.msg),
            Some(Err(e)) => return Err(format!("frames: {e}")),
            None => {}
        }
    }
    Ok(out)
}

/// One sample of telemetry: `(k, u bits, y bits)` (`y` is the measurement the step used).
type Sample = (u32, u32, u32);

/// The host's run of the same messages: the board's own `Device` in a `Simulated` run,
/// ticked until the run ends; its telemetry and the reference `d[k]`.
pub fn host_run(msgs: &[Message]) -> Result<(Vec<Sample>, Vec<f32>), String> {
    let mut dev = Device::new();
    let mut out = Vec::new();
    let mut sink = |b: &[u8]| out.extend_from_slice(b);
    let (mut n, mut controller) = (0, None);
    for (seq, m) in msgs.iter().enumerate() {
        dev.on_packet(Ok(Packet { seq: seq as u16, msg: m.clone() }), &mut sink);
        match m {
            Message::Start { samples, .. } => n = *samples,
            Message::SetController(c) => controller = Some(c.clone()),
            _ => {}
        }
        // The board's answers are checked on the board's side; here only the run counts.
    }
    for _ in 0..n {
        dev.on_packet(Ok(Packet { seq: 0xFFFF, msg: Message::GetStatus }), &mut |_: &[u8]| {});
        dev.on_tick(0, &mut NoFrontEnd, &|| 0, &mut sink);
    }
    let mut dec = Decoder::new();
    let mut samples = Vec::new();
    for &b in &out {
        match dec.push(b) {
            Some(Ok(Packet { msg: Message::Telemetry { k, u, y, .. }, .. })) => {
                samples.push((k, u.to_bits(), y.to_bits()))
            }
            Some(Ok(Packet { msg: Message::Fault(f), .. })) => {
                return Err(format!("host run: {:?}: {}", f.code, f.text));
            }
            _ => {}
        }
    }
    let c = controller.ok_or("frames lack SetController")?;
    let mut r = Reference::new(&c);
    let d = (0..n).map(|_| r.next_sample()).collect();
    Ok((samples, d))
}

/// What the board sent during a self-test.
struct BoardRun {
    samples: Vec<Sample>,
    diag: Option<Diagnostics>,
    faults: Vec<String>,
}

/// Runs the self-test's messages on the board over its link: configuration (with a host
/// timeout long enough for a run the host only watches), the run, then the diagnostics.
fn board_run(pty: &str, msgs: &[Message], n: u32) -> Result<BoardRun, String> {
    let port = transport::open_serial(pty, crate::BAUD).map_err(|e| e.to_string())?;
    let mut link = Link::new(port);
    let timeout = Duration::from_secs(2);
    let mut faults = Vec::new();
    link.flush_peer().map_err(|e| e.to_string())?;
    let quiet = SafetyParams { host_timeout_ms: 60_000, ..SafetyParams::DEFAULT };
    for m in std::iter::once(&Message::SetSafety(quiet)).chain(msgs) {
        let want = m.kind();
        let ok = link
            .request(m, 3, timeout, |seq, a| match a {
                Message::Ack { kind, seq: s } if *kind == want && *s == seq => Some(Ok(())),
                Message::Fault(f) if f.seq == seq => Some(Err(format!("{:?}: {}", f.code, f.text))),
                _ => None,
            })
            .map_err(|e| e.to_string())?;
        match ok {
            Some(Ok(())) => {}
            Some(Err(e)) => return Err(format!("the board refused {m:?}: {e}")),
            None => return Err(format!("no answer from the board to message kind 0x{want:02x}")),
        }
    }
    let mut samples = Vec::with_capacity(n as usize);
    loop {
        match link.recv(Instant::now() + Duration::from_secs(10)).map_err(|e| e.to_string())? {
            None => {
                faults.push(format!("the board went silent after {} samples", samples.len()));
                break;
            }
            Some(Err(e)) => faults.push(format!("a damaged frame from the board: {e}")),
            Some(Ok(p)) => match p.msg {
                Message::Telemetry { k, u, y, .. } => samples.push((k, u.to_bits(), y.to_bits())),
                Message::Status(s) if s.state != RunState::Running as u8 => break,
                Message::Fault(f) => faults.push(format!("{:?}: {}", f.code, f.text)),
                _ => {}
            },
        }
    }
    let diag = link
        .request(&Message::GetDiagnostics, 3, timeout, |_, m| match m {
            Message::Diagnostics(d) => Some(*d),
            _ => None,
        })
        .map_err(|e| e.to_string())?;
    Ok(BoardRun { samples, diag, faults })
}

/// Instructions per clock unit, from the board's calibration.
pub fn insns_per_unit(d: &Diagnostics) -> f64 {
    if d.calib_ticks == 0 { f64::NAN } else { d.calib_insns as f64 / d.calib_ticks as f64 }
}

/// One case's results.
struct CaseResult {
    samples: usize,
    mismatches: usize,
    max_abs_diff: f64,
    insns_per_sample: f64,
    max_step_insns: f64,
    isr_insns_mean: f64,
    stack: u32,
    rmse_um: f64,
}

/// Runs `case` on the board in QEMU and compares it with the host; failures go to `failures`.
fn run_case(
    board: Board,
    elf: &Path,
    case: &Case,
    samples: u32,
    failures: &mut Vec<String>,
) -> Option<CaseResult> {
    let mut fail = |what: String| failures.push(format!("{}: {what}", case.name));
    let msgs = match frames(case, samples).and_then(|f| messages(&f)) {
        Ok(m) => m,
        Err(e) => {
            fail(e);
            return None;
        }
    };
    let (host, d) = match host_run(&msgs) {
        Ok(h) => h,
        Err(e) => {
            fail(e);
            return None;
        }
    };
    eprintln!("running the self-test on {} in QEMU: {} ({samples} samples)", board.name(), case.name);
    let session = match Session::start(board, elf, true) {
        Ok(s) => s,
        Err(e) => {
            fail(e);
            return None;
        }
    };
    let run = match board_run(&session.pty, &msgs, samples) {
        Ok(r) => r,
        Err(e) => {
            fail(e);
            return None;
        }
    };
    drop(session);
    for f in &run.faults {
        fail(f.clone());
    }
    if run.samples.len() != host.len() {
        fail(format!("the board sent {} samples, the host computed {}", run.samples.len(), host.len()));
    }
    let (mut mismatches, mut max_abs_diff, mut first_bad) = (0usize, 0.0f64, None);
    for &(k, u, y) in &run.samples {
        let Some(&(hk, hu, hy)) = host.get(k as usize) else {
            fail(format!("the board sent sample {k}, beyond the run"));
            continue;
        };
        let du = (f32::from_bits(u) as f64 - f32::from_bits(hu) as f64).abs();
        max_abs_diff = if du.is_nan() { f64::INFINITY } else { max_abs_diff.max(du) };
        if (k, u, y) != (hk, hu, hy) {
            mismatches += 1;
            first_bad.get_or_insert((k, u, hu, y, hy));
        }
    }
    if let Some((k, u, hu, y, hy)) = first_bad {
        fail(format!(
            "{mismatches} samples differ from the host; first at k = {k}: u {u:08x} vs {hu:08x}, y {y:08x} vs {hy:08x}"
        ));
    }
    let Some(diag) = run.diag else {
        fail("no diagnostics from the board".into());
        return None;
    };
    if diag.tx_dropped > 0 || diag.missed_ticks > 0 {
        fail(format!(
            "the board dropped {} frames (transmit queue full) and missed {} ticks",
            diag.tx_dropped, diag.missed_ticks
        ));
    }
    let per = insns_per_unit(&diag);
    let steps = diag.steps.max(1) as f64;
    let overhead = diag.clock_overhead_ticks as f64;
    let insns_per_sample = (diag.step_ticks_sum as f64 / steps - overhead) * per;
    // The interrupts of the run's ticks, one control step each.
    let isr_insns_mean = (diag.isr_ticks_sum as f64 / steps - overhead) * per;
    // Tracking: y the step used is y[k-1].
    let settle = 1500.min(run.samples.len());
    let tail: Vec<f64> = run.samples[settle..]
        .iter()
        .filter(|s| s.0 >= 1)
        .map(|&(k, _, y)| f32::from_bits(y) as f64 - d[k as usize - 1] as f64)
        .collect();
    let rmse_um = (tail.iter().map(|e| e * e).sum::<f64>() / tail.len().max(1) as f64).sqrt();
    Some(CaseResult {
        samples: run.samples.len(),
        mismatches,
        max_abs_diff,
        insns_per_sample,
        max_step_insns: diag.step_ticks_max as f64 * per,
        isr_insns_mean,
        stack: diag.stack_peak_bytes,
        rmse_um,
    })
}

/// The self-test's figures (worst case over the cases).
pub struct Summary {
    /// Samples compared, all cases.
    pub samples: usize,
    /// Largest |u_firmware − u_host|, V.
    pub max_abs_diff: f64,
    /// Mean instructions per control step, largest over the cases.
    pub insns_per_sample: f64,
    /// Flash bytes.
    pub flash_bytes: u32,
    /// RAM bytes (statics and the largest peak stack).
    pub ram_bytes: u32,
}

/// Builds (with the `orc` feature if `orc`), runs every case (the ORC's too if `orc`) and
/// checks; returns the figures and every failure found.
pub fn run(board: Board, samples: u32, json: bool, orc: bool) -> (Option<Summary>, Vec<String>) {
    let mut failures = Vec::new();
    if let Err(mut e) = tools::check(&[&tools::QEMU]) {
        failures.append(&mut e);
    }
    let features = board.qemu_features(if orc { &["orc"] } else { &[] });
    let elf = match tools::build_firmware(&features) {
        Ok(e) => e,
        Err(mut e) => {
            failures.append(&mut e);
            return (None, failures);
        }
    };
    if !failures.is_empty() {
        return (None, failures);
    }
    let usage = match elf::usage(&elf) {
        Ok(u) => Some(u),
        Err(e) => {
            failures.push(e);
            None
        }
    };
    if samples < 1000 {
        failures.push(format!("--samples {samples}: at least 1000 are required"));
    }
    let out = |s: String| if json { eprintln!("{s}") } else { println!("{s}") };
    let mut results = Vec::new();
    let preview = !features.contains(&"no-preview");
    if !preview {
        out("this build has no preview of the reference (feature no-preview): its case is left out".into());
    }
    let cases: Vec<&Case> = CASES
        .iter()
        .filter(|c| preview || c.preview_samples == 0.0)
        .chain(orc.then_some(&ORC_CASE))
        .collect();
    for case in cases {
        let Some(r) = run_case(board, &elf, case, samples, &mut failures) else { continue };
        out(format!("{}:", case.name));
        out(format!(
            "  {} samples, {} differ from the host (max |Δu| = {:e} V); tracking RMSE after 1.5 s {:.4} µm of 20 µm",
            r.samples, r.mismatches, r.max_abs_diff, r.rmse_um
        ));
        out(format!(
            "  control step ({}): {:.1} instructions mean, {:.0} largest; whole tick interrupt {:.1} mean; peak stack {} B",
            if case.orc {
                "reference, PI, odd-harmonic internal model"
            } else {
                "reference, u_f, harmonic RLS"
            },
            r.insns_per_sample,
            r.max_step_insns,
            r.isr_insns_mean,
            r.stack
        ));
        if r.insns_per_sample.is_nan() || r.insns_per_sample > STEP_BUDGET_INSNS {
            failures.push(format!(
                "{}: control step takes {:.0} instructions (budget {STEP_BUDGET_INSNS})",
                case.name, r.insns_per_sample
            ));
        }
        results.push(r);
    }
    let stack = results.iter().map(|r| r.stack).max().unwrap_or(0);
    let (flash_bytes, static_ram) = usage.as_ref().map_or((0, 0), |u| (u.flash_bytes, u.static_ram_bytes));
    let ram_bytes = static_ram + stack;
    if flash_bytes > FLASH_BUDGET {
        failures.push(format!("flash {flash_bytes} B exceeds {FLASH_BUDGET} B"));
    }
    if ram_bytes > RAM_BUDGET {
        failures.push(format!("RAM {ram_bytes} B exceeds {RAM_BUDGET} B"));
    }
    if let Some(u) = &usage {
        let list: Vec<String> = u.sections.iter().map(|s| format!("{} {}", s.name, s.size)).collect();
        out(format!("sections: {}", list.join(", ")));
    }
    out(format!(
        "flash: {flash_bytes} B of {FLASH_BUDGET}; RAM: {ram_bytes} B of {RAM_BUDGET} ({static_ram} static + {stack} peak stack)"
    ));
    if results.is_empty() {
        return (None, failures);
    }
    let summary = Summary {
        samples: results.iter().map(|r| r.samples).sum(),
        max_abs_diff: results.iter().map(|r| r.max_abs_diff).fold(0.0, f64::max),
        insns_per_sample: results.iter().map(|r| r.insns_per_sample).fold(f64::NEG_INFINITY, f64::max),
        flash_bytes,
        ram_bytes,
    };
    (Some(summary), failures)
}

/// The `--json` line.
pub fn json_line(s: &Summary) -> String {
    let num =
        |x: f64| serde_json::Number::from_f64(x).map_or(serde_json::Value::Null, serde_json::Value::Number);
    serde_json::json!({
        "samples": s.samples,
        "max_abs_diff": num(s.max_abs_diff),
        "insns_per_sample": num((s.insns_per_sample * 10.0).round() / 10.0),
        "flash_bytes": s.flash_bytes,
        "ram_bytes": s.ram_bytes,
    })
    .to_string()
}

/// Whether `path` looks like a firmware ELF (used by `firmware`).
pub fn describe(elf: &Path) -> Result<String, String> {
    let u = elf::usage(elf)?;
    Ok(format!(
        "{}: flash {} B of {FLASH_BUDGET}, static RAM {} B of {RAM_BUDGET}",
        elf.display(),
        u.flash_bytes,
        u.static_ram_bytes
    ))
}

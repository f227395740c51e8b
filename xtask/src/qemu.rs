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
use crate::tools::{self, Finished};
use boucwen_core::compensator::{HarmonicSpec, PhaseRule, Saturation, harmonic_response};
use boucwen_core::controllers::{TuneOptions, tune};
use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
use boucwen_core::rls::RlsConfig;
use boucwen_lab::design::{ReferenceSpec, controller_params, orc_params};
use boucwen_link::device::{ClosedLoop, Controller, OnChipPlant, OrcLoop};
use boucwen_link::message::{ControllerParams, Mode, OrcParams, PlantParams};
use boucwen_link::{self as wire, Decoder, Message};
use std::path::Path;
use std::time::Duration;

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
}

/// The cases run: the paper's 23 Hz with its third harmonic, and the worst case the board
/// supports (two cancelled harmonics: the third and fifth of 14 Hz, the fifth on the
/// resonance).
pub const CASES: [Case; 2] = [
    Case { name: "23 Hz, 3rd harmonic", drive_hz: 23.0, branches: &[(3, 0.10, -0.06)], orc: false },
    Case {
        name: "14 Hz, 3rd and 5th harmonics",
        drive_hz: 14.0,
        branches: &[(3, 0.05, 0.03), (5, 0.08, -0.04)],
        orc: false,
    },
];

/// The case of `--orc`: Li et al.'s odd-harmonic repetitive controller on its PI, tuned by
/// the core's rule from the model, on the 23 Hz plant.
pub const ORC_CASE: Case =
    Case { name: "23 Hz, ORC on PI", drive_hz: 23.0, branches: &[(3, 0.10, -0.06)], orc: true };

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
    let reference = ReferenceSpec { freq_hz: case.drive_hz, amplitude_um: 20.0, fade_s: 0.5 };
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
    msgs.push(Message::Start { mode: Mode::Control, samples });
    for (seq, m) in msgs.iter().enumerate() {
        out.extend_from_slice(
            &wire::encode(seq as u16, m).map_err(|e| format!("encoding the scenario: {e}"))?,
        );
    }
    Ok(out)
}

/// The host's run of the same frames: `(u bits, y bits, d)` per sample.
pub fn host_run(frames: &[u8]) -> Result<Vec<(u32, u32, f32)>, String> {
    let (mut c, mut p, mut n, mut orc) = (None, None, None, None);
    let mut dec = Decoder::new();
    for &b in frames {
        match dec.push(b) {
            Some(Ok(pk)) => match pk.msg {
                Message::SetController(x) => c = Some(x),
                Message::SetPlant(x) => p = Some(x),
                Message::SetOrc(x) => orc = Some(x),
                Message::Start { samples, .. } => n = Some(samples),
                other => return Err(format!("unexpected message in the frames: {other:?}")),
            },
            Some(Err(e)) => return Err(format!("frames: {e}")),
            None => {}
        }
    }
    let (c, p, n) = match (c, p, n) {
        (Some(c), Some(p), Some(n)) => (c, p, n),
        _ => return Err("frames lack SetController, SetPlant or Start".into()),
    };
    if let Some(o) = orc {
        let mut l = OrcLoop::new(&c, &o, &p).map_err(|e| format!("ORC: {e}"))?;
        return (0..n)
            .map(|k| {
                let s = l.control().map_err(|e| format!("host step {k}: {e}"))?;
                let y = l.actuate(s.out.u);
                Ok((s.out.u.to_bits(), y.to_bits(), s.d))
            })
            .collect();
    }
    let controller = Controller::new(&c).map_err(|e| format!("controller: {e}"))?;
    let plant = OnChipPlant::new(&p).map_err(|e| format!("plant: {e}"))?;
    let mut cl = ClosedLoop::new(controller, plant);
    (0..n)
        .map(|k| {
            let s = cl.control().map_err(|e| format!("host step {k}: {e}"))?;
            let y = cl.actuate(s.out.u);
            Ok((s.out.u.to_bits(), y.to_bits(), s.d))
        })
        .collect()
}

/// What the firmware printed.
#[derive(Debug, Default)]
struct Printed {
    samples: Vec<(u32, u32, u32)>,
    clock: Option<(u64, u64)>,
    timing: Option<(u64, u64, u64, u64)>,
    stack: Option<u32>,
    done: bool,
    errors: Vec<String>,
}

fn parse(stdout: &str) -> Printed {
    let mut p = Printed::default();
    for line in stdout.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        let num = |i: usize| w.get(i).and_then(|s| s.parse::<u64>().ok());
        let hex = |i: usize| w.get(i).and_then(|s| u32::from_str_radix(s, 16).ok());
        match w.first().copied() {
            Some("sample") => match (num(1), hex(2), hex(3)) {
                (Some(k), Some(u), Some(y)) => p.samples.push((k as u32, u, y)),
                _ => p.errors.push(format!("unreadable line: {line}")),
            },
            Some("clock") => p.clock = num(1).zip(num(2)),
            Some("timing") => {
                p.timing = match (num(1), num(2), num(3), num(4)) {
                    (Some(a), Some(b), Some(c), Some(d)) => Some((a, b, c, d)),
                    _ => None,
                }
            }
            Some("stack") => p.stack = num(1).map(|s| s as u32),
            Some("done") => p.done = true,
            Some("error:") => p.errors.push(line.to_string()),
            _ => {}
        }
    }
    p
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

/// One case's results.
struct CaseResult {
    samples: usize,
    mismatches: usize,
    max_abs_diff: f64,
    insns_per_tick: f64,
    insns_per_sample: f64,
    max_step_insns: f64,
    stack: u32,
    rmse_um: f64,
}

/// Runs `case` in QEMU and compares it with the host; failures go to `failures`.
fn run_case(
    elf: &Path,
    case: &Case,
    index: usize,
    samples: u32,
    failures: &mut Vec<String>,
) -> Option<CaseResult> {
    let feature = case.orc.then_some("orc");
    let mut fail = |what: String| failures.push(format!("{}: {what}", case.name));
    let frames = match frames(case, samples) {
        Ok(f) => f,
        Err(e) => {
            fail(e);
            return None;
        }
    };
    let path = tools::firmware_target_dir(feature).join(format!("selftest-{index}.frames"));
    if let Err(e) = std::fs::write(&path, &frames) {
        fail(format!("{}: {e}", path.display()));
        return None;
    }
    let host = match host_run(&frames) {
        Ok(h) => h,
        Err(e) => {
            fail(e);
            return None;
        }
    };
    let path_str = path.to_string_lossy().into_owned();
    if path_str.contains([' ', ',']) {
        fail(format!("{path_str}: the frames path must not contain spaces or commas (QEMU arguments)"));
        return None;
    }
    eprintln!("running the self-test in QEMU: {} ({samples} samples)", case.name);
    let cmd = tools::qemu_command(elf, &["selftest", &path_str], "null");
    let Finished { status, stdout, stderr } = match tools::run_with_limit(cmd, Duration::from_secs(300)) {
        Ok(f) => f,
        Err(e) => {
            fail(e);
            return None;
        }
    };
    match status {
        None => fail("QEMU did not finish within 300 s".into()),
        Some(s) if !s.success() => fail(format!("the firmware exited with {s}")),
        _ => {}
    }
    if !stderr.trim().is_empty() {
        eprintln!("qemu stderr: {}", stderr.trim());
    }
    let printed = parse(&stdout);
    for e in &printed.errors {
        fail(e.clone());
    }
    if !printed.done {
        fail("the firmware did not finish the self-test (no 'done' line)".into());
    }
    // Bit-for-bit comparison.
    if printed.samples.len() != host.len() {
        fail(format!(
            "the firmware printed {} samples, the host computed {}",
            printed.samples.len(),
            host.len()
        ));
    }
    let (mut mismatches, mut max_abs_diff, mut first_bad) = (0usize, 0.0f64, None);
    for (i, (&(k, u, y), &(hu, hy, _))) in printed.samples.iter().zip(&host).enumerate() {
        if k as usize != i {
            fail(format!("sample line {i} carries index {k}"));
            break;
        }
        let d = (f32::from_bits(u) as f64 - f32::from_bits(hu) as f64).abs();
        max_abs_diff = if d.is_nan() { f64::INFINITY } else { max_abs_diff.max(d) };
        if u != hu || y != hy {
            mismatches += 1;
            first_bad.get_or_insert((k, u, hu, y, hy));
        }
    }
    if let Some((k, u, hu, y, hy)) = first_bad {
        fail(format!(
            "{mismatches} samples differ from the host; first at k = {k}: u {u:08x} vs {hu:08x}, y {y:08x} vs {hy:08x}"
        ));
    }
    let n = printed.samples.len();
    // Timing.
    let insns_per_tick = match printed.clock {
        Some((insns, ticks)) if ticks > 0 => insns as f64 / ticks as f64,
        _ => {
            fail("no clock calibration line".into());
            f64::NAN
        }
    };
    let (insns_per_sample, max_step_insns) = match printed.timing {
        Some((tn, step, empty, max)) if tn > 0 => {
            ((step as f64 - empty as f64) * insns_per_tick / tn as f64, max as f64 * insns_per_tick)
        }
        _ => {
            fail("no timing line".into());
            (f64::NAN, f64::NAN)
        }
    };
    let stack = printed.stack.unwrap_or_else(|| {
        fail("no stack line".into());
        0
    });
    // Tracking on the (identical) host run, after the fade-in and a settling second.
    let settle = 1500.min(host.len()).min(n);
    let tail: Vec<f64> = host[settle..]
        .iter()
        .zip(&printed.samples[settle..])
        .map(|(&(_, _, d), &(_, _, y))| f32::from_bits(y) as f64 - d as f64)
        .collect();
    let rmse_um = (tail.iter().map(|e| e * e).sum::<f64>() / tail.len().max(1) as f64).sqrt();
    Some(CaseResult {
        samples: n,
        mismatches,
        max_abs_diff,
        insns_per_tick,
        insns_per_sample,
        max_step_insns,
        stack,
        rmse_um,
    })
}

/// Builds (with the `orc` feature if `orc`), runs every case (the ORC's too if `orc`) and
/// checks; returns the figures and every failure found.
pub fn run(samples: u32, json: bool, orc: bool) -> (Option<Summary>, Vec<String>) {
    let mut failures = Vec::new();
    if let Err(mut e) = tools::check(&[&tools::QEMU]) {
        failures.append(&mut e);
    }
    let elf = match tools::build_firmware(orc.then_some("orc")) {
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
    let cases: Vec<&Case> = CASES.iter().chain(orc.then_some(&ORC_CASE)).collect();
    for (i, case) in cases.into_iter().enumerate() {
        let Some(r) = run_case(&elf, case, i, samples, &mut failures) else { continue };
        out(format!("{}:", case.name));
        out(format!(
            "  {} samples, {} differ from the host (max |Δu| = {:e} V); tracking RMSE after 1.5 s {:.4} µm of 20 µm",
            r.samples, r.mismatches, r.max_abs_diff, r.rmse_um
        ));
        out(format!(
            "  control step ({}): {:.1} instructions mean, {:.0} ± {:.0} largest; \
             clock {:.3} instructions per 25 MHz tick; peak stack {} B",
            if case.orc {
                "reference, PI, odd-harmonic internal model"
            } else {
                "reference, u_f, harmonic RLS"
            },
            r.insns_per_sample,
            r.max_step_insns,
            r.insns_per_tick,
            r.insns_per_tick,
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

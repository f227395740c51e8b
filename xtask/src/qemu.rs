//! `cargo xtask qemu`: the firmware's self-test in QEMU, checked bit for bit against the
//! same computation on the host.
//!
//! The scenario (below) is encoded with the wire protocol into a frames file that the
//! firmware reads through semihosting; the host decodes the *same bytes* and runs the same
//! `boucwen_hal::wire::device::ClosedLoop` in `f32`. Every `u[k]` and `y[k]` the firmware
//! prints must equal the host's bit for bit.
//!
//! Instructions per control step: QEMU runs with `-icount shift=0` (one instruction per
//! nanosecond of virtual time); the firmware times each step with a 25 MHz CMSDK timer,
//! and calibrates that clock against a spin loop of known length (`clock` line). The mean
//! step is `(Σ step ticks − Σ empty ticks) · instructions per tick / N`.

use crate::elf;
use crate::tools::{self, Finished};
use boucwen_core::compensator::{HarmonicSpec, PhaseRule, Saturation, harmonic_response};
use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
use boucwen_core::rls::RlsConfig;
use boucwen_core::signal::Oscillator;
use boucwen_hal::wire::device::{ClosedLoop, Controller, OnChipPlant};
use boucwen_hal::wire::message::{ControllerParams, MAX_AR, Mode, PlantParams};
use boucwen_hal::wire::{self, Decoder, Message};
use nalgebra::Complex;
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

/// The self-test's actuator and controller: a plant in µm per volt with a lightly damped
/// resonance near 70 Hz, the Bouc–Wen loop of the core's tests and a third harmonic of
/// 23 Hz (about 15 % of the 20 µm reference); the compensator inverts the plant's extended
/// part and cancels the third harmonic with the model's phase at 69 Hz.
pub fn scenario() -> (ControllerParams, PlantParams) {
    let w0 = std::f64::consts::TAU * 70.0 * TS;
    let ext = ExtendedParams::<f64, 2> {
        bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
        ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
    };
    let mut ar = [0.0f32; MAX_AR];
    for (a, &b) in ar.iter_mut().zip(&ext.ar) {
        *a = b as f32;
    }
    let bw = ext.bw;
    let model = ExtendedParams {
        bw: BoucWenParams {
            a1: bw.a1 as f32,
            a: bw.a as f32,
            a0: bw.a0 as f32,
            gamma: bw.gamma as f32,
            beta: bw.beta as f32,
        },
        ar,
    };
    let drive = Oscillator::new(23.0, TS).expect("23 Hz at 1 kHz is below Nyquist");
    let g = harmonic_response(&ext, 3, 23.0, TS, PhaseRule::Model);
    let controller = ControllerParams {
        model,
        drive,
        sample_period_us: 1000,
        amplitude_um: 20.0,
        fade_samples: 500,
        harmonics: [HarmonicSpec { order: 3, response: Complex::new(g.re as f32, g.im as f32) }]
            .into_iter()
            .collect(),
        rls: RlsConfig::with_forgetting(0.999, 1e-2),
        saturation: Saturation::symmetric(10.0),
        uc_max: 5.0,
    };
    let plant = PlantParams {
        base: model,
        drive,
        branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }].into_iter().collect(),
    };
    (controller, plant)
}

/// The frames file of a self-test of `samples` samples.
pub fn frames(samples: u32) -> Result<Vec<u8>, String> {
    let (c, p) = scenario();
    let mut out = Vec::new();
    let msgs =
        [Message::SetController(c), Message::SetPlant(p), Message::Start { mode: Mode::Control, samples }];
    for (seq, m) in msgs.iter().enumerate() {
        out.extend_from_slice(
            &wire::encode(seq as u16, m).map_err(|e| format!("encoding the scenario: {e}"))?,
        );
    }
    Ok(out)
}

/// The host's run of the same frames: `(u bits, y bits, d)` per sample.
pub fn host_run(frames: &[u8]) -> Result<Vec<(u32, u32, f32)>, String> {
    let (mut c, mut p, mut n) = (None, None, None);
    let mut dec = Decoder::new();
    for &b in frames {
        match dec.push(b) {
            Some(Ok(pk)) => match pk.msg {
                Message::SetController(x) => c = Some(x),
                Message::SetPlant(x) => p = Some(x),
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

/// The self-test's figures.
pub struct Summary {
    /// Samples compared.
    pub samples: usize,
    /// Largest |u_firmware − u_host|, V.
    pub max_abs_diff: f64,
    /// Mean instructions per control step.
    pub insns_per_sample: f64,
    /// Flash bytes.
    pub flash_bytes: u32,
    /// RAM bytes (statics and peak stack).
    pub ram_bytes: u32,
}

/// Builds, runs and checks; returns the figures and every failure found.
pub fn run(samples: u32, json: bool) -> (Option<Summary>, Vec<String>) {
    let mut failures = Vec::new();
    if let Err(mut e) = tools::check(&[&tools::QEMU]) {
        failures.append(&mut e);
    }
    let elf = match tools::build_firmware() {
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
    let frames = match frames(samples) {
        Ok(f) => f,
        Err(e) => return (None, vec![e]),
    };
    let path = tools::firmware_target_dir().join("selftest.frames");
    if let Err(e) = std::fs::write(&path, &frames) {
        return (None, vec![format!("{}: {e}", path.display())]);
    }
    let host = match host_run(&frames) {
        Ok(h) => h,
        Err(e) => return (None, vec![e]),
    };
    let path_str = path.to_string_lossy().into_owned();
    if path_str.contains([' ', ',']) {
        return (
            None,
            vec![format!("{path_str}: the frames path must not contain spaces or commas (QEMU arguments)")],
        );
    }
    eprintln!("running the self-test in QEMU ({samples} samples)");
    let cmd = tools::qemu_command(&elf, &["selftest", &path_str], "null");
    let Finished { status, stdout, stderr } = match tools::run_with_limit(cmd, Duration::from_secs(300)) {
        Ok(f) => f,
        Err(e) => return (None, vec![e]),
    };
    match status {
        None => failures.push("QEMU did not finish within 300 s".into()),
        Some(s) if !s.success() => failures.push(format!("the firmware exited with {s}")),
        _ => {}
    }
    if !stderr.trim().is_empty() {
        eprintln!("qemu stderr: {}", stderr.trim());
    }
    let printed = parse(&stdout);
    failures.extend(printed.errors.iter().cloned());
    if !printed.done {
        failures.push("the firmware did not finish the self-test (no 'done' line)".into());
    }
    // Bit-for-bit comparison.
    if printed.samples.len() != host.len() {
        failures.push(format!(
            "the firmware printed {} samples, the host computed {}",
            printed.samples.len(),
            host.len()
        ));
    }
    let (mut mismatches, mut max_abs_diff, mut first_bad) = (0usize, 0.0f64, None);
    for (i, (&(k, u, y), &(hu, hy, _))) in printed.samples.iter().zip(&host).enumerate() {
        if k as usize != i {
            failures.push(format!("sample line {i} carries index {k}"));
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
        failures.push(format!(
            "{mismatches} samples differ from the host; first at k = {k}: u {u:08x} vs {hu:08x}, y {y:08x} vs {hy:08x}"
        ));
    }
    let n = printed.samples.len();
    if n < 1000 {
        failures.push(format!("only {n} samples compared (at least 1000 are required)"));
    }
    // Timing.
    let insns_per_tick = match printed.clock {
        Some((insns, ticks)) if ticks > 0 => insns as f64 / ticks as f64,
        _ => {
            failures.push("no clock calibration line".into());
            f64::NAN
        }
    };
    let (insns_per_sample, max_step_insns) = match printed.timing {
        Some((tn, step, empty, max)) if tn > 0 => {
            ((step as f64 - empty as f64) * insns_per_tick / tn as f64, max as f64 * insns_per_tick)
        }
        _ => {
            failures.push("no timing line".into());
            (f64::NAN, f64::NAN)
        }
    };
    if insns_per_sample.is_nan() || insns_per_sample > STEP_BUDGET_INSNS {
        failures.push(format!(
            "control step takes {insns_per_sample:.0} instructions (budget {STEP_BUDGET_INSNS})"
        ));
    }
    let stack = printed.stack.unwrap_or_else(|| {
        failures.push("no stack line".into());
        0
    });
    let (flash_bytes, static_ram) = usage.as_ref().map_or((0, 0), |u| (u.flash_bytes, u.static_ram_bytes));
    let ram_bytes = static_ram + stack;
    if flash_bytes > FLASH_BUDGET {
        failures.push(format!("flash {flash_bytes} B exceeds {FLASH_BUDGET} B"));
    }
    if ram_bytes > RAM_BUDGET {
        failures.push(format!("RAM {ram_bytes} B exceeds {RAM_BUDGET} B"));
    }
    // Tracking on the (identical) host run, after the fade-in and a settling second.
    let settle = 1500.min(host.len());
    let tail: Vec<f64> = host[settle..]
        .iter()
        .zip(&printed.samples[settle.min(printed.samples.len())..])
        .map(|(&(_, _, d), &(_, _, y))| f32::from_bits(y) as f64 - d as f64)
        .collect();
    let rmse = (tail.iter().map(|e| e * e).sum::<f64>() / tail.len().max(1) as f64).sqrt();

    let out = |s: String| if json { eprintln!("{s}") } else { println!("{s}") };
    out(format!("self-test: {n} samples, {mismatches} differ from the host (max |Δu| = {max_abs_diff:e} V)"));
    out(format!(
        "clock: {:.3} instructions per tick of the 25 MHz timer (measured by a {}-instruction spin loop)",
        insns_per_tick,
        printed.clock.map_or(0, |c| c.0)
    ));
    out(format!(
        "control step (reference, u_f, harmonic RLS): {insns_per_sample:.1} instructions mean, \
         {max_step_insns:.0} ± {insns_per_tick:.0} largest (budget {STEP_BUDGET_INSNS})"
    ));
    if let Some(u) = &usage {
        let list: Vec<String> = u.sections.iter().map(|s| format!("{} {}", s.name, s.size)).collect();
        out(format!("sections: {}", list.join(", ")));
    }
    out(format!(
        "flash: {flash_bytes} B of {FLASH_BUDGET}; RAM: {ram_bytes} B of {RAM_BUDGET} ({static_ram} static + {stack} peak stack)"
    ));
    out(format!("tracking RMSE after {settle} samples: {rmse:.4} µm (20 µm reference)"));
    let summary = Summary { samples: n, max_abs_diff, insns_per_sample, flash_bytes, ram_bytes };
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

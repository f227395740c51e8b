//! `cargo xtask panic`: a panic in the middle of a run, in QEMU, and the drive's ramp to
//! 0 V after the reset that follows.
//!
//! The firmware is built with its `panic-test` hook (a `Stop` during a run panics instead
//! of stopping). The board runs the self-test's compensator on its simulated actuator; once
//! the reference has faded in, the host sends `Stop`. The panic handler adds the reason to
//! the record the tick keeps of the drive (RAM the start-up code leaves alone) and resets
//! the chip (`SYSRESETREQ`, which QEMU honours by restarting the machine with RAM intact).
//! The next start finds the record and ramps the drive from there to 0 V at the slew,
//! reporting each step and then `Safe{reason: Panic}`.
//!
//! The task checks that the ramp starts at a drive the run had (within what the run moved
//! in the ticks the host had not seen yet), falls monotonically to 0 V in steps of at most
//! the slew per period, that `Safe` names the panic and that the board's diagnostics give
//! the panic as the cause of the reset. The watchdog's path is the same after start-up,
//! but QEMU has no model of the STM32's independent watchdog, so it is not run.

use crate::qemu::{CASES, frames};
use crate::session::{Session, request_ok};
use crate::tools::{self, Board};
use boucwen_hal::transport::{self, Link};
use boucwen_link::message::{Mode, SafeReason, SafetyParams, command_flags};
use boucwen_link::{Decoder, Message};
use std::time::{Duration, Instant};

/// Samples of the run before the host sends `Stop` (after the 0.5 s fade-in), at the next
/// peak of the drive (within 10 % of the largest of the last [`PEAK_WINDOW`] samples).
const PANIC_AT: u32 = 800;
/// Samples over which the peak is taken (more than a period of the 23 Hz drive).
const PEAK_WINDOW: usize = 60;

/// What the task saw.
struct Seen {
    /// Drives of the run's last telemetry frames before the panic.
    run: Vec<f32>,
    /// The ramp after the reset.
    ramp: Vec<f32>,
    reason: u8,
    reset_cause: u8,
    period_us: u32,
}

/// Runs the task; returns every failure.
pub fn run(board: Board, json: bool) -> Vec<String> {
    if let Err(e) = tools::check(&[&tools::QEMU]) {
        return e;
    }
    let elf = match tools::build_firmware(&board.qemu_features(&["panic-test"])) {
        Ok(e) => e,
        Err(e) => return e,
    };
    // A slow ramp (the self-test's drive peaks near 0.2 V: at 5 V/s that is some 40 steps),
    // kept across the reset with the drive.
    let safety = SafetyParams { host_timeout_ms: 60_000, slew_v_per_s: 5.0, ..SafetyParams::DEFAULT };
    let go = || -> Result<Seen, String> {
        let session = Session::start(board, &elf, true)?;
        let port = transport::open_serial(&session.pty, crate::BAUD).map_err(|e| e.to_string())?;
        let mut link = Link::new(port);
        link.flush_peer().map_err(|e| e.to_string())?;
        request_ok(&mut link, &Message::SetSafety(safety))?;
        let mut dec = Decoder::new();
        for &b in &frames(&CASES[0], 1000)? {
            match dec.push(b) {
                Some(Ok(p)) if !matches!(p.msg, Message::Start { .. }) => request_ok(&mut link, &p.msg)?,
                _ => {}
            }
        }
        request_ok(&mut link, &Message::Start { mode: Mode::Simulated, samples: 0 })?;
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut run = Vec::new();
        let recv = |link: &mut Link<_>| -> Result<Message, String> {
            loop {
                if Instant::now() > deadline {
                    return Err("the board went silent".into());
                }
                if let Some(Ok(p)) =
                    link.recv(Instant::now() + Duration::from_secs(10)).map_err(|e| e.to_string())?
                {
                    return Ok(p.msg);
                }
            }
        };
        let at = loop {
            match recv(&mut link)? {
                Message::Telemetry { k, u, flags, .. } if flags & command_flags::SAFE_RAMP == 0 => {
                    run.push(u);
                    let window = &run[run.len().saturating_sub(PEAK_WINDOW)..];
                    let peak = window.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                    if k >= PANIC_AT && u.abs() >= 0.9 * peak {
                        break k;
                    }
                }
                _ => {}
            }
        };
        eprintln!(
            "{}: Stop at sample {at}, drive {:.3} V (the panic-test hook panics)",
            board.name(),
            run[run.len() - 1]
        );
        link.send(&Message::Stop).map_err(|e| e.to_string())?;
        let mut ramp = Vec::new();
        let (reason, period_us) = loop {
            match recv(&mut link)? {
                Message::Telemetry { u, flags, .. } if flags & command_flags::SAFE_RAMP != 0 => ramp.push(u),
                Message::Telemetry { .. } if ramp.is_empty() => {}
                Message::Safe { reason, period_us, .. } => break (reason, period_us),
                Message::Status(s) => return Err(format!("the board stopped instead of panicking: {s:?}")),
                _ => {}
            }
        };
        link.flush_peer().map_err(|e| e.to_string())?;
        let d = link
            .request(&Message::GetDiagnostics, 5, Duration::from_secs(2), |_, m| match m {
                Message::Diagnostics(d) => Some(*d),
                _ => None,
            })
            .map_err(|e| e.to_string())?
            .ok_or("no diagnostics from the board")?;
        drop(session);
        let tail = run.len().saturating_sub(10);
        Ok(Seen { run: run[tail..].to_vec(), ramp, reason, reset_cause: d.reset_cause, period_us })
    };
    let seen = match go() {
        Ok(s) => s,
        Err(e) => return vec![e],
    };
    let mut failures = Vec::new();
    let step = safety.slew_v_per_s * seen.period_us as f32 * 1e-6;
    let Some(&from) = seen.ramp.first() else {
        return vec!["no ramp after the reset".into()];
    };
    // The drive the panic left: the last of the run's ticks, a few of which the host had
    // not received when the chip reset (its transmit queue is lost); at a peak the drive
    // moves little in a few ticks. The first step of the ramp is one step below it.
    let (lo, hi) =
        seen.run.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &u| (a.min(u), b.max(u)));
    let span = hi - lo;
    if !(from.abs() + step >= lo.abs().min(hi.abs()) - span && from.abs() <= lo.abs().max(hi.abs()) + span)
        || from.signum() != seen.run[seen.run.len() - 1].signum()
    {
        failures.push(format!("the ramp starts at {from} V; the run's last drives were {:?} V", seen.run));
    }
    if seen.ramp.len() < 5 {
        failures.push(format!("a ramp of {} steps from {from} V shows little", seen.ramp.len()));
    }
    let mut prev = from;
    for &u in &seen.ramp[1..] {
        if !(u.abs() <= prev.abs() && (prev - u).abs() <= step * 1.0001) {
            failures.push(format!("ramp step {prev} V to {u} V (at most {step} V)"));
        }
        prev = u;
    }
    if prev != 0.0 {
        failures.push(format!("the ramp ended at {prev} V"));
    }
    if seen.reason != SafeReason::Panic as u8 || seen.reset_cause != SafeReason::Panic as u8 {
        failures.push(format!(
            "safe state for reason {}, reset cause {} (the panic is {})",
            seen.reason,
            seen.reset_cause,
            SafeReason::Panic as u8
        ));
    }
    let ms = seen.ramp.len() as f64 * seen.period_us as f64 * 1e-3;
    let out = |s: String| if json { eprintln!("{s}") } else { println!("{s}") };
    out(format!(
        "{}: panic during a run; after the reset the drive ramped from {from:.3} V to 0 V in {} steps ({ms:.0} ms at {} V/s); Safe reason {}, reset cause {}",
        board.name(),
        seen.ramp.len(),
        safety.slew_v_per_s,
        seen.reason,
        seen.reset_cause
    ));
    if json {
        println!(
            "{}",
            serde_json::json!({
                "ramp_from_v": from,
                "ramp_steps": seen.ramp.len(),
                "ramp_ms": ms,
                "safe_reason": seen.reason,
                "reset_cause": seen.reset_cause,
            })
        );
    }
    failures
}

//! `cargo xtask timing`: what the control interrupt costs, and whether it keeps its rate
//! while the link is busy with line noise.
//!
//! The board runs the self-test's compensator (two cancelled harmonics, the heavier case)
//! on its simulated actuator for [`SAMPLES`] ticks. Its transmitter is paced at the baud
//! rate (the emulator build's per-byte delay), so its telemetry and its answers take the
//! time they take on a real line. Meanwhile the host sends a burst of damaged frames
//! (each a valid frame with one bit flipped, or cut short), which the board must decode,
//! count and answer at its bounded rate. The frames go out in chunks of 16, as fast as
//! QEMU takes them; how dense the burst was in the board's time is measured from the
//! board's answers to it (rate-bound, but one every 10 ticks while bad frames keep coming)
//! between its telemetry: about the line's rate.
//!
//! QEMU runs with `-icount shift=0,sleep=off`: the board's clock is its instruction count
//! and never follows the host's, so a loaded host cannot make it miss a tick.
//!
//! Afterwards the board's diagnostics give the ticks since the run's start, the ticks
//! missed (an interrupt that started more than 1.5 periods after the previous one), the
//! interrupt's instructions over the run's ticks (worst and mean, from the free-running
//! clock calibrated against a spin loop) and the bad frames counted. Missed ticks, a
//! burst that missed the run, or lost telemetry fail the task.

use crate::qemu::{CASES, frames, insns_per_unit};
use crate::session::{Session, request_ok};
use crate::tools::{self, Board};
use boucwen_hal::transport::{self, Link};
use boucwen_link::message::{Diagnostics, FaultCode, Mode, RunState, SafetyParams, Status};
use boucwen_link::{Decoder, Message, encode};
use std::time::{Duration, Instant};

/// Ticks of the run.
pub const SAMPLES: u32 = 4000;

/// A damaged copy of a measurement frame: one bit flipped (`i` odd) or the frame cut in
/// half (`i` even), delimiter kept.
fn damaged(i: u32) -> Result<Vec<u8>, String> {
    let f = encode(i as u16, &Message::Measurement { k: i, y: i as f32 * 0.5 })
        .map_err(|e| e.to_string())?
        .to_vec();
    let body = f.len() - 1;
    let mut out = if i % 2 == 1 {
        let mut g = f.clone();
        let at = (i as usize * 7) % body;
        let bit = 1u8 << (i % 7);
        g[at] ^= if g[at] ^ bit == 0 { bit << 1 } else { bit };
        g
    } else {
        let mut g = f[..body / 2].to_vec();
        g.push(0);
        g
    };
    out.truncate(f.len());
    Ok(out)
}

/// What the host saw of the run.
#[derive(Default)]
struct Seen {
    telemetry: u32,
    /// The last telemetry's sample index.
    k: u32,
    /// The ticks of the first and the last answer to a bad frame.
    faults: Option<(u32, u32)>,
    /// The run's final status.
    ended: Option<Status>,
}

impl Seen {
    fn handle(&mut self, m: &Message) {
        match m {
            Message::Telemetry { k, .. } => {
                self.telemetry += 1;
                self.k = *k;
            }
            Message::Fault(f) if f.code == FaultCode::BadFrame && self.ended.is_none() => {
                let first = self.faults.map_or(self.k, |(a, _)| a);
                self.faults = Some((first, self.k));
            }
            Message::Status(s) if s.state != RunState::Running as u8 => self.ended = Some(*s),
            _ => {}
        }
    }
}

/// Runs the task; prints the report (and the JSON line) and returns every failure.
pub fn run(board: Board, burst: u32, json: bool) -> Vec<String> {
    let mut failures = Vec::new();
    if let Err(mut e) = tools::check(&[&tools::QEMU]) {
        failures.append(&mut e);
        return failures;
    }
    let elf = match tools::build_firmware(&board.qemu_features(&[])) {
        Ok(e) => e,
        Err(e) => return e,
    };
    let go = || -> Result<(Diagnostics, u32, Status, u32, f64), String> {
        let session = Session::start(board, &elf, true)?;
        let port = transport::open_serial(&session.pty, crate::BAUD).map_err(|e| e.to_string())?;
        let mut link = Link::new(port);
        link.flush_peer().map_err(|e| e.to_string())?;
        let quiet = SafetyParams { host_timeout_ms: 60_000, ..SafetyParams::DEFAULT };
        request_ok(&mut link, &Message::SetSafety(quiet))?;
        let mut dec = Decoder::new();
        for &b in &frames(&CASES[1], SAMPLES)? {
            match dec.push(b) {
                Some(Ok(p)) if !matches!(p.msg, Message::Start { .. }) => request_ok(&mut link, &p.msg)?,
                _ => {}
            }
        }
        request_ok(&mut link, &Message::Start { mode: Mode::Simulated, samples: SAMPLES })?;
        eprintln!("board on {}: {SAMPLES} ticks, {burst} damaged frames sent meanwhile", board.name());
        // The burst, interleaved with reading so neither side's buffers fill.
        let mut seen = Seen::default();
        let mut burst_bytes = 0usize;
        let mut chunk = Vec::new();
        for i in 0..burst {
            let frame = damaged(i)?;
            burst_bytes += frame.len();
            chunk.extend_from_slice(&frame);
            if i % 16 != 15 && i + 1 < burst {
                continue;
            }
            link.send_raw(&chunk).map_err(|e| e.to_string())?;
            chunk.clear();
            while let Some(r) = link.recv(Instant::now()).map_err(|e| e.to_string())? {
                if let Ok(p) = r {
                    seen.handle(&p.msg);
                }
            }
        }
        let until = Instant::now() + Duration::from_secs(120);
        while seen.ended.is_none() && Instant::now() < until {
            match link.recv(Instant::now() + Duration::from_secs(10)).map_err(|e| e.to_string())? {
                None => {
                    return Err(format!("the board went silent after {} telemetry frames", seen.telemetry));
                }
                Some(Ok(p)) => seen.handle(&p.msg),
                Some(Err(_)) => {}
            }
        }
        let run = seen.ended.ok_or("the run did not end within 120 s")?;
        // The burst's span in the board's time: its answers (rate-bound but never absent
        // while bad frames keep coming) between the telemetry of the ticks around them.
        let span_ticks = match seen.faults {
            Some((first, last)) => last.saturating_sub(first) + 1,
            None => SAMPLES,
        };
        let bytes_per_ms = run.rx_bad as f64 * burst_bytes as f64 / burst.max(1) as f64 / span_ticks as f64;
        link.flush_peer().map_err(|e| e.to_string())?;
        let d = link
            .request(&Message::GetDiagnostics, 5, Duration::from_secs(2), |_, m| match m {
                Message::Diagnostics(d) => Some(*d),
                _ => None,
            })
            .map_err(|e| e.to_string())?
            .ok_or("no diagnostics from the board")?;
        Ok((d, seen.telemetry, run, span_ticks, bytes_per_ms))
    };
    let (d, telemetry, run, span_ticks, run_bytes_per_ms) = match go() {
        Ok(x) => x,
        Err(e) => return vec![e],
    };
    let per = insns_per_unit(&d);
    let overhead = d.clock_overhead_ticks as f64;
    let isr_max = (d.isr_ticks_max as f64 - overhead) * per;
    // Over the run's ticks (one control step each).
    let isr_mean = (d.isr_ticks_sum as f64 / d.steps.max(1) as f64 - overhead) * per;
    let out = |s: String| if json { eprintln!("{s}") } else { println!("{s}") };
    out(format!(
        "{}: {} ticks since the run's start ({telemetry} telemetry frames of the {SAMPLES}-tick run received), {} missed",
        board.name(),
        d.ticks,
        d.missed_ticks
    ));
    out(format!("control interrupt: {isr_mean:.1} instructions mean, {isr_max:.0} largest"));
    out(format!(
        "bad frames: {} counted ({burst} sent), {} answered, {} not answered (rate bound); {} frames not queued",
        d.bad_frames,
        d.bad_frames.saturating_sub(d.faults_suppressed),
        d.faults_suppressed,
        d.tx_dropped
    ));
    // How dense the burst was in the board's time: QEMU's UART takes a byte per turn of
    // its main loop, so the host cannot make it arrive at the line rate.
    let line_bytes_per_ms = crate::BAUD as f64 / 10.0 / 1000.0;
    out(format!(
        "during the {SAMPLES}-tick run: {} bad frames arrived over ~{span_ticks} ticks (~{run_bytes_per_ms:.1} bytes per ms, {:.0} % of the line's {line_bytes_per_ms:.1}), {} tick overruns",
        run.rx_bad,
        100.0 * run_bytes_per_ms / line_bytes_per_ms,
        run.tick_overruns
    ));
    if json {
        println!(
            "{}",
            serde_json::json!({
                "ticks": d.ticks,
                "missed_ticks": d.missed_ticks,
                "isr_insns_max": isr_max.round(),
                "isr_insns_mean": (isr_mean * 10.0).round() / 10.0,
                "bad_frames": d.bad_frames,
            })
        );
    }
    if d.missed_ticks > 0 {
        failures.push(format!("{} ticks missed", d.missed_ticks));
    }
    if telemetry < SAMPLES {
        failures.push(format!("{telemetry} of {SAMPLES} telemetry frames received"));
    }
    if run.rx_bad == 0 {
        failures.push("the board counted no bad frame during the run: the burst missed it".into());
    }
    failures
}

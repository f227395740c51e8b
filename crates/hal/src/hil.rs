//! Hardware in the loop: the board computes `u[k]` every sample, the host is its actuator.
//!
//! The host configures the board ([`boucwen_link::message::ControllerParams`]), starts a
//! control run of `n` samples and then, for every `Command{k, u[k]}` the board sends on its
//! own sample clock, applies `u[k]` to a [`Plant`] (the virtual bimorph, a model, or a
//! real actuator behind it) and sends back `Measurement{k, y[k]}`, which the board uses at
//! its next tick.
//!
//! ## Faults and accounting
//! With a fault rate the host damages both directions at that rate per byte
//! ([`crate::transport::FaultInjector`]): bytes it sends before writing them, bytes it
//! receives before decoding them. Every damaged frame is caught by the frame checks (COBS,
//! CRC-32C, layout) or shows as a gap in the sender's sequence numbers, and nothing stops:
//! * a command that does not arrive (rejected or missing) is replaced by the last applied
//!   input, as a driver's DAC holds its output; the sample is logged as
//!   [`InputSource::Held`] when the next command shows the gap;
//! * a measurement that does not arrive makes the board step without it (the compensator
//!   skips that sample's adaptation); each command carries the board's record of which of
//!   its last 16 steps had their measurement, so the host logs every sample's
//!   [`MeasurementFate`] even across lost commands.
//!
//! Every sample `0..n` gets exactly one [`SampleRecord`]. After the run the host asks the
//! board (over a clean link) for its counters and checks that they account for every
//! sample: steps with and without a measurement add up to `n - 1`, and agree with what the
//! host learnt sample by sample ([`HilReport::samples_accounted`]).
//!
//! ## Lockstep
//! The host's actuator is a simulation on an operating system that is not real-time, and
//! at 460,800 baud a command and its measurement take 0.80 ms of the 1 ms period on the
//! line alone. By default the run is in lockstep ([`Mode::Lockstep`]): the board's tick
//! waits for the previous sample's measurement (boundedly), so the loop is the loop of
//! the plant's sample index whatever the host's latency; [`HilOptions::lockstep`] `false`
//! runs a free-running control run, where a measurement later than the next tick is
//! missing.
//!
//! ## Safe state at the end
//! After the run the host stays silent. The board, idle with its drive where the last
//! command left it, declares the host lost after [`SafetyParams::host_timeout_ms`] and ramps
//! the drive to 0 V (telemetry flagged [`command_flags::SAFE_RAMP`], then
//! [`Message::Safe`]). The host checks the ramp (monotonic, steps of at most the slew,
//! ending at 0 V) and reports the time from its last frame to 0 V as the board counted it
//! ([`HilReport::safe_state`]).
//!
//! ## Shadow check
//! The host runs the same controller ([`boucwen_link::device::Controller`], `f32`, the
//! same code as the firmware) fed exactly what the board reports it used, and compares
//! every command it receives with it bit for bit ([`HilReport::shadow_mismatches`]). A
//! corrupted frame that slipped through the checks, or a firmware that computes something
//! else, shows there.

use crate::transport::{FaultCounts, Link, LinkStats, Port, TransportError};
use boucwen_core::Plant;
use boucwen_link::device::{Controller, Reference};
use boucwen_link::message::{
    ControllerParams, Fault, Message, Mode, RunState, SafeReason, SafetyParams, Status, command_flags,
};
use serde::Serialize;
use std::fmt;
use std::time::{Duration, Instant};

/// Settings of a run.
#[derive(Clone, Copy, Debug)]
pub struct HilOptions {
    /// Samples to run.
    pub samples: u32,
    /// Probability that a byte is damaged, each direction (0: a clean link).
    pub fault_rate: f64,
    /// Seed of the fault injection.
    pub seed: u64,
    /// The tracking RMSE is taken from this sample on.
    pub settle_samples: u32,
    /// How long to wait for the board's answer to a configuration request.
    pub reply_timeout: Duration,
    /// Silence on the link that ends the run's exchange.
    pub link_timeout: Duration,
    /// Run in lockstep (the board's tick waits for the measurement); else free-running.
    pub lockstep: bool,
    /// The board's drive limits and safe state for the run.
    pub safety: SafetyParams,
}

impl HilOptions {
    /// `samples` samples on a clean link in lockstep; RMSE after the first fifth (at least
    /// the fade-in of 500 samples); 0.5 s per configuration request, 2 s of silence ends
    /// the run; the board's default safety parameters.
    pub fn new(samples: u32) -> Self {
        Self {
            samples,
            fault_rate: 0.0,
            seed: 1,
            settle_samples: (samples / 5).max(500).min(samples / 2),
            reply_timeout: Duration::from_millis(500),
            link_timeout: Duration::from_secs(2),
            lockstep: true,
            safety: SafetyParams::DEFAULT,
        }
    }
}

/// Where the input applied at a sample came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputSource {
    /// The board's command for this sample.
    Commanded,
    /// The command was lost or rejected: the last input was held.
    Held,
}

/// What the board did with a sample's measurement (used by its next step or not).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeasurementFate {
    /// The next step used it.
    Used,
    /// The next step ran without it (lost, damaged or late).
    Missed,
    /// The commands that would say were lost; the board's totals account for it.
    Unknown,
    /// The last sample of the run: no step follows.
    Last,
}

/// One sample of the run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleRecord {
    /// Sample index.
    pub k: u32,
    /// The reference `d[k]`, µm (the board's, recomputed on the host).
    pub d_um: f32,
    /// The input applied, V.
    pub u_v: f32,
    /// The plant's output, µm.
    pub y_um: f64,
    /// Where `u_v` came from.
    pub input: InputSource,
    /// What happened to the measurement.
    pub measurement: MeasurementFate,
}

/// How the board reached its safe state after the host fell silent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SafeState {
    /// The drive when the host fell silent, V.
    pub from_v: f32,
    /// From the host's last frame to 0 V, as the board counted it (ticks times the
    /// period), ms.
    pub board_ms: f64,
    /// From the host sending its last frame to receiving the board's `Safe`, ms (link
    /// and, in an emulator, its clock included); NaN when the board went there on its own
    /// before the host fell silent on purpose (a run whose end the host missed).
    pub host_ms: f64,
    /// Ramp steps seen (telemetry frames flagged as the ramp).
    pub ramp_steps: u32,
}

/// The result of a run.
#[derive(Clone, Debug)]
pub struct HilReport {
    /// Samples run.
    pub samples: u32,
    /// Samples with exactly one record and a fate consistent with the board's counters;
    /// equals `samples` unless something was silently lost.
    pub samples_accounted: u32,
    /// Commands received and applied.
    pub commands_applied: u32,
    /// Samples at which the last input was held.
    pub commands_held: u32,
    /// Frames rejected by their checks, host and board together.
    pub corrupted_frames: u64,
    /// Frames that vanished (sequence gaps not explained by rejected frames), both sides.
    pub lost_frames: u64,
    /// Frames the fault injector damaged: `(sent by the host, received by the host)`.
    pub damaged_frames: (u64, u64),
    /// Damaged frames taken for intact ones: received by the host and passing its checks,
    /// or measurements the host sent damaged that the board reports it used. Must be 0.
    pub undetected_frames: u64,
    /// Tracking RMSE `√mean((y − d)²)` from [`HilOptions::settle_samples`] on, µm.
    pub rmse_um: f64,
    /// Commands compared with the host's shadow controller.
    pub shadow_checked: u32,
    /// Commands that differed from it.
    pub shadow_mismatches: u32,
    /// Frames the host received during the run.
    pub host_link: LinkStats,
    /// The board's counters after the run.
    pub board: Status,
    /// Bytes damaged on purpose: `(sent, received)`.
    pub injected: (FaultCounts, FaultCounts),
    /// Commands that came for a sample already past (not applied).
    pub stale_commands: u32,
    /// Rejections (`Fault`) the board sent during the run.
    pub board_faults: u32,
    /// Whether the run was in lockstep.
    pub lockstep: bool,
    /// Ticks the board waited for measurements (lockstep).
    pub lockstep_waits: u32,
    /// The ramp to 0 V after the run (`None` if the drive was at 0 V already).
    pub safe_state: Option<SafeState>,
    /// Inconsistencies found by the accounting (empty when all is well).
    pub problems: Vec<String>,
    /// Every sample.
    pub log: Vec<SampleRecord>,
}

/// Why a run could not be done.
#[derive(Debug)]
pub enum HilError {
    /// The link failed.
    Link(TransportError),
    /// The board refused a request.
    Refused {
        /// What was asked.
        request: &'static str,
        /// The board's fault.
        fault: Fault,
    },
    /// The board did not answer.
    NoAnswer {
        /// What was asked.
        request: &'static str,
        /// The port.
        port: String,
    },
    /// The plant failed.
    Plant {
        /// The plant's name.
        plant: String,
        /// Its error.
        error: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The controller's parameters were rejected, or a step failed, on the host.
    Controller(boucwen_core::Error),
    /// The options are unusable.
    Options(&'static str),
}

impl fmt::Display for HilError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HilError::Link(e) => write!(f, "link: {e}"),
            HilError::Refused { request, fault } => {
                write!(f, "the board refused {request}: {:?}: {}", fault.code, fault.text)
            }
            HilError::NoAnswer { request, port } => {
                write!(f, "{port}: no answer from the board to {request}")
            }
            HilError::Plant { plant, error } => write!(f, "plant: {plant}: {error}"),
            HilError::Controller(e) => write!(f, "controller: {e}"),
            HilError::Options(what) => write!(f, "options: {what}"),
        }
    }
}

impl std::error::Error for HilError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            HilError::Link(e) => Some(e),
            HilError::Plant { error, .. } => Some(error.as_ref()),
            HilError::Controller(e) => Some(e),
            _ => None,
        }
    }
}

fn plant_error<P: Plant<f64> + ?Sized>(plant: &P, e: P::Error) -> HilError
where
    P::Error: std::error::Error + Send + Sync + 'static,
{
    HilError::Plant { plant: plant.name().to_owned(), error: Box::new(e) }
}

impl From<TransportError> for HilError {
    fn from(e: TransportError) -> Self {
        HilError::Link(e)
    }
}

/// Sends `msg` and waits for its `Ack` (or the `Fault` naming it).
fn configure<P: Port>(
    link: &mut Link<P>,
    msg: &Message,
    request: &'static str,
    opts: &HilOptions,
) -> Result<(), HilError> {
    let want = msg.kind();
    let answer = link.request(msg, 3, opts.reply_timeout, |seq, m| match m {
        Message::Ack { kind, seq: s } if *kind == want && *s == seq => Some(Ok(())),
        Message::Fault(f) if f.seq == seq => Some(Err(f.clone())),
        _ => None,
    })?;
    match answer {
        Some(Ok(())) => Ok(()),
        Some(Err(fault)) => Err(HilError::Refused { request, fault }),
        None => Err(HilError::NoAnswer { request, port: link.port_name() }),
    }
}

/// Asks for the board's status until it is no longer running (or `patience` runs out).
fn final_status<P: Port>(
    link: &mut Link<P>,
    opts: &HilOptions,
    patience: Duration,
) -> Result<Status, HilError> {
    let until = Instant::now() + patience;
    loop {
        link.flush_peer()?;
        link.discard_input();
        let s = link.request(&Message::GetStatus, 3, opts.reply_timeout, |_, m| match m {
            Message::Status(s) => Some(*s),
            _ => None,
        })?;
        match s {
            Some(s) if s.state != RunState::Running as u8 => return Ok(s),
            Some(_) if Instant::now() < until => std::thread::sleep(Duration::from_millis(50)),
            Some(s) => return Ok(s),
            None => return Err(HilError::NoAnswer { request: "GetStatus", port: link.port_name() }),
        }
    }
}

/// The board's diagnostics (over a clean link).
fn diagnostics<P: Port>(
    link: &mut Link<P>,
    opts: &HilOptions,
) -> Result<boucwen_link::message::Diagnostics, HilError> {
    link.request(&Message::GetDiagnostics, 3, opts.reply_timeout, |_, m| match m {
        Message::Diagnostics(d) => Some(*d),
        _ => None,
    })?
    .ok_or_else(|| HilError::NoAnswer { request: "GetDiagnostics", port: link.port_name() })
}

/// What the host saw of the board's way to its safe state: the ramp's drives and the
/// `Safe` message (reason, ticks, period).
#[derive(Clone, Debug, Default)]
struct SafeSeen {
    ramp: Vec<f32>,
    safe: Option<(u8, u32, u32)>,
}

impl SafeSeen {
    /// Takes what belongs to the safe state; `true` for `Safe`, the last of it.
    fn take(&mut self, m: &Message) -> bool {
        match *m {
            Message::Telemetry { u, flags, .. } if flags & command_flags::SAFE_RAMP != 0 => {
                self.ramp.push(u);
                false
            }
            Message::Safe { reason, ticks, period_us } => {
                self.safe = Some((reason, ticks, period_us));
                true
            }
            _ => false,
        }
    }
}

/// Falls silent and watches the board take its drive from `from_v` to 0 V.
fn watch_safe_state<P: Port>(
    link: &mut Link<P>,
    safety: &SafetyParams,
    period_us: u32,
    problems: &mut Vec<String>,
) -> Result<(SafeSeen, f64), HilError> {
    let silent_since = Instant::now();
    let period_s = period_us as f64 * 1e-6;
    let bound_ticks = safe_bound_ticks(safety, period_s, safety.u_max.abs().max(safety.u_min.abs()));
    // Wall-clock patience: an emulator's clock may run slower than the wall's.
    let deadline = silent_since + Duration::from_secs_f64(bound_ticks * period_s * 20.0 + 2.0);
    let mut seen = SafeSeen::default();
    loop {
        let Some(r) = link.recv(deadline)? else {
            let waited = (deadline - silent_since).as_secs_f64();
            problems.push(format!("no Safe message within {waited:.1} s of silence"));
            return Ok((seen, f64::NAN));
        };
        if let Ok(p) = r {
            if seen.take(&p.msg) {
                return Ok((seen, silent_since.elapsed().as_secs_f64() * 1e3));
            }
        }
    }
}

/// Ticks from the host's last frame to 0 V at most: the timeout, the ramp from `from_v`
/// at the slew, and two ticks of slack.
fn safe_bound_ticks(safety: &SafetyParams, period_s: f64, from_v: f32) -> f64 {
    let step_v = safety.slew_v_per_s as f64 * period_s;
    let timeout_ticks = (safety.host_timeout_ms as f64 * 1e-3 / period_s).ceil();
    timeout_ticks + (from_v.abs() as f64 / step_v).ceil() + 2.0
}

/// Checks the way to 0 V from `from_v`: the ramp falls monotonically to 0 V in steps of at
/// most the slew per period, and `Safe` names the lost host and comes within
/// [`safe_bound_ticks`] plus the `skipped` periods the board counted as missed meanwhile
/// (its count of time includes them; in an emulator whose clock follows a loaded host's,
/// it jumps). What is wrong goes to `problems`.
fn check_safe_state(
    seen: &SafeSeen,
    from_v: f32,
    host_ms: f64,
    skipped: u32,
    safety: &SafetyParams,
    period_us: u32,
    problems: &mut Vec<String>,
) -> Option<SafeState> {
    let (reason, ticks, p_us) = seen.safe?;
    let period_s = period_us as f64 * 1e-6;
    let step_v = safety.slew_v_per_s as f64 * period_s;
    let mut last = from_v;
    for &u in &seen.ramp {
        let ok = u.abs() <= last.abs()
            && (u == 0.0 || u.signum() == from_v.signum())
            && ((last - u).abs() as f64) <= step_v * (1.0 + 1e-5);
        if !ok {
            problems.push(format!("ramp to 0 V: {last} V then {u} V (step at most {step_v} V)"));
        }
        last = u;
    }
    if reason != SafeReason::HostLost as u8 {
        problems.push(format!("safe state for reason {reason}, not the lost host"));
    }
    if last != 0.0 {
        problems.push(format!("Safe came with the drive at {last} V"));
    }
    let bound = safe_bound_ticks(safety, period_s, from_v) + skipped as f64;
    if ticks as f64 > bound || p_us != period_us {
        problems.push(format!(
            "safe state after {ticks} ticks of {p_us} µs (at most {bound} of {period_us} µs expected, {skipped} of them missed)"
        ));
    }
    let board_ms = ticks as f64 * p_us as f64 * 1e-3;
    Some(SafeState { from_v, board_ms, host_ms, ramp_steps: seen.ramp.len() as u32 })
}

/// The host's replica of the board's controller, stepped as the board reports.
struct Shadow {
    controller: Controller,
    next: u32,
    alive: bool,
    checked: u32,
    mismatches: u32,
}

/// Runs the board in a control run of `opts.samples` samples with `plant` as its actuator.
pub fn run<L: Port, P: Plant<f64> + ?Sized>(
    link: &mut Link<L>,
    plant: &mut P,
    params: &ControllerParams,
    opts: &HilOptions,
) -> Result<HilReport, HilError>
where
    P::Error: std::error::Error + Send + Sync + 'static,
{
    let n = opts.samples;
    if n < 2 {
        return Err(HilError::Options("at least 2 samples"));
    }
    let controller = Controller::new(params).map_err(HilError::Controller)?;

    // Configuration over a clean link.
    link.inject_faults(None, 0);
    link.flush_peer()?;
    link.discard_input();
    let stopped = link.request(&Message::Stop, 3, opts.reply_timeout, |_, m| {
        matches!(m, Message::Status(_)).then_some(())
    })?;
    if stopped.is_none() {
        return Err(HilError::NoAnswer { request: "Stop", port: link.port_name() });
    }
    configure(link, &Message::SetSafety(opts.safety), "SetSafety", opts)?;
    configure(link, &Message::SetController(params.clone()), "SetController", opts)?;
    let waits0 = diagnostics(link, opts)?.lockstep_waits;
    let mode = if opts.lockstep { Mode::Lockstep } else { Mode::Control };
    configure(link, &Message::Start { mode, samples: n }, "Start", opts)?;
    let stats0 = link.stats();
    let injected0 = link.fault_counts();
    if opts.fault_rate > 0.0 {
        link.inject_faults(Some(opts.fault_rate), opts.seed);
    }

    let mut reference = Reference::new(params);
    let mut log: Vec<SampleRecord> = Vec::with_capacity(n as usize);
    let mut sent_y: Vec<Option<f32>> = vec![None; n as usize];
    // Whether the injector damaged the measurement frame of each sample.
    let mut sent_damaged = vec![false; n as usize];
    let (mut tx_damaged, mut used_damaged) = (0u64, 0u64);
    let mut shadow = Shadow { controller, next: 0, alive: true, checked: 0, mismatches: 0 };
    let mut problems = Vec::new();
    let (mut last_u, mut stale, mut board_faults) = (0.0f32, 0u32, 0u32);
    let mut board_done = None;

    let mut apply = |log: &mut Vec<SampleRecord>, u: f32, input: InputSource| -> Result<f64, HilError> {
        let k = log.len() as u32;
        let y = plant.step(u as f64).map_err(|e| plant_error(&*plant, e))?;
        let measurement = if k + 1 == n { MeasurementFate::Last } else { MeasurementFate::Unknown };
        log.push(SampleRecord { k, d_um: reference.next_sample(), u_v: u, y_um: y, input, measurement });
        Ok(y)
    };

    // The board's way to 0 V if it gets there while the host still waits for the run's end.
    let mut early = SafeSeen::default();
    while board_done.is_none() {
        // After the last sample the run's end follows at once: wait briefly, then ask (a
        // long silence would make the board declare the host lost).
        let wait = if log.len() as u32 >= n { Duration::from_millis(100) } else { opts.link_timeout };
        let Some(r) = link.recv(Instant::now() + wait)? else {
            break;
        };
        let Ok(packet) = r else { continue };
        match packet.msg {
            Message::Command { k, u, used, .. } => {
                let next = log.len() as u32;
                if k < next || k >= n {
                    stale += 1;
                    continue;
                }
                while (log.len() as u32) < k {
                    apply(&mut log, last_u, InputSource::Held)?;
                }
                let y = apply(&mut log, u, InputSource::Commanded)?;
                last_u = u;
                if k + 1 < n {
                    link.send(&Message::Measurement { k, y: y as f32 })?;
                    sent_y[k as usize] = Some(y as f32);
                    if link.last_sent_damaged() {
                        sent_damaged[k as usize] = true;
                        tx_damaged += 1;
                    }
                }
                // Bit i: the step of sample k - i used y[k - i - 1].
                for i in 0..16u32.min(k) {
                    let j = (k - i - 1) as usize;
                    let fate =
                        if used >> i & 1 == 1 { MeasurementFate::Used } else { MeasurementFate::Missed };
                    if fate == MeasurementFate::Used
                        && sent_damaged[j]
                        && log[j].measurement != MeasurementFate::Used
                    {
                        used_damaged += 1;
                        problems.push(format!(
                            "the board used the measurement of sample {j}, whose frame was damaged on the way"
                        ));
                    }
                    log[j].measurement = fate;
                }
                if shadow.alive {
                    if k - shadow.next >= 16 {
                        shadow.alive = false;
                        problems.push(format!(
                            "shadow check stopped at sample {}: more than 16 commands in a row were lost",
                            shadow.next
                        ));
                    } else {
                        while shadow.next <= k {
                            let j = shadow.next;
                            let y_prev =
                                if j > 0 && used >> (k - j) & 1 == 1 { sent_y[j as usize - 1] } else { None };
                            if j > 0 && used >> (k - j) & 1 == 1 && y_prev.is_none() {
                                problems.push(format!(
                                    "the board used a measurement of sample {} never sent",
                                    j - 1
                                ));
                            }
                            match shadow.controller.step(y_prev) {
                                Ok(s) if j == k => {
                                    shadow.checked += 1;
                                    if s.out.u.to_bits() != u.to_bits() {
                                        shadow.mismatches += 1;
                                    }
                                }
                                Ok(_) => {}
                                Err(e) => problems.push(format!("shadow step {j}: {e}")),
                            }
                            shadow.next += 1;
                        }
                    }
                }
            }
            Message::Status(s) if s.state != RunState::Running as u8 => board_done = Some(s),
            Message::Fault(_) => board_faults += 1,
            ref m => {
                early.take(m);
            }
        }
    }

    // The rest over a clean link.
    let stats1 = link.stats();
    link.inject_faults(None, 0);
    let injected1 = link.fault_counts();
    let board = final_status(link, opts, Duration::from_secs(5))?;
    if board.samples_done < n {
        problems.push(format!("the board stopped after {} of {n} samples", board.samples_done));
    }
    let diag = diagnostics(link, opts)?;
    let lockstep_waits = diag.lockstep_waits.wrapping_sub(waits0);
    let period_us = params.sample_period_us;
    let safe_state = if diag.drive_v != 0.0 {
        let (seen, host_ms) = watch_safe_state(link, &opts.safety, period_us, &mut problems)?;
        let skipped = diagnostics(link, opts)?.missed_ticks.wrapping_sub(diag.missed_ticks);
        check_safe_state(&seen, diag.drive_v, host_ms, skipped, &opts.safety, period_us, &mut problems)
    } else {
        // At 0 V already: the last command was 0 V, or the board reached it while the host
        // waited for the run's end (checked from the ramp's first step: the host may have
        // missed the last command; the periods skipped are the run's).
        let from = early.ramp.first().copied().unwrap_or(last_u);
        let skipped = diag.missed_ticks;
        check_safe_state(&early, from, f64::NAN, skipped, &opts.safety, period_us, &mut problems)
    };
    while (log.len() as u32) < n {
        apply(&mut log, last_u, InputSource::Held)?;
    }

    // Accounting.
    let count = |f: MeasurementFate| log.iter().filter(|r| r.measurement == f).count() as u32;
    let (used, missed, unknown) =
        (count(MeasurementFate::Used), count(MeasurementFate::Missed), count(MeasurementFate::Unknown));
    let steps_with_prev = board.measurements_used + board.measurements_missing;
    let indices_ok = log.iter().enumerate().all(|(i, r)| r.k as usize == i) && log.len() == n as usize;
    let fates_ok = steps_with_prev == n - 1
        && board.measurements_used >= used
        && board.measurements_missing >= missed
        && (board.measurements_used - used) + (board.measurements_missing - missed) == unknown;
    if !indices_ok {
        problems.push("the sample log is not one record per sample".into());
    }
    if !fates_ok {
        problems.push(format!(
            "measurement accounting: board used {} and missed {} (of {} steps), host saw {used} used, {missed} missed, {unknown} unknown",
            board.measurements_used,
            board.measurements_missing,
            n - 1
        ));
    }
    let samples_accounted = if !indices_ok {
        0
    } else if fates_ok {
        n
    } else {
        n - unknown
    };
    let commands_applied = log.iter().filter(|r| r.input == InputSource::Commanded).count() as u32;
    let host_link = LinkStats {
        tx_frames: stats1.tx_frames - stats0.tx_frames,
        rx_frames: stats1.rx_frames - stats0.rx_frames,
        rx_bad: stats1.rx_bad - stats0.rx_bad,
        rx_lost: stats1.rx_lost - stats0.rx_lost,
        rx_damaged: stats1.rx_damaged - stats0.rx_damaged,
        rx_undetected: stats1.rx_undetected - stats0.rx_undetected,
    };
    if host_link.rx_undetected > 0 {
        problems.push(format!(
            "{} damaged frames from the board passed the host's checks",
            host_link.rx_undetected
        ));
    }
    let diff = |a: FaultCounts, b: FaultCounts| FaultCounts {
        bytes: a.bytes - b.bytes,
        dropped: a.dropped - b.dropped,
        corrupted: a.corrupted - b.corrupted,
    };
    let injected = (diff(injected1.0, injected0.0), diff(injected1.1, injected0.1));
    let from = (opts.settle_samples as usize).min(log.len());
    let tail = &log[from..];
    let rmse_um = (tail.iter().map(|r| (r.y_um - r.d_um as f64).powi(2)).sum::<f64>()
        / tail.len().max(1) as f64)
        .sqrt();
    Ok(HilReport {
        samples: n,
        samples_accounted,
        commands_applied,
        commands_held: n - commands_applied,
        corrupted_frames: host_link.rx_bad + board.rx_bad as u64,
        lost_frames: host_link.rx_lost + board.rx_lost as u64,
        damaged_frames: (tx_damaged, host_link.rx_damaged),
        undetected_frames: host_link.rx_undetected + used_damaged,
        rmse_um,
        shadow_checked: shadow.checked,
        shadow_mismatches: shadow.mismatches,
        host_link,
        board,
        injected,
        stale_commands: stale,
        board_faults,
        lockstep: opts.lockstep,
        lockstep_waits,
        safe_state,
        problems,
        log,
    })
}

/// The same loop without the link: `params`' controller and `plant` stepped in-process,
/// every measurement used at the next step. Returns the tracking RMSE from `settle` on,
/// µm, the figure a run over a perfect link reaches.
pub fn without_link<P: Plant<f64> + ?Sized>(
    plant: &mut P,
    params: &ControllerParams,
    samples: u32,
    settle: u32,
) -> Result<f64, HilError>
where
    P::Error: std::error::Error + Send + Sync + 'static,
{
    let mut c = Controller::new(params).map_err(HilError::Controller)?;
    let (mut y_prev, mut sq, mut count) = (None, 0.0, 0u32);
    for k in 0..samples {
        let s = c.step(y_prev).map_err(HilError::Controller)?;
        let y = plant.step(s.out.u as f64).map_err(|e| plant_error(&*plant, e))?;
        y_prev = Some(y as f32);
        if k >= settle {
            sq += (y - s.d as f64).powi(2);
            count += 1;
        }
    }
    Ok((sq / count.max(1) as f64).sqrt())
}

/// Opens the serial device `port` and runs: what `boucwen hil --port PATH` does once it
/// has its controller and plant.
pub fn run_on_port<P: Plant<f64> + ?Sized>(
    port: &str,
    baud: u32,
    plant: &mut P,
    params: &ControllerParams,
    opts: &HilOptions,
) -> Result<HilReport, HilError>
where
    P::Error: std::error::Error + Send + Sync + 'static,
{
    let mut link = Link::new(crate::transport::open_serial(port, baud)?);
    run(&mut link, plant, params, opts)
}

/// The figures of a run that `boucwen hil --json` prints as its last line (`cargo xtask hil`
/// and CI read these keys).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct HilSummary {
    /// Samples run.
    pub samples: u32,
    /// Samples accounted for ([`HilReport::samples_accounted`]).
    pub samples_accounted: u32,
    /// Frames rejected by their checks, host and board together.
    pub corrupted_frames: u64,
    /// Frames that vanished, both sides.
    pub lost_frames: u64,
    /// Tracking RMSE, µm (`null` if not finite).
    pub rmse_um: Option<f64>,
    /// From the host's last frame to 0 V after the run, as the board counted it, ms
    /// (`null` if the board did not get there).
    pub safe_state_ms: Option<f64>,
    /// Whether the run was in lockstep.
    pub lockstep: bool,
}

/// What is wrong with a run ([`HilReport::verdict`]): every problem found, in order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Verdict(pub Vec<String>);

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0.join("; "))
    }
}

impl std::error::Error for Verdict {}

impl HilReport {
    /// The figures of `--json`.
    pub fn json_summary(&self) -> HilSummary {
        HilSummary {
            samples: self.samples,
            samples_accounted: self.samples_accounted,
            corrupted_frames: self.corrupted_frames,
            lost_frames: self.lost_frames,
            rmse_um: self.rmse_um.is_finite().then_some(self.rmse_um),
            safe_state_ms: self.safe_state.map(|s| s.board_ms),
            lockstep: self.lockstep,
        }
    }

    /// `Ok` when every sample is accounted for, the shadow agrees with every command and
    /// the accounting found nothing wrong; otherwise what is wrong.
    pub fn verdict(&self) -> Result<(), Verdict> {
        let mut bad = self.problems.clone();
        if self.samples_accounted != self.samples {
            bad.push(format!("{} of {} samples accounted for", self.samples_accounted, self.samples));
        }
        if self.undetected_frames > 0 {
            bad.push(format!("{} damaged frames were taken for intact ones", self.undetected_frames));
        }
        if self.shadow_mismatches > 0 {
            bad.push(format!("{} commands differ from the host's shadow controller", self.shadow_mismatches));
        }
        if bad.is_empty() { Ok(()) } else { Err(Verdict(bad)) }
    }

    /// A human-readable summary, one fact per line.
    pub fn summary(&self) -> String {
        let b = &self.board;
        let (tx, rx) = self.injected;
        format!(
            "samples: {} run, {} accounted\n\
             commands: {} applied, {} held (lost or rejected), {} stale\n\
             measurements (board): {} used, {} missing, {} stale\n\
             frames: {} corrupted (host {}, board {}), {} lost (host {}, board {})\n\
             injected: sent {} bytes ({} dropped, {} flipped), received {} bytes ({} dropped, {} flipped)\n\
             damaged frames: {} sent, {} received; {} taken for intact\n\
             shadow: {} commands compared bit for bit, {} differ\n\
             tracking RMSE: {:.4} µm\n\
             board: {} tick overruns, {} bytes overflowed, {} compute errors\n\
             loop: {}\n\
             safe state: {}",
            self.samples,
            self.samples_accounted,
            self.commands_applied,
            self.commands_held,
            self.stale_commands,
            b.measurements_used,
            b.measurements_missing,
            b.measurements_stale,
            self.corrupted_frames,
            self.host_link.rx_bad,
            b.rx_bad,
            self.lost_frames,
            self.host_link.rx_lost,
            b.rx_lost,
            tx.bytes,
            tx.dropped,
            tx.corrupted,
            rx.bytes,
            rx.dropped,
            rx.corrupted,
            self.damaged_frames.0,
            self.damaged_frames.1,
            self.undetected_frames,
            self.shadow_checked,
            self.shadow_mismatches,
            self.rmse_um,
            b.tick_overruns,
            b.rx_overflow_bytes,
            b.compute_errors,
            if self.lockstep {
                format!("lockstep, the board waited {} ticks for measurements", self.lockstep_waits)
            } else {
                "free-running (a measurement later than the next tick is missing)".into()
            },
            match self.safe_state {
                Some(s) => format!(
                    "host silent, drive {:.3} V to 0 V in {} ramp steps; {:.0} ms from the host's last frame to 0 V (board's count; {} on the host's clock to the Safe message)",
                    s.from_v,
                    s.ramp_steps,
                    s.board_ms,
                    if s.host_ms.is_nan() {
                        "—, reached before the host fell silent".into()
                    } else {
                        format!("{:.0} ms", s.host_ms)
                    }
                ),
                None => "not reached (the drive was at 0 V, or see the problems)".into(),
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::{MemoryPort, SerialPort};
    use boucwen_core::compensator::{HarmonicSpec, PhaseRule, Saturation, harmonic_response};
    use boucwen_core::model::{BoucWenParams, EnhancedParams, ExtendedParams, HarmonicBranch};
    use boucwen_core::plant::ModelPlant;
    use boucwen_core::rls::RlsConfig;
    use boucwen_core::signal::Oscillator;
    use boucwen_link::message::MAX_AR;
    use nalgebra::Complex;
    use std::sync::atomic::Ordering;

    const TS: f64 = 1e-3;

    fn ext() -> ExtendedParams<f64, 2> {
        let w0 = std::f64::consts::TAU * 70.0 * TS;
        ExtendedParams {
            bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
            ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
        }
    }

    /// The core's enhanced model (f64) as the actuator: a third harmonic of 23 Hz.
    type EnhancedPlant = ModelPlant<f64, EnhancedParams<f64, 2, 0, 1>>;

    fn model_plant() -> EnhancedPlant {
        let model = EnhancedParams {
            base: ext(),
            branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }],
            drive: Oscillator::new(23.0, TS).unwrap(),
        };
        ModelPlant::new(model, TS).unwrap()
    }

    fn params() -> ControllerParams {
        let e = ext();
        let m = |x: f64| x as f32;
        let g = harmonic_response(&e, 3, 23.0, TS, PhaseRule::Model);
        let mut ar = [0.0f32; MAX_AR];
        ar[0] = m(e.ar[0]);
        ar[1] = m(e.ar[1]);
        ControllerParams {
            model: ExtendedParams {
                bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
                ar,
            },
            drive: Oscillator::new(23.0, TS).unwrap(),
            sample_period_us: 1000,
            amplitude_um: 20.0,
            fade_samples: 500,
            harmonics: [HarmonicSpec { order: 3, response: Complex::new(m(g.re), m(g.im)) }]
                .into_iter()
                .collect(),
            rls: RlsConfig::with_forgetting(0.999, 1e-2),
            saturation: Saturation::symmetric(10.0),
            uc_max: 5.0,
            preview_samples: 0.0,
        }
    }

    /// A run against the test board, which ticks when the last command's measurement is in
    /// or `patience` after its last tick (long on a clean link, where no measurement is lost,
    /// so a busy machine does not make the board step without one).
    fn run_over<P: Port>(
        port: P,
        board_port: impl Port + Send + 'static,
        opts: HilOptions,
        patience: Duration,
    ) -> HilReport {
        let (stop, h) = crate::transport::test_board::spawn(board_port, patience);
        let mut link = Link::new(port);
        let mut plant = model_plant();
        let r = run(&mut link, &mut plant, &params(), &opts).unwrap();
        stop.store(true, Ordering::Relaxed);
        drop(link);
        h.join().unwrap();
        r
    }

    #[test]
    fn clean_link_reproduces_the_loop_exactly() {
        let (a, b) = MemoryPort::pair();
        let opts = HilOptions::new(3000);
        let r = run_over(a, b, opts, Duration::from_secs(1));
        assert!(r.problems.is_empty(), "{:?}", r.problems);
        assert_eq!((r.samples, r.samples_accounted, r.commands_applied), (3000, 3000, 3000));
        assert_eq!((r.corrupted_frames, r.lost_frames, r.shadow_mismatches), (0, 0, 0));
        assert_eq!(r.shadow_checked, 3000);
        assert_eq!((r.board.measurements_used, r.board.measurements_missing), (2999, 0));
        // Every measurement was used, so the run is the ideal loop, bit for bit in u.
        let ideal = without_link(&mut model_plant(), &params(), 3000, opts.settle_samples).unwrap();
        assert!((r.rmse_um - ideal).abs() < 1e-9, "{} vs {ideal}", r.rmse_um);
        assert!(r.rmse_um < 0.5, "{}", r.rmse_um);
        // Then the host fell silent: 250 ms of timeout, then the ramp at 100 V/s (one step
        // of 0.1 V per tick) from the last command.
        let last_u = r.log.last().unwrap().u_v;
        let s = r.safe_state.expect("the board ramped to 0 V");
        assert_eq!(s.from_v, last_u);
        let ramp = (last_u.abs() / 0.1).ceil() as u32;
        assert!((ramp..=ramp + 1).contains(&s.ramp_steps), "{s:?}");
        assert!(s.board_ms >= 250.0 && s.board_ms <= 250.0 + ramp as f64 + 2.0, "{s:?}");
        assert!(r.verdict().is_ok());
        // The JSON line's keys, which `cargo xtask hil` and CI read.
        let j = serde_json::to_value(r.json_summary()).unwrap();
        let keys: Vec<&str> = j.as_object().unwrap().keys().map(String::as_str).collect();
        assert_eq!(keys.len(), 7);
        for k in [
            "samples",
            "samples_accounted",
            "corrupted_frames",
            "lost_frames",
            "rmse_um",
            "safe_state_ms",
            "lockstep",
        ] {
            assert!(keys.contains(&k), "{k} in {keys:?}");
        }
        assert_eq!(j["samples"], 3000);
        assert_eq!(j["rmse_um"].as_f64(), Some(r.rmse_um));
        assert_eq!(j["safe_state_ms"].as_f64(), Some(s.board_ms));
        assert_eq!(j["lockstep"], true);
    }

    #[test]
    fn faults_are_detected_and_every_sample_accounted() {
        let (a, b) = MemoryPort::pair();
        // Free-running: the test board ticks 3 ms after its last tick if no measurement
        // came (in lockstep every lost frame would cost 20 such ticks).
        let opts = HilOptions { fault_rate: 0.01, seed: 7, lockstep: false, ..HilOptions::new(3000) };
        let r = run_over(a, b, opts, Duration::from_millis(3));
        assert!(r.problems.is_empty(), "{:?}", r.problems);
        assert_eq!(r.samples_accounted, 3000);
        assert_eq!(r.commands_applied + r.commands_held, 3000);
        assert!(r.commands_held > 0 && r.board.measurements_missing > 0);
        assert!(r.corrupted_frames > 0, "{}", r.summary());
        // No damaged frame was taken for a good one: the shadow agrees everywhere, and
        // none of the frames known to be damaged passed (either way).
        assert_eq!(r.shadow_mismatches, 0);
        assert!(r.damaged_frames.0 > 0 && r.damaged_frames.1 > 0, "{}", r.summary());
        assert_eq!(r.undetected_frames, 0);
        assert_eq!(r.host_link.rx_damaged, r.host_link.rx_bad, "{}", r.summary());
        assert!(r.shadow_checked >= r.commands_applied.saturating_sub(1));
        let (tx, rx) = r.injected;
        assert!(tx.dropped + tx.corrupted > 0 && rx.dropped + rx.corrupted > 0);
        // Held inputs and skipped adaptation cost a little tracking.
        assert!(r.rmse_um.is_finite() && r.rmse_um < 2.0, "{}", r.summary());
    }

    #[test]
    fn runs_over_a_real_pseudo_terminal() {
        let (master, slave) = serialport::TTYPort::pair().expect("a pseudo-terminal pair");
        let host = SerialPort::from_port(Box::new(slave), "pty slave");
        let dev = SerialPort::from_port(Box::new(master), "pty master");
        let r = run_over(host, dev, HilOptions::new(1000), Duration::from_secs(1));
        assert!(r.problems.is_empty(), "{:?}", r.problems);
        assert_eq!(
            (r.samples_accounted, r.corrupted_frames, r.lost_frames, r.shadow_mismatches),
            (1000, 0, 0, 0)
        );
    }

    #[test]
    fn a_silent_board_is_an_error_naming_the_request() {
        let (a, _b) = MemoryPort::pair();
        let mut link = Link::new(a);
        let opts = HilOptions { reply_timeout: Duration::from_millis(20), ..HilOptions::new(10) };
        let e = run(&mut link, &mut model_plant(), &params(), &opts).unwrap_err();
        assert_eq!(e.to_string(), "memory port A: no answer from the board to Stop");
    }

    #[test]
    fn invalid_parameters_are_refused_before_sending() {
        let (a, _b) = MemoryPort::pair();
        let mut link = Link::new(a);
        let mut p = params();
        p.rls.lambda = 1.5;
        let e = run(&mut link, &mut model_plant(), &p, &HilOptions::new(10)).unwrap_err();
        assert!(e.to_string().contains("forgetting factor (must be in (0, 1])"), "{e}");
    }
}

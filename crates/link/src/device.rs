//! The board's side of the protocol: what the firmware runs, written once here so the host
//! runs the very same code (in tests, and as the bit-exact reference of the QEMU self-test).
//!
//! * [`Reference`]: the reference `d[k] = α·w[k]·sin(2π f k Ts)` with the raised-cosine
//!   fade-in `w[k] = ½ − ½·cos(π k / K)` for `k < K` (`w = 1` after), computed from the
//!   core's integer phase and `sin_cos`, so it has the same bits on every target.
//! * [`Controller`]: the reference plus the core's [`Compensator`] in `f32` for up to
//!   [`MAX_HARMONICS`] cancelled harmonics; [`Controller::step`] is one full control step
//!   (`d[k]`, `u_f[k]`, the harmonic RLS update and `u[k]`).
//! * [`OnChipPlant`]: the core's enhanced model in `f32`, the board's stand-in actuator.
//! * [`ClosedLoop`]: controller and on-chip plant wired together (the self-test).
//! * [`OrcLoop`]: the reference, the odd-harmonic repetitive controller on its PI
//!   ([`OrcParams`]) and the on-chip plant (the firmware's `orc` self-test).
//! * [`Device`]: the message handler and per-tick step of the firmware.
//!
//! ## Device behaviour
//! | received | idle | control run | plant run |
//! |---|---|---|---|
//! | `GetStatus` | `Status` | `Status` | `Status` |
//! | `SetController`, `SetPlant` | validate, `Ack` or `Fault(InvalidParams)` | `Fault(Busy)` | `Fault(Busy)` |
//! | `SetOrc` | `Fault(Unexpected)`: the link runs the compensator | `Fault(Unexpected)` | `Fault(Unexpected)` |
//! | `Start{mode, n}` | `Ack`, run starts (`Fault(NotConfigured)` without parameters) | `Fault(Busy)` | `Fault(Busy)` |
//! | `Stop` | `Status` | run ends, `Status` | run ends, `Status` |
//! | `Measurement{k}` | counted stale | kept for the next tick if `k` is the last command's sample, else counted stale | `Fault(Unexpected)` |
//! | `Command{k, u}` | `Fault(Unexpected)` | `Fault(Unexpected)` | plant steps (holding the last `u` over missed samples), `Measurement{k, y}`; the same command again: the same answer again |
//! | a bad frame | `Fault(BadFrame)` | `Fault(BadFrame)` | `Fault(BadFrame)` |
//!
//! At each tick of a control run the board takes the measurement of the previous sample if
//! it arrived (else steps without it: the compensator holds its adaptation for that sample),
//! steps the controller and sends `Command{k, u[k]}`; after the last sample it sends its
//! `Status` and tells the firmware to stop the timer.

use super::frame::SeqTracker;
use super::message::{
    ControllerParams, Fault, FaultCode, MAX_AR, MAX_HARMONICS, Message, Mode, OrcParams, PlantParams,
    RunState, Status, command_flags, kind,
};
use super::{Packet, WireError, encode};
use boucwen_core::Error;
use boucwen_core::compensator::{Compensator, CompensatorConfig, CompensatorOutput, HarmonicSpec};
use boucwen_core::controllers::{ControlOutput, Controller as _, ORC_CAPACITY, OrcController};
use boucwen_core::model::{EnhancedParams, EnhancedState, HarmonicBranch, Model};
use boucwen_core::signal::sin_cos;
use nalgebra::Complex;

const _: () = assert!(MAX_HARMONICS == 2, "Controller has one variant per harmonic count 0..=2");

/// The reference signal of a control run.
#[derive(Clone, Copy, Debug)]
pub struct Reference {
    amplitude_um: f32,
    increment: u64,
    phase: u64,
    fade_samples: u32,
    fade_increment: u64,
    k: u32,
}

impl Reference {
    /// The reference of `p` at `k = 0`.
    pub fn new(p: &ControllerParams) -> Self {
        let fade_increment = if p.fade_samples > 0 { (1u64 << 63) / p.fade_samples as u64 } else { 0 };
        Self {
            amplitude_um: p.amplitude_um,
            increment: p.drive.increment(),
            phase: 0,
            fade_samples: p.fade_samples,
            fade_increment,
            k: 0,
        }
    }

    /// `d[k]`, µm; advances `k`.
    #[inline]
    pub fn next_sample(&mut self) -> f32 {
        let (s, _) = sin_cos::<f32>(self.phase);
        let envelope = if self.k < self.fade_samples {
            // Half a turn over the fade: w = ½ − ½·cos(π k / K).
            let (_, c) = sin_cos::<f32>((self.k as u64).wrapping_mul(self.fade_increment));
            0.5 - 0.5 * c
        } else {
            1.0
        };
        self.phase = self.phase.wrapping_add(self.increment);
        self.k = self.k.saturating_add(1);
        self.amplitude_um * envelope * s
    }
}

/// The compensator for each number of cancelled harmonics.
#[derive(Clone, Debug)]
enum Comp {
    M0(Compensator<f32, MAX_AR, 0>),
    M1(Compensator<f32, MAX_AR, 1>),
    M2(Compensator<f32, MAX_AR, 2>),
}

/// One control step's result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlStep {
    /// Sample index.
    pub k: u32,
    /// The reference `d[k]`, µm.
    pub d: f32,
    /// The compensator's output (`u[k]` and its parts).
    pub out: CompensatorOutput<f32>,
}

/// Reference and compensator: everything computed per sample on the board.
#[derive(Clone, Debug)]
pub struct Controller {
    reference: Reference,
    comp: Comp,
    k: u32,
}

impl Controller {
    /// Builds the controller of `p`, validating it (the error names the parameter).
    pub fn new(p: &ControllerParams) -> Result<Self, Error> {
        p.validate()?;
        fn config<const M: usize>(p: &ControllerParams) -> CompensatorConfig<f32, MAX_AR, M> {
            CompensatorConfig {
                model: p.model,
                drive: p.drive,
                harmonics: core::array::from_fn(|m| {
                    p.harmonics
                        .get(m)
                        .copied()
                        .unwrap_or(HarmonicSpec { order: 0, response: Complex::new(0.0, 0.0) })
                }),
                rls: p.rls,
                saturation: p.saturation,
                uc_max: p.uc_max,
            }
        }
        let comp = match p.harmonics.len() {
            0 => Comp::M0(Compensator::new(config::<0>(p))?),
            1 => Comp::M1(Compensator::new(config::<1>(p))?),
            _ => Comp::M2(Compensator::new(config::<2>(p))?),
        };
        Ok(Self { reference: Reference::new(p), comp, k: 0 })
    }

    /// One full control step at sample `k`: `d[k]`, then `u[k]` from the measurement
    /// `y[k-1]` (`None` if it was lost). On `Err` (a non-finite `y`) nothing changed.
    #[inline]
    pub fn step(&mut self, y_prev: Option<f32>) -> Result<ControlStep, Error> {
        if let Some(y) = y_prev {
            if !y.is_finite() {
                return Err(Error::NonFinite("y"));
            }
        }
        let mut reference = self.reference;
        let d = reference.next_sample();
        let out = match &mut self.comp {
            Comp::M0(c) => c.step(d, y_prev)?,
            Comp::M1(c) => c.step(d, y_prev)?,
            Comp::M2(c) => c.step(d, y_prev)?,
        };
        self.reference = reference;
        let k = self.k;
        self.k = self.k.saturating_add(1);
        Ok(ControlStep { k, d, out })
    }

    /// The next sample index.
    pub fn next_k(&self) -> u32 {
        self.k
    }
}

/// The board's stand-in actuator: the core's enhanced model in `f32`.
#[derive(Clone, Debug)]
pub struct OnChipPlant {
    model: EnhancedParams<f32, MAX_AR, 0, MAX_HARMONICS>,
    state: EnhancedState<f32, MAX_AR, 0, MAX_HARMONICS>,
}

impl OnChipPlant {
    /// The plant of `p` at rest. Unused branches are zero-weight branches of the second
    /// harmonic (they add exactly zero).
    pub fn new(p: &PlantParams) -> Result<Self, Error> {
        let branches = core::array::from_fn(|m| p.branches.get(m).copied().unwrap_or(HarmonicBranch::new(2)));
        let model = EnhancedParams { base: p.base, branches, drive: p.drive };
        model.validate()?;
        Ok(Self { state: model.initial_state(), model })
    }

    /// Applies `u[k]` (V), returns `y[k]` (µm).
    #[inline]
    pub fn step(&mut self, u: f32) -> f32 {
        self.model.step(&mut self.state, u)
    }
}

/// Controller and on-chip plant in a loop: the firmware's self-test, and the host's
/// reference computation of it.
#[derive(Clone, Debug)]
pub struct ClosedLoop {
    /// The controller.
    pub controller: Controller,
    /// The plant.
    pub plant: OnChipPlant,
    y_prev: Option<f32>,
}

impl ClosedLoop {
    /// Both at `k = 0`.
    pub fn new(controller: Controller, plant: OnChipPlant) -> Self {
        Self { controller, plant, y_prev: None }
    }

    /// The control step of the next sample (what the self-test times).
    #[inline]
    pub fn control(&mut self) -> Result<ControlStep, Error> {
        self.controller.step(self.y_prev)
    }

    /// Applies `u` to the plant and keeps its output for the next control step.
    #[inline]
    pub fn actuate(&mut self, u: f32) -> f32 {
        let y = self.plant.step(u);
        self.y_prev = Some(y);
        y
    }
}

/// The odd-harmonic repetitive controller against the on-chip plant: Li et al.'s peer of
/// the compensator, run on the board in the firmware's `orc` self-test and on the host as
/// its bit-exact reference. The delay line holds [`ORC_CAPACITY`] samples (2 KiB).
#[derive(Clone, Debug)]
pub struct OrcLoop {
    reference: Reference,
    /// The controller.
    pub orc: OrcController<f32, ORC_CAPACITY>,
    /// The plant.
    pub plant: OnChipPlant,
    y_prev: Option<f32>,
    k: u32,
}

/// One ORC step's result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrcStep {
    /// Sample index.
    pub k: u32,
    /// The reference `d[k]`, µm.
    pub d: f32,
    /// The controller's output (`u[k]` and its parts).
    pub out: ControlOutput<f32>,
}

impl OrcLoop {
    /// The loop of `c` (reference, range), `o` (gains) and `p` (plant), validated.
    pub fn new(c: &ControllerParams, o: &OrcParams, p: &PlantParams) -> Result<Self, Error> {
        let (pi, orc) = o.configs(c);
        Ok(Self {
            reference: Reference::new(c),
            orc: OrcController::new(pi, orc)?,
            plant: OnChipPlant::new(p)?,
            y_prev: None,
            k: 0,
        })
    }

    /// The control step of the next sample: `d[k]`, then `u[k]` from `y[k-1]`.
    #[inline]
    pub fn control(&mut self) -> Result<OrcStep, Error> {
        let mut reference = self.reference;
        let d = reference.next_sample();
        let out = self.orc.step(d, self.y_prev)?;
        self.reference = reference;
        let k = self.k;
        self.k = self.k.saturating_add(1);
        Ok(OrcStep { k, d, out })
    }

    /// Applies `u` to the plant and keeps its output for the next control step.
    #[inline]
    pub fn actuate(&mut self, u: f32) -> f32 {
        let y = self.plant.step(u);
        self.y_prev = Some(y);
        y
    }
}

/// What the firmware must do with its sample timer after a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimerRequest {
    /// Leave it as it is.
    Keep,
    /// Start ticking every `period_us` µs; the first tick is sample 0.
    Start {
        /// Tick period, µs.
        period_us: u32,
    },
    /// Stop ticking.
    Stop,
}

#[derive(Clone, Debug)]
struct ControlRun {
    controller: Controller,
    total: u32,
    /// `y[k-1]` if it arrived for the next tick.
    pending: Option<f32>,
    used: u16,
}

#[derive(Clone, Debug)]
struct PlantRun {
    plant: OnChipPlant,
    total: u32,
    next_k: u32,
    u_last: f32,
    /// The last measurement sent, for a repeated command.
    y_last: f32,
}

// The firmware has no heap; the board holds one run at a time, so the size is fixed anyway.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum Run {
    Idle,
    Control(ControlRun),
    Plant(PlantRun),
}

/// The firmware's protocol state machine. Bytes in through [`Device::on_packet`] (after
/// the firmware's [`super::Decoder`]), ticks in through [`Device::on_tick`]; every frame to
/// send goes to the `send` closure.
#[derive(Clone, Debug)]
pub struct Device {
    controller: Option<ControllerParams>,
    plant: Option<PlantParams>,
    run: Run,
    status: Status,
    rx_seq: SeqTracker,
    bad_since_good: u32,
    tx_seq: u16,
}

impl Default for Device {
    fn default() -> Self {
        Self::new()
    }
}

impl Device {
    /// A board just out of reset: unconfigured, idle.
    pub fn new() -> Self {
        Self {
            controller: None,
            plant: None,
            run: Run::Idle,
            status: Status { state: RunState::Unconfigured as u8, ..Status::default() },
            rx_seq: SeqTracker::new(),
            bad_since_good: 0,
            tx_seq: 0,
        }
    }

    /// The counters as the next [`Message::Status`] would report them.
    pub fn status(&self) -> Status {
        self.status
    }

    /// Whether a run is going on.
    pub fn running(&self) -> bool {
        !matches!(self.run, Run::Idle)
    }

    /// Notes bytes the firmware had to drop (receive buffer full).
    pub fn note_rx_overflow(&mut self, bytes: u32) {
        self.status.rx_overflow_bytes = self.status.rx_overflow_bytes.saturating_add(bytes);
    }

    fn send(&mut self, send: &mut impl FnMut(&[u8]), msg: &Message) {
        if let Ok(bytes) = encode(self.tx_seq, msg) {
            send(&bytes);
            self.tx_seq = self.tx_seq.wrapping_add(1);
            self.status.tx_frames = self.status.tx_frames.wrapping_add(1);
        }
    }

    fn fault(
        &mut self,
        send: &mut impl FnMut(&[u8]),
        code: FaultCode,
        seq: u16,
        what: impl core::fmt::Display,
    ) {
        let f = Fault::new(code, seq, what);
        self.send(send, &Message::Fault(f));
    }

    fn idle_state(&self) -> u8 {
        if self.controller.is_some() || self.plant.is_some() {
            RunState::Idle as u8
        } else {
            RunState::Unconfigured as u8
        }
    }

    fn finish(&mut self, send: &mut impl FnMut(&[u8])) {
        self.run = Run::Idle;
        self.status.state = self.idle_state();
        let s = Message::Status(self.status);
        self.send(send, &s);
    }

    /// Handles one decoded frame (or the error that rejected it).
    pub fn on_packet(
        &mut self,
        packet: Result<Packet, WireError>,
        send: &mut impl FnMut(&[u8]),
    ) -> TimerRequest {
        let Packet { seq, msg } = match packet {
            Ok(p) => p,
            Err(e) => {
                self.status.rx_bad = self.status.rx_bad.wrapping_add(1);
                self.bad_since_good = self.bad_since_good.saturating_add(1);
                self.fault(send, FaultCode::BadFrame, 0xFFFF, e);
                return TimerRequest::Keep;
            }
        };
        self.status.rx_frames = self.status.rx_frames.wrapping_add(1);
        if let super::frame::SeqGap::Missed(n) = self.rx_seq.observe(seq) {
            let lost = (n as u32).saturating_sub(self.bad_since_good);
            self.status.rx_lost = self.status.rx_lost.wrapping_add(lost);
        }
        self.bad_since_good = 0;
        let busy = self.running();
        match msg {
            Message::GetStatus => {
                let s = Message::Status(self.status);
                self.send(send, &s);
            }
            Message::SetController(p) if !busy => match Controller::new(&p) {
                Ok(_) => {
                    self.controller = Some(p);
                    self.status.state = self.idle_state();
                    self.send(send, &Message::Ack { kind: kind::SET_CONTROLLER, seq });
                }
                Err(e) => self.fault(send, FaultCode::InvalidParams, seq, e),
            },
            Message::SetPlant(p) if !busy => match OnChipPlant::new(&p) {
                Ok(_) => {
                    self.plant = Some(p);
                    self.status.state = self.idle_state();
                    self.send(send, &Message::Ack { kind: kind::SET_PLANT, seq });
                }
                Err(e) => self.fault(send, FaultCode::InvalidParams, seq, e),
            },
            Message::Start { mode, samples } if !busy => return self.start(mode, samples, seq, send),
            // The link runs the compensator; the ORC runs in the self-test (feature `orc`).
            Message::SetOrc(_) => {
                self.fault(send, FaultCode::Unexpected, seq, "the link runs the compensator, not the ORC")
            }
            Message::SetController(_) | Message::SetPlant(_) | Message::Start { .. } => {
                self.fault(send, FaultCode::Busy, seq, "a run is going on; send Stop first")
            }
            Message::Stop => {
                let was_control = matches!(self.run, Run::Control(_));
                self.finish(send);
                return if was_control { TimerRequest::Stop } else { TimerRequest::Keep };
            }
            Message::Measurement { k, y } => match &mut self.run {
                Run::Control(run) if k.wrapping_add(1) == run.controller.next_k() => run.pending = Some(y),
                Run::Plant(_) => self.fault(send, FaultCode::Unexpected, seq, "measurement in a plant run"),
                _ => self.status.measurements_stale = self.status.measurements_stale.wrapping_add(1),
            },
            Message::Command { k, u, .. } => return self.plant_command(k, u, seq, send),
            Message::Ack { .. } | Message::Status(_) | Message::Fault(_) => {
                self.fault(send, FaultCode::Unexpected, seq, "a board-to-host message sent to the board")
            }
        }
        TimerRequest::Keep
    }

    fn start(&mut self, mode: Mode, samples: u32, seq: u16, send: &mut impl FnMut(&[u8])) -> TimerRequest {
        let run = match mode {
            Mode::Control => match &self.controller {
                None => Err("no controller parameters (send SetController first)"),
                Some(p) => match Controller::new(p) {
                    Ok(c) => Ok((
                        Run::Control(ControlRun { controller: c, total: samples, pending: None, used: 0 }),
                        Some(p.sample_period_us),
                    )),
                    Err(_) => Err("controller parameters rejected"),
                },
            },
            Mode::Plant => match &self.plant {
                None => Err("no plant parameters (send SetPlant first)"),
                Some(p) => match OnChipPlant::new(p) {
                    Ok(plant) => Ok((
                        Run::Plant(PlantRun { plant, total: samples, next_k: 0, u_last: 0.0, y_last: 0.0 }),
                        None,
                    )),
                    Err(_) => Err("plant parameters rejected"),
                },
            },
        };
        match run {
            Err(what) => {
                self.fault(send, FaultCode::NotConfigured, seq, what);
                TimerRequest::Keep
            }
            Ok((run, period)) => {
                // Counters are per run; the link's own (frames) go on.
                self.status = Status {
                    state: RunState::Running as u8,
                    mode: mode as u8,
                    samples_total: samples,
                    tx_frames: self.status.tx_frames,
                    ..Status::default()
                };
                self.run = run;
                self.send(send, &Message::Ack { kind: kind::START, seq });
                period.map_or(TimerRequest::Keep, |period_us| TimerRequest::Start { period_us })
            }
        }
    }

    fn plant_command(&mut self, k: u32, u: f32, seq: u16, send: &mut impl FnMut(&[u8])) -> TimerRequest {
        let Run::Plant(run) = &mut self.run else {
            self.fault(send, FaultCode::Unexpected, seq, "command outside a plant run");
            return TimerRequest::Keep;
        };
        if run.next_k > 0 && k == run.next_k - 1 && u.to_bits() == run.u_last.to_bits() {
            // The host repeats a command whose answer it did not get: answer again.
            let y = run.y_last;
            self.send(send, &Message::Measurement { k, y });
            return TimerRequest::Keep;
        }
        if k < run.next_k || (run.total > 0 && k >= run.total) || !u.is_finite() {
            self.status.measurements_stale = self.status.measurements_stale.wrapping_add(1);
            return TimerRequest::Keep;
        }
        // Samples whose command never came: the driver holds the last input.
        while run.next_k < k {
            run.plant.step(run.u_last);
            run.next_k += 1;
        }
        let y = run.plant.step(u);
        run.u_last = u;
        run.y_last = y;
        run.next_k = k + 1;
        let done = run.total > 0 && run.next_k >= run.total;
        self.status.samples_done = run.next_k;
        self.send(send, &Message::Measurement { k, y });
        if done {
            self.finish(send);
        }
        TimerRequest::Keep
    }

    /// One tick of the sample timer; `missed` ticks were lost before it (the loop overran).
    pub fn on_tick(&mut self, missed: u32, send: &mut impl FnMut(&[u8])) -> TimerRequest {
        self.status.tick_overruns = self.status.tick_overruns.wrapping_add(missed);
        let Run::Control(run) = &mut self.run else {
            return TimerRequest::Keep;
        };
        let k = run.controller.next_k();
        let y_prev = run.pending.take();
        let (step, used_now) = match run.controller.step(y_prev) {
            Ok(s) => (s, y_prev.is_some()),
            Err(_) => {
                // Only a non-finite measurement fails a step; the step runs without it.
                self.status.compute_errors = self.status.compute_errors.wrapping_add(1);
                match run.controller.step(None) {
                    Ok(s) => (s, false),
                    Err(_) => return TimerRequest::Keep,
                }
            }
        };
        if k > 0 {
            if used_now {
                self.status.measurements_used = self.status.measurements_used.wrapping_add(1);
            } else {
                self.status.measurements_missing = self.status.measurements_missing.wrapping_add(1);
            }
        }
        run.used = (run.used << 1) | used_now as u16;
        let mut flags = 0;
        if step.out.saturated {
            flags |= command_flags::SATURATED;
        }
        if step.out.guarded {
            flags |= command_flags::GUARDED;
        }
        let msg = Message::Command { k, u: step.out.u, used: run.used, flags };
        let done = run.total > 0 && k + 1 >= run.total;
        self.status.samples_done = k + 1;
        self.send(send, &msg);
        if done {
            self.finish(send);
            return TimerRequest::Stop;
        }
        TimerRequest::Keep
    }
}

//! The board's side of the protocol: what the firmware runs, written once here so the host
//! runs the very same code (in tests, and as the bit-exact reference of the QEMU self-test).
//!
//! * [`Reference`]: the reference `d[k] = α·w[k]·sin(2π f k Ts)` with the raised-cosine
//!   fade-in `w[k] = ½ − ½·cos(π k / K)` for `k < K` (`w = 1` after), computed from the
//!   core's integer phase and `sin_cos`, so it has the same bits on every target; and its
//!   preview `d(k + τ)`, the same sine and fade-in at the fractional sample `k + τ`
//!   (`τ` = [`ControllerParams::preview_samples`], the identified input delay, in steps of
//!   2⁻¹⁶ sample: the phases advance by `τ` times their increments, exactly in integers).
//! * [`Controller`]: the reference plus the core's [`Compensator`] in `f32` for up to
//!   [`MAX_HARMONICS`] cancelled harmonics; [`Controller::step`] is one full control step:
//!   `d[k]` and `d(k + τ)`, the inverse `u_f[k]` of the extended model on `d(k + τ)` (a
//!   plant that applies its input `τ` samples late then follows `d[k]`), the harmonic RLS
//!   update on the tracking error `y[k-1] − d[k-1]`, and
//!   `u[k] = sat(u_f[k] − Σ_n (α̂_s,n sin nθ_k + α̂_c,n cos nθ_k))`. With `τ = 0` it is the
//!   compensator without preview, bit for bit. The repetitive controller (feature `orc`)
//!   does not preview (its own phase lead does that job).
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
//! | `SetController`, `SetPlant`, `SetExcitation` | validate, `Ack` or `Fault(InvalidParams)` | `Fault(Busy)` | `Fault(Busy)` |
//! | `SetOrc` | feature `orc`: validate, `Ack`; else `Fault(Unexpected)` | `Fault(Busy)` | `Fault(Busy)` |
//! | `SetSafety` | validate, `Ack` or `Fault(InvalidParams)` (`Fault(Busy)` if the drive held is outside the new limits) | `Fault(Busy)` | `Fault(Busy)` |
//! | `GetDiagnostics` | `Diagnostics` | `Diagnostics` | `Diagnostics` |
//! | `GetParams` | `Params` | `Params` | `Params` |
//! | `Start{mode, n}` | `Ack`, run starts (`Fault(NotConfigured)` without parameters) | `Fault(Busy)` | `Fault(Busy)` |
//! | `Stop` | `Status` | run ends, `Status` | run ends, `Status` |
//! | `Measurement{k}` | counted stale | kept for the next tick if `k` is the last command's sample, else counted stale (control and lockstep runs) | `Fault(Unexpected)` |
//! | `Command{k, u}` | `Fault(Unexpected)` | `Fault(Unexpected)` | plant steps (holding the last `u` over at most [`limits::MAX_CATCH_UP`] missed samples), `Measurement{k, y}`; the same command again: the same answer again; `k` past, too far ahead or `u` outside the drive limits: counted stale |
//! | a bad frame | `Fault(BadFrame)` | `Fault(BadFrame)` | `Fault(BadFrame)` |
//!
//! Bad frames are all counted, and answered at a bounded rate ([`limits::FAULT_BURST`],
//! then one per [`limits::FAULT_REFILL_TICKS`] ticks), so line noise cannot fill the
//! transmit queue. Runs of mode `Simulated` and `Local` step at each tick like a control
//! run, with the on-chip simulated actuator or the board's converters
//! ([`super::analog::FrontEnd`]) instead of the host, and send [`Message::Telemetry`].
//!
//! What a run computes is the last of `SetController` (and `SetOrc`) and `SetExcitation`
//! the board accepted: the controller, or the excitation ([`super::excitation`]: the board
//! as data acquisition, the same runs with the excitation's `u[k]` in place of the
//! controller's). `GetParams` reports which, with the controller's and the safety
//! parameters as the board holds them.
//!
//! At each tick of a control run the board takes the measurement of the previous sample if
//! it arrived (else steps without it: the compensator holds its adaptation for that sample),
//! steps the controller and sends `Command{k, u[k]}`; after the last sample it sends its
//! `Status` and tells the firmware to stop the timer.
//! A lockstep run ([`Mode::Lockstep`]) is a control run whose tick, when the previous
//! sample's measurement has not arrived, does nothing (counted in
//! [`Diagnostics::lockstep_waits`]) for up to [`limits::LOCKSTEP_PATIENCE_TICKS`] ticks.

use super::analog::{FrontEnd, SimulatedActuator};
use super::excitation::{Active, BoardParams, Excitation, ExcitationParams};
use super::frame::SeqTracker;
use super::limits;
use super::message::{
    ControllerParams, Diagnostics, Fault, FaultCode, MAX_AR, MAX_HARMONICS, Message, Mode, OrcParams,
    PlantParams, RunState, SafeReason, SafetyParams, Status, command_flags, kind,
};
use super::plant::OnChipPlant;
use super::{Packet, WireError, encode};
use boucwen_core::Error;
use boucwen_core::compensator::{Compensator, CompensatorConfig, CompensatorOutput, HarmonicSpec};
use boucwen_core::controllers::{ControlOutput, Controller as _, ORC_CAPACITY, OrcController};

use boucwen_core::signal::sin_cos;
use nalgebra::Complex;

const _: () = assert!(MAX_HARMONICS == 2, "Controller has one variant per harmonic count 0..=2");

/// The reference signal of a control run, and its preview.
#[derive(Clone, Copy, Debug)]
pub struct Reference {
    amplitude_um: f32,
    increment: u64,
    phase: u64,
    fade_samples: u32,
    fade_increment: u64,
    k: u32,
    /// The preview `τ` in 2⁻¹⁶ sample (0: none). (Its phases are computed at each step
    /// rather than kept: 4 bytes fit the struct's padding, 20 more made the ORC build's
    /// stack overflow its 16 KiB.)
    preview_q16: u32,
}

/// `x · q / 2¹⁶` modulo 2⁶⁴ (a phase increment times a 16.16 fixed-point number of
/// samples), exactly, with 32 × 32-bit multiplies.
#[inline]
fn mul_q16(x: u64, q: u32) -> u64 {
    let (hi, lo) = (x >> 32, x & 0xFFFF_FFFF);
    (hi * q as u64).wrapping_shl(16).wrapping_add((lo * q as u64) >> 16)
}

impl Reference {
    /// The reference of `p` at `k = 0`.
    pub fn new(p: &ControllerParams) -> Self {
        let fade_increment = if p.fade_samples > 0 { (1u64 << 63) / p.fade_samples as u64 } else { 0 };
        // `validate` keeps τ in [0, PREVIEW_MAX_SAMPLES]; a value outside (or NaN) is no
        // preview, and `as` saturates.
        let tau = p.preview_samples;
        let preview_q16 =
            if tau > 0.0 && tau <= limits::PREVIEW_MAX_SAMPLES { (tau * 65536.0 + 0.5) as u32 } else { 0 };
        Self {
            amplitude_um: p.amplitude_um,
            increment: p.drive.increment(),
            phase: 0,
            fade_samples: p.fade_samples,
            fade_increment,
            k: 0,
            preview_q16,
        }
    }

    /// `d[k]`, µm; advances `k`.
    #[inline]
    pub fn next_sample(&mut self) -> f32 {
        self.next_previewed().0
    }

    /// `d[k]` and the previewed `d(k + τ)` (the sine and the fade-in each at its
    /// fractional sample), µm; advances `k`. Without preview both are `d[k]`, bit for bit,
    /// and nothing more is computed.
    #[inline]
    pub fn next_previewed(&mut self) -> (f32, f32) {
        let (s, _) = sin_cos::<f32>(self.phase);
        let envelope = if self.k < self.fade_samples {
            // Half a turn over the fade: w = ½ − ½·cos(π k / K).
            let (_, c) = sin_cos::<f32>((self.k as u64).wrapping_mul(self.fade_increment));
            0.5 - 0.5 * c
        } else {
            1.0
        };
        let d = self.amplitude_um * envelope * s;
        let d_ahead = if cfg!(feature = "no-preview") || self.preview_q16 == 0 { d } else { self.ahead() };
        self.phase = self.phase.wrapping_add(self.increment);
        self.k = self.k.saturating_add(1);
        (d, d_ahead)
    }

    /// `d(k + τ)`: the sine's and the fade's phases advanced by `τ` times their increments.
    #[inline(never)]
    fn ahead(&self) -> f32 {
        let (s, _) = sin_cos::<f32>(self.phase.wrapping_add(mul_q16(self.increment, self.preview_q16)));
        let envelope =
            if ((self.k as u64) << 16) + (self.preview_q16 as u64) < ((self.fade_samples as u64) << 16) {
                let fade_phase = (self.k as u64).wrapping_mul(self.fade_increment);
                let (_, c) =
                    sin_cos::<f32>(fade_phase.wrapping_add(mul_q16(self.fade_increment, self.preview_q16)));
                0.5 - 0.5 * c
            } else {
                1.0
            };
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
        let (d, d_ahead) = reference.next_previewed();
        let out = match &mut self.comp {
            Comp::M0(c) => c.step_previewed(d, d_ahead, y_prev)?,
            Comp::M1(c) => c.step_previewed(d, d_ahead, y_prev)?,
            Comp::M2(c) => c.step_previewed(d, d_ahead, y_prev)?,
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

/// Checks a [`SafetyParams`].
pub fn check_safety(p: &SafetyParams) -> Result<(), Error> {
    if !(p.u_min <= 0.0 && p.u_min >= -limits::U_MAX_V) {
        return Err(Error::OutOfRange("drive limit u_min (-1000 to 0 V)"));
    }
    if !(p.u_max >= 0.0 && p.u_max <= limits::U_MAX_V) {
        return Err(Error::OutOfRange("drive limit u_max (0 to 1000 V)"));
    }
    let (lo, hi) = limits::SLEW_V_PER_S;
    if !(p.slew_v_per_s >= lo && p.slew_v_per_s <= hi) {
        return Err(Error::OutOfRange("slew (0.1 to 1e5 V/s)"));
    }
    let (lo, hi) = limits::HOST_TIMEOUT_MS;
    if !(lo..=hi).contains(&p.host_timeout_ms) {
        return Err(Error::OutOfRange("host timeout (10 ms to 60 s)"));
    }
    Ok(())
}

/// What the firmware must do with its sample timer after a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimerRequest {
    /// Leave it as it is.
    Keep,
    /// Tick every `period_us` µs; the next tick is sample 0 of the run.
    Start {
        /// Tick period, µs.
        period_us: u32,
    },
    /// The run no longer needs the timer. (The firmware keeps it ticking: the safe state
    /// runs on it.)
    Stop,
}

/// The controller of a run: the compensator, or (feature `orc`) the repetitive controller.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum Ctl {
    Comp(Controller),
    /// The board as data acquisition: the excitation, whatever the measurement.
    Excite(Excitation),
    #[cfg(feature = "orc")]
    Orc(OrcCtl),
}

#[cfg(feature = "orc")]
#[derive(Clone, Debug)]
struct OrcCtl {
    reference: Reference,
    orc: OrcController<f32, ORC_CAPACITY>,
    k: u32,
}

/// One step of either controller: `(k, u, flags)`.
impl Ctl {
    /// The run's controller, `p` checked by [`ControllerParams::validate`] (the host's
    /// check too).
    fn new(p: &ControllerParams, _orc: Option<&OrcParams>) -> Result<Self, Error> {
        #[cfg(feature = "orc")]
        if let Some(o) = _orc {
            p.validate()?;
            let (pi, orc) = o.configs(p);
            return Ok(Ctl::Orc(OrcCtl {
                reference: Reference::new(p),
                orc: OrcController::new(pi, orc)?,
                k: 0,
            }));
        }
        Ok(Ctl::Comp(Controller::new(p)?))
    }

    fn next_k(&self) -> u32 {
        match self {
            Ctl::Comp(c) => c.next_k(),
            Ctl::Excite(e) => e.next_k(),
            #[cfg(feature = "orc")]
            Ctl::Orc(o) => o.k,
        }
    }

    #[inline]
    fn step(&mut self, y_prev: Option<f32>) -> Result<(u32, f32, u8), Error> {
        match self {
            Ctl::Comp(c) => {
                let s = c.step(y_prev)?;
                let mut flags = 0;
                if s.out.saturated {
                    flags |= command_flags::SATURATED;
                }
                if s.out.guarded {
                    flags |= command_flags::GUARDED;
                }
                Ok((s.k, s.out.u, flags))
            }
            Ctl::Excite(e) => {
                let (k, u) = e.next_sample();
                Ok((k, u, 0))
            }
            #[cfg(feature = "orc")]
            Ctl::Orc(o) => {
                let mut reference = o.reference;
                let d = reference.next_sample();
                let out = o.orc.step(d, y_prev)?;
                o.reference = reference;
                let k = o.k;
                o.k = o.k.saturating_add(1);
                Ok((k, out.u, if out.saturated { command_flags::SATURATED } else { 0 }))
            }
        }
    }
}

/// Which actuator the drive goes to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Front {
    /// The host over the link (control mode).
    Host,
    /// The on-chip simulated actuator.
    Simulated,
    /// The board's converters.
    Converters,
}

#[derive(Clone, Debug)]
struct ControlRun {
    ctl: Ctl,
    total: u32,
    /// `y[k-1]` if it arrived for the next tick.
    pending: Option<f32>,
    used: u16,
    /// [`Mode::Lockstep`]: ticks wait for the measurement.
    lockstep: bool,
    /// Ticks waited so far for the pending measurement.
    waited: u32,
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

#[derive(Clone, Debug)]
struct FrontRun {
    ctl: Ctl,
    total: u32,
    /// The simulated actuator (`None`: the board's converters).
    sim: Option<SimulatedActuator>,
}

// The firmware has no heap; the board holds one run at a time, so the size is fixed anyway.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum Run {
    Idle,
    Control(ControlRun),
    Plant(PlantRun),
    Front(FrontRun),
}

/// The ramp of the drive to 0 V.
#[derive(Clone, Copy, Debug)]
struct Ramp {
    reason: SafeReason,
    k: u32,
}

/// The firmware's protocol state machine and control loop. Bytes in through
/// [`Device::on_packet`] (after the firmware's [`super::Decoder`]), ticks in through
/// [`Device::on_tick`]; every frame to send goes to the `send` closure.
///
/// ## Safe state
/// The drive holds its last value between runs. It ramps to 0 V at
/// [`SafetyParams::slew_v_per_s`] (one step per tick, telemetry flagged
/// [`command_flags::SAFE_RAMP`], then [`Message::Safe`] with the reason and the ticks since
/// the last intact frame) when no intact frame came for [`SafetyParams::host_timeout_ms`]
/// while a run goes on or the drive is not 0 V, when a step computes a non-finite or
/// out-of-range value, and when the firmware starts after a panic or a watchdog reset
/// ([`Device::begin_safe_state`]). Runs cannot start while it ramps.
#[derive(Clone, Debug)]
pub struct Device {
    controller: Option<ControllerParams>,
    plant: Option<PlantParams>,
    orc: Option<OrcParams>,
    excitation: Option<ExcitationParams>,
    /// What the next run computes.
    active: Active,
    safety: SafetyParams,
    converters: bool,
    run: Run,
    status: Status,
    diag: Diagnostics,
    rx_seq: SeqTracker,
    bad_since_good: u32,
    tx_seq: u16,
    fault_tokens: u32,
    refill: u32,
    period_us: u32,
    since_frame: u32,
    front: Front,
    ramp: Option<Ramp>,
}

impl Default for Device {
    fn default() -> Self {
        Self::new()
    }
}

/// The tick period before any run sets one, µs.
pub const DEFAULT_PERIOD_US: u32 = 1000;

impl Device {
    /// A board just out of reset, without converters: unconfigured, idle, drive at 0 V.
    pub fn new() -> Self {
        Self {
            controller: None,
            plant: None,
            orc: None,
            excitation: None,
            active: Active::None,
            safety: SafetyParams::DEFAULT,
            converters: false,
            run: Run::Idle,
            status: Status { state: RunState::Unconfigured as u8, ..Status::default() },
            diag: Diagnostics::default(),
            rx_seq: SeqTracker::new(),
            bad_since_good: 0,
            tx_seq: 0,
            fault_tokens: limits::FAULT_BURST,
            refill: 0,
            period_us: DEFAULT_PERIOD_US,
            since_frame: 0,
            front: Front::Host,
            ramp: None,
        }
    }

    /// The same board with converters: [`Mode::Local`] runs drive the `FrontEnd` given to
    /// [`Device::on_tick`].
    pub fn with_converters(mut self) -> Self {
        self.converters = true;
        self
    }

    /// The counters as the next [`Message::Status`] would report them.
    pub fn status(&self) -> Status {
        self.status
    }

    /// The timing and health figures; the firmware fills in what only it can measure.
    pub fn diagnostics_mut(&mut self) -> &mut Diagnostics {
        &mut self.diag
    }

    /// The timing and health figures.
    pub fn diagnostics(&self) -> Diagnostics {
        self.diag
    }

    /// The drive now, V.
    pub fn drive_v(&self) -> f32 {
        self.diag.drive_v
    }

    /// Whether the drive is on its way to 0 V.
    pub fn ramping(&self) -> bool {
        self.ramp.is_some()
    }

    /// The tick period in force, µs.
    pub fn period_us(&self) -> u32 {
        self.period_us
    }

    /// Whether a run is going on.
    pub fn running(&self) -> bool {
        !matches!(self.run, Run::Idle)
    }

    /// Notes bytes the firmware had to drop (receive buffer full).
    pub fn note_rx_overflow(&mut self, bytes: u32) {
        self.status.rx_overflow_bytes = self.status.rx_overflow_bytes.saturating_add(bytes);
    }

    /// Notes a frame the firmware could not queue for sending.
    pub fn note_tx_dropped(&mut self) {
        self.diag.tx_dropped = self.diag.tx_dropped.saturating_add(1);
    }

    /// The drive limits and safe state in force.
    pub fn safety(&self) -> SafetyParams {
        self.safety
    }

    /// Starts the ramp to 0 V from `drive_v` (clamped to the limits; a non-finite value is
    /// taken as 0 V) on the board's converters at `slew_v_per_s` (the default's if out of
    /// [`limits::SLEW_V_PER_S`]): what the firmware calls at start-up after a panic or a
    /// watchdog reset, with the drive and the slew it had saved.
    pub fn begin_safe_state(&mut self, reason: SafeReason, drive_v: f32, slew_v_per_s: f32) {
        let (lo, hi) = limits::SLEW_V_PER_S;
        if slew_v_per_s >= lo && slew_v_per_s <= hi {
            self.safety.slew_v_per_s = slew_v_per_s;
        }
        let v = if drive_v.is_finite() { drive_v.clamp(self.safety.u_min, self.safety.u_max) } else { 0.0 };
        self.diag.drive_v = v;
        self.diag.reset_cause = reason as u8;
        self.front = if self.converters { Front::Converters } else { Front::Host };
        self.ramp = Some(Ramp { reason, k: 0 });
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
        if self.controller.is_some() || self.plant.is_some() || self.excitation.is_some() {
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

    /// Ends the run and starts the ramp to 0 V.
    fn enter_safe_state(&mut self, reason: SafeReason) {
        self.run = Run::Idle;
        self.status.state = self.idle_state();
        self.ramp = Some(Ramp { reason, k: 0 });
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
                self.diag.bad_frames = self.diag.bad_frames.wrapping_add(1);
                self.bad_since_good = self.bad_since_good.saturating_add(1);
                if self.fault_tokens > 0 {
                    self.fault_tokens -= 1;
                    self.fault(send, FaultCode::BadFrame, 0xFFFF, e);
                } else {
                    self.diag.faults_suppressed = self.diag.faults_suppressed.wrapping_add(1);
                }
                return TimerRequest::Keep;
            }
        };
        self.since_frame = 0;
        self.status.rx_frames = self.status.rx_frames.wrapping_add(1);
        if let super::frame::SeqGap::Missed(n) = self.rx_seq.observe(seq) {
            let lost = (n as u32).saturating_sub(self.bad_since_good);
            self.status.rx_lost = self.status.rx_lost.wrapping_add(lost);
        }
        self.bad_since_good = 0;
        let busy = self.running() || self.ramping();
        match msg {
            Message::GetStatus => {
                let s = Message::Status(self.status);
                self.send(send, &s);
            }
            Message::GetDiagnostics => {
                let d = Message::Diagnostics(self.diag);
                self.send(send, &d);
            }
            Message::GetParams => {
                let p = Message::Params(BoardParams {
                    active: self.active,
                    controller: self.controller.clone(),
                    safety: self.safety,
                });
                self.send(send, &p);
            }
            Message::SetExcitation(p) if !busy => match p.validate() {
                Ok(()) => {
                    self.excitation = Some(p);
                    self.active = Active::Excitation;
                    self.status.state = self.idle_state();
                    self.send(send, &Message::Ack { kind: kind::SET_EXCITATION, seq });
                }
                Err(e) => self.fault(send, FaultCode::InvalidParams, seq, e),
            },
            Message::SetController(p) if !busy => match Ctl::new(&p, None) {
                Ok(_) => {
                    self.controller = Some(p);
                    self.active = Active::Controller;
                    self.orc = None;
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
            Message::SetSafety(p) if !busy => match check_safety(&p) {
                Ok(()) if !(self.diag.drive_v >= p.u_min && self.diag.drive_v <= p.u_max) => {
                    // The drive held between runs would be outside the new limits.
                    self.fault(send, FaultCode::Busy, seq, "the drive held is outside the new limits")
                }
                Ok(()) => {
                    self.safety = p;
                    self.send(send, &Message::Ack { kind: kind::SET_SAFETY, seq });
                }
                Err(e) => self.fault(send, FaultCode::InvalidParams, seq, e),
            },
            Message::Start { mode, samples } if !busy => return self.start(mode, samples, seq, send),
            Message::SetOrc(o) if !busy => self.set_orc(o, seq, send),
            Message::SetController(_)
            | Message::SetExcitation(_)
            | Message::SetPlant(_)
            | Message::SetSafety(_)
            | Message::SetOrc(_)
            | Message::Start { .. } => {
                self.fault(send, FaultCode::Busy, seq, "a run or the ramp to 0 V is going on")
            }
            Message::Stop => {
                let was_ticking = matches!(self.run, Run::Control(_) | Run::Front(_));
                self.finish(send);
                return if was_ticking { TimerRequest::Stop } else { TimerRequest::Keep };
            }
            Message::Measurement { k, y } => match &mut self.run {
                Run::Control(run)
                    if k.wrapping_add(1) == run.ctl.next_k()
                        && y.is_finite()
                        && y.abs() <= limits::Y_MAX_UM =>
                {
                    run.pending = Some(y)
                }
                Run::Plant(_) => self.fault(send, FaultCode::Unexpected, seq, "measurement in a plant run"),
                _ => self.status.measurements_stale = self.status.measurements_stale.wrapping_add(1),
            },
            Message::Command { k, u, .. } => return self.plant_command(k, u, seq, send),
            Message::Ack { .. }
            | Message::Status(_)
            | Message::Fault(_)
            | Message::Telemetry { .. }
            | Message::Safe { .. }
            | Message::Params(_)
            | Message::Diagnostics(_) => {
                self.fault(send, FaultCode::Unexpected, seq, "a board-to-host message sent to the board")
            }
        }
        TimerRequest::Keep
    }

    #[cfg(feature = "orc")]
    fn set_orc(&mut self, o: OrcParams, seq: u16, send: &mut impl FnMut(&[u8])) {
        let Some(c) = &self.controller else {
            self.fault(send, FaultCode::NotConfigured, seq, "SetOrc needs SetController first");
            return;
        };
        match Ctl::new(c, Some(&o)) {
            Ok(_) => {
                self.orc = Some(o);
                self.active = Active::Controller;
                self.send(send, &Message::Ack { kind: kind::SET_ORC, seq });
            }
            Err(e) => self.fault(send, FaultCode::InvalidParams, seq, e),
        }
    }

    #[cfg(not(feature = "orc"))]
    fn set_orc(&mut self, _o: OrcParams, seq: u16, send: &mut impl FnMut(&[u8])) {
        self.fault(send, FaultCode::Unexpected, seq, "the ORC is not built in (feature orc)")
    }

    fn start(&mut self, mode: Mode, samples: u32, seq: u16, send: &mut impl FnMut(&[u8])) -> TimerRequest {
        let ctl = |d: &Self| match (d.active, &d.controller, &d.excitation) {
            (Active::Excitation, _, Some(e)) => {
                Excitation::new(e).map(Ctl::Excite).map_err(|_| "excitation parameters rejected")
            }
            (_, None, _) => Err("no controller parameters (send SetController first)"),
            (_, Some(p), _) => Ctl::new(p, d.orc.as_ref()).map_err(|_| "controller parameters rejected"),
        };
        let period = match (self.active, &self.excitation) {
            (Active::Excitation, Some(e)) => e.sample_period_us,
            _ => self.controller.as_ref().map_or(DEFAULT_PERIOD_US, |p| p.sample_period_us),
        };
        let run = match mode {
            Mode::Control | Mode::Lockstep => ctl(self).map(|ctl| {
                let lockstep = mode == Mode::Lockstep;
                let run = ControlRun { ctl, total: samples, pending: None, used: 0, lockstep, waited: 0 };
                (Run::Control(run), Front::Host)
            }),
            Mode::Plant => match &self.plant {
                None => Err("no plant parameters (send SetPlant first)"),
                Some(p) => match OnChipPlant::new(p) {
                    Ok(plant) => Ok((
                        Run::Plant(PlantRun { plant, total: samples, next_k: 0, u_last: 0.0, y_last: 0.0 }),
                        self.front,
                    )),
                    Err(_) => Err("plant parameters rejected"),
                },
            },
            Mode::Simulated => match (&self.plant, ctl(self)) {
                (None, _) => Err("no plant parameters (send SetPlant first)"),
                (_, Err(e)) => Err(e),
                (Some(p), Ok(ctl)) => match OnChipPlant::new(p) {
                    Ok(plant) => Ok((
                        Run::Front(FrontRun {
                            ctl,
                            total: samples,
                            sim: Some(SimulatedActuator::new(plant)),
                        }),
                        Front::Simulated,
                    )),
                    Err(_) => Err("plant parameters rejected"),
                },
            },
            Mode::Local if !self.converters => Err("this board has no converters"),
            Mode::Local => ctl(self)
                .map(|ctl| (Run::Front(FrontRun { ctl, total: samples, sim: None }), Front::Converters)),
        };
        match run {
            Err(what) => {
                self.fault(send, FaultCode::NotConfigured, seq, what);
                TimerRequest::Keep
            }
            Ok((run, front)) => {
                if front != self.front && self.diag.drive_v != 0.0 {
                    // Switching actuators with the old one still driven: it would be left
                    // where it is.
                    self.fault(send, FaultCode::Busy, seq, "the drive is not at 0 V");
                    return TimerRequest::Keep;
                }
                // Counters are per run; the link's own (frames) go on, and so do the
                // diagnostics' except the timing of ticks and steps.
                let d = &mut self.diag;
                (d.ticks, d.missed_ticks, d.isr_ticks_max, d.isr_ticks_sum) = (0, 0, 0, 0);
                (d.steps, d.step_ticks_max, d.step_ticks_sum) = (0, 0, 0);
                self.status = Status {
                    state: RunState::Running as u8,
                    mode: mode as u8,
                    samples_total: samples,
                    tx_frames: self.status.tx_frames,
                    ..Status::default()
                };
                self.run = run;
                self.front = front;
                self.send(send, &Message::Ack { kind: kind::START, seq });
                if mode == Mode::Plant {
                    TimerRequest::Keep
                } else {
                    self.period_us = period;
                    TimerRequest::Start { period_us: period }
                }
            }
        }
    }

    fn plant_command(&mut self, k: u32, u: f32, seq: u16, send: &mut impl FnMut(&[u8])) -> TimerRequest {
        let (u_min, u_max) = (self.safety.u_min, self.safety.u_max);
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
        // A sample already past, beyond the run, too far ahead to catch up in bounded time,
        // the last index (no next one), or an input outside the drive limits: not taken.
        let in_run = k >= run.next_k
            && (run.total == 0 || k < run.total)
            && k - run.next_k <= limits::MAX_CATCH_UP
            && k < u32::MAX;
        if !(in_run && u >= u_min && u <= u_max) {
            self.status.measurements_stale = self.status.measurements_stale.wrapping_add(1);
            return TimerRequest::Keep;
        }
        // Samples whose command never came: the driver holds the last input.
        let mut y = 0.0;
        while run.next_k < k {
            y = run.plant.step(run.u_last);
            run.next_k += 1;
        }
        if k == run.next_k {
            y = run.plant.step(u);
        }
        if !(y.is_finite() && y.abs() <= limits::Y_MAX_UM) {
            self.status.compute_errors = self.status.compute_errors.wrapping_add(1);
            self.fault(send, FaultCode::Compute, seq, "the plant's output left its range; run ended");
            self.finish(send);
            return TimerRequest::Keep;
        }
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

    /// One tick of the sample timer; `missed` ticks were lost before it. `fe` is the
    /// board's converters (used by [`Mode::Local`] runs and, after them, by the ramp to
    /// 0 V); `clock` reads the board's free-running clock, to time the control step.
    pub fn on_tick(
        &mut self,
        missed: u32,
        fe: &mut impl FrontEnd,
        clock: &impl Fn() -> u32,
        send: &mut impl FnMut(&[u8]),
    ) -> TimerRequest {
        self.status.tick_overruns = self.status.tick_overruns.wrapping_add(missed);
        self.diag.ticks = self.diag.ticks.wrapping_add(1);
        self.diag.missed_ticks = self.diag.missed_ticks.wrapping_add(missed);
        self.refill = self.refill.saturating_add(missed.saturating_add(1));
        if self.refill >= limits::FAULT_REFILL_TICKS {
            self.refill = 0;
            self.fault_tokens = (self.fault_tokens + 1).min(limits::FAULT_BURST);
        }
        self.since_frame = self.since_frame.saturating_add(missed.saturating_add(1));
        let timeout_ticks =
            (self.safety.host_timeout_ms as u64 * 1000).div_ceil(self.period_us.max(1) as u64) as u32;
        let driving = matches!(self.run, Run::Control(_) | Run::Front(_)) || self.diag.drive_v != 0.0;
        if self.ramp.is_none() && driving && self.since_frame > timeout_ticks {
            let was_ticking = self.running();
            self.enter_safe_state(SafeReason::HostLost);
            if was_ticking {
                self.ramp_step(fe, send);
                return TimerRequest::Keep;
            }
        }
        if self.ramp.is_some() {
            self.ramp_step(fe, send);
            return TimerRequest::Keep;
        }
        match &mut self.run {
            Run::Control(_) => self.control_tick(clock, send),
            Run::Front(_) => self.front_tick(fe, clock, send),
            _ => TimerRequest::Keep,
        }
    }

    /// `u` within the drive limits, and the flag if it was clamped.
    fn limit(&self, u: f32, flags: u8) -> (f32, u8) {
        if u > self.safety.u_max {
            (self.safety.u_max, flags | command_flags::LIMITED)
        } else if u < self.safety.u_min {
            (self.safety.u_min, flags | command_flags::LIMITED)
        } else {
            (u, flags)
        }
    }

    /// Steps `ctl` with `y_prev` (retrying without it if it made the step fail); `None` if
    /// the step failed or its output is not finite.
    fn step_timed(
        ctl: &mut Ctl,
        y_prev: Option<f32>,
        clock: &impl Fn() -> u32,
        diag: &mut Diagnostics,
        status: &mut Status,
    ) -> Option<((u32, f32, u8), bool)> {
        let t0 = clock();
        let first = ctl.step(y_prev);
        let t1 = clock();
        let dt = t1.wrapping_sub(t0);
        diag.steps = diag.steps.wrapping_add(1);
        diag.step_ticks_sum = diag.step_ticks_sum.wrapping_add(dt as u64);
        diag.step_ticks_max = diag.step_ticks_max.max(dt);
        let (s, used) = match first {
            Ok(s) => (s, y_prev.is_some()),
            Err(_) => {
                // Only a non-finite measurement fails a step; the step runs without it.
                status.compute_errors = status.compute_errors.wrapping_add(1);
                (ctl.step(None).ok()?, false)
            }
        };
        s.1.is_finite().then_some((s, used))
    }

    fn control_tick(&mut self, clock: &impl Fn() -> u32, send: &mut impl FnMut(&[u8])) -> TimerRequest {
        let Run::Control(run) = &mut self.run else { return TimerRequest::Keep };
        if run.lockstep
            && run.ctl.next_k() > 0
            && run.pending.is_none()
            && run.waited < limits::LOCKSTEP_PATIENCE_TICKS
        {
            run.waited += 1;
            self.diag.lockstep_waits = self.diag.lockstep_waits.wrapping_add(1);
            return TimerRequest::Keep;
        }
        run.waited = 0;
        let y_prev = run.pending.take();
        let Some(((k, u, flags), used_now)) =
            Self::step_timed(&mut run.ctl, y_prev, clock, &mut self.diag, &mut self.status)
        else {
            return self.compute_fault(send);
        };
        if k > 0 {
            if used_now {
                self.status.measurements_used = self.status.measurements_used.wrapping_add(1);
            } else {
                self.status.measurements_missing = self.status.measurements_missing.wrapping_add(1);
            }
        }
        run.used = (run.used << 1) | used_now as u16;
        let (used, total) = (run.used, run.total);
        let (u, flags) = self.limit(u, flags);
        self.diag.drive_v = u;
        let msg = Message::Command { k, u, used, flags };
        let done = total > 0 && k.saturating_add(1) >= total;
        self.status.samples_done = k.saturating_add(1);
        self.send(send, &msg);
        if done {
            self.finish(send);
            return TimerRequest::Stop;
        }
        TimerRequest::Keep
    }

    fn front_tick(
        &mut self,
        fe: &mut impl FrontEnd,
        clock: &impl Fn() -> u32,
        send: &mut impl FnMut(&[u8]),
    ) -> TimerRequest {
        let Run::Front(run) = &mut self.run else { return TimerRequest::Keep };
        let k_now = run.ctl.next_k();
        let y_prev = match &mut run.sim {
            Some(sim) => sim.sense(),
            None => fe.sense(),
        }
        .filter(|y| y.is_finite() && y.abs() <= limits::Y_MAX_UM);
        let Some(((k, u, flags), used_now)) =
            Self::step_timed(&mut run.ctl, y_prev, clock, &mut self.diag, &mut self.status)
        else {
            return self.compute_fault(send);
        };
        if k_now > 0 {
            if used_now {
                self.status.measurements_used = self.status.measurements_used.wrapping_add(1);
            } else {
                self.status.measurements_missing = self.status.measurements_missing.wrapping_add(1);
            }
        }
        let (u_min, u_max) = (self.safety.u_min, self.safety.u_max);
        let (u, mut flags) = if u > u_max {
            (u_max, flags | command_flags::LIMITED)
        } else if u < u_min {
            (u_min, flags | command_flags::LIMITED)
        } else {
            (u, flags)
        };
        if !used_now {
            flags |= command_flags::Y_MISSING;
        }
        let Run::Front(run) = &mut self.run else { return TimerRequest::Keep };
        let applied = match &mut run.sim {
            Some(sim) => sim.drive(u),
            None => fe.drive(u),
        };
        let total = run.total;
        self.diag.drive_v = applied;
        let y = y_prev.unwrap_or(f32::NAN);
        self.send(send, &Message::Telemetry { k, u: applied, y, flags });
        self.status.samples_done = k.saturating_add(1);
        if total > 0 && k.saturating_add(1) >= total {
            self.finish(send);
            return TimerRequest::Stop;
        }
        TimerRequest::Keep
    }

    fn compute_fault(&mut self, send: &mut impl FnMut(&[u8])) -> TimerRequest {
        self.status.compute_errors = self.status.compute_errors.wrapping_add(1);
        self.fault(send, FaultCode::Compute, 0xFFFF, "the control step failed; drive to 0 V");
        self.enter_safe_state(SafeReason::Fault);
        let s = Message::Status(self.status);
        self.send(send, &s);
        TimerRequest::Keep
    }

    /// One step of the ramp to 0 V.
    fn ramp_step(&mut self, fe: &mut impl FrontEnd, send: &mut impl FnMut(&[u8])) {
        let Some(mut ramp) = self.ramp else { return };
        let step = self.safety.slew_v_per_s * self.period_us as f32 * 1e-6;
        let v = self.diag.drive_v;
        let next = if v > step {
            v - step
        } else if v < -step {
            v + step
        } else {
            0.0
        };
        let applied = if self.front == Front::Converters { fe.drive(next) } else { next };
        self.diag.drive_v = applied;
        let k = ramp.k;
        ramp.k = ramp.k.saturating_add(1);
        self.send(send, &Message::Telemetry { k, u: applied, y: f32::NAN, flags: command_flags::SAFE_RAMP });
        if applied == 0.0 {
            self.ramp = None;
            self.diag.safe_reason = ramp.reason as u8;
            self.diag.safe_ticks = self.since_frame;
            let msg = Message::Safe {
                reason: ramp.reason as u8,
                ticks: self.since_frame,
                period_us: self.period_us,
            };
            self.send(send, &msg);
        } else {
            self.ramp = Some(ramp);
        }
    }
}

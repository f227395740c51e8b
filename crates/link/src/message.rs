//! The messages and their payloads: explicit little-endian fields, fixed layouts.
//!
//! | kind | message | direction | payload (bytes) |
//! |---|---|---|---|
//! | `0x01` | [`Message::GetStatus`] | host → board | 0 |
//! | `0x02` | [`Message::SetController`] | host → board | [`ControllerParams`], 99 |
//! | `0x03` | [`Message::SetPlant`] | host → board | [`PlantParams`], 59 |
//! | `0x04` | [`Message::Start`] | host → board | mode u8, samples u32 |
//! | `0x05` | [`Message::Stop`] | host → board | 0 |
//! | `0x06` | [`Message::Measurement`] | either | k u32, y f32 (µm) |
//! | `0x07` | [`Message::Command`] | either | k u32, u f32 (V), used u16, flags u8 |
//! | `0x08` | [`Message::SetOrc`] | host → board | [`OrcParams`], 27 |
//! | `0x09` | [`Message::SetSafety`] | host → board | [`SafetyParams`], 16 |
//! | `0x0A` | [`Message::GetDiagnostics`] | host → board | 0 |
//! | `0x0B` | [`Message::GetParams`] | host → board | 0 |
//! | `0x0C` | [`Message::SetExcitation`] | host → board | [`ExcitationParams`], 105 |
//! | `0x10` | [`Message::Ack`] | board → host | kind u8, seq u16 |
//! | `0x11` | [`Message::Status`] | board → host | [`Status`], 50 |
//! | `0x12` | [`Message::Fault`] | board → host | code u8, seq u16, text (≤ 48 bytes UTF-8) |
//! | `0x13` | [`Message::Telemetry`] | board → host | k u32, u f32 (V), y f32 (µm), flags u8 |
//! | `0x14` | [`Message::Safe`] | board → host | reason u8, ticks u32, period_us u32 |
//! | `0x15` | [`Message::Diagnostics`] | board → host | [`Diagnostics`], 78 |
//! | `0x16` | [`Message::Params`] | board → host | [`BoardParams`], 117 |
//!
//! Every multi-byte field is little-endian; `f32` is its IEEE 754 bit pattern (so values
//! cross the link bit for bit); `u64` phase increments are the core's
//! [`Oscillator`] units (2⁻⁶⁴ turn per sample). A payload must have exactly its layout's
//! length; enumerations and counts are range-checked here; the ranges of the numbers are
//! the board's to check ([`crate::limits`]), so a decoded message can still hold a
//! value the board refuses.

use super::WireError;
use super::frame::MAX_PAYLOAD;
use super::limits;
use boucwen_core::Error;
use boucwen_core::compensator::{CompensatorConfig, DirectInverse, HarmonicSpec, Saturation};
use boucwen_core::controllers::{OrcConfig, OrcPlacement, PiConfig};
use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
use boucwen_core::rls::RlsConfig;
use boucwen_core::signal::Oscillator;
use core::fmt::{self, Write as _};
use heapless::{String, Vec};
use nalgebra::Complex;

/// AR order carried on the wire; lower orders are padded with zero coefficients.
pub const MAX_AR: usize = 3;
/// Most harmonics the board cancels (and the on-chip plant's most branches).
pub const MAX_HARMONICS: usize = 2;
/// Longest [`Fault`] text, bytes.
pub const MAX_TEXT: usize = 48;

/// Everything the board needs to run the compensator of `boucwen_core::compensator`:
/// the identified model, the reference, the cancelled harmonics, the RLS settings and the
/// driver's range.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerParams {
    /// The extended model inverted by `u_f` (AR part zero-padded to [`MAX_AR`]).
    pub model: ExtendedParams<f32, MAX_AR>,
    /// The reference frequency `f`: phase increment per sample.
    pub drive: Oscillator,
    /// The board's sample period, µs (what its timer ticks at; the model's `Ts`).
    pub sample_period_us: u32,
    /// Reference amplitude `α`, µm: `d[k] = α·w[k]·sin(2π f k Ts)`.
    pub amplitude_um: f32,
    /// Length of the raised-cosine fade-in `w[k]` of the reference, samples (0: none).
    pub fade_samples: u32,
    /// The cancelled harmonics: order `n` and the plant's response at `n·f`.
    pub harmonics: Vec<HarmonicSpec<f32>, MAX_HARMONICS>,
    /// RLS of the cancellation weights.
    pub rls: RlsConfig<f32>,
    /// The driver's input range, V.
    pub saturation: Saturation<f32>,
    /// Bound on each cancellation amplitude `|α̂_n|`, V.
    pub uc_max: f32,
    /// The preview `τ`, samples (the identified model's input delay): the inverse works on
    /// the reference `τ` samples ahead, `d(k + τ)`, the tracking error on `d[k]`
    /// ([`boucwen_core::compensator::Compensator::step_previewed`]). 0 (no preview) to
    /// [`crate::limits::PREVIEW_MAX_SAMPLES`], resolved to 2⁻¹⁶ sample on the board.
    pub preview_samples: f32,
}

impl ControllerParams {
    /// Checks the parameters as the board does before it accepts them (`SetController`
    /// answers `Fault(InvalidParams)` with this error), and as the host does before it
    /// sends or writes them: this is the one check of both ends. Every number within the
    /// board's [`limits`] (sample period, amplitude, fade-in,
    /// preview, saturation, `uc_max`); a model the direct inverse can use (a gain `A1` of at
    /// least [`MIN_GAIN_UM_PER_V`](crate::limits::MIN_GAIN_UM_PER_V) in size, and the
    /// static part `A1·u − h` moving with `u` the way `A1` does on both branches at rest,
    /// `sign(A1)·(A1 − A ∓ A0) ≥`
    /// [`MIN_SLOPE_AT_REST`](crate::limits::MIN_SLOPE_AT_REST)`·|A1|`, where every
    /// run starts); and each cancelled harmonic, RLS setting and range as the core's
    /// compensator checks them. The error names the parameter.
    ///
    /// A model that fails the inverse's condition (`A1 = 0`: `bouc_wen = [0, 0, 0, 0, 0]`)
    /// would drive the actuator to a saturation bound and hold it there, without a fault.
    ///
    /// ```
    /// use boucwen_core::compensator::Saturation;
    /// use boucwen_core::model::{BoucWenParams, ExtendedParams};
    /// use boucwen_core::rls::RlsConfig;
    /// use boucwen_core::signal::Oscillator;
    /// use boucwen_link::message::ControllerParams;
    /// let mut p = ControllerParams {
    ///     model: ExtendedParams {
    ///         bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
    ///         ar: [1.5, -0.6, 0.0],
    ///     },
    ///     drive: Oscillator::new(23.0, 1e-3)?,
    ///     sample_period_us: 1000,
    ///     amplitude_um: 20.0,
    ///     fade_samples: 500,
    ///     harmonics: heapless::Vec::new(),
    ///     rls: RlsConfig::with_forgetting(0.999, 1e-2),
    ///     saturation: Saturation::symmetric(10.0),
    ///     uc_max: 2.0,
    ///     preview_samples: 0.0,
    /// };
    /// assert!(p.validate().is_ok());
    /// p.sample_period_us = 0;
    /// assert!(p.validate().is_err());
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    #[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x <= max)` does")]
    pub fn validate(&self) -> Result<(), Error> {
        if cfg!(feature = "no-preview") && self.preview_samples != 0.0 {
            return Err(Error::OutOfRange("preview (not built in: feature no-preview)"));
        }
        let (lo, hi) = limits::SAMPLE_PERIOD_US;
        if !(lo..=hi).contains(&self.sample_period_us) {
            return Err(Error::OutOfRange("sample period (100 µs to 100 ms)"));
        }
        if !self.amplitude_um.is_finite() {
            return Err(Error::NonFinite("reference amplitude"));
        }
        if self.amplitude_um.abs() > limits::AMPLITUDE_MAX_UM {
            return Err(Error::OutOfRange("reference amplitude (at most 1e4 µm)"));
        }
        if self.fade_samples > limits::FADE_MAX_SAMPLES {
            return Err(Error::OutOfRange("fade-in (at most 1e7 samples)"));
        }
        if !(self.preview_samples >= 0.0 && self.preview_samples <= limits::PREVIEW_MAX_SAMPLES) {
            return Err(Error::OutOfRange("preview (0 to 16 samples)"));
        }
        let s = &self.saturation;
        if !(s.u_min.abs() <= limits::U_MAX_V && s.u_max.abs() <= limits::U_MAX_V) {
            return Err(Error::OutOfRange("saturation (at most 1000 V)"));
        }
        if !(self.uc_max <= limits::U_MAX_V) {
            return Err(Error::OutOfRange("uc_max (at most 1000 V)"));
        }
        let base = CompensatorConfig::<f32, MAX_AR, 0> {
            model: self.model,
            drive: self.drive,
            harmonics: [],
            rls: self.rls,
            saturation: self.saturation,
            uc_max: self.uc_max,
        };
        base.validate()?;
        DirectInverse::new(self.model)?;
        check_invertible(&self.model.bw)?;
        for &h in &self.harmonics {
            CompensatorConfig::<f32, MAX_AR, 1> {
                model: base.model,
                drive: base.drive,
                harmonics: [h],
                rls: base.rls,
                saturation: base.saturation,
                uc_max: base.uc_max,
            }
            .validate()?;
        }
        Ok(())
    }
}

/// The direct inverse's condition on the model (see [`ControllerParams::validate`]): a
/// gain `A1` the inverse can divide by, and a static part `A1·u − h` that moves with `u` the
/// way `A1` does on both branches at rest (`h = 0`). A sensor counting the stroke downwards
/// gives the mirrored model (`A1 < 0`), which passes as its mirror does.
#[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x >= min)` does")]
fn check_invertible(bw: &BoucWenParams<f32>) -> Result<(), Error> {
    if !(bw.a1.abs() >= limits::MIN_GAIN_UM_PER_V) {
        return Err(Error::OutOfRange("model gain A1 (the inverse divides by it: |A1| at least 1e-6 µm/V)"));
    }
    let sign = if bw.a1 > 0.0 { 1.0 } else { -1.0 };
    for rising in [true, false] {
        let slope = sign * (bw.a1 - bw.slope(0.0, rising));
        if !(slope >= limits::MIN_SLOPE_AT_REST * bw.a1.abs()) {
            return Err(Error::OutOfRange(
                "model's slope at rest (not invertible: A1 − A ∓ A0 must have A1's sign, ≥ 1e-3·|A1|)",
            ));
        }
    }
    Ok(())
}

/// The on-chip plant of the self-test and of the board's plant mode: the core's enhanced
/// model in `f32` (the extended model plus harmonic branches without AR part).
#[derive(Clone, Debug, PartialEq)]
pub struct PlantParams {
    /// Hysteresis, gain and structure.
    pub base: ExtendedParams<f32, MAX_AR>,
    /// The drive frequency whose harmonics the branches follow.
    pub drive: Oscillator,
    /// The harmonic branches.
    pub branches: Vec<HarmonicBranch<f32, 0>, MAX_HARMONICS>,
}

/// The odd-harmonic repetitive controller on its PI (`boucwen_core::controllers`), which a
/// board built with the firmware's `orc` feature runs in place of the compensator: the
/// gains of [`boucwen_core::controllers::tune`]. The reference, the sample period and the
/// driver's range are the [`ControllerParams`]' (sent before).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrcParams {
    /// PI proportional gain `Kp`, V/µm.
    pub kp: f32,
    /// PI integral gain `Ki`, V/(µm·s).
    pub ki_per_s: f32,
    /// Static feedforward gain `k_ff`, V/µm (0: none).
    pub feedforward_gain: f32,
    /// `a` of the robustness filter `Q = [a, 1-2a, a]`.
    pub q_coeff: f32,
    /// Learning gain (see `OrcConfig::learning_gain`).
    pub learning_gain: f32,
    /// Phase lead `m`, samples.
    pub lead_samples: u16,
    /// Bound on `|u_rc|`.
    pub limit: f32,
    /// Where `u_rc` enters the loop.
    pub placement: OrcPlacement,
}

impl OrcParams {
    /// The PI and internal-model configurations with the controller's reference, sample
    /// period and range.
    pub fn configs(&self, c: &ControllerParams) -> (PiConfig<f32>, OrcConfig<f32>) {
        let pi = PiConfig {
            kp: self.kp,
            ki_per_s: self.ki_per_s,
            ts_s: c.sample_period_us as f32 * 1e-6,
            feedforward_gain: self.feedforward_gain,
            saturation: c.saturation,
        };
        let orc = OrcConfig {
            drive: c.drive,
            q_coeff: self.q_coeff,
            learning_gain: self.learning_gain,
            lead_samples: u32::from(self.lead_samples),
            limit: self.limit,
            placement: self.placement,
        };
        (pi, orc)
    }

    fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        for v in [self.kp, self.ki_per_s, self.feedforward_gain, self.q_coeff, self.learning_gain] {
            w.f32(v)?;
        }
        w.u16(self.lead_samples)?;
        w.f32(self.limit)?;
        w.u8(match self.placement {
            OrcPlacement::PlantInput => 1,
            OrcPlacement::PiInput => 2,
        })
    }

    fn read(r: &mut Reader<'_>) -> Result<Self, WireError> {
        let (kp, ki_per_s, feedforward_gain, q_coeff, learning_gain) =
            (r.f32()?, r.f32()?, r.f32()?, r.f32()?, r.f32()?);
        let lead_samples = r.u16()?;
        let limit = r.f32()?;
        let placement = match r.u8()? {
            1 => OrcPlacement::PlantInput,
            2 => OrcPlacement::PiInput,
            _ => return Err(WireError::BadValue("ORC placement")),
        };
        Ok(Self { kp, ki_per_s, feedforward_gain, q_coeff, learning_gain, lead_samples, limit, placement })
    }
}

/// What a [`Message::Start`] starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// The board is the controller: every tick it sends [`Message::Command`] `u[k]`, and
    /// the host answers with [`Message::Measurement`] `y[k]` from its actuator.
    Control = 1,
    /// The board is the plant (its on-chip model stands for actuator and sensor): every
    /// [`Message::Command`] from the host is answered with a [`Message::Measurement`].
    Plant = 2,
    /// The board is the controller and its actuator is the on-chip simulated one (the
    /// [`PlantParams`] model, the emulator's stand-in for the converters): every tick it
    /// reads the simulated sensor, steps, drives the simulation and sends
    /// [`Message::Telemetry`]. The self-test.
    Simulated = 3,
    /// The board is the controller of its own converters (ADC and DAC): every tick it
    /// reads the sensor, steps, writes the drive and sends [`Message::Telemetry`]. Boards
    /// without converters refuse it.
    Local = 4,
    /// A [`Mode::Control`] run in lockstep with its host: a tick whose step would run
    /// without the previous sample's measurement waits for it, at most
    /// [`crate::limits::LOCKSTEP_PATIENCE_TICKS`] ticks, then steps without it as
    /// a control run does at once. For hardware in the loop with a simulated actuator on a
    /// host that is not real-time (or a board in an emulator whose clock follows the
    /// host's): the plant's time is the sample index, not the wall clock, so a late answer
    /// costs time, not a measurement. The cadence of the commands is then the host's; the
    /// board's own timing is what `Simulated` and `Local` runs measure.
    Lockstep = 5,
}

impl Mode {
    /// The mode of its number.
    pub fn from_u8(v: u8) -> Option<Self> {
        match v {
            1 => Some(Mode::Control),
            2 => Some(Mode::Plant),
            3 => Some(Mode::Simulated),
            4 => Some(Mode::Local),
            5 => Some(Mode::Lockstep),
            _ => None,
        }
    }
}

/// The board's state in a [`Status`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunState {
    /// Nothing configured.
    Unconfigured = 0,
    /// Configured, not running.
    Idle = 1,
    /// A run is going on.
    Running = 2,
}

/// Counters of the board's current (or last) run; they reset at [`Message::Start`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Status {
    /// [`RunState`] as its number.
    pub state: u8,
    /// [`Mode`] of the run as its number (0: none yet).
    pub mode: u8,
    /// Samples done.
    pub samples_done: u32,
    /// Samples asked for (0: until [`Message::Stop`]).
    pub samples_total: u32,
    /// Intact frames received.
    pub rx_frames: u32,
    /// Frames received and rejected (COBS, CRC, length, unknown kind or value).
    pub rx_bad: u32,
    /// Frames missing from the host's sequence numbers and never seen even as bad frames.
    pub rx_lost: u32,
    /// Frames sent.
    pub tx_frames: u32,
    /// Control mode: ticks at which `y[k-1]` had arrived and was used.
    pub measurements_used: u32,
    /// Control mode: ticks at which `y[k-1]` had not arrived (the step ran without it).
    pub measurements_missing: u32,
    /// Measurements that arrived after their tick, or for a sample not in the run.
    pub measurements_stale: u32,
    /// Bytes dropped because the receive buffer was full.
    pub rx_overflow_bytes: u32,
    /// Ticks missed because the loop was still busy with an earlier one.
    pub tick_overruns: u32,
    /// Steps that failed (non-finite measurement): the step ran without the measurement.
    pub compute_errors: u32,
}

/// Why the board refused something.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultCode {
    /// A frame failed its checks (text: which); this is the board's negative acknowledge.
    BadFrame = 1,
    /// The message is not valid now (e.g. a measurement while idle).
    Unexpected = 2,
    /// [`Message::Start`] before the parameters the mode needs.
    NotConfigured = 3,
    /// The parameters were rejected (text: which one and why).
    InvalidParams = 4,
    /// A run is going on (or the drive is ramping to 0 V); stop it first.
    Busy = 5,
    /// A computed value was not finite or out of its range (the run ended, the drive
    /// ramps to 0 V).
    Compute = 6,
}

/// A refusal, naming the frame that caused it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fault {
    /// What kind of refusal.
    pub code: FaultCode,
    /// Sequence number of the frame refused (`0xFFFF` for a frame too damaged to read it).
    pub seq: u16,
    /// Detail, e.g. the parameter rejected.
    pub text: String<MAX_TEXT>,
}

impl Fault {
    /// A fault whose text is `what`'s `Display`, cut at [`MAX_TEXT`] bytes (on a character
    /// boundary).
    pub fn new(code: FaultCode, seq: u16, what: impl fmt::Display) -> Self {
        struct Cut<'a>(&'a mut String<MAX_TEXT>);
        impl fmt::Write for Cut<'_> {
            fn write_str(&mut self, s: &str) -> fmt::Result {
                for c in s.chars() {
                    if self.0.push(c).is_err() {
                        return Err(fmt::Error);
                    }
                }
                Ok(())
            }
        }
        let mut text = String::new();
        // A cut text is still the best description there is.
        let _ = write!(Cut(&mut text), "{what}");
        Self { code, seq, text }
    }
}

/// Flags of a [`Message::Command`] from the board.
pub mod command_flags {
    /// `u` was clamped to the driver's range.
    pub const SATURATED: u8 = 1;
    /// The inverse's denominator guard acted.
    pub const GUARDED: u8 = 2;
    /// The drive is ramping to 0 V (safe state), not following the controller.
    pub const SAFE_RAMP: u8 = 4;
    /// The step ran without a measurement (none arrived, or the sensor had none).
    pub const Y_MISSING: u8 = 8;
    /// `u` was clamped to the board's drive limits ([`super::SafetyParams`]).
    pub const LIMITED: u8 = 16;
}

/// The board's drive limits and safe state, set by [`Message::SetSafety`]; the board
/// starts with [`SafetyParams::DEFAULT`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SafetyParams {
    /// Lowest drive, V (≤ 0).
    pub u_min: f32,
    /// Highest drive, V (≥ 0).
    pub u_max: f32,
    /// Fastest change of the drive on the way to 0 V, V/s.
    pub slew_v_per_s: f32,
    /// No intact frame for this long while a run goes on or the drive is not 0 V: the host
    /// is lost, the run ends and the drive ramps to 0 V, ms.
    pub host_timeout_ms: u32,
}

impl SafetyParams {
    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        for v in [self.u_min, self.u_max, self.slew_v_per_s] {
            w.f32(v)?;
        }
        w.u32(self.host_timeout_ms)
    }

    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, WireError> {
        Ok(Self { u_min: r.f32()?, u_max: r.f32()?, slew_v_per_s: r.f32()?, host_timeout_ms: r.u32()? })
    }

    /// ±10 V, 100 V/s (10 V to 0 in 0.1 s), host lost after 250 ms.
    pub const DEFAULT: Self = Self { u_min: -10.0, u_max: 10.0, slew_v_per_s: 100.0, host_timeout_ms: 250 };
}

/// Why the drive went to its safe state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SafeReason {
    /// No intact frame from the host for [`SafetyParams::host_timeout_ms`].
    HostLost = 1,
    /// A computed value was not finite or out of range.
    Fault = 2,
    /// The firmware panicked (reported after the reset that follows).
    Panic = 3,
    /// The independent watchdog reset the chip.
    Watchdog = 4,
}

impl SafeReason {
    /// The reason of its number.
    pub fn from_u8(v: u8) -> Option<Self> {
        match v {
            1 => Some(SafeReason::HostLost),
            2 => Some(SafeReason::Fault),
            3 => Some(SafeReason::Panic),
            4 => Some(SafeReason::Watchdog),
            _ => None,
        }
    }
}

/// The board's timing and health figures ([`Message::Diagnostics`]). Durations are in
/// ticks of the board's free-running clock; `calib_insns` instructions of a spin loop took
/// `calib_ticks` of them (under QEMU's `-icount shift=0` that converts ticks to
/// instructions; on a chip, to cycles of the loop).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Diagnostics {
    /// Sample-timer interrupts handled since the last [`Message::Start`] (or reset): this
    /// and the timing fields up to `step_ticks_sum` are per run; the others since reset.
    pub ticks: u32,
    /// Sample-timer periods that passed without their interrupt (the handler started more
    /// than 1.5 periods after the previous one).
    pub missed_ticks: u32,
    /// Longest sample-timer interrupt of a tick that found a run going on, clock ticks.
    pub isr_ticks_max: u32,
    /// Sum over those interrupts, clock ticks (a `Simulated` or `Local` run steps at every
    /// one of them: divide by [`Diagnostics::steps`]).
    pub isr_ticks_sum: u64,
    /// Control steps timed.
    pub steps: u32,
    /// Longest control step (reference, compensator), clock ticks.
    pub step_ticks_max: u32,
    /// Sum over the steps, clock ticks.
    pub step_ticks_sum: u64,
    /// Clock ticks of two back-to-back clock reads (subtracted by the host per interval).
    pub clock_overhead_ticks: u32,
    /// Instructions of the calibration loop.
    pub calib_insns: u32,
    /// Clock ticks it took.
    pub calib_ticks: u32,
    /// Deepest stack seen, bytes.
    pub stack_peak_bytes: u32,
    /// What caused the last reset: 0 power-on or pin, [`SafeReason`] as its number otherwise.
    pub reset_cause: u8,
    /// Bad frames received (the same as [`Status::rx_bad`] but never reset by a run).
    pub bad_frames: u32,
    /// Bad frames not answered (the answers are rate-limited).
    pub faults_suppressed: u32,
    /// Frames not sent because the transmit queue was full.
    pub tx_dropped: u32,
    /// The last safe state's reason (0: none yet).
    pub safe_reason: u8,
    /// Ticks from the last intact frame to 0 V in that safe state.
    pub safe_ticks: u32,
    /// The drive now, V.
    pub drive_v: f32,
    /// Ticks a [`Mode::Lockstep`] run waited for a measurement, since reset.
    pub lockstep_waits: u32,
}

/// One message of the protocol.
#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    /// Asks for a [`Message::Status`].
    GetStatus,
    /// Configures the compensator (answered by [`Message::Ack`] or [`Message::Fault`]).
    SetController(ControllerParams),
    /// Configures the on-chip plant (answered by [`Message::Ack`] or [`Message::Fault`]).
    SetPlant(PlantParams),
    /// Configures the odd-harmonic repetitive controller (a board built with the `orc`
    /// feature; others answer with a [`Message::Fault`]).
    SetOrc(OrcParams),
    /// Sets the drive limits and the safe state (answered by [`Message::Ack`] or
    /// [`Message::Fault`]).
    SetSafety(SafetyParams),
    /// Asks for a [`Message::Diagnostics`].
    GetDiagnostics,
    /// Starts a run of `samples` samples (0: until [`Message::Stop`]).
    Start {
        /// What the board does in the run.
        mode: Mode,
        /// Run length.
        samples: u32,
    },
    /// Ends the run (answered by [`Message::Status`]).
    Stop,
    /// The measurement `y[k]`, µm.
    Measurement {
        /// Sample index.
        k: u32,
        /// Measured output, µm.
        y: f32,
    },
    /// The command `u[k]`, V.
    Command {
        /// Sample index.
        k: u32,
        /// Command, V.
        u: f32,
        /// From the board: bit `i` set when the step of sample `k - i` used the measurement
        /// `y[k-i-1]` (so a host that lost a few commands still learns what the board did).
        /// From the host: 0.
        used: u16,
        /// [`command_flags`].
        flags: u8,
    },
    /// A request was carried out.
    Ack {
        /// Kind of the message acknowledged.
        kind: u8,
        /// Its sequence number.
        seq: u16,
    },
    /// The board's counters.
    Status(Status),
    /// A refusal.
    Fault(Fault),
    /// One sample of a run on the board's own actuator, or of the ramp to 0 V.
    Telemetry {
        /// Sample index (ticks since the run or the ramp began).
        k: u32,
        /// The drive `u[k]`, V.
        u: f32,
        /// The measurement the step used, `y[k-1]`, µm (NaN: none).
        y: f32,
        /// [`command_flags`].
        flags: u8,
    },
    /// The drive reached 0 V in its safe state.
    Safe {
        /// [`SafeReason`] as its number.
        reason: u8,
        /// Ticks from the last intact frame received to 0 V.
        ticks: u32,
        /// The tick period, µs.
        period_us: u32,
    },
    /// The board's timing and health figures.
    Diagnostics(Diagnostics),
    /// Asks for a [`Message::Params`]: the parameters in force, to compare with what was
    /// sent.
    GetParams,
    /// Configures an excitation that the next runs drive instead of the controller (the
    /// board as data acquisition; answered by [`Message::Ack`] or [`Message::Fault`]).
    SetExcitation(ExcitationParams),
    /// The parameters in force on the board.
    Params(BoardParams),
}

/// Message kinds (the byte after the sequence number).
pub mod kind {
    /// [`super::Message::GetStatus`]
    pub const GET_STATUS: u8 = 0x01;
    /// [`super::Message::SetController`]
    pub const SET_CONTROLLER: u8 = 0x02;
    /// [`super::Message::SetPlant`]
    pub const SET_PLANT: u8 = 0x03;
    /// [`super::Message::Start`]
    pub const START: u8 = 0x04;
    /// [`super::Message::Stop`]
    pub const STOP: u8 = 0x05;
    /// [`super::Message::Measurement`]
    pub const MEASUREMENT: u8 = 0x06;
    /// [`super::Message::Command`]
    pub const COMMAND: u8 = 0x07;
    /// [`super::Message::SetOrc`]
    pub const SET_ORC: u8 = 0x08;
    /// [`super::Message::SetSafety`]
    pub const SET_SAFETY: u8 = 0x09;
    /// [`super::Message::GetDiagnostics`]
    pub const GET_DIAGNOSTICS: u8 = 0x0A;
    /// [`super::Message::GetParams`]
    pub const GET_PARAMS: u8 = 0x0B;
    /// [`super::Message::SetExcitation`]
    pub const SET_EXCITATION: u8 = 0x0C;
    /// [`super::Message::Ack`]
    pub const ACK: u8 = 0x10;
    /// [`super::Message::Status`]
    pub const STATUS: u8 = 0x11;
    /// [`super::Message::Fault`]
    pub const FAULT: u8 = 0x12;
    /// [`super::Message::Telemetry`]
    pub const TELEMETRY: u8 = 0x13;
    /// [`super::Message::Safe`]
    pub const SAFE: u8 = 0x14;
    /// [`super::Message::Diagnostics`]
    pub const DIAGNOSTICS: u8 = 0x15;
    /// [`super::Message::Params`]
    pub const PARAMS: u8 = 0x16;
}

/// Payload lengths of the fixed layouts.
pub(crate) const CONTROLLER_LEN: usize =
    5 * 4 + MAX_AR * 4 + 8 + 4 + 4 + 4 + 1 + MAX_HARMONICS * 9 + 3 * 4 + 2 * 4 + 4 + 4;
const PLANT_LEN: usize = 5 * 4 + MAX_AR * 4 + 8 + 1 + MAX_HARMONICS * 9;
const STATUS_LEN: usize = 2 + 12 * 4;
const ORC_LEN: usize = 5 * 4 + 2 + 4 + 1;
pub(crate) const SAFETY_LEN: usize = 4 * 4;
const DIAGNOSTICS_LEN: usize = 15 * 4 + 2 * 8 + 2;
const _: () = assert!(CONTROLLER_LEN <= MAX_PAYLOAD && PLANT_LEN <= MAX_PAYLOAD);
const _: () = assert!(4 + MAX_TEXT <= MAX_PAYLOAD);

/// Little-endian writer over a payload buffer.
pub(crate) struct Writer<'a> {
    buf: &'a mut [u8],
    at: usize,
}

impl Writer<'_> {
    pub(crate) fn bytes(&mut self, b: &[u8]) -> Result<(), WireError> {
        let dst = self.buf.get_mut(self.at..self.at + b.len()).ok_or(WireError::TooLong)?;
        dst.copy_from_slice(b);
        self.at += b.len();
        Ok(())
    }
    pub(crate) fn u8(&mut self, v: u8) -> Result<(), WireError> {
        self.bytes(&[v])
    }
    pub(crate) fn u16(&mut self, v: u16) -> Result<(), WireError> {
        self.bytes(&v.to_le_bytes())
    }
    pub(crate) fn u32(&mut self, v: u32) -> Result<(), WireError> {
        self.bytes(&v.to_le_bytes())
    }
    pub(crate) fn u64(&mut self, v: u64) -> Result<(), WireError> {
        self.bytes(&v.to_le_bytes())
    }
    pub(crate) fn f32(&mut self, v: f32) -> Result<(), WireError> {
        self.bytes(&v.to_bits().to_le_bytes())
    }
}

/// Little-endian reader over a payload; every read checks the length.
pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn take<const N: usize>(&mut self) -> Result<[u8; N], WireError> {
        let src = self.buf.get(self.at..self.at + N).ok_or(WireError::BadLength)?;
        self.at += N;
        let mut out = [0u8; N];
        out.copy_from_slice(src);
        Ok(out)
    }
    pub(crate) fn u8(&mut self) -> Result<u8, WireError> {
        Ok(self.take::<1>()?[0])
    }
    pub(crate) fn u16(&mut self) -> Result<u16, WireError> {
        Ok(u16::from_le_bytes(self.take()?))
    }
    pub(crate) fn u32(&mut self) -> Result<u32, WireError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    pub(crate) fn u64(&mut self) -> Result<u64, WireError> {
        Ok(u64::from_le_bytes(self.take()?))
    }
    pub(crate) fn f32(&mut self) -> Result<f32, WireError> {
        Ok(f32::from_bits(self.u32()?))
    }
    fn rest(&mut self) -> &'a [u8] {
        let r = self.buf.get(self.at..).unwrap_or(&[]);
        self.at = self.buf.len();
        r
    }
    fn end(&self) -> Result<(), WireError> {
        if self.at == self.buf.len() { Ok(()) } else { Err(WireError::BadLength) }
    }
}

fn write_model(w: &mut Writer<'_>, m: &ExtendedParams<f32, MAX_AR>) -> Result<(), WireError> {
    for v in [m.bw.a1, m.bw.a, m.bw.a0, m.bw.gamma, m.bw.beta] {
        w.f32(v)?;
    }
    for &a in &m.ar {
        w.f32(a)?;
    }
    Ok(())
}

fn read_model(r: &mut Reader<'_>) -> Result<ExtendedParams<f32, MAX_AR>, WireError> {
    let bw = BoucWenParams { a1: r.f32()?, a: r.f32()?, a0: r.f32()?, gamma: r.f32()?, beta: r.f32()? };
    let mut ar = [0.0f32; MAX_AR];
    for a in &mut ar {
        *a = r.f32()?;
    }
    Ok(ExtendedParams { bw, ar })
}

fn order_byte(order: u32) -> Result<u8, WireError> {
    u8::try_from(order).map_err(|_| WireError::BadValue("harmonic order (at most 255 on the wire)"))
}

fn count_byte(n: usize) -> Result<u8, WireError> {
    if n > MAX_HARMONICS {
        return Err(WireError::BadValue("harmonic count"));
    }
    Ok(n as u8)
}

fn read_count(r: &mut Reader<'_>) -> Result<usize, WireError> {
    let n = r.u8()? as usize;
    if n > MAX_HARMONICS { Err(WireError::BadValue("harmonic count")) } else { Ok(n) }
}

impl ControllerParams {
    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        write_model(w, &self.model)?;
        w.u64(self.drive.increment())?;
        w.u32(self.sample_period_us)?;
        w.f32(self.amplitude_um)?;
        w.u32(self.fade_samples)?;
        w.u8(count_byte(self.harmonics.len())?)?;
        for m in 0..MAX_HARMONICS {
            match self.harmonics.get(m) {
                Some(h) => {
                    w.u8(order_byte(h.order)?)?;
                    w.f32(h.response.re)?;
                    w.f32(h.response.im)?;
                }
                None => w.bytes(&[0; 9])?,
            }
        }
        for v in [self.rls.lambda, self.rls.p0, self.rls.p_max, self.saturation.u_min, self.saturation.u_max]
        {
            w.f32(v)?;
        }
        w.f32(self.uc_max)?;
        w.f32(self.preview_samples)
    }

    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, WireError> {
        let model = read_model(r)?;
        let drive = Oscillator::from_increment(r.u64()?);
        let sample_period_us = r.u32()?;
        let amplitude_um = r.f32()?;
        let fade_samples = r.u32()?;
        let n = read_count(r)?;
        let mut harmonics = Vec::new();
        for m in 0..MAX_HARMONICS {
            let order = r.u8()? as u32;
            let response = Complex::new(r.f32()?, r.f32()?);
            if m < n {
                // n <= MAX_HARMONICS, so the push cannot fail.
                let _ = harmonics.push(HarmonicSpec { order, response });
            }
        }
        let rls = RlsConfig { lambda: r.f32()?, p0: r.f32()?, p_max: r.f32()? };
        let saturation = Saturation { u_min: r.f32()?, u_max: r.f32()? };
        let uc_max = r.f32()?;
        let preview_samples = r.f32()?;
        Ok(Self {
            model,
            drive,
            sample_period_us,
            amplitude_um,
            fade_samples,
            harmonics,
            rls,
            saturation,
            uc_max,
            preview_samples,
        })
    }
}

impl PlantParams {
    fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        write_model(w, &self.base)?;
        w.u64(self.drive.increment())?;
        w.u8(count_byte(self.branches.len())?)?;
        for m in 0..MAX_HARMONICS {
            match self.branches.get(m) {
                Some(b) => {
                    w.u8(order_byte(b.order)?)?;
                    w.f32(b.alpha_s)?;
                    w.f32(b.alpha_c)?;
                }
                None => w.bytes(&[0; 9])?,
            }
        }
        Ok(())
    }

    fn read(r: &mut Reader<'_>) -> Result<Self, WireError> {
        let base = read_model(r)?;
        let drive = Oscillator::from_increment(r.u64()?);
        let n = read_count(r)?;
        let mut branches = Vec::new();
        for m in 0..MAX_HARMONICS {
            let order = r.u8()? as u32;
            let (alpha_s, alpha_c) = (r.f32()?, r.f32()?);
            if m < n {
                let _ = branches.push(HarmonicBranch { order, alpha_s, alpha_c, ar: [] });
            }
        }
        Ok(Self { base, drive, branches })
    }
}

impl Status {
    fn counters(&self) -> [u32; 12] {
        [
            self.samples_done,
            self.samples_total,
            self.rx_frames,
            self.rx_bad,
            self.rx_lost,
            self.tx_frames,
            self.measurements_used,
            self.measurements_missing,
            self.measurements_stale,
            self.rx_overflow_bytes,
            self.tick_overruns,
            self.compute_errors,
        ]
    }

    fn read(r: &mut Reader<'_>) -> Result<Self, WireError> {
        let (state, mode) = (r.u8()?, r.u8()?);
        let mut c = [0u32; 12];
        for v in &mut c {
            *v = r.u32()?;
        }
        Ok(Self {
            state,
            mode,
            samples_done: c[0],
            samples_total: c[1],
            rx_frames: c[2],
            rx_bad: c[3],
            rx_lost: c[4],
            tx_frames: c[5],
            measurements_used: c[6],
            measurements_missing: c[7],
            measurements_stale: c[8],
            rx_overflow_bytes: c[9],
            tick_overruns: c[10],
            compute_errors: c[11],
        })
    }
}

impl Diagnostics {
    fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        for v in [self.ticks, self.missed_ticks, self.isr_ticks_max] {
            w.u32(v)?;
        }
        w.u64(self.isr_ticks_sum)?;
        for v in [self.steps, self.step_ticks_max] {
            w.u32(v)?;
        }
        w.u64(self.step_ticks_sum)?;
        for v in [self.clock_overhead_ticks, self.calib_insns, self.calib_ticks, self.stack_peak_bytes] {
            w.u32(v)?;
        }
        w.u8(self.reset_cause)?;
        for v in [self.bad_frames, self.faults_suppressed, self.tx_dropped] {
            w.u32(v)?;
        }
        w.u8(self.safe_reason)?;
        w.u32(self.safe_ticks)?;
        w.f32(self.drive_v)?;
        w.u32(self.lockstep_waits)
    }

    fn read(r: &mut Reader<'_>) -> Result<Self, WireError> {
        Ok(Self {
            ticks: r.u32()?,
            missed_ticks: r.u32()?,
            isr_ticks_max: r.u32()?,
            isr_ticks_sum: r.u64()?,
            steps: r.u32()?,
            step_ticks_max: r.u32()?,
            step_ticks_sum: r.u64()?,
            clock_overhead_ticks: r.u32()?,
            calib_insns: r.u32()?,
            calib_ticks: r.u32()?,
            stack_peak_bytes: r.u32()?,
            reset_cause: r.u8()?,
            bad_frames: r.u32()?,
            faults_suppressed: r.u32()?,
            tx_dropped: r.u32()?,
            safe_reason: r.u8()?,
            safe_ticks: r.u32()?,
            drive_v: r.f32()?,
            lockstep_waits: r.u32()?,
        })
    }
}

impl Message {
    /// The kind byte of this message.
    pub fn kind(&self) -> u8 {
        match self {
            Message::GetStatus => kind::GET_STATUS,
            Message::SetController(_) => kind::SET_CONTROLLER,
            Message::SetPlant(_) => kind::SET_PLANT,
            Message::SetOrc(_) => kind::SET_ORC,
            Message::Start { .. } => kind::START,
            Message::Stop => kind::STOP,
            Message::Measurement { .. } => kind::MEASUREMENT,
            Message::Command { .. } => kind::COMMAND,
            Message::SetSafety(_) => kind::SET_SAFETY,
            Message::GetDiagnostics => kind::GET_DIAGNOSTICS,
            Message::Telemetry { .. } => kind::TELEMETRY,
            Message::Safe { .. } => kind::SAFE,
            Message::Diagnostics(_) => kind::DIAGNOSTICS,
            Message::GetParams => kind::GET_PARAMS,
            Message::SetExcitation(_) => kind::SET_EXCITATION,
            Message::Params(_) => kind::PARAMS,
            Message::Ack { .. } => kind::ACK,
            Message::Status(_) => kind::STATUS,
            Message::Fault(_) => kind::FAULT,
        }
    }

    /// Writes the payload into `out` and returns its length.
    pub fn encode_payload(&self, out: &mut [u8; MAX_PAYLOAD]) -> Result<usize, WireError> {
        let mut w = Writer { buf: out, at: 0 };
        match self {
            Message::GetStatus | Message::Stop | Message::GetDiagnostics | Message::GetParams => {}
            Message::SetSafety(p) => p.write(&mut w)?,
            Message::SetExcitation(p) => p.write(&mut w)?,
            Message::Params(p) => p.write(&mut w)?,
            Message::Telemetry { k, u, y, flags } => {
                w.u32(*k)?;
                w.f32(*u)?;
                w.f32(*y)?;
                w.u8(*flags)?;
            }
            Message::Safe { reason, ticks, period_us } => {
                w.u8(*reason)?;
                w.u32(*ticks)?;
                w.u32(*period_us)?;
            }
            Message::Diagnostics(d) => d.write(&mut w)?,
            Message::SetController(p) => p.write(&mut w)?,
            Message::SetPlant(p) => p.write(&mut w)?,
            Message::SetOrc(p) => p.write(&mut w)?,
            Message::Start { mode, samples } => {
                w.u8(*mode as u8)?;
                w.u32(*samples)?;
            }
            Message::Measurement { k, y } => {
                w.u32(*k)?;
                w.f32(*y)?;
            }
            Message::Command { k, u, used, flags } => {
                w.u32(*k)?;
                w.f32(*u)?;
                w.u16(*used)?;
                w.u8(*flags)?;
            }
            Message::Ack { kind, seq } => {
                w.u8(*kind)?;
                w.u16(*seq)?;
            }
            Message::Status(s) => {
                w.u8(s.state)?;
                w.u8(s.mode)?;
                for c in s.counters() {
                    w.u32(c)?;
                }
            }
            Message::Fault(f) => {
                w.u8(f.code as u8)?;
                w.u16(f.seq)?;
                w.u8(f.text.len() as u8)?;
                w.bytes(f.text.as_bytes())?;
            }
        }
        Ok(w.at)
    }

    /// Reads a message of kind `kind` from its payload. Never panics: every length, count,
    /// enumeration and text is checked.
    pub fn decode(kind: u8, payload: &[u8]) -> Result<Self, WireError> {
        let mut r = Reader { buf: payload, at: 0 };
        let msg = match kind {
            kind::GET_STATUS => Message::GetStatus,
            kind::GET_DIAGNOSTICS => Message::GetDiagnostics,
            kind::SET_SAFETY => Message::SetSafety(SafetyParams::read(&mut r)?),
            kind::GET_PARAMS => Message::GetParams,
            kind::SET_EXCITATION => Message::SetExcitation(ExcitationParams::read(&mut r)?),
            kind::PARAMS => Message::Params(BoardParams::read(&mut r)?),
            kind::TELEMETRY => Message::Telemetry { k: r.u32()?, u: r.f32()?, y: r.f32()?, flags: r.u8()? },
            kind::SAFE => Message::Safe { reason: r.u8()?, ticks: r.u32()?, period_us: r.u32()? },
            kind::DIAGNOSTICS => Message::Diagnostics(Diagnostics::read(&mut r)?),
            kind::SET_CONTROLLER => Message::SetController(ControllerParams::read(&mut r)?),
            kind::SET_PLANT => Message::SetPlant(PlantParams::read(&mut r)?),
            kind::SET_ORC => Message::SetOrc(OrcParams::read(&mut r)?),
            kind::START => {
                let mode = Mode::from_u8(r.u8()?).ok_or(WireError::BadValue("start mode"))?;
                Message::Start { mode, samples: r.u32()? }
            }
            kind::STOP => Message::Stop,
            kind::MEASUREMENT => Message::Measurement { k: r.u32()?, y: r.f32()? },
            kind::COMMAND => Message::Command { k: r.u32()?, u: r.f32()?, used: r.u16()?, flags: r.u8()? },
            kind::ACK => Message::Ack { kind: r.u8()?, seq: r.u16()? },
            kind::STATUS => Message::Status(Status::read(&mut r)?),
            kind::FAULT => {
                let code = match r.u8()? {
                    1 => FaultCode::BadFrame,
                    2 => FaultCode::Unexpected,
                    3 => FaultCode::NotConfigured,
                    4 => FaultCode::InvalidParams,
                    5 => FaultCode::Busy,
                    6 => FaultCode::Compute,
                    _ => return Err(WireError::BadValue("fault code")),
                };
                let seq = r.u16()?;
                let len = r.u8()? as usize;
                let bytes = r.rest();
                if bytes.len() != len || len > MAX_TEXT {
                    return Err(WireError::BadLength);
                }
                let s =
                    core::str::from_utf8(bytes).map_err(|_| WireError::BadValue("fault text (not UTF-8)"))?;
                let text = String::try_from(s).map_err(|_| WireError::BadLength)?;
                Message::Fault(Fault { code, seq, text })
            }
            other => return Err(WireError::UnknownKind(other)),
        };
        r.end()?;
        Ok(msg)
    }
}

const _: () = assert!(CONTROLLER_LEN == 99 && PLANT_LEN == 59 && STATUS_LEN == 50 && ORC_LEN == 27);
const _: () = assert!(SAFETY_LEN == 16 && DIAGNOSTICS_LEN == 78 && DIAGNOSTICS_LEN <= MAX_PAYLOAD);

// The board as data acquisition ([`crate::excitation`] runs it) and what it reports of its
// parameters.

/// Most tones of an excitation.
pub const MAX_TONES: usize = 6;

/// One tone of an excitation: `amplitude_v · sin(2π f k Ts + φ)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tone {
    /// Its frequency: phase increment per sample.
    pub drive: Oscillator,
    /// Amplitude, V.
    pub amplitude_v: f32,
    /// Phase at `k = 0`, in 2⁻³² turn.
    pub phase: u32,
}

/// What the board drives in an excitation run.
#[derive(Clone, Debug, PartialEq)]
pub struct ExcitationParams {
    /// The sample period, µs.
    pub sample_period_us: u32,
    /// Length of the raised-cosine fade-in, samples (0: none).
    pub fade_samples: u32,
    /// The tones (1 to [`MAX_TONES`]).
    pub tones: Vec<Tone, MAX_TONES>,
}

/// Payload length of [`ExcitationParams`] on the wire.
pub(crate) const EXCITATION_LEN: usize = 4 + 4 + 1 + MAX_TONES * 16;

impl ExcitationParams {
    /// Checks the parameters as the board does before it accepts them (the error names
    /// the parameter).
    ///
    /// ```
    /// use boucwen_core::signal::Oscillator;
    /// use boucwen_link::excitation::{ExcitationParams, Tone};
    /// let tone = Tone { drive: Oscillator::new(23.0, 1e-3)?, amplitude_v: 1.0, phase: 0 };
    /// let mut p = ExcitationParams { sample_period_us: 1000, fade_samples: 500, tones: [tone].into_iter().collect() };
    /// assert!(p.validate().is_ok());
    /// p.tones[0].amplitude_v = f32::NAN;
    /// assert!(p.validate().is_err());
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn validate(&self) -> Result<(), Error> {
        let (lo, hi) = limits::SAMPLE_PERIOD_US;
        if !(lo..=hi).contains(&self.sample_period_us) {
            return Err(Error::OutOfRange("sample period (100 µs to 100 ms)"));
        }
        if self.fade_samples > limits::FADE_MAX_SAMPLES {
            return Err(Error::OutOfRange("fade-in (at most 1e7 samples)"));
        }
        if self.tones.is_empty() {
            return Err(Error::OutOfRange("excitation tones (at least one)"));
        }
        let mut sum = 0.0f32;
        for t in &self.tones {
            if !t.amplitude_v.is_finite() {
                return Err(Error::NonFinite("excitation amplitude"));
            }
            sum += t.amplitude_v.abs();
        }
        // Every amplitude is finite, so the sum is not NaN (an overflow to ∞ is caught).
        if sum > limits::U_MAX_V {
            return Err(Error::OutOfRange("excitation amplitude (sum at most 1000 V)"));
        }
        Ok(())
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        if self.tones.len() > MAX_TONES {
            return Err(WireError::BadValue("tone count"));
        }
        w.u32(self.sample_period_us)?;
        w.u32(self.fade_samples)?;
        w.u8(self.tones.len() as u8)?;
        for m in 0..MAX_TONES {
            match self.tones.get(m) {
                Some(t) => {
                    w.u64(t.drive.increment())?;
                    w.f32(t.amplitude_v)?;
                    w.u32(t.phase)?;
                }
                None => w.bytes(&[0; 16])?,
            }
        }
        Ok(())
    }

    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, WireError> {
        let sample_period_us = r.u32()?;
        let fade_samples = r.u32()?;
        let n = r.u8()? as usize;
        if n > MAX_TONES {
            return Err(WireError::BadValue("tone count"));
        }
        let mut tones = Vec::new();
        for m in 0..MAX_TONES {
            let (inc, amplitude_v, phase) = (r.u64()?, r.f32()?, r.u32()?);
            if m < n {
                // m < n <= MAX_TONES: the push cannot fail.
                let _ = tones.push(Tone { drive: Oscillator::from_increment(inc), amplitude_v, phase });
            }
        }
        Ok(Self { sample_period_us, fade_samples, tones })
    }
}

/// What runs on the board's next [`super::Message::Start`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Active {
    /// Nothing configured.
    None = 0,
    /// The controller of [`super::Message::SetController`] (or the ORC on it).
    Controller = 1,
    /// The excitation of [`super::Message::SetExcitation`].
    Excitation = 2,
}

/// The parameters in force on the board ([`super::Message::Params`]).
#[derive(Clone, Debug, PartialEq)]
pub struct BoardParams {
    /// What the next run computes: the last of `SetController` and `SetExcitation` accepted.
    pub active: Active,
    /// The controller's parameters, as the board holds them.
    pub controller: Option<ControllerParams>,
    /// The drive limits and safe state.
    pub safety: SafetyParams,
}

/// Payload length of [`BoardParams`] on the wire.
pub(crate) const PARAMS_LEN: usize = 1 + 1 + CONTROLLER_LEN + super::message::SAFETY_LEN;

impl BoardParams {
    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), WireError> {
        w.u8(self.active as u8)?;
        match &self.controller {
            Some(c) => {
                w.u8(1)?;
                c.write(w)?;
            }
            None => {
                w.u8(0)?;
                w.bytes(&[0; CONTROLLER_LEN])?;
            }
        }
        self.safety.write(w)
    }

    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, WireError> {
        let active = match r.u8()? {
            0 => Active::None,
            1 => Active::Controller,
            2 => Active::Excitation,
            _ => return Err(WireError::BadValue("active parameters")),
        };
        let controller = match r.u8()? {
            0 => {
                r.take::<{ CONTROLLER_LEN }>()?;
                None
            }
            1 => Some(ControllerParams::read(r)?),
            _ => return Err(WireError::BadValue("controller present")),
        };
        Ok(Self { active, controller, safety: SafetyParams::read(r)? })
    }
}

const _: () = assert!(EXCITATION_LEN <= MAX_PAYLOAD && PARAMS_LEN <= MAX_PAYLOAD);

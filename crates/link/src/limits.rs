//! The ranges of every number the board takes from the wire. A value outside is refused
//! (parameters: `Fault(InvalidParams)` naming it; samples: counted and not used), so no
//! message can make the board compute for long, overflow a counter or drive a state to
//! infinity.
//!
//! A leaf of the crate: the wire's checks ([`crate::message`]) and the board's state machine
//! ([`crate::device`]) both take their bounds from here.

/// Sample period, µs: 100 µs (10 kHz) to 100 ms.
pub const SAMPLE_PERIOD_US: (u32, u32) = (100, 100_000);
/// Largest |y| taken from the host, µm (the sensor's range is far below).
pub const Y_MAX_UM: f32 = 1.0e5;
/// Largest |u| of any drive limit or saturation, V.
pub const U_MAX_V: f32 = 1000.0;
/// Largest reference amplitude, µm.
pub const AMPLITUDE_MAX_UM: f32 = 1.0e4;
/// Longest fade-in, samples.
pub const FADE_MAX_SAMPLES: u32 = 10_000_000;
/// Longest preview `τ` of the reference, samples (the host's fit considers input delays
/// up to 3 samples).
pub const PREVIEW_MAX_SAMPLES: f32 = 16.0;
/// Plant mode: most samples one command may skip (the plant steps that many with the
/// last input); a command further ahead is refused.
pub const MAX_CATCH_UP: u32 = 64;
/// Slew of the ramp to 0 V, V/s.
pub const SLEW_V_PER_S: (f32, f32) = (0.1, 1.0e5);
/// Host timeout, ms.
pub const HOST_TIMEOUT_MS: (u32, u32) = (10, 60_000);
/// Bad frames answered in a burst; after it, one answer per
/// [`FAULT_REFILL_TICKS`] ticks (the rest are counted, not answered).
pub const FAULT_BURST: u32 = 4;
/// Ticks per bad-frame answer once the burst is spent.
pub const FAULT_REFILL_TICKS: u32 = 10;
/// Smallest `|A1|` of a model the inverse divides by, µm/V (a picometre per volt: no
/// actuator the board drives is that weak; `A1 = 0` makes the inverse useless).
pub const MIN_GAIN_UM_PER_V: f32 = 1.0e-6;
/// Smallest slope of the static part `A1·u − h` at rest, on either branch, relative to
/// `|A1|` (below it the inverse's denominator guard acts from the first sample, and
/// `u_f` runs to a bound of the saturation).
pub const MIN_SLOPE_AT_REST: f32 = 1.0e-3;
/// Lockstep run: most ticks a step waits for the previous sample's measurement before
/// it steps without it (20 ms at 1 kHz: a host that answers at all answers sooner, and
/// a lost frame costs no more than this).
pub const LOCKSTEP_PATIENCE_TICKS: u32 = 20;

//! The peer controllers the proposed compensator is compared with, on the same per-sample
//! interface: open loop, a PI feedback, and the odd-harmonic repetitive controller (ORC) of
//! Li, Gu, Zhu and Su, "Odd-harmonic repetitive control for high-speed raster scanning of
//! piezo-actuated nanopositioning stages with hysteresis nonlinearity" (Sensors and
//! Actuators A 244, 2016, pp. 95–105; reference \[11\] of Fujii et al.), which treats the
//! hysteresis as a periodic disturbance and cancels it with an internal model of the odd
//! harmonics, plugged into a stabilising feedback. [`tune`] derives every gain from the
//! identified model.
//!
//! ## Timing and sign convention
//! As for the compensator: `step` at sample `k` takes the reference `d[k]` and the
//! measurement `y[k-1]` (the response to the previous output; `None` if it was lost) and
//! returns `u[k]`. The tracking error is `e = d - y`, so the feedback can only use
//! `e[k-1] = d[k-1] - y[k-1]`: every loop below carries that one-sample delay.
//!
//! ## Open loop
//! `u[k] = sat(d[k] / G0)`, `G0` the identified model's static gain
//! ([`crate::model::ExtendedParams::static_gain`], `(A1 - A)/(1 - Σ a_j)`).
//!
//! ## PI feedback
//! ```text
//! I[k]   = I[k-1] + Ki·Ts·e[k-1]
//! u[k]   = sat(u_ff[k] + Kp·e[k-1] + I[k] (+ u_rc[k] under the ORC, below))
//! u_ff[k] = k_ff·d[k]   (k_ff = 0: plain feedback, or 1/G0: static feedforward)
//! ```
//! so `u_fb = C(z)·z⁻¹·e` with `C(z) = Kp + Ki·Ts/(1 - z⁻¹)`. Anti-windup by conditional
//! integration: when the output saturates and the integration step pushes further into
//! the limit, `I` keeps its old value. A lost measurement holds the previous error for the
//! proportional term and skips the integration.
//!
//! ## Odd-harmonic repetitive control (the internal model of Li et al.)
//! With `L = N/2` the half period in samples (`N = 1/(f·Ts)`), the internal model
//! `-z^{-L}/(1 + z^{-L})` has its poles where `z^{-L} = -1`, i.e. at the odd multiples of the
//! reference frequency `f` only: a signal with half-wave symmetry (`x[k-L] = -x[k]`, the odd
//! harmonics, where the hysteresis puts its distortion and where the reference itself is)
//! is integrated from one half period to the next, while an even harmonic or a constant
//! (`x[k-L] = x[k]`) is not. The robust form with the low-pass `Q`, the learning gain `k_r`
//! and a phase lead of `m` samples is
//! ```text
//! G_orc(z) = U_rc/E = -k_r·Q(z)·z^{m-L} / (1 + Q(z)·z^{-L})
//! ```
//! implemented as the recursion on one delay line (this crate keeps `v`, not `u_rc`):
//! ```text
//! v[j]     = u_rc[j] + g·e[j+m]                   (completed once e[j+m] arrives)
//! u_rc[k]  = -Σ_i h_i·v[k - (L0 - 1) - i],   i = 0..3
//! h        = [a, 1-2a, a] ∗ [1-μ, μ]             (Q, then the fractional part of L)
//! ```
//! `Q(z) = a·z + (1-2a) + a·z⁻¹` is zero-phase about the delay (`Q(ω) = 1 - 2a(1 - cos ω)`,
//! `0 ≤ a ≤ 1/4`), `L = L0 + μ` (`L0` an integer, `0 ≤ μ < 1`) and `g` is
//! [`OrcConfig::learning_gain`]. Where `u_rc` enters ([`OrcPlacement`]):
//! * **at the PI's input** (Li et al.'s plug-in form, the default):
//!   `u = u_ff + C z⁻¹ (e + u_rc)`, `u_rc` in output units, `g = k_r`; the ORC learns
//!   through the closed loop `T = L_fb/(1 + L_fb)`, `L_fb = z⁻¹·C·P`;
//! * **at the plant input**: `u = u_ff + C z⁻¹ e + u_rc`, `u_rc` in input units,
//!   `g = k_r/G0`; it learns through `S·P_n`, `S = 1/(1 + L_fb)`, `P = G0·P_n`.
//!
//! With `H` that learning path (`T` or `S·P_n`), the error is
//! ```text
//! E = S · (1 + Q F z^{-L0}) / (1 + Q F z^{-L0}·(1 - k_r z^m H)) · (D - W)
//! ```
//! (`W` the output disturbance, `F(z) = 1-μ + μ z⁻¹`): at an odd harmonic, where
//! `Q F z^{-L0} ≈ -1`, the numerator vanishes. The loop is stable if the feedback is
//! (`S` stable) and, sufficiently,
//! ```text
//! ρ(ω) = |Q(ω) F(ω)| · |1 - k_r e^{imω} H(ω)| < 1   for every ω
//! ```
//! (Li et al.'s condition, with `F`). The lead `m` compensates the phase of `H` at the
//! harmonics, `Q` makes the condition hold where it cannot be compensated.
//!
//! The two placements trade differently on a lightly damped actuator. `T` carries the PI's
//! integrator, so learning through it is strong at low frequencies and weak near the
//! resonance, and it leaves the resonance out of the stability condition; `S·P_n` is flat
//! below the resonance but peaks there, which caps `k_r` for every frequency: the sharper
//! the resonance, the smaller the learning gain the rule below allows at the plant input,
//! while at the PI's input the Ms-bounded loop keeps `|T|` moderate at the resonance.
//!
//! ### Where this departs from Li et al., and why
//! 1. **Fractional half period.** `N/2` is rarely an integer (1 kHz / 23 Hz / 2 = 21.74
//!    samples). Rounding `L` would put the internal model's poles off the harmonics (by
//!    1.2 % at 23 Hz, so a 3rd-harmonic phase error of 0.11 rad); the code interpolates
//!    linearly between `L0` and `L0 + 1` (the `F` above, `|F| ≤ 1`), which keeps the
//!    poles on the harmonics at the cost of a slight attenuation at high harmonics
//!    (`1 - |F| ≈ μ(1-μ)(1 - cos ω)`), accounted for in the tuning.
//! 2. **The stabilising feedback is the PI** of this module (with an optional static
//!    feedforward), and the ORC may also be placed at the plant input.
//! 3. **Learning pauses** on a sample whose measurement was lost or whose previous output
//!    saturated (the applied input was not the computed one), as the compensator's
//!    adaptation does; `|u_rc|` is clamped to `limit` so a saturated actuator cannot wind
//!    the delay line up.
//! 4. **Tuning from the model** ([`tune`]), not by hand per frequency.
//!
//! The delay line holds `NCAP` values (a const generic, [`ORC_CAPACITY`] suggested): the
//! recursion reads offsets `L0 - 1 ..= L0 + 2`, so `L0 + 2 ≤ NCAP`, and the newest value it
//! reads must be complete, so `L0 ≥ m + 2`. With `NCAP = 512` at 1 kHz the lowest reference
//! is 0.98 Hz (`L = 500` at 1 Hz) and the line takes 2 KiB in `f32`.
//!
//! ## Tuning rule ([`tune`])
//! Everything is computed from the identified extended model and its input delay `τ` on a
//! grid of [`TUNE_GRID`] frequencies `ω_i = π(i + ½)/TUNE_GRID`, with the plant normalised
//! to unit static gain, `P_n = P/G0` (so the gains carry the sign of `G0`).
//! * **Gain range.** The incremental gain of `A1·u - h` runs over `[min, max]` of
//!   `A1 - slope(h, ±)` on the hysteresis range ([`crate::model::BoucWenParams::h_range`]); relative to
//!   the small-signal `A1 - A` that is a factor `κ ∈ [κ_lo, κ_hi]` (`κ_lo` at least 0.1).
//!   Every constraint below must hold for `κ ∈ {κ_lo, 1, κ_hi}`.
//! * **PI: maximum integral gain under a sensitivity bound** (the MIGO rule of Åström,
//!   Panagopoulos and Hägglund, 1998): for the loop `κ·z⁻¹·(kp + ki/(1 - z⁻¹))·P_n`,
//!   require `|1 + L_fb(ω)| ≥ 1/Ms` everywhere, which guarantees a gain margin of at least
//!   `Ms/(Ms - 1)` and a phase margin of at least `2·asin(1/(2 Ms))` (3.0 and 38.9° for the
//!   default `Ms = 1.5`). The largest `kp` meeting the bound with `ki = 0` is `kp_lim`
//!   (capped at 2); for `kp = kp_lim·j/16`, `j = 0..16`, the largest `ki` whose whole path
//!   from 0 meets the bound is found in closed form per frequency (the bound is a
//!   quadratic in `ki`); the pair with the largest `ki` wins (`ki ≤ 1`, the deadbeat
//!   integrator). Then `Kp = kp/G0`, `Ki = ki/(G0·Ts)`. A lightly damped resonance makes
//!   this design integral-dominant with a crossover far below the resonance; that is what a
//!   PI can do there.
//! * **ORC.** For `a ∈ {1/4, 1/10, 1/20, 1/40, 1/100}` and `m ∈ 0..=min(32, L0 - 2)`, the
//!   largest learning gain `k_max(a, m)` with `ρ(ω) ≤ 1` at every grid frequency and
//!   every `κ` (closed form per frequency); then `k_r = min(1, k_max/2)` (a learning gain
//!   margin of 2). Each candidate is scored by its predicted steady-state error ratio to
//!   the PI alone, `η_n = |1 + Q F z^{-L0}| / |1 + Q F z^{-L0}(1 - k_r z^m H)|`, at the odd
//!   harmonics `n ∈ {1, 3, 5}` below Nyquist (nominal gain), `J = Σ η_n / n`, and the
//!   lowest `J` wins (ties to the stronger `Q`). `limit` is the driver's range
//!   `max(|u_min|, |u_max|)` at the plant input; at the PI's input it is that range divided
//!   by `|C|` at `f` (the `ε` for which the PI alone would ask for the whole range).
//!
//! The rule is a sufficient-condition design on the linearised model; the hysteresis is the
//! disturbance `W` the ORC removes, as in Li et al. It scores the steady state only: the
//! learning transient is not in `J`, and with the PI's slow loop it can take tens of
//! periods at low reference frequencies without feedforward.

mod open_loop;
mod orc;
mod pi;
#[cfg(test)]
mod tests;
mod tune;

pub use open_loop::{OpenLoop, OpenLoopConfig};
pub use orc::{ORC_CAPACITY, OrcConfig, OrcController, OrcMemory, OrcPlacement, half_period};
pub use pi::{PiConfig, PiController, PiState};
pub use tune::{
    OrcDesign, PiDesign, TUNE_GRID, TUNE_MAX_LEAD, TUNE_MAX_LEARNING_GAIN, TUNE_Q_COEFFS, TuneOptions,
    Tuning, tune, tune_orc, tune_pi,
};

use crate::error::finite;
use crate::{Error, Real};

/// One step's output, common to every [`Controller`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlOutput<T> {
    /// `u[k]`, what to apply (after saturation).
    pub u: T,
    /// The feedforward part: `d/G0`, `k_ff·d`, the caller's, or the compensator's direct
    /// inverse `u_f`.
    pub u_ff: T,
    /// The feedback part `Kp·ε + I` (0 in open loop and for the compensator).
    pub u_fb: T,
    /// The learned periodic part: the ORC's `u_rc[k]` (input units at the plant input,
    /// output units at the PI's), or the compensator's cancellation as applied, `-Σ û_n[k]`
    /// (input units); 0 otherwise.
    pub u_rc: T,
    /// `u` was clamped.
    pub saturated: bool,
}

/// A controller on the per-sample interface of this crate: the proposed compensator
/// ([`crate::compensator::Compensator`], [`crate::compensator::AnyCompensator`]) and every
/// peer ([`OpenLoop`], [`PiController`], [`OrcController`]). The other side of the loop is
/// a [`crate::Plant`].
///
/// ```
/// use boucwen_core::compensator::Saturation;
/// use boucwen_core::controllers::{Controller, OpenLoop, OpenLoopConfig};
/// use boucwen_core::model::ExtendedParams;
/// use boucwen_core::plant::{ModelPlant, Plant};
/// let mut model = ExtendedParams::<f64, 1>::default();
/// model.bw.a1 = 4.0;
/// let mut plant = ModelPlant::new(model, 1e-3)?;
/// let mut ctrl = OpenLoop::new(OpenLoopConfig { static_gain: 4.0, saturation: Saturation::symmetric(10.0) })?;
/// let mut y = None;
/// for d in [1.0, 2.0, 3.0] {
///     let u = ctrl.step(d, y)?.u;
///     y = Some(plant.step(u)?);
///     assert_eq!(y, Some(d));
/// }
/// # Ok::<(), boucwen_core::Error>(())
/// ```
pub trait Controller<T: Real> {
    /// One sample: reference `d[k]`, measurement `y[k-1]` (`None` if lost); returns `u[k]`.
    /// On `Err` (a non-finite input) nothing changed.
    fn step(&mut self, d: T, y_prev: Option<T>) -> Result<ControlOutput<T>, Error>;
    /// Back to `k = 0` with the same configuration.
    fn reset(&mut self);
}

fn check_inputs<T: Real>(d: T, y_prev: Option<T>) -> Result<(), Error> {
    finite(d, "d")?;
    if let Some(y) = y_prev {
        finite(y, "y")?;
    }
    Ok(())
}

/// Bookkeeping shared by the feedback controllers: `d[k-1]`, whether a sample was taken,
/// whether the last output saturated.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Past<T> {
    d_prev: T,
    started: bool,
    saturated_prev: bool,
}

impl<T: Real> Past<T> {
    /// `e[k-1] = d[k-1] - y[k-1]` if there is one.
    #[inline(always)]
    fn error(&self, y_prev: Option<T>) -> Option<T> {
        match (self.started, y_prev) {
            (true, Some(y)) => Some(self.d_prev - y),
            _ => None,
        }
    }
}

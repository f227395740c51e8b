//! The PI feedback with conditional integration and an optional static feedforward.

use super::{ControlOutput, Controller, Past, check_inputs};
use crate::compensator::Saturation;
use crate::error::finite;
use crate::{Error, Real};

/// Parameters of the PI feedback.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PiConfig<T> {
    /// Proportional gain `Kp` (input units per output unit).
    pub kp: T,
    /// Integral gain `Ki` (input units per output unit and second).
    pub ki_per_s: T,
    /// Sample interval `Ts` (s).
    pub ts_s: T,
    /// Feedforward gain `k_ff`: `u_ff = k_ff·d` (0: plain feedback; `1/G0`: static inverse).
    pub feedforward_gain: T,
    /// The driver's range.
    pub saturation: Saturation<T>,
}

impl<T: Real> PiConfig<T> {
    /// Checks every field: finite, `Ts > 0`, gains of one sign (`Kp·Ki ≥ 0`) and not both 0.
    #[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x > 0)` does")]
    pub fn validate(&self) -> Result<(), Error> {
        finite(self.kp, "PI Kp")?;
        finite(self.ki_per_s, "PI Ki")?;
        finite(self.ts_s, "PI sample interval")?;
        finite(self.feedforward_gain, "feedforward gain")?;
        if !(self.ts_s > T::zero()) {
            return Err(Error::OutOfRange("PI sample interval (must be > 0)"));
        }
        if self.kp * self.ki_per_s < T::zero() {
            return Err(Error::OutOfRange("PI gains (Kp and Ki must have the same sign)"));
        }
        if self.kp == T::zero() && self.ki_per_s == T::zero() {
            return Err(Error::OutOfRange("PI gains (both zero)"));
        }
        self.saturation.validate()
    }
}

/// State of the PI feedback.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PiState<T> {
    /// The integrator `I[k-1]`.
    pub integral: T,
    /// The last `ε` used (held when a measurement is lost).
    pub eps_prev: T,
}

impl<T: Real> PiConfig<T> {
    /// One PI update on the error `e[k-1]` (`None`: lost, hold the last one and do not
    /// integrate) with the offset `u_ff` (feedforward, plus the ORC's share); returns
    /// `(u, u_fb, saturated)` and advances `st`.
    #[inline]
    pub fn update(&self, st: &mut PiState<T>, eps: Option<T>, u_ff: T) -> (T, T, bool) {
        let (eps, integrate) = match eps {
            Some(e) => (e, true),
            None => (st.eps_prev, false),
        };
        let push = if integrate { self.ki_per_s * self.ts_s * eps } else { T::zero() };
        let mut integral = st.integral + push;
        let mut raw = u_ff + self.kp * eps + integral;
        let (mut u, saturated) = self.saturation.clamp(raw);
        if saturated
            && ((raw > self.saturation.u_max && push > T::zero())
                || (raw < self.saturation.u_min && push < T::zero()))
        {
            // Conditional integration: do not integrate further into the limit.
            integral = st.integral;
            raw = u_ff + self.kp * eps + integral;
            u = self.saturation.clamp(raw).0;
        }
        st.integral = integral;
        st.eps_prev = eps;
        (u, self.kp * eps + integral, saturated)
    }
}

/// The PI controller (with optional static feedforward).
///
/// ```
/// use boucwen_core::compensator::Saturation;
/// use boucwen_core::controllers::{Controller, PiConfig, PiController};
/// let cfg = PiConfig { kp: 0.0_f64, ki_per_s: 2.0, ts_s: 1e-3, feedforward_gain: 0.0,
///                      saturation: Saturation::symmetric(10.0) };
/// let mut c = PiController::new(cfg)?;
/// c.step(1.0, None)?;                       // k = 0: no measurement yet
/// let out = c.step(1.0, Some(0.0))?;        // e[0] = 1: I = 2·1e-3·1
/// assert!((out.u - 2e-3).abs() < 1e-15);
/// # Ok::<(), boucwen_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PiController<T> {
    cfg: PiConfig<T>,
    state: PiState<T>,
    past: Past<T>,
}

impl<T: Real> PiController<T> {
    /// A PI controller from a validated configuration.
    ///
    /// ```
    /// use boucwen_core::compensator::Saturation;
    /// use boucwen_core::controllers::{PiConfig, PiController};
    /// let cfg = PiConfig { kp: 0.1_f64, ki_per_s: 5.0, ts_s: 1e-3, feedforward_gain: 0.0,
    ///                      saturation: Saturation::symmetric(10.0) };
    /// assert!(PiController::new(cfg).is_ok());
    /// assert!(PiController::new(PiConfig { kp: -0.1, ..cfg }).is_err()); // gains of opposite signs
    /// ```
    pub fn new(cfg: PiConfig<T>) -> Result<Self, Error> {
        cfg.validate()?;
        Ok(Self { cfg, state: PiState::default(), past: Past::default() })
    }

    /// One sample with the caller's feedforward `u_ff[k]` (e.g. the compensator's `u_f`)
    /// in place of `k_ff·d[k]`.
    #[inline]
    pub fn step_with_feedforward(
        &mut self,
        d: T,
        y_prev: Option<T>,
        u_ff: T,
    ) -> Result<ControlOutput<T>, Error> {
        check_inputs(d, y_prev)?;
        finite(u_ff, "u_ff")?;
        let e = self.past.error(y_prev);
        let (u, u_fb, saturated) = self.cfg.update(&mut self.state, e, u_ff);
        self.past = Past { d_prev: d, started: true, saturated_prev: saturated };
        Ok(ControlOutput { u, u_ff, u_fb, u_rc: T::zero(), saturated })
    }

    /// The configuration.
    pub fn config(&self) -> &PiConfig<T> {
        &self.cfg
    }

    /// The PI state.
    pub fn state(&self) -> &PiState<T> {
        &self.state
    }
}

impl<T: Real> Controller<T> for PiController<T> {
    #[inline]
    fn step(&mut self, d: T, y_prev: Option<T>) -> Result<ControlOutput<T>, Error> {
        let u_ff = self.cfg.feedforward_gain * d;
        self.step_with_feedforward(d, y_prev, u_ff)
    }

    fn reset(&mut self) {
        self.state = PiState::default();
        self.past = Past::default();
    }
}

//! Open loop: `u[k] = sat(d[k] / G0)`.

use super::{ControlOutput, Controller, check_inputs};
use crate::compensator::Saturation;
use crate::error::finite;
use crate::{Error, Real};

/// Open loop: `u = sat(d / G0)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OpenLoopConfig<T> {
    /// `G0`, the static gain (output units per input unit).
    pub static_gain: T,
    /// The driver's range.
    pub saturation: Saturation<T>,
}

impl<T: Real> OpenLoopConfig<T> {
    /// Checks `G0` finite and non-zero, and the saturation.
    pub fn validate(&self) -> Result<(), Error> {
        finite(self.static_gain, "static gain G0")?;
        if self.static_gain.abs() < T::MIN_POSITIVE {
            return Err(Error::OutOfRange("static gain G0 (must be non-zero)"));
        }
        self.saturation.validate()
    }
}

/// The open-loop controller.
///
/// ```
/// use boucwen_core::compensator::Saturation;
/// use boucwen_core::controllers::{Controller, OpenLoop, OpenLoopConfig};
/// let mut c = OpenLoop::new(OpenLoopConfig { static_gain: 20.0, saturation: Saturation::symmetric(10.0) })?;
/// assert_eq!(c.step(5.0, None)?.u, 0.25);
/// assert_eq!(c.step(1e4, None)?.u, 10.0); // saturated
/// # Ok::<(), boucwen_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OpenLoop<T> {
    cfg: OpenLoopConfig<T>,
    inv_gain: T,
}

impl<T: Real> OpenLoop<T> {
    /// An open-loop controller from a validated configuration.
    ///
    /// ```
    /// use boucwen_core::compensator::Saturation;
    /// use boucwen_core::controllers::{OpenLoop, OpenLoopConfig};
    /// let sat = Saturation::symmetric(10.0_f64);
    /// assert!(OpenLoop::new(OpenLoopConfig { static_gain: 14.0, saturation: sat }).is_ok());
    /// assert!(OpenLoop::new(OpenLoopConfig { static_gain: 0.0, saturation: sat }).is_err());
    /// ```
    pub fn new(cfg: OpenLoopConfig<T>) -> Result<Self, Error> {
        cfg.validate()?;
        let inv_gain = T::one() / cfg.static_gain;
        finite(inv_gain, "1/G0")?;
        Ok(Self { cfg, inv_gain })
    }

    /// The configuration.
    pub fn config(&self) -> &OpenLoopConfig<T> {
        &self.cfg
    }
}

impl<T: Real> Controller<T> for OpenLoop<T> {
    #[inline]
    fn step(&mut self, d: T, y_prev: Option<T>) -> Result<ControlOutput<T>, Error> {
        check_inputs(d, y_prev)?;
        let u_ff = d * self.inv_gain;
        let (u, saturated) = self.cfg.saturation.clamp(u_ff);
        Ok(ControlOutput { u, u_ff, u_fb: T::zero(), u_rc: T::zero(), saturated })
    }

    fn reset(&mut self) {}
}

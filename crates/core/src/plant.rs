//! The plant: one sample of drive in, one measurement out.
//!
//! Every experiment (identification, tracking, the sweep, hardware in the loop) talks to a
//! [`Plant`]: it applies `u[k]` (V) for one sample interval `Ts` and reads `y[k]` (µm) at
//! the end of that interval, so `y[k]` already responds to `u[k]`, the direct feed-through
//! `A1·u[k]` of the models in [`crate::model`]. The same experiment code runs against
//!
//! | plant | crate | what `step` does |
//! |---|---|---|
//! | the virtual bimorph | `boucwen-sim` | integrates its physics over one interval |
//! | a measured record | `boucwen-lab` (`record::Replay`) | returns the next recorded sample |
//! | the driver board | `boucwen-hal` (`transport::BoardPlant`) | sends `u[k]` over the serial link, waits for `y[k]` |
//! | a model of this crate | here ([`ModelPlant`]) | steps the model |
//!
//! The error is the plant's own type, so a `no_std` plant needs no allocation; a plant
//! that rejects a step (a non-finite command, a lost link) keeps its state from before it.
//! The controllers' side of the loop is [`crate::controllers::Controller`].

use crate::model::Model;
use crate::{Error, Real};

/// A plant driven one sample at a time.
pub trait Plant<T: Real> {
    /// Why a step failed.
    type Error;

    /// Applies `u` (V) for one sample interval and returns the measured `y` (µm) at its
    /// end. A non-finite `u` is an error and leaves the plant as it was.
    fn step(&mut self, u: T) -> Result<T, Self::Error>;

    /// The sample interval `Ts`, s.
    fn sample_interval_s(&self) -> T;

    /// Back to the start: a replay rewinds, a simulation returns to rest, hardware returns
    /// the actuator to 0 V.
    fn reset(&mut self) -> Result<(), Self::Error>;

    /// A short name for messages (the record's file, the serial port, "virtual bimorph").
    fn name(&self) -> &str;

    /// Steps through `u` and writes the measurements into `y` (as many as the shorter of
    /// the two), stopping at the first error.
    fn run_into(&mut self, u: &[T], y: &mut [T]) -> Result<(), Self::Error> {
        for (yk, &uk) in y.iter_mut().zip(u) {
            *yk = self.step(uk)?;
        }
        Ok(())
    }
}

impl<T: Real, P: Plant<T> + ?Sized> Plant<T> for &mut P {
    type Error = P::Error;
    fn step(&mut self, u: T) -> Result<T, Self::Error> {
        (**self).step(u)
    }
    fn sample_interval_s(&self) -> T {
        (**self).sample_interval_s()
    }
    fn reset(&mut self) -> Result<(), Self::Error> {
        (**self).reset()
    }
    fn name(&self) -> &str {
        (**self).name()
    }
}

/// A model of [`crate::model`] as a plant: parameters, running state and sample interval.
///
/// ```
/// use boucwen_core::model::{BoucWenParams, ExtendedParams};
/// use boucwen_core::plant::{ModelPlant, Plant};
/// let model = ExtendedParams {
///     bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.0, gamma: 2.0, beta: 3.0 },
///     ar: [0.5],
/// };
/// let mut plant = ModelPlant::new(model, 1e-3)?;
/// assert_eq!(plant.step(0.0)?, 0.0);
/// assert!(plant.step(1.0)? > 0.0);
/// assert!(plant.step(f64::NAN).is_err());
/// # Ok::<(), boucwen_core::Error>(())
/// ```
#[derive(Clone)]
pub struct ModelPlant<T: Real, M: Model<T>> {
    model: M,
    state: M::State,
    ts_s: T,
}

impl<T: Real, M: Model<T>> ModelPlant<T, M> {
    /// The model at rest, sampled every `ts_s` seconds (finite, > 0).
    ///
    /// ```
    /// use boucwen_core::model::ExtendedParams;
    /// use boucwen_core::plant::{ModelPlant, Plant};
    /// let mut model = ExtendedParams::<f64, 1>::default();
    /// model.bw.a1 = 2.0;
    /// let mut p = ModelPlant::new(model, 1e-3)?;
    /// assert_eq!(p.step(0.5)?, 1.0);
    /// assert!(ModelPlant::new(model, 0.0).is_err());
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn new(model: M, ts_s: T) -> Result<Self, Error> {
        if !(ts_s.is_finite() && ts_s > T::zero()) {
            return Err(Error::OutOfRange("sample interval (must be finite and > 0)"));
        }
        model.validate()?;
        Ok(Self { state: model.initial_state(), model, ts_s })
    }

    /// The model's parameters.
    pub fn model(&self) -> &M {
        &self.model
    }
}

impl<T: Real, M: Model<T>> Plant<T> for ModelPlant<T, M> {
    type Error = Error;
    fn step(&mut self, u: T) -> Result<T, Error> {
        crate::error::finite(u, "u")?;
        Ok(self.model.step(&mut self.state, u))
    }
    fn sample_interval_s(&self) -> T {
        self.ts_s
    }
    fn reset(&mut self) -> Result<(), Error> {
        self.state = self.model.initial_state();
        Ok(())
    }
    fn name(&self) -> &str {
        "model"
    }
}

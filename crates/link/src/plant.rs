//! The board's stand-in actuator ([`OnChipPlant`]): the core's enhanced model in `f32`, for
//! the self-tests, the simulated runs and the front end that simulates the converters
//! ([`crate::analog::SimulatedActuator`]).

use crate::message::{MAX_AR, MAX_HARMONICS, PlantParams};
use boucwen_core::Error;
use boucwen_core::model::{EnhancedParams, EnhancedState, HarmonicBranch, Model};

#[cfg(test)]
std::thread_local! {
    /// Steps of the on-chip plant (counted by [`OnChipPlant::step`] in tests: the fuzzer
    /// checks that no packet or tick steps it more than the limits allow).
    pub(crate) static PLANT_STEPS: core::cell::Cell<u64> = const { core::cell::Cell::new(0) };
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
        #[cfg(test)]
        PLANT_STEPS.with(|c| c.set(c.get() + 1));
        self.model.step(&mut self.state, u)
    }
}

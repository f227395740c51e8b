//! The scenario: every parameter of the virtual bimorph, read from TOML.
//!
//! A scenario file has one table per stage of the signal chain (see the crate docs for the
//! equations): `[sampling]`, `[dac]`, `[delay]`, `[driver]`, `[hysteresis]`, `[creep]`,
//! `[structure]` (with `[[structure.modes]]` and their `stiffening` lists), `[sensor]`, and
//! a top-level `seed`. Missing tables and missing keys take the values of
//! [`Scenario::default`] (the paper's actuator, also written out with comments in
//! `crates/sim/scenarios/paper.toml`); unknown keys are rejected. After parsing,
//! [`Scenario::validate`] checks every range and names the offending field.
//!
//! Units are in the field names: `_s` seconds, `_hz` hertz, `_v` volts, `_um` micrometres,
//! `_per_v` per volt. A value `0` switches some effects off; each field says which.
//!
//! ```
//! use boucwen_sim::Scenario;
//! let s = Scenario::from_toml_str("seed = 3\n[sensor]\nnoise_um = 0.0\n").unwrap();
//! assert_eq!(s.seed, 3);
//! assert_eq!(s.sensor.noise_um, 0.0);
//! assert_eq!(s.structure, Scenario::default().structure);
//!
//! let err = Scenario::from_toml_str("[structure]\nmodes = [{ freq_hz = 70.0, damping = -1.0 }]")
//!     .unwrap_err();
//! assert_eq!(err.to_string(), "invalid scenario: structure.modes[0].damping must be > 0 (got -1)");
//! ```

use crate::SimError;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Most bending modes a scenario may have.
pub const MAX_MODES: usize = 4;
/// Most creep relaxation terms a scenario may have.
pub const MAX_CREEP_TERMS: usize = 4;
/// Highest power of the stiffening polynomial.
pub const MAX_STIFFENING_POWER: u32 = 9;
/// Highest power of the nonlinear damping.
pub const MAX_DAMPING_POWER: u32 = 4;
/// Longest transport delay, in seconds.
pub const MAX_DELAY_S: f64 = 1.0;

/// All parameters of the virtual bimorph.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scenario {
    /// Seed of the sensor noise and drift random walk (`0..=i64::MAX`, as TOML integers
    /// are signed 64-bit).
    pub seed: u64,
    /// Sample interval and integration step.
    pub sampling: Sampling,
    /// The digital-to-analogue converter.
    pub dac: Dac,
    /// Transport delay of the command.
    pub delay: Delay,
    /// The high-voltage driver amplifier.
    pub driver: Driver,
    /// Bouc–Wen hysteresis of the piezo ceramic and its gain to free deflection.
    pub hysteresis: Hysteresis,
    /// Slow creep of the deflection.
    pub creep: Creep,
    /// Bending modes of the cantilever and their stiffening.
    pub structure: Structure,
    /// The displacement sensor.
    pub sensor: Sensor,
}

/// Sampling of the controller and integration step of the physics.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Sampling {
    /// Sample interval `Ts` of the DAC and the sensor, s (`0 < ts_s ≤ 1`).
    pub ts_s: f64,
    /// RK4 steps per sample interval (`1..=1024`); the integration step is `ts_s / substeps`.
    pub substeps: u32,
}

/// The digital-to-analogue converter: quantisation, saturation, zero-order hold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Dac {
    /// Resolution in bits over `±range_v` (`0..=32`; `0` = no quantisation).
    pub bits: u32,
    /// Output range, V: the output saturates at `±range_v` (`> 0`).
    pub range_v: f64,
}

/// Transport delay of the command between the controller and the driver.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Delay {
    /// Delay, s (`0..=1`); rounded to the nearest integration step `ts_s / substeps`.
    pub transport_s: f64,
}

/// The driver amplifier: gain, first-order bandwidth, output rails.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Driver {
    /// Voltage gain, V/V (`> 0`).
    pub gain: f64,
    /// First-order (−3 dB) bandwidth, Hz (`> 0`).
    pub bandwidth_hz: f64,
    /// Output rails, V: the amplifier's target `gain·u` is clamped to `±limit_v` (`> 0`,
    /// `inf` allowed).
    pub limit_v: f64,
}

/// Bouc–Wen hysteresis of the actuator voltage `v` and the gain to free deflection.
///
/// `ḣ = A·v̇ + A0·|v̇| − γ·|h|·v̇ − β·|v̇|·h`, drive `w = kp·(v − h + Σ c_j)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Hysteresis {
    /// `A`, dimensionless: initial slope of `h` against `v` (`0` with `a0 = 0` switches
    /// the hysteresis off).
    pub a: f64,
    /// `A0`, dimensionless: velocity-sign asymmetry; moves the loop off-centre.
    pub a0: f64,
    /// `γ`, 1/V: shape (saturation) of the loop.
    pub gamma_per_v: f64,
    /// `β`, 1/V: shape (saturation) of the loop.
    pub beta_per_v: f64,
    /// `kp`, µm/V: free deflection per volt of `v − h` (`> 0`).
    pub kp_um_per_v: f64,
}

/// Creep: parallel first-order relaxations that add slow extra deflection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Creep {
    /// The relaxation terms (at most [`MAX_CREEP_TERMS`]; empty = no creep).
    pub terms: Vec<CreepTerm>,
}

/// One creep term: `ċ = (amplitude·(v − h) − c) / tau_s`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreepTerm {
    /// Steady-state extra deflection as a fraction of the instantaneous one (finite).
    pub amplitude: f64,
    /// Time constant, s (`≥ ts_s`).
    pub tau_s: f64,
}

/// The cantilever's bending modes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Structure {
    /// Reference deflection `q_ref` of the stiffening polynomial, µm (`> 0`).
    pub q_ref_um: f64,
    /// Reference velocity `v_ref` of the nonlinear damping, µm/s (`> 0`).
    pub v_ref_um_per_s: f64,
    /// The modes (`1..=`[`MAX_MODES`]); the sensed deflection is the sum of their
    /// coordinates.
    pub modes: Vec<Mode>,
}

/// One bending mode:
/// `q̈ + 2ζω·q̇·(1 + D(|q̇|)) + ω²·(q + N(q)) = ω²·φ·w`, with the stiffening
/// `N(q) = q_ref·Σ_p c_p·(q/q_ref)^p` and the nonlinear damping `D(s) = Σ_p d_p·(s/v_ref)^p`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mode {
    /// Natural frequency `ω/2π` at small deflection, Hz (`> 0`, and `ω·ts_s/substeps ≤ 1`).
    pub freq_hz: f64,
    /// Damping ratio `ζ` (`0 < ζ ≤ 10`).
    pub damping: f64,
    /// Participation `φ`: static deflection of this mode per µm of drive `w` (finite).
    #[serde(default = "one")]
    pub participation: f64,
    /// The stiffening polynomial `N(q)` (empty = linear stiffness).
    #[serde(default)]
    pub stiffening: Vec<StiffeningTerm>,
    /// The nonlinear damping `D(|q̇|)` (empty = linear damping).
    #[serde(default)]
    pub damping_nl: Vec<DampingTerm>,
}

fn one() -> f64 {
    1.0
}

/// One term `c_p·q_ref·(q/q_ref)^p` of a mode's stiffening polynomial: at `q = q_ref` it
/// adds the fraction `c_p` to the linear restoring force.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StiffeningTerm {
    /// The power `p` (`2..=`[`MAX_STIFFENING_POWER`]; odd powers are symmetric
    /// stiffening, even powers an asymmetric bimorph); each power at most once per mode.
    pub power: u32,
    /// The coefficient `c_p` (finite; negative softens).
    pub coeff: f64,
}

/// One term `d_p·(|q̇|/v_ref)^p` of a mode's nonlinear damping: at `|q̇| = v_ref` it adds
/// the fraction `d_p` to the linear damping (`p = 1`: quadratic drag `q̇·|q̇|`; `p = 2`:
/// cubic damping `q̇³`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DampingTerm {
    /// The power `p` (`1..=`[`MAX_DAMPING_POWER`]); each power at most once per mode.
    pub power: u32,
    /// The coefficient `d_p` (`≥ 0`: the damping never turns negative).
    pub coeff: f64,
}

/// The displacement sensor, sampled at the end of each sample interval.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Sensor {
    /// Standard deviation of white Gaussian noise, µm (`≥ 0`; `0` = none).
    pub noise_um: f64,
    /// Quantisation step, µm (`≥ 0`; `0` = none).
    pub resolution_um: f64,
    /// Constant offset, µm (finite).
    pub offset_um: f64,
    /// Linear drift, µm/s (finite).
    pub drift_um_per_s: f64,
    /// Random-walk drift intensity, µm/√s (`≥ 0`; the walk's standard deviation after
    /// `t` seconds is `random_walk_um_per_sqrt_s·√t`).
    pub random_walk_um_per_sqrt_s: f64,
}

impl Default for Scenario {
    /// The paper's actuator (FDK PZBA-00030 on an NF As-904-150B driver, 1 kHz sampling);
    /// `crates/sim/scenarios/paper.toml` is the same set with the reasons for each value.
    fn default() -> Self {
        Self {
            seed: 1,
            sampling: Sampling::default(),
            dac: Dac::default(),
            delay: Delay::default(),
            driver: Driver::default(),
            hysteresis: Hysteresis::default(),
            creep: Creep::default(),
            structure: Structure::default(),
            sensor: Sensor::default(),
        }
    }
}

impl Default for Sampling {
    fn default() -> Self {
        Self { ts_s: 1e-3, substeps: 8 }
    }
}

impl Default for Dac {
    fn default() -> Self {
        Self { bits: 16, range_v: 10.0 }
    }
}

impl Default for Delay {
    fn default() -> Self {
        Self { transport_s: 0.5e-3 }
    }
}

impl Default for Driver {
    fn default() -> Self {
        Self { gain: 15.0, bandwidth_hz: 2000.0, limit_v: 150.0 }
    }
}

impl Default for Hysteresis {
    fn default() -> Self {
        Self { a: 0.3, a0: 0.0043, gamma_per_v: 0.0004, beta_per_v: 0.006, kp_um_per_v: 1.7 }
    }
}

impl Default for Creep {
    fn default() -> Self {
        Self {
            terms: vec![CreepTerm { amplitude: 0.01, tau_s: 0.3 }, CreepTerm { amplitude: 0.01, tau_s: 3.0 }],
        }
    }
}

impl Default for Structure {
    fn default() -> Self {
        Self {
            q_ref_um: 20.0,
            v_ref_um_per_s: 3000.0,
            modes: vec![
                Mode {
                    freq_hz: 68.3,
                    damping: 0.012,
                    participation: 0.97,
                    stiffening: vec![
                        StiffeningTerm { power: 2, coeff: -0.020 },
                        StiffeningTerm { power: 3, coeff: -0.1115 },
                        StiffeningTerm { power: 4, coeff: 0.036 },
                        StiffeningTerm { power: 5, coeff: 0.12 },
                    ],
                    damping_nl: vec![DampingTerm { power: 4, coeff: 0.2 }],
                },
                Mode {
                    freq_hz: 428.0,
                    damping: 0.02,
                    participation: 0.03,
                    stiffening: vec![],
                    damping_nl: vec![],
                },
            ],
        }
    }
}

impl Default for Sensor {
    fn default() -> Self {
        Self {
            noise_um: 0.01,
            resolution_um: 0.01,
            offset_um: 0.0,
            drift_um_per_s: 0.002,
            random_walk_um_per_sqrt_s: 0.005,
        }
    }
}

impl Scenario {
    /// Parses a scenario from TOML text and validates it. Missing tables and keys take
    /// the defaults; unknown keys are an error.
    pub fn from_toml_str(text: &str) -> Result<Self, SimError> {
        let s: Scenario = toml::from_str(text).map_err(|e| SimError::Parse(e.to_string()))?;
        s.validate()?;
        Ok(s)
    }

    /// Reads, parses and validates a scenario file.
    pub fn from_path(path: impl AsRef<Path>) -> Result<Self, SimError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path)
            .map_err(|e| SimError::Io { path: path.display().to_string(), message: e.to_string() })?;
        Self::from_toml_str(&text).map_err(|e| match e {
            SimError::Parse(msg) => SimError::Parse(format!("{}: {msg}", path.display())),
            other => other,
        })
    }

    /// The scenario as TOML text (every key written; [`Scenario::from_toml_str`] reads it
    /// back to an equal scenario).
    pub fn to_toml_string(&self) -> Result<String, SimError> {
        toml::to_string(self).map_err(|e| SimError::Serialize(e.to_string()))
    }

    /// Checks every value, naming the first offending field and its allowed range.
    pub fn validate(&self) -> Result<(), SimError> {
        if self.seed > i64::MAX as u64 {
            return Err(invalid("seed", format!("must be ≤ {} (got {})", i64::MAX, self.seed)));
        }
        let s = &self.sampling;
        check::positive("sampling.ts_s", s.ts_s)?;
        check::at_most("sampling.ts_s", s.ts_s, 1.0)?;
        if !(1..=1024).contains(&s.substeps) {
            return Err(invalid("sampling.substeps", format!("must be in 1..=1024 (got {})", s.substeps)));
        }
        let h = s.ts_s / f64::from(s.substeps);

        if self.dac.bits > 32 {
            return Err(invalid("dac.bits", format!("must be in 0..=32 (got {})", self.dac.bits)));
        }
        check::positive("dac.range_v", self.dac.range_v)?;
        check::non_negative("delay.transport_s", self.delay.transport_s)?;
        check::at_most("delay.transport_s", self.delay.transport_s, MAX_DELAY_S)?;

        check::positive("driver.gain", self.driver.gain)?;
        check::positive("driver.bandwidth_hz", self.driver.bandwidth_hz)?;
        if self.driver.limit_v.is_nan() || self.driver.limit_v <= 0.0 {
            return Err(invalid("driver.limit_v", format!("must be > 0 (got {})", self.driver.limit_v)));
        }

        let hy = &self.hysteresis;
        check::finite("hysteresis.a", hy.a)?;
        check::finite("hysteresis.a0", hy.a0)?;
        check::finite("hysteresis.gamma_per_v", hy.gamma_per_v)?;
        check::finite("hysteresis.beta_per_v", hy.beta_per_v)?;
        check::positive("hysteresis.kp_um_per_v", hy.kp_um_per_v)?;

        if self.creep.terms.len() > MAX_CREEP_TERMS {
            return Err(invalid(
                "creep.terms",
                format!("must have at most {MAX_CREEP_TERMS} entries (got {})", self.creep.terms.len()),
            ));
        }
        for (j, t) in self.creep.terms.iter().enumerate() {
            check::finite(&format!("creep.terms[{j}].amplitude"), t.amplitude)?;
            let field = format!("creep.terms[{j}].tau_s");
            check::finite(&field, t.tau_s)?;
            if t.tau_s < s.ts_s {
                return Err(invalid(
                    &field,
                    format!("must be ≥ sampling.ts_s = {} (got {})", s.ts_s, t.tau_s),
                ));
            }
        }

        let st = &self.structure;
        check::positive("structure.q_ref_um", st.q_ref_um)?;
        check::positive("structure.v_ref_um_per_s", st.v_ref_um_per_s)?;
        if st.modes.is_empty() || st.modes.len() > MAX_MODES {
            return Err(invalid(
                "structure.modes",
                format!("must have 1..={MAX_MODES} entries (got {})", st.modes.len()),
            ));
        }
        let f_max = 1.0 / (core::f64::consts::TAU * h);
        for (i, m) in st.modes.iter().enumerate() {
            let p = format!("structure.modes[{i}]");
            check::positive(&format!("{p}.freq_hz"), m.freq_hz)?;
            if m.freq_hz > f_max {
                return Err(invalid(
                    &format!("{p}.freq_hz"),
                    format!(
                        "must be ≤ 1/(2π·ts_s/substeps) = {f_max:.1} Hz for an accurate RK4 step \
                         (got {}; raise sampling.substeps)",
                        m.freq_hz
                    ),
                ));
            }
            check::positive(&format!("{p}.damping"), m.damping)?;
            check::at_most(&format!("{p}.damping"), m.damping, 10.0)?;
            check::finite(&format!("{p}.participation"), m.participation)?;
            let mut seen = [false; MAX_STIFFENING_POWER as usize + 1];
            for (k, t) in m.stiffening.iter().enumerate() {
                let field = format!("{p}.stiffening[{k}].power");
                if !(2..=MAX_STIFFENING_POWER).contains(&t.power) {
                    return Err(invalid(
                        &field,
                        format!("must be in 2..={MAX_STIFFENING_POWER} (got {})", t.power),
                    ));
                }
                if seen[t.power as usize] {
                    return Err(invalid(
                        &field,
                        format!("must not repeat (power {} appears twice)", t.power),
                    ));
                }
                seen[t.power as usize] = true;
                check::finite(&format!("{p}.stiffening[{k}].coeff"), t.coeff)?;
            }
            let mut seen = [false; MAX_DAMPING_POWER as usize + 1];
            for (k, t) in m.damping_nl.iter().enumerate() {
                let field = format!("{p}.damping_nl[{k}].power");
                if !(1..=MAX_DAMPING_POWER).contains(&t.power) {
                    return Err(invalid(
                        &field,
                        format!("must be in 1..={MAX_DAMPING_POWER} (got {})", t.power),
                    ));
                }
                if seen[t.power as usize] {
                    return Err(invalid(
                        &field,
                        format!("must not repeat (power {} appears twice)", t.power),
                    ));
                }
                seen[t.power as usize] = true;
                check::non_negative(&format!("{p}.damping_nl[{k}].coeff"), t.coeff)?;
            }
        }

        let se = &self.sensor;
        check::non_negative("sensor.noise_um", se.noise_um)?;
        check::non_negative("sensor.resolution_um", se.resolution_um)?;
        check::finite("sensor.offset_um", se.offset_um)?;
        check::finite("sensor.drift_um_per_s", se.drift_um_per_s)?;
        check::non_negative("sensor.random_walk_um_per_sqrt_s", se.random_walk_um_per_sqrt_s)?;
        Ok(())
    }

    /// No sensor noise, offset or drift, no DAC or sensor quantisation: the physics alone
    /// (delay, driver, hysteresis, creep, structure, saturation) as a clean record.
    pub fn ideal() -> Self {
        Self::default().without_noise().without_drift().without_quantisation()
    }

    /// Sensor noise off.
    pub fn without_noise(mut self) -> Self {
        self.sensor.noise_um = 0.0;
        self
    }

    /// Sensor offset, linear drift and random walk off.
    pub fn without_drift(mut self) -> Self {
        self.sensor.offset_um = 0.0;
        self.sensor.drift_um_per_s = 0.0;
        self.sensor.random_walk_um_per_sqrt_s = 0.0;
        self
    }

    /// DAC and sensor quantisation off (saturation stays).
    pub fn without_quantisation(mut self) -> Self {
        self.dac.bits = 0;
        self.sensor.resolution_um = 0.0;
        self
    }

    /// Creep off.
    pub fn without_creep(mut self) -> Self {
        self.creep.terms.clear();
        self
    }

    /// Every mode's stiffening polynomial off (linear stiffness).
    pub fn without_stiffening(mut self) -> Self {
        for m in &mut self.structure.modes {
            m.stiffening.clear();
        }
        self
    }

    /// Every mode's nonlinear damping off (linear damping).
    pub fn without_nonlinear_damping(mut self) -> Self {
        for m in &mut self.structure.modes {
            m.damping_nl.clear();
        }
        self
    }

    /// Hysteresis off (`A = A0 = 0`): the drive is `kp·v` (plus creep).
    pub fn without_hysteresis(mut self) -> Self {
        self.hysteresis.a = 0.0;
        self.hysteresis.a0 = 0.0;
        self
    }

    /// Transport delay off.
    pub fn without_delay(mut self) -> Self {
        self.delay.transport_s = 0.0;
        self
    }

    /// The same scenario with another seed.
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// The same scenario with another number of RK4 steps per sample.
    pub fn with_substeps(mut self, substeps: u32) -> Self {
        self.sampling.substeps = substeps;
        self
    }
}

fn invalid(field: &str, requirement: String) -> SimError {
    SimError::Invalid { field: field.to_string(), requirement }
}

/// Range checks that name the field.
mod check {
    use super::invalid;
    use crate::SimError;

    pub(super) fn finite(field: &str, x: f64) -> Result<(), SimError> {
        if x.is_finite() { Ok(()) } else { Err(invalid(field, format!("must be finite (got {x})"))) }
    }
    pub(super) fn positive(field: &str, x: f64) -> Result<(), SimError> {
        finite(field, x)?;
        if x > 0.0 { Ok(()) } else { Err(invalid(field, format!("must be > 0 (got {x})"))) }
    }
    pub(super) fn non_negative(field: &str, x: f64) -> Result<(), SimError> {
        finite(field, x)?;
        if x >= 0.0 { Ok(()) } else { Err(invalid(field, format!("must be ≥ 0 (got {x})"))) }
    }
    pub(super) fn at_most(field: &str, x: f64, max: f64) -> Result<(), SimError> {
        if x <= max { Ok(()) } else { Err(invalid(field, format!("must be ≤ {max} (got {x})"))) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PAPER: &str = include_str!("../scenarios/paper.toml");

    #[test]
    fn paper_file_is_exactly_the_default() {
        assert_eq!(Scenario::from_toml_str(PAPER).unwrap(), Scenario::default());
    }

    #[test]
    fn default_survives_a_toml_round_trip() {
        let mut s = Scenario { seed: 12345, ..Scenario::default() };
        s.sensor.offset_um = -2.5;
        let text = s.to_toml_string().unwrap();
        assert_eq!(Scenario::from_toml_str(&text).unwrap(), s);
        assert_eq!(
            Scenario::from_toml_str(&Scenario::ideal().to_toml_string().unwrap()).unwrap(),
            Scenario::ideal()
        );
    }

    #[test]
    fn partial_files_take_defaults() {
        let s = Scenario::from_toml_str("[driver]\ngain = 20.0\n").unwrap();
        assert_eq!(s.driver.gain, 20.0);
        assert_eq!(s.driver.bandwidth_hz, Scenario::default().driver.bandwidth_hz);
        assert_eq!(s.structure, Scenario::default().structure);
        assert_eq!(Scenario::from_toml_str("").unwrap(), Scenario::default());
        // A mode without participation or polynomials is a linear mode with φ = 1.
        let s = Scenario::from_toml_str("[[structure.modes]]\nfreq_hz = 70.0\ndamping = 0.01\n").unwrap();
        assert_eq!(s.structure.modes.len(), 1);
        assert_eq!(s.structure.modes[0].participation, 1.0);
        assert!(s.structure.modes[0].stiffening.is_empty());
    }

    #[test]
    fn unknown_keys_are_rejected() {
        for text in [
            "[sensor]\nnoise = 0.1\n",
            "sed = 3\n",
            "[structure]\nmodes = [{ freq_hz = 70.0, damping = 0.01, zeta = 1.0 }]\n",
        ] {
            match Scenario::from_toml_str(text) {
                Err(SimError::Parse(msg)) => assert!(msg.contains("unknown field"), "{msg}"),
                other => panic!("{text:?} gave {other:?}"),
            }
        }
    }

    #[test]
    fn invalid_values_name_the_field() {
        let cases = [
            (
                "[structure]\nmodes = [{ freq_hz = 70.0, damping = 0.0 }]",
                "structure.modes[0].damping must be > 0 (got 0)",
            ),
            ("[sampling]\nsubsteps = 0", "sampling.substeps must be in 1..=1024 (got 0)"),
            ("[sampling]\nts_s = -0.001", "sampling.ts_s must be > 0 (got -0.001)"),
            ("[dac]\nbits = 40", "dac.bits must be in 0..=32 (got 40)"),
            ("[delay]\ntransport_s = 2.0", "delay.transport_s must be ≤ 1 (got 2)"),
            ("[driver]\nlimit_v = nan", "driver.limit_v must be > 0 (got NaN)"),
            ("[hysteresis]\nbeta_per_v = inf", "hysteresis.beta_per_v must be finite (got inf)"),
            ("[sensor]\nnoise_um = -1.0", "sensor.noise_um must be ≥ 0 (got -1)"),
            (
                "[creep]\nterms = [{ amplitude = 0.1, tau_s = 0.0001 }]",
                "creep.terms[0].tau_s must be ≥ sampling.ts_s = 0.001 (got 0.0001)",
            ),
            ("[structure]\nmodes = []", "structure.modes must have 1..=4 entries (got 0)"),
            (
                "[structure]\nmodes = [{ freq_hz = 70.0, damping = 0.01, stiffening = [{ power = 3, coeff = 0.1 }, { power = 3, coeff = 0.2 }] }]",
                "structure.modes[0].stiffening[1].power must not repeat (power 3 appears twice)",
            ),
            (
                "[structure]\nmodes = [{ freq_hz = 70.0, damping = 0.01, stiffening = [{ power = 1, coeff = 0.1 }] }]",
                "structure.modes[0].stiffening[0].power must be in 2..=9 (got 1)",
            ),
            (
                "[structure]\nmodes = [{ freq_hz = 70.0, damping = 0.01, damping_nl = [{ power = 2, coeff = -1.0 }] }]",
                "structure.modes[0].damping_nl[0].coeff must be ≥ 0 (got -1)",
            ),
            (
                "[structure]\nmodes = [{ freq_hz = 5000.0, damping = 0.01 }]",
                "structure.modes[0].freq_hz must be ≤ 1/(2π·ts_s/substeps) = 1273.2 Hz for an accurate RK4 step (got 5000; raise sampling.substeps)",
            ),
        ];
        for (text, expected) in cases {
            match Scenario::from_toml_str(text) {
                Err(e @ SimError::Invalid { .. }) => {
                    assert_eq!(e.to_string(), format!("invalid scenario: {expected}"), "for {text:?}")
                }
                other => panic!("{text:?} gave {other:?}"),
            }
        }
    }

    #[test]
    fn a_missing_file_names_the_path() {
        let e = Scenario::from_path("/nonexistent/scenario.toml").unwrap_err();
        assert!(matches!(e, SimError::Io { .. }));
        assert!(e.to_string().starts_with("/nonexistent/scenario.toml: "), "{e}");
    }

    #[test]
    fn switches_turn_effects_off() {
        let s = Scenario::default().without_noise().without_drift().without_quantisation().without_creep();
        assert_eq!(s.sensor.noise_um, 0.0);
        assert_eq!(s.sensor.random_walk_um_per_sqrt_s, 0.0);
        assert_eq!(s.dac.bits, 0);
        assert!(s.creep.terms.is_empty());
        let s = s.without_stiffening().without_nonlinear_damping().without_hysteresis().without_delay();
        assert!(s.structure.modes.iter().all(|m| m.stiffening.is_empty() && m.damping_nl.is_empty()));
        assert_eq!((s.hysteresis.a, s.hysteresis.a0, s.delay.transport_s), (0.0, 0.0, 0.0));
        assert!(s.validate().is_ok());
    }
}

//! More records with hidden effects (feature `fixtures`): sine records with saturation, creep
//! or an input delay, two effects at once, and periodic records (triangles, odd random-phase
//! multisines) of an actuator with a hidden odd or even nonlinearity. For testing and
//! benchmarking [`crate::diagnose`]; what is hidden is known only to the caller.
//!
//! ## Sine records ([`SineCase`])
//! Built on a case of [`crate::hidden`] (its actuator, drive frequency and amplitude), with:
//!
//! | [`SineEffect`] | what is switched on |
//! |---|---|
//! | `Saturation` | the driver's rails at 60–85 % of the drive's peak (the amplifier clips; the output flattens through the structure) |
//! | `SensorRange` | the sensor's range at 55–85 % of the output's excursion above (or below, or both) its mean: the record is clipped there |
//! | `Creep` | a creep relaxation of 10–25 % of the deflection with a time constant of 2–5 s (the record is 10 s: it still relaxes in the held-out half), and a drive with an offset of 40–80 % of its amplitude (a sine about zero barely moves the creep's level) |
//! | `Delay` | a transport delay of 3–8 ms (the default actuator's is 0.5 ms) |
//! | `HarmonicAndDrift(n)` | a hidden odd harmonic of order `n` and the sensor drift of [`Effect::Drift`] |
//! | `RangeAndHarmonic(n)` | a hidden odd harmonic of order `n` and the sensor's range, as `SensorRange` |
//!
//! ## Periodic records ([`PeriodicCase`])
//! The paper's actuator with the first mode drawn (40–200 Hz, damping 0.02–0.06, no
//! nonlinear damping), no sensor drift, and one of [`Nonlinearity`]: none, an odd (cubic)
//! hardening of the bending centred on the operating point, or an even (quadratic) one of
//! either sign.
//! The stiffening adds 10–25 % to the restoring force at the record's largest deflection.
//! The drive is a symmetric triangle (4–20 Hz) or an odd random-phase multisine over odd
//! lines of 1 or 2 Hz up to 0.5–1.2 times the resonance, one odd line of four left out, in
//! two realisations (new phases) of 8 periods each. The hysteresis is there in every case:
//! it is itself an odd nonlinearity (with an even part from its off-centre loop), which the
//! extended model holds.

use crate::excitation::{Multisine, SplitMix64, triangle};
use crate::experiment;
use crate::hidden::{Case, CaseError, DAMPING_RANGE, Effect, RESONANCE_RANGE_HZ};
use crate::record::Record;
use boucwen_sim::scenario::{CreepTerm, Mode, StiffeningTerm};
use boucwen_sim::{Bimorph, Scenario};

/// The effect hidden in a sine record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SineEffect {
    /// The driver saturates (its rails below the drive's peak).
    Saturation,
    /// The sensor's range clips the output.
    SensorRange,
    /// A strong creep under a drive with an offset.
    Creep,
    /// A long input (transport) delay.
    Delay,
    /// A hidden odd harmonic of this order and sensor drift.
    HarmonicAndDrift(u32),
    /// A hidden odd harmonic of this order and the sensor's range clipping the output.
    RangeAndHarmonic(u32),
}

impl SineEffect {
    /// One of each kind (the harmonics at the orders the batch draws), in the order reports
    /// list them.
    pub const ALL: [SineEffect; 6] = [
        SineEffect::Saturation,
        SineEffect::SensorRange,
        SineEffect::Creep,
        SineEffect::Delay,
        SineEffect::HarmonicAndDrift(5),
        SineEffect::RangeAndHarmonic(3),
    ];

    /// A short name: "saturation", "sensor-range", "creep", "delay", "odd5+drift",
    /// "sensor-range+odd3".
    pub fn name(&self) -> String {
        match self {
            SineEffect::Saturation => "saturation".into(),
            SineEffect::SensorRange => "sensor-range".into(),
            SineEffect::Creep => "creep".into(),
            SineEffect::Delay => "delay".into(),
            SineEffect::HarmonicAndDrift(n) => format!("odd{n}+drift"),
            SineEffect::RangeAndHarmonic(n) => format!("sensor-range+odd{n}"),
        }
    }

    /// The base effect of [`crate::hidden`] the case is drawn from.
    fn base(&self) -> Effect {
        match *self {
            SineEffect::HarmonicAndDrift(n) | SineEffect::RangeAndHarmonic(n) => Effect::OddHarmonic(n),
            _ => Effect::Clean,
        }
    }
}

/// What a right diagnosis of a hidden-effect record names.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Truth {
    /// A harmonic of this order at this frequency (Hz).
    Harmonic {
        /// Order.
        order: u32,
        /// Frequency (Hz).
        freq_hz: f64,
    },
    /// Drift.
    Drift,
    /// Saturation of the drive (`input`) or of the output, at this level (V or µm).
    Saturation {
        /// The drive saturates (else the output).
        input: bool,
        /// The level: the drive's (V, of `u`) or the output's (µm), the nearer side.
        level: f64,
    },
    /// Creep.
    Creep,
    /// An input delay of about this many samples.
    Delay {
        /// Samples.
        samples: f64,
    },
    /// Odd nonlinear distortion.
    OddDistortion,
    /// Even nonlinear distortion.
    EvenDistortion,
}

/// A drawn sine record with a hidden effect.
#[derive(Clone, Debug)]
pub struct SineCase {
    /// The effect.
    pub effect: SineEffect,
    /// The case of [`crate::hidden`] it is built on (its scenario carries the effect).
    pub case: Case,
    /// The drive's offset (V).
    pub offset_v: f64,
    /// The sensor's range `[lo, hi]` (µm), if it clips.
    pub sensor_range: Option<[f64; 2]>,
    /// What a right diagnosis names (all of it, in no particular order).
    pub truth: Vec<Truth>,
}

impl SineCase {
    /// Draws a case with `effect` from `seed` (same seed, same case).
    pub fn generate(effect: SineEffect, seed: u64) -> Result<SineCase, CaseError> {
        let mut case = Case::generate(effect.base(), seed)?;
        let tag = match effect {
            SineEffect::Saturation => 1,
            SineEffect::SensorRange => 2,
            SineEffect::Creep => 3,
            SineEffect::Delay => 4,
            SineEffect::HarmonicAndDrift(n) => 10 + u64::from(n),
            SineEffect::RangeAndHarmonic(n) => 20 + u64::from(n),
        };
        let mut d = SplitMix64::new(seed ^ tag.wrapping_mul(0xE77E_C75E_ED00_0001));
        let s = &mut case.scenario;
        let peak_v = case.amplitude_v;
        let mut truth = vec![];
        let mut offset_v = 0.0;
        let mut sensor_range = None;
        if let Effect::OddHarmonic(n) = effect.base() {
            truth.push(Truth::Harmonic { order: n, freq_hz: f64::from(n) * case.drive_hz });
        }
        match effect {
            SineEffect::Saturation => {
                let frac = d.uniform(0.6, 0.85);
                s.driver.limit_v = frac * peak_v * s.driver.gain;
                truth.push(Truth::Saturation { input: true, level: frac * peak_v });
            }
            SineEffect::SensorRange | SineEffect::RangeAndHarmonic(_) => {
                // The range is set on the record's own excursion (measured below).
                let frac = d.uniform(0.55, 0.85);
                let side = d.index(3); // 0: top, 1: bottom, 2: both
                let u0 = sine_drive(peak_v, case.drive_hz, s.sampling.ts_s, case.seconds, 0.0);
                let rec = Bimorph::new(s)?.run(&u0)?;
                let settled = &rec[rec.len() / 5..];
                let mean = crate::analysis::mean(settled);
                let (lo, hi) = crate::analysis::extent(settled);
                let top = mean + frac * (hi - mean);
                let bottom = mean - frac * (mean - lo);
                let range = match side {
                    0 => [-crate::record::Y_LIMIT_UM, top],
                    1 => [bottom, crate::record::Y_LIMIT_UM],
                    _ => [bottom, top],
                };
                let level = if side == 1 { bottom } else { top };
                sensor_range = Some(range);
                truth.push(Truth::Saturation { input: false, level });
            }
            SineEffect::Creep => {
                let amplitude = d.uniform(0.1, 0.25);
                let tau_s = d.uniform(2.0, 5.0);
                s.creep.terms.push(CreepTerm { amplitude, tau_s });
                offset_v = if d.index(2) == 0 { 1.0 } else { -1.0 } * d.uniform(0.4, 0.8) * peak_v;
                truth.push(Truth::Creep);
            }
            SineEffect::Delay => {
                let transport = d.uniform(3e-3, 8e-3);
                s.delay.transport_s = transport;
                // Beyond the transport: the zero-order hold (half a sample) and the driver's lag.
                let ts = s.sampling.ts_s;
                truth.push(Truth::Delay { samples: transport / ts + 0.5 });
            }
            SineEffect::HarmonicAndDrift(_) => {
                s.sensor.drift_um_per_s = if d.index(2) == 0 { 1.0 } else { -1.0 } * d.log_uniform(0.05, 0.3);
                s.sensor.random_walk_um_per_sqrt_s = d.log_uniform(0.005, 0.03);
                truth.push(Truth::Drift);
            }
        }
        s.validate()?;
        Ok(SineCase { effect, case, offset_v, sensor_range, truth })
    }

    /// Runs the virtual bimorph from rest with the case's drive (the sine, plus the offset)
    /// and clips the output at the sensor's range; the record is named "creep-12".
    pub fn record(&self) -> Result<Record, CaseError> {
        let ts = self.case.scenario.sampling.ts_s;
        let c = &self.case;
        let u = sine_drive(c.amplitude_v, c.drive_hz, ts, c.seconds, self.offset_v);
        let mut y = Bimorph::new(&self.case.scenario)?.run(&u)?;
        if let Some([lo, hi]) = self.sensor_range {
            y.iter_mut().for_each(|v| *v = v.clamp(lo, hi));
        }
        let name = format!("{}-{}", self.effect.name(), self.case.seed);
        Record::new(&name, 0.0, ts, u, y, None).map_err(CaseError::Record)
    }
}

/// `offset + amplitude·sin(2π f k Ts)` over `seconds`.
fn sine_drive(amplitude_v: f64, drive_hz: f64, ts: f64, seconds: f64, offset_v: f64) -> Vec<f64> {
    let n = (seconds / ts).round() as usize;
    let sine = experiment::sine(amplitude_v, drive_hz, ts, n).unwrap_or_else(|_| vec![0.0; n]);
    sine.into_iter().map(|v| v + offset_v).collect()
}

/// The drive of a periodic record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PeriodicDrive {
    /// A symmetric triangle.
    Triangle,
    /// An odd random-phase multisine, in two realisations.
    Multisine,
}

/// The nonlinearity hidden in the actuator of a periodic record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Nonlinearity {
    /// None beyond the hysteresis.
    None,
    /// An odd (cubic) stiffening, centred on the operating point.
    Odd,
    /// An even (quadratic) stiffening: an asymmetric actuator.
    Even,
}

impl Nonlinearity {
    /// "clean", "odd", "even".
    pub fn name(self) -> &'static str {
        match self {
            Nonlinearity::None => "clean",
            Nonlinearity::Odd => "odd",
            Nonlinearity::Even => "even",
        }
    }
}

/// Periods in each periodic record.
pub const PERIODS: usize = 8;
/// Realisations of a multisine.
pub const REALISATIONS: usize = 2;
/// Share the stiffening adds to the restoring force at the largest deflection (drawn).
pub const STIFFENING_RANGE: (f64, f64) = (0.1, 0.25);

/// A drawn periodic case.
#[derive(Clone, Debug)]
pub struct PeriodicCase {
    /// The drive.
    pub drive: PeriodicDrive,
    /// The hidden nonlinearity.
    pub nonlinearity: Nonlinearity,
    /// The seed it was drawn from.
    pub seed: u64,
    /// The virtual bimorph.
    pub scenario: Scenario,
    /// Samples per period.
    pub period_samples: usize,
    /// The drive's peak (V).
    pub amplitude_v: f64,
    /// The multisine (first realisation), for a multisine drive.
    pub multisine: Option<Multisine>,
    /// The first mode's resonance (Hz).
    pub resonance_hz: f64,
}

impl PeriodicCase {
    /// Draws a case from `seed` (same seed, same case).
    pub fn generate(
        drive: PeriodicDrive,
        nonlinearity: Nonlinearity,
        seed: u64,
    ) -> Result<PeriodicCase, CaseError> {
        let tag = match (drive, nonlinearity) {
            (PeriodicDrive::Triangle, n) => 100 + n as u64,
            (PeriodicDrive::Multisine, n) => 200 + n as u64,
        };
        let mut d = SplitMix64::new(seed ^ tag.wrapping_mul(0x9E1D_0D1C_5EED_0003));
        let mut s = Scenario::default().with_seed(seed & (i64::MAX as u64)).without_drift();
        let ts = s.sampling.ts_s;
        let f_r = d.uniform(RESONANCE_RANGE_HZ.0, RESONANCE_RANGE_HZ.1);
        let zeta = d.log_uniform(DAMPING_RANGE.0, DAMPING_RANGE.1);
        let participation = s.structure.modes[0].participation;
        s.structure.modes[0] =
            Mode { freq_hz: f_r, damping: zeta, participation, stiffening: vec![], damping_nl: vec![] };
        s.structure.modes[1].freq_hz = (6.27 * f_r).min(1200.0);
        let amplitude_v = d.uniform(0.6, 1.4);
        let (period_samples, multisine) = match drive {
            PeriodicDrive::Triangle => ((d.uniform(50.0, 250.0)).round() as usize, None),
            PeriodicDrive::Multisine => {
                let n = if d.index(2) == 0 { 500 } else { 1000 };
                let f0 = 1.0 / (n as f64 * ts);
                let top = ((d.uniform(0.5, 1.2) * f_r / f0).round() as u32).max(15);
                let ms = Multisine::odd_random_phase(n, 1, top, 4, d.next_u64());
                (n, Some(ms))
            }
        };
        let mut case = PeriodicCase {
            drive,
            nonlinearity,
            seed,
            scenario: s,
            period_samples,
            amplitude_v,
            multisine,
            resonance_hz: f_r,
        };
        if nonlinearity != Nonlinearity::None {
            // The deflection's mean and largest excursion on the linear actuator.
            let mut lin = case.scenario.clone().without_noise().without_quantisation();
            lin.sensor.noise_um = 0.0;
            let u = case.drive_signal(0);
            let mut plant = Bimorph::new(&lin)?;
            let mut q = Vec::with_capacity(u.len());
            for &uk in &u {
                q.push(plant.step_detail(uk)?.y_true_um);
            }
            let settled = &q[q.len() / 2..];
            let q0 = crate::analysis::mean(settled);
            let x = settled.iter().fold(0.0f64, |m, v| m.max((v - q0).abs())).max(1e-6);
            let share = d.uniform(STIFFENING_RANGE.0, STIFFENING_RANGE.1);
            let q_ref = case.scenario.structure.q_ref_um;
            let sign = if d.index(2) == 0 { 1.0 } else { -1.0 };
            let terms = match nonlinearity {
                // c·q_ref·((q − q0)/q_ref)³ adds c·(X/q_ref)² of the linear force at q0 ± X;
                // its constant and linear parts are left out (an offset and a stiffness).
                // Hardening (a cantilever's geometric stiffening): a softening cubic this strong
                // would lose its restoring force beyond the largest deflection.
                Nonlinearity::Odd => {
                    let c = share * (q_ref / x).powi(2);
                    let z = q0 / q_ref;
                    vec![
                        StiffeningTerm { power: 3, coeff: c },
                        StiffeningTerm { power: 2, coeff: -3.0 * c * z },
                    ]
                }
                Nonlinearity::Even => {
                    let c = sign * share * q_ref / x;
                    vec![StiffeningTerm { power: 2, coeff: c }]
                }
                Nonlinearity::None => vec![],
            };
            case.scenario.structure.modes[0].stiffening = terms;
        }
        case.scenario.validate()?;
        Ok(case)
    }

    /// "multisine-odd-12", "triangle-clean-3".
    pub fn name(&self) -> String {
        let drive = match self.drive {
            PeriodicDrive::Triangle => "triangle",
            PeriodicDrive::Multisine => "multisine",
        };
        format!("{drive}-{}-{}", self.nonlinearity.name(), self.seed)
    }

    /// How many records (realisations) the case has.
    pub fn realisations(&self) -> usize {
        match self.drive {
            PeriodicDrive::Triangle => 1,
            PeriodicDrive::Multisine => REALISATIONS,
        }
    }

    /// The drive of realisation `r`: [`PERIODS`] periods (a triangle: 10 s).
    pub fn drive_signal(&self, r: usize) -> Vec<f64> {
        match (&self.drive, &self.multisine) {
            (PeriodicDrive::Multisine, Some(ms)) => {
                let m = if r == 0 {
                    ms.clone()
                } else {
                    ms.realisation(self.seed.wrapping_mul(31).wrapping_add(r as u64))
                };
                m.signal(self.amplitude_v, PERIODS)
            }
            _ => {
                let ts = self.scenario.sampling.ts_s;
                let n = ((10.0 / ts) as usize / self.period_samples) * self.period_samples;
                triangle(self.amplitude_v, self.period_samples, n)
            }
        }
    }

    /// The records, one per realisation, each from rest with its own sensor noise; named
    /// "multisine-odd-12-r1".
    pub fn records(&self) -> Result<Vec<Record>, CaseError> {
        let ts = self.scenario.sampling.ts_s;
        (0..self.realisations())
            .map(|r| {
                let u = self.drive_signal(r);
                let s = self
                    .scenario
                    .clone()
                    .with_seed((self.seed.wrapping_mul(7).wrapping_add(r as u64)) & (i64::MAX as u64));
                let y = Bimorph::new(&s)?.run(&u)?;
                Record::new(&format!("{}-r{}", self.name(), r + 1), 0.0, ts, u, y, None)
                    .map_err(CaseError::Record)
            })
            .collect()
    }

    /// What a right diagnosis names: the hidden nonlinearity's kind (none for a clean case).
    pub fn truth(&self) -> Option<Truth> {
        match self.nonlinearity {
            Nonlinearity::None => None,
            Nonlinearity::Odd => Some(Truth::OddDistortion),
            Nonlinearity::Even => Some(Truth::EvenDistortion),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cases_are_reproducible_and_valid() {
        for e in SineEffect::ALL {
            let a = SineCase::generate(e, 4).unwrap();
            let b = SineCase::generate(e, 4).unwrap();
            assert_eq!(a.case.scenario, b.case.scenario, "{}", e.name());
            assert_eq!(a.sensor_range, b.sensor_range);
            assert!(!a.truth.is_empty());
        }
        for drive in [PeriodicDrive::Triangle, PeriodicDrive::Multisine] {
            for nl in [Nonlinearity::None, Nonlinearity::Odd, Nonlinearity::Even] {
                let a = PeriodicCase::generate(drive, nl, 2).unwrap();
                let b = PeriodicCase::generate(drive, nl, 2).unwrap();
                assert_eq!(a.scenario, b.scenario);
                assert_eq!(a.drive_signal(1), b.drive_signal(1));
                assert_eq!(a.scenario.structure.modes[0].stiffening.is_empty(), nl == Nonlinearity::None);
            }
        }
    }
}

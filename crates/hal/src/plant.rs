//! A plant the host can drive: one sample in, one measurement out.
//!
//! Every experiment the host runs (identification, tracking, the sweep) talks to a
//! [`Plant`]: it applies `u[k]` (V) for one sample interval `Ts` and reads `y[k]` (µm) at
//! the end of that interval, so `y[k]` already responds to `u[k]`, the direct
//! feed-through of the core's models. The same experiment code runs against
//!
//! | plant | where | what `step` does |
//! |---|---|---|
//! | [`Replay`] | here | returns the next sample of a measured [`Record`] |
//! | [`boucwen_sim::Bimorph`] | here (impl) | integrates the virtual bimorph over one interval |
//! | the driver board | `transport` module of this crate | sends `u[k]` over the serial link and waits for `y[k]` |
//!
//! The trait is object safe, so tools hold a `&mut dyn Plant` or `Box<dyn Plant>` chosen
//! at run time from the command line.

use std::fmt;

use crate::record::Record;

/// What went wrong while driving a plant.
#[derive(Debug)]
#[non_exhaustive]
pub enum PlantError {
    /// A [`Replay`] was stepped past its last sample.
    EndOfRecord {
        /// The record's source.
        source: String,
        /// Samples in the record (all of them were returned).
        samples: usize,
    },
    /// A [`Replay`] was given a command that differs from the recorded one: the recorded
    /// `y` did not respond to it, so going on would pair `u` and `y` that do not belong
    /// together.
    InputMismatch {
        /// The record's source.
        source: String,
        /// The sample, counting from 0.
        sample: usize,
        /// The command applied, V.
        applied_v: f64,
        /// The command recorded, V.
        recorded_v: f64,
        /// The largest accepted difference, V.
        tolerance_v: f64,
    },
    /// The command was NaN or infinite; the plant was not stepped.
    NonFiniteInput {
        /// The plant's name.
        plant: String,
        /// The sample, counting from 0.
        sample: usize,
    },
    /// The virtual bimorph failed (its state diverged); see [`boucwen_sim::SimError`].
    Sim(boucwen_sim::SimError),
    /// A hardware plant failed (serial link, timeout, board fault); `error` says how.
    Device {
        /// The plant's name (e.g. the serial port).
        plant: String,
        /// The underlying error.
        error: Box<dyn std::error::Error + Send + Sync>,
    },
}

impl fmt::Display for PlantError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PlantError::EndOfRecord { source, samples } => {
                write!(f, "{source}: end of record: all {samples} samples were replayed")
            }
            PlantError::InputMismatch { source, sample, applied_v, recorded_v, tolerance_v } => write!(
                f,
                "{source}: sample {sample}: applied u = {applied_v} V differs from the recorded \
                 {recorded_v} V by more than {tolerance_v} V (a replay answers only the recorded input)"
            ),
            PlantError::NonFiniteInput { plant, sample } => {
                write!(f, "{plant}: sample {sample}: the command u is not finite")
            }
            PlantError::Sim(e) => write!(f, "{BIMORPH_NAME}: {e}"),
            PlantError::Device { plant, error } => write!(f, "{plant}: {error}"),
        }
    }
}

impl std::error::Error for PlantError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            PlantError::Sim(e) => Some(e),
            PlantError::Device { error, .. } => Some(error.as_ref()),
            _ => None,
        }
    }
}

/// A plant the host can drive, one sample at a time.
///
/// Implemented by [`Replay`] (a measured record), by `boucwen_sim::Bimorph` (the virtual
/// bimorph), and by the serial driver board in this crate's `transport` module. The trait
/// is kept small and object safe (`&mut dyn Plant` works) so a new plant needs only these
/// four methods.
///
/// ```
/// use boucwen_hal::plant::{Plant, Replay};
/// use boucwen_hal::record::Record;
/// let rec = Record::new("bench.csv", 0.0, 1e-3, vec![0.0, 1.0, 0.5], vec![0.0, 4.0, 3.0], None)?;
/// let mut replay = Replay::new(rec);
/// let plant: &mut dyn Plant = &mut replay;
/// let y = plant.run(&[0.0, 1.0, 0.5])?;
/// assert_eq!(y, [0.0, 4.0, 3.0]);
/// assert!(plant.step(0.0).is_err()); // past the end
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub trait Plant {
    /// Applies `u_v` (V) for one sample interval and returns the measured `y` (µm) at its
    /// end. A non-finite `u_v` is an error and leaves the plant as it was.
    fn step(&mut self, u_v: f64) -> Result<f64, PlantError>;

    /// The sample interval `Ts`, s.
    fn sample_interval(&self) -> f64;

    /// Back to the start: a replay rewinds, the virtual bimorph returns to rest with its
    /// noise reseeded, hardware returns the actuator to 0 V.
    fn reset(&mut self) -> Result<(), PlantError>;

    /// A short name for messages (the record's file, the serial port, "virtual bimorph").
    fn name(&self) -> &str;

    /// Steps through `u_v` and returns the measured `y`, stopping at the first error.
    fn run(&mut self, u_v: &[f64]) -> Result<Vec<f64>, PlantError> {
        u_v.iter().map(|&u| self.step(u)).collect()
    }
}

impl<P: Plant + ?Sized> Plant for Box<P> {
    fn step(&mut self, u_v: f64) -> Result<f64, PlantError> {
        (**self).step(u_v)
    }
    fn sample_interval(&self) -> f64 {
        (**self).sample_interval()
    }
    fn reset(&mut self) -> Result<(), PlantError> {
        (**self).reset()
    }
    fn name(&self) -> &str {
        (**self).name()
    }
}

/// Default [`Replay`] input tolerance, V (1 µV): a replay is meant to be driven with the
/// record's own `u`, which a record read from disk gives back exactly.
pub const REPLAY_TOLERANCE_V: f64 = 1e-6;

/// A measured [`Record`] played back as a plant.
///
/// `step(u)` returns the recorded `y[k]` and advances `k`. Past the last sample it returns
/// [`PlantError::EndOfRecord`] (and stays there until [`Plant::reset`]). Because the
/// recorded `y` answered only the recorded `u`, `step` checks by default that
/// `|u − u_rec[k]| ≤` [`REPLAY_TOLERANCE_V`] and returns [`PlantError::InputMismatch`]
/// otherwise, without advancing; [`Replay::with_tolerance`] changes the tolerance and
/// [`Replay::unchecked`] turns the check off (for tools that only need the measured
/// `y`, e.g. playing a record through a filter). A non-finite `u` is always rejected.
///
/// ```
/// use boucwen_hal::plant::{Plant, PlantError, Replay};
/// use boucwen_hal::record::Record;
/// let rec = Record::new("bench.csv", 0.0, 1e-3, vec![0.0, 1.0], vec![0.1, 4.0], None)?;
/// let mut replay = Replay::new(rec);
/// assert_eq!(replay.step(0.0)?, 0.1);
/// let e = replay.step(2.0).unwrap_err();
/// assert!(matches!(e, PlantError::InputMismatch { sample: 1, .. }));
/// assert_eq!(replay.step(replay.record().u[1])?, 4.0);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct Replay {
    record: Record,
    k: usize,
    tolerance_v: Option<f64>,
}

impl Replay {
    /// A replay of `record` from its first sample, checking the input within
    /// [`REPLAY_TOLERANCE_V`].
    pub fn new(record: Record) -> Self {
        Self { record, k: 0, tolerance_v: Some(REPLAY_TOLERANCE_V) }
    }

    /// The same replay, checking the input within `tolerance_v` (V, ≥ 0; a negative or
    /// NaN tolerance is taken as 0).
    pub fn with_tolerance(mut self, tolerance_v: f64) -> Self {
        self.tolerance_v = Some(if tolerance_v >= 0.0 { tolerance_v } else { 0.0 });
        self
    }

    /// The same replay, returning the recorded `y` whatever finite `u` is applied.
    pub fn unchecked(mut self) -> Self {
        self.tolerance_v = None;
        self
    }

    /// The record being replayed.
    pub fn record(&self) -> &Record {
        &self.record
    }

    /// The next sample to be returned, counting from 0.
    pub fn position(&self) -> usize {
        self.k
    }

    /// Samples left.
    pub fn remaining(&self) -> usize {
        self.record.len() - self.k
    }

    /// The record back, for reuse.
    pub fn into_record(self) -> Record {
        self.record
    }
}

impl Plant for Replay {
    fn step(&mut self, u_v: f64) -> Result<f64, PlantError> {
        let k = self.k;
        if !u_v.is_finite() {
            return Err(PlantError::NonFiniteInput { plant: self.record.source.clone(), sample: k });
        }
        if k >= self.record.len() {
            return Err(PlantError::EndOfRecord {
                source: self.record.source.clone(),
                samples: self.record.len(),
            });
        }
        let recorded_v = self.record.u[k];
        if let Some(tolerance_v) = self.tolerance_v {
            if (u_v - recorded_v).abs() > tolerance_v {
                return Err(PlantError::InputMismatch {
                    source: self.record.source.clone(),
                    sample: k,
                    applied_v: u_v,
                    recorded_v,
                    tolerance_v,
                });
            }
        }
        self.k += 1;
        Ok(self.record.y[k])
    }

    fn sample_interval(&self) -> f64 {
        self.record.ts
    }

    fn reset(&mut self) -> Result<(), PlantError> {
        self.k = 0;
        Ok(())
    }

    fn name(&self) -> &str {
        &self.record.source
    }
}

/// The [`Plant::name`] of the virtual bimorph.
pub const BIMORPH_NAME: &str = "virtual bimorph";

/// The virtual bimorph of `boucwen-sim`: each step integrates its physics over one
/// sample interval (see that crate's docs for the signal chain). A non-finite command is
/// [`PlantError::NonFiniteInput`], a diverged state [`PlantError::Sim`]; either way the
/// bimorph keeps its state from before the call. `reset` returns it to rest at time 0
/// with its noise reseeded, so a second run repeats the first exactly.
impl Plant for boucwen_sim::Bimorph {
    fn step(&mut self, u_v: f64) -> Result<f64, PlantError> {
        boucwen_sim::Bimorph::step(self, u_v).map_err(|e| match e {
            boucwen_sim::SimError::NonFiniteInput { sample } => PlantError::NonFiniteInput {
                plant: BIMORPH_NAME.to_owned(),
                sample: usize::try_from(sample).unwrap_or(usize::MAX),
            },
            other => PlantError::Sim(other),
        })
    }

    fn sample_interval(&self) -> f64 {
        self.ts_s()
    }

    fn reset(&mut self) -> Result<(), PlantError> {
        boucwen_sim::Bimorph::reset(self);
        Ok(())
    }

    fn name(&self) -> &str {
        BIMORPH_NAME
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec() -> Record {
        Record::new("bench.csv", 0.0, 1e-3, vec![0.0, 1.0, -1.0], vec![0.5, 2.0, -3.0], None).unwrap()
    }

    #[test]
    fn replay_returns_recorded_y_then_end_of_record() {
        let mut p = Replay::new(rec());
        assert_eq!(p.run(&[0.0, 1.0, -1.0]).unwrap(), [0.5, 2.0, -3.0]);
        assert_eq!(p.remaining(), 0);
        let e = p.step(0.0).unwrap_err();
        assert!(matches!(e, PlantError::EndOfRecord { samples: 3, .. }));
        assert_eq!(e.to_string(), "bench.csv: end of record: all 3 samples were replayed");
        // It stays at the end, and reset rewinds.
        assert!(p.step(0.0).is_err());
        p.reset().unwrap();
        assert_eq!((p.position(), p.step(0.0).unwrap()), (0, 0.5));
    }

    #[test]
    fn replay_checks_the_input() {
        let mut p = Replay::new(rec());
        p.step(0.0).unwrap();
        let e = p.step(1.1).unwrap_err();
        assert_eq!(
            e.to_string(),
            "bench.csv: sample 1: applied u = 1.1 V differs from the recorded 1 V by more than \
             0.000001 V (a replay answers only the recorded input)"
        );
        assert_eq!(p.position(), 1, "a rejected step does not advance");
        assert_eq!(p.step(1.0 + 0.5e-6).unwrap(), 2.0);

        let mut loose = Replay::new(rec()).with_tolerance(0.2);
        assert_eq!(loose.run(&[0.1, 1.1, -0.9]).unwrap(), [0.5, 2.0, -3.0]);
        let mut free = Replay::new(rec()).unchecked();
        assert_eq!(free.run(&[9.0, 9.0, 9.0]).unwrap(), [0.5, 2.0, -3.0]);
    }

    #[test]
    fn replay_rejects_non_finite_input_even_unchecked() {
        for mut p in [Replay::new(rec()), Replay::new(rec()).unchecked()] {
            let e = p.step(f64::NAN).unwrap_err();
            assert_eq!(e.to_string(), "bench.csv: sample 0: the command u is not finite");
            assert_eq!(p.position(), 0);
        }
    }

    /// The command of a short identification run: a 23 Hz sine of 1.5 V at 1 kHz.
    fn sine(n: usize, ts: f64) -> Vec<f64> {
        (0..n).map(|k| 1.5 * (2.0 * std::f64::consts::PI * 23.0 * k as f64 * ts).sin()).collect()
    }

    #[test]
    fn bimorph_through_the_trait_resets_to_a_repeatable_run() {
        let mut bimorph = boucwen_sim::Bimorph::new(&boucwen_sim::Scenario::default()).unwrap();
        let plant: &mut dyn Plant = &mut bimorph;
        assert_eq!(plant.name(), "virtual bimorph");
        let ts = plant.sample_interval();
        assert!(ts > 0.0);
        let u = sine(500, ts);
        let first = plant.run(&u).unwrap();
        let moved = first.iter().fold(0.0f64, |m, y| m.max(y.abs()));
        assert!(moved > 1.0, "the actuator moves under 1.5 V (peak {moved} µm)");
        plant.reset().unwrap();
        assert_eq!(plant.run(&u).unwrap(), first, "reset reseeds noise: same run");
    }

    #[test]
    fn bimorph_rejects_non_finite_input_and_keeps_its_state() {
        let scenario = boucwen_sim::Scenario::default();
        let mut a = boucwen_sim::Bimorph::new(&scenario).unwrap();
        let mut b = boucwen_sim::Bimorph::new(&scenario).unwrap();
        let u = sine(50, a.ts_s());
        let ya = Plant::run(&mut a, &u[..25]).unwrap();
        let e = Plant::step(&mut a, f64::INFINITY).unwrap_err();
        assert_eq!(e.to_string(), "virtual bimorph: sample 25: the command u is not finite");
        let ya_rest = Plant::run(&mut a, &u[25..]).unwrap();
        let yb = Plant::run(&mut b, &u).unwrap();
        assert_eq!([ya, ya_rest].concat(), yb, "the rejected sample left no trace");
    }

    #[test]
    fn simulated_record_written_read_and_replayed() {
        // The workflow of a user without hardware: run the virtual bimorph, save the
        // record, read it back, replay it with the input check on.
        let mut bimorph = boucwen_sim::Bimorph::new(&boucwen_sim::Scenario::default()).unwrap();
        let ts = Plant::sample_interval(&bimorph);
        let u = sine(2000, ts);
        let y = Plant::run(&mut bimorph, &u).unwrap();
        let rec = Record::new("sim", 0.0, ts, u.clone(), y.clone(), None).unwrap();
        rec.validate_for_fit(1000).unwrap();
        let dir = std::env::temp_dir().join(format!("boucwen-plant-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("sim.csv");
        rec.write(&path).unwrap();
        let back = Record::read(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let mut replay = Replay::new(back);
        assert_eq!(replay.sample_interval(), ts);
        assert_eq!(replay.run(&u).unwrap(), y);
        assert!(matches!(replay.step(0.0), Err(PlantError::EndOfRecord { samples: 2000, .. })));
    }

    #[test]
    fn object_safe_and_boxed() {
        let mut boxed: Box<dyn Plant> = Box::new(Replay::new(rec()));
        assert_eq!(boxed.name(), "bench.csv");
        assert_eq!(boxed.sample_interval(), 1e-3);
        assert_eq!(boxed.step(0.0).unwrap(), 0.5);
        fn drive(p: &mut dyn Plant) -> Result<f64, PlantError> {
            p.step(1.0)
        }
        assert_eq!(drive(&mut boxed).unwrap(), 2.0);
    }
}

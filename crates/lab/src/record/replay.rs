//! A measured record played back as a plant ([`Replay`]).

use super::Record;
use boucwen_core::Plant;
use std::fmt;

/// Why a [`Replay`] did not step.
#[derive(Clone, Debug, PartialEq)]
pub enum ReplayError {
    /// Stepped past its last sample.
    EndOfRecord {
        /// The record's source.
        source: String,
        /// Samples in the record (all of them were returned).
        samples: usize,
    },
    /// Given a command that differs from the recorded one: the recorded `y` did not
    /// respond to it, so going on would pair `u` and `y` that do not belong together.
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
    /// The command was NaN or infinite; the replay did not advance.
    NonFiniteInput {
        /// The record's source.
        source: String,
        /// The sample, counting from 0.
        sample: usize,
    },
}

impl fmt::Display for ReplayError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ReplayError::EndOfRecord { source, samples } => {
                write!(f, "{source}: end of record: all {samples} samples were replayed")
            }
            ReplayError::InputMismatch { source, sample, applied_v, recorded_v, tolerance_v } => write!(
                f,
                "{source}: sample {sample}: applied u = {applied_v} V differs from the recorded \
                 {recorded_v} V by more than {tolerance_v} V (a replay answers only the recorded input)"
            ),
            ReplayError::NonFiniteInput { source, sample } => {
                write!(f, "{source}: sample {sample}: the command u is not finite")
            }
        }
    }
}

impl std::error::Error for ReplayError {}

/// Default [`Replay`] input tolerance, V (1 µV): a replay is meant to be driven with the
/// record's own `u`, which a record read from disk gives back exactly.
pub const REPLAY_TOLERANCE_V: f64 = 1e-6;

/// A measured [`Record`] played back as a plant.
///
/// `step(u)` returns the recorded `y[k]` and advances `k`. Past the last sample it returns
/// [`ReplayError::EndOfRecord`] (and stays there until [`Plant::reset`]). Because the
/// recorded `y` answered only the recorded `u`, `step` checks by default that
/// `|u − u_rec[k]| ≤` [`REPLAY_TOLERANCE_V`] and returns [`ReplayError::InputMismatch`]
/// otherwise, without advancing; [`Replay::with_tolerance`] changes the tolerance and
/// [`Replay::unchecked`] turns the check off (for tools that only need the measured
/// `y`, e.g. playing a record through a filter). A non-finite `u` is always rejected.
///
/// ```
/// use boucwen_core::Plant;
/// use boucwen_lab::record::{Record, Replay, ReplayError};
/// let rec = Record::new("bench.csv", 0.0, 1e-3, vec![0.0, 1.0], vec![0.1, 4.0], None)?;
/// let mut replay = Replay::new(rec);
/// assert_eq!(replay.step(0.0)?, 0.1);
/// let e = replay.step(2.0).unwrap_err();
/// assert!(matches!(e, ReplayError::InputMismatch { sample: 1, .. }));
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

impl Plant<f64> for Replay {
    type Error = ReplayError;

    fn step(&mut self, u_v: f64) -> Result<f64, ReplayError> {
        let k = self.k;
        if !u_v.is_finite() {
            return Err(ReplayError::NonFiniteInput { source: self.record.source.clone(), sample: k });
        }
        if k >= self.record.len() {
            return Err(ReplayError::EndOfRecord {
                source: self.record.source.clone(),
                samples: self.record.len(),
            });
        }
        let recorded_v = self.record.u[k];
        if let Some(tolerance_v) = self.tolerance_v {
            if (u_v - recorded_v).abs() > tolerance_v {
                return Err(ReplayError::InputMismatch {
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

    fn sample_interval_s(&self) -> f64 {
        self.record.ts
    }

    fn reset(&mut self) -> Result<(), ReplayError> {
        self.k = 0;
        Ok(())
    }

    fn name(&self) -> &str {
        &self.record.source
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::Record;

    fn run(p: &mut Replay, u: &[f64]) -> Result<Vec<f64>, ReplayError> {
        let mut y = vec![0.0; u.len()];
        p.run_into(u, &mut y)?;
        Ok(y)
    }

    fn rec() -> Record {
        Record::new("bench.csv", 0.0, 1e-3, vec![0.0, 1.0, -1.0], vec![0.5, 2.0, -3.0], None).unwrap()
    }

    #[test]
    fn replay_returns_recorded_y_then_end_of_record() {
        let mut p = Replay::new(rec());
        assert_eq!(run(&mut p, &[0.0, 1.0, -1.0]).unwrap(), [0.5, 2.0, -3.0]);
        assert_eq!(p.remaining(), 0);
        let e = p.step(0.0).unwrap_err();
        assert!(matches!(e, ReplayError::EndOfRecord { samples: 3, .. }));
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
        assert_eq!(run(&mut loose, &[0.1, 1.1, -0.9]).unwrap(), [0.5, 2.0, -3.0]);
        let mut free = Replay::new(rec()).unchecked();
        assert_eq!(run(&mut free, &[9.0, 9.0, 9.0]).unwrap(), [0.5, 2.0, -3.0]);
    }

    #[test]
    fn replay_rejects_non_finite_input_even_unchecked() {
        for mut p in [Replay::new(rec()), Replay::new(rec()).unchecked()] {
            let e = p.step(f64::NAN).unwrap_err();
            assert_eq!(e.to_string(), "bench.csv: sample 0: the command u is not finite");
            assert_eq!(p.position(), 0);
        }
    }

    #[test]
    fn object_safe() {
        let mut replay = Replay::new(rec());
        let plant: &mut dyn Plant<f64, Error = ReplayError> = &mut replay;
        assert_eq!(plant.name(), "bench.csv");
        assert_eq!(plant.sample_interval_s(), 1e-3);
        assert_eq!(plant.step(0.0).unwrap(), 0.5);
    }
}

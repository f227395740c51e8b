//! The crate's errors: a bad scenario (naming the field and the allowed range), a bad
//! input sample, or a simulation that left the finite numbers.

use std::fmt;

/// What went wrong in the simulator.
///
/// ```
/// use boucwen_sim::SimError;
/// let e = SimError::Invalid {
///     field: "structure.modes[0].damping".into(),
///     requirement: "must be > 0".into(),
/// };
/// assert_eq!(e.to_string(), "invalid scenario: structure.modes[0].damping must be > 0");
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SimError {
    /// The scenario text is not valid TOML or does not match the schema (unknown key,
    /// wrong type); the message is the TOML parser's, with line and column.
    Parse(String),
    /// A scenario value is outside its allowed range.
    Invalid {
        /// The dotted path of the field, e.g. `structure.modes[0].damping`.
        field: String,
        /// What the field must satisfy, e.g. `must be > 0`.
        requirement: String,
    },
    /// A scenario file could not be read or written.
    Io {
        /// The file.
        path: String,
        /// The operating system's message.
        message: String,
    },
    /// The scenario could not be written as TOML (e.g. a seed above `i64::MAX`).
    Serialize(String),
    /// The command `u[sample]` was NaN or infinite; the plant's state was left untouched.
    NonFiniteInput {
        /// The index of the rejected sample (samples accepted so far).
        sample: u64,
    },
    /// The state left the finite numbers during `sample` (e.g. a softening stiffening
    /// polynomial let the structure escape); the state before that sample was kept.
    Diverged {
        /// The index of the sample that diverged.
        sample: u64,
    },
    /// A measurement helper got a record it cannot analyse; the text says why.
    Analysis(&'static str),
}

impl fmt::Display for SimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SimError::Parse(msg) => write!(f, "cannot parse scenario: {msg}"),
            SimError::Invalid { field, requirement } => {
                write!(f, "invalid scenario: {field} {requirement}")
            }
            SimError::Io { path, message } => write!(f, "{path}: {message}"),
            SimError::Serialize(msg) => write!(f, "cannot write scenario as TOML: {msg}"),
            SimError::NonFiniteInput { sample } => {
                write!(f, "input u[{sample}] is not finite (the plant state is unchanged)")
            }
            SimError::Diverged { sample } => write!(
                f,
                "the simulated state became non-finite at sample {sample} (check the \
                 stiffening polynomial and hysteresis parameters)"
            ),
            SimError::Analysis(why) => write!(f, "cannot analyse record: {why}"),
        }
    }
}

impl std::error::Error for SimError {}

//! The crate's error vocabulary: one small `Copy` enum that names what was wrong.

use core::fmt;

/// What went wrong, naming the offending parameter or signal.
///
/// ```
/// use boucwen_core::Error;
/// let e = Error::NonFinite("y");
/// assert_eq!(e.to_string(), "y is not finite");
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// A value that must be finite is NaN or infinite.
    NonFinite(&'static str),
    /// A parameter is outside its allowed range; the text says which and what range.
    OutOfRange(&'static str),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::NonFinite(what) => write!(f, "{what} is not finite"),
            Error::OutOfRange(what) => write!(f, "{what} is out of range"),
        }
    }
}

impl core::error::Error for Error {}

/// Checks that `x` is finite, naming it otherwise.
#[inline]
pub(crate) fn finite<T: crate::Real>(x: T, what: &'static str) -> Result<T, Error> {
    if x.is_finite() { Ok(x) } else { Err(Error::NonFinite(what)) }
}

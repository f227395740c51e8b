//! Sinusoids from a phase accumulator: the drive `u[k] = sin(2π f (k-1) Ts)` of eq. (13),
//! the reference `d[k] = α sin(2π f (k-1) Ts)` of eq. (24) and the harmonic regressors
//! `u_n1[k] = sin(2π n f (k-1) Ts)`, `u_n2[k] = cos(2π n f (k-1) Ts)` of eqs. (4)/(5).
//!
//! ## Phase
//! The phase is a 64-bit accumulator counting 2⁻⁶⁴ turn ([`Oscillator`]): it wraps
//! exactly, never loses precision however long the run, and the phase of the `n`-th
//! harmonic is the fundamental's phase times `n` (wrapping), so all harmonics stay exactly
//! coherent with the drive. The frequency resolution is `fs / 2⁶⁴`.
//!
//! ## sin/cos
//! [`sin_cos`] reduces the phase to the nearest quarter turn (integer arithmetic) and
//! evaluates Taylor polynomials on `|x| ≤ π/4` (error below 2·10⁻⁹ for `f32` before
//! rounding, below 10⁻¹⁸ for `f64`). It uses only `+`, `-`, `×` and an integer-to-float
//! conversion, all exactly specified by IEEE 754, so a Cortex-M4F and an x86-64 host get
//! the same bits. The time index counts from 0: sample `k` here is the paper's `k + 1`.

use crate::{Error, Real};

/// A numerically controlled oscillator: a phase increment per sample, in 2⁻⁶⁴ turn.
///
/// ```
/// use boucwen_core::signal::Oscillator;
/// let osc = Oscillator::new(250.0, 1e-3).unwrap(); // a quarter turn per sample
/// assert_eq!(osc.increment(), 1u64 << 62);
/// assert_eq!(osc.harmonic(3).increment(), 3u64 << 62);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Oscillator {
    increment: u64,
}

impl Oscillator {
    /// The oscillator for `freq_hz` at sample interval `ts_s`.
    ///
    /// `freq_hz` must be in `[0, 1/(2 ts_s)]` (zero up to Nyquist) and `ts_s > 0`.
    ///
    /// ```
    /// use boucwen_core::signal::Oscillator;
    /// let osc = Oscillator::new(250.0, 1e-3)?; // a quarter turn per sample
    /// assert_eq!(osc.increment(), 1u64 << 62);
    /// assert!(Oscillator::new(600.0, 1e-3).is_err()); // above Nyquist
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn new(freq_hz: f64, ts_s: f64) -> Result<Self, Error> {
        if !freq_hz.is_finite() {
            return Err(Error::NonFinite("frequency"));
        }
        if !ts_s.is_finite() {
            return Err(Error::NonFinite("sample interval"));
        }
        if ts_s <= 0.0 {
            return Err(Error::OutOfRange("sample interval (must be > 0)"));
        }
        let turns = freq_hz * ts_s;
        if !(0.0..=0.5).contains(&turns) {
            return Err(Error::OutOfRange("frequency (must be in 0..=Nyquist)"));
        }
        // turns * 2^64 <= 2^63: fits u64; round to nearest.
        let increment = (turns * 18_446_744_073_709_551_616.0 + 0.5) as u64;
        Ok(Self { increment })
    }

    /// An oscillator with a raw phase increment (2⁻⁶⁴ turn per sample).
    ///
    /// ```
    /// use boucwen_core::signal::Oscillator;
    /// assert_eq!(Oscillator::from_increment(1 << 62), Oscillator::new(250.0, 1e-3)?);
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub const fn from_increment(increment: u64) -> Self {
        Self { increment }
    }

    /// The phase increment per sample, in 2⁻⁶⁴ turn.
    pub const fn increment(&self) -> u64 {
        self.increment
    }

    /// The oscillator at `n` times this frequency (exactly coherent with it).
    ///
    /// ```
    /// use boucwen_core::signal::Oscillator;
    /// let osc = Oscillator::new(23.0, 1e-3)?;
    /// assert_eq!(osc.harmonic(3).phase_at(7), osc.phase_at(21));
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub const fn harmonic(&self, n: u32) -> Self {
        Self { increment: self.increment.wrapping_mul(n as u64) }
    }

    /// The frequency in Hz at sample interval `ts_s`.
    pub fn freq_hz(&self, ts_s: f64) -> f64 {
        self.increment as f64 / 18_446_744_073_709_551_616.0 / ts_s
    }

    /// The phase of sample `k` (counting from 0), in 2⁻⁶⁴ turn.
    pub const fn phase_at(&self, k: u64) -> u64 {
        self.increment.wrapping_mul(k)
    }
}

/// `(sin θ, cos θ)` for a phase `θ` given in 2⁻⁶⁴ turn.
///
/// ```
/// use boucwen_core::signal::sin_cos;
/// let (s, c) = sin_cos::<f64>(1u64 << 61); // 45 degrees
/// assert!((s - core::f64::consts::FRAC_1_SQRT_2).abs() < 1e-15);
/// assert!((c - core::f64::consts::FRAC_1_SQRT_2).abs() < 1e-15);
/// ```
#[inline]
pub fn sin_cos<T: Real>(phase: u64) -> (T, T) {
    // Nearest quarter turn q, remainder r in [-1/8, 1/8) turn.
    let q = phase.wrapping_add(1 << 61) >> 62;
    let r = phase.wrapping_sub(q << 62) as i64;
    let x = T::phase_offset_rad(r);
    let x2 = x * x;
    let s = x * horner(x2, T::SIN_COEFFS);
    let c = horner(x2, T::COS_COEFFS);
    match q {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

#[inline(always)]
fn horner<T: Real>(x: T, coeffs: &[T]) -> T {
    let mut acc = T::zero();
    for &c in coeffs.iter().rev() {
        acc = acc * x + c;
    }
    acc
}

/// A sinusoid `amplitude · sin(2π f k Ts)`, `k = 0, 1, …`: the drive (13) with amplitude 1
/// or the reference (24) with amplitude `α`.
///
/// ```
/// use boucwen_core::signal::{Oscillator, Sine};
/// let mut d = Sine::new(2.0_f64, Oscillator::new(250.0, 1e-3).unwrap());
/// let v: Vec<f64> = (0..4).map(|_| d.next_sample()).collect();
/// assert!(v[0].abs() < 1e-15 && (v[1] - 2.0).abs() < 1e-15 && v[2].abs() < 1e-15);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Sine<T> {
    /// Peak amplitude.
    pub amplitude: T,
    osc: Oscillator,
    phase: u64,
}

impl<T: Real> Sine<T> {
    /// A sinusoid starting at phase 0.
    ///
    /// ```
    /// use boucwen_core::signal::{Oscillator, Sine};
    /// let mut s = Sine::new(3.0_f64, Oscillator::new(250.0, 1e-3)?);
    /// assert_eq!(s.next_sample(), 0.0);
    /// assert!((s.next_sample() - 3.0).abs() < 1e-15);
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn new(amplitude: T, osc: Oscillator) -> Self {
        Self { amplitude, osc, phase: 0 }
    }

    /// The current sample; advances by one sample.
    #[inline]
    pub fn next_sample(&mut self) -> T {
        let (s, _) = sin_cos::<T>(self.phase);
        self.phase = self.phase.wrapping_add(self.osc.increment());
        self.amplitude * s
    }

    /// The phase of the next sample, in 2⁻⁶⁴ turn.
    pub fn phase(&self) -> u64 {
        self.phase
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_cos_matches_libm_over_a_dense_grid() {
        // Independent reference: the platform's sin/cos of the exact angle.
        let mut worst64: f64 = 0.0;
        let mut worst32: f64 = 0.0;
        for i in 0..100_003u64 {
            let phase = i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let angle = phase as f64 / 18_446_744_073_709_551_616.0 * core::f64::consts::TAU;
            let (s, c) = sin_cos::<f64>(phase);
            worst64 = worst64.max((s - angle.sin()).abs()).max((c - angle.cos()).abs());
            let (s, c) = sin_cos::<f32>(phase);
            worst32 = worst32.max((s as f64 - angle.sin()).abs()).max((c as f64 - angle.cos()).abs());
        }
        assert!(worst64 < 2e-15, "f64 error {worst64}");
        assert!(worst32 < 2e-7, "f32 error {worst32}");
    }

    #[test]
    fn quadrant_boundaries_are_exact() {
        assert_eq!(sin_cos::<f64>(0), (0.0, 1.0));
        assert_eq!(sin_cos::<f64>(1 << 62), (1.0, -0.0));
        assert_eq!(sin_cos::<f64>(2 << 62), (-0.0, -1.0));
        assert_eq!(sin_cos::<f64>(3 << 62), (-1.0, 0.0));
    }

    #[test]
    fn oscillator_rejects_bad_arguments() {
        assert_eq!(Oscillator::new(f64::NAN, 1e-3), Err(Error::NonFinite("frequency")));
        assert!(Oscillator::new(10.0, 0.0).is_err());
        assert!(Oscillator::new(600.0, 1e-3).is_err());
        assert!(Oscillator::new(-1.0, 1e-3).is_err());
        assert!(Oscillator::new(500.0, 1e-3).is_ok());
    }

    #[test]
    fn long_runs_keep_phase_exact() {
        // 23 Hz at 1 kHz for 10^6 samples: the accumulator's phase after k steps equals
        // k * increment (mod 2^64), so sample 10^6 is computed as accurately as sample 0.
        let osc = Oscillator::new(23.0, 1e-3).unwrap();
        let mut d = Sine::new(1.0f64, osc);
        for _ in 0..1_000_000 {
            d.next_sample();
        }
        assert_eq!(d.phase(), osc.phase_at(1_000_000));
        let want = (core::f64::consts::TAU * 23.0 * 1000.0).sin(); // = sin(2π·23000) = 0
        let (s, _) = sin_cos::<f64>(d.phase());
        assert!((s - want).abs() < 1e-9, "{s} vs {want}");
        assert!((osc.freq_hz(1e-3) - 23.0).abs() < 1e-12);
    }
}

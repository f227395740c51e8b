//! The scalar type: one generic implementation serves `f32` and `f64`.
//!
//! [`Real`] is nalgebra's `RealField` (so fixed-size matrices work) plus what the
//! per-sample code needs in a form that is bit-identical on every target: literal
//! conversion and the coefficients of the sin/cos polynomials used by
//! [`crate::signal::sin_cos`]. No function of the platform's libm is called per sample,
//! which is what lets the firmware reproduce the host's `f32` results bit for bit.

use nalgebra::RealField;

/// A floating-point scalar: `f32` or `f64`.
pub trait Real:
    RealField + Copy + Default + core::fmt::Debug + core::fmt::Display + Send + Sync + 'static
{
    /// Taylor coefficients of `sin(x)/x` in powers of `x²`, enough for full precision on
    /// `|x| ≤ π/4`.
    const SIN_COEFFS: &'static [Self];
    /// Taylor coefficients of `cos(x)` in powers of `x²`, on `|x| ≤ π/4`.
    const COS_COEFFS: &'static [Self];
    /// The smallest positive normal value.
    const MIN_POSITIVE: Self;

    /// Converts an `f64` constant (rounding to nearest for `f32`).
    fn lit(x: f64) -> Self;
    /// Widens to `f64` (exact for both types).
    fn to_f64(self) -> f64;
    /// Converts a signed phase offset in units of 2⁻⁶⁴ turn into radians.
    fn phase_offset_rad(offset: i64) -> Self;
}

impl Real for f64 {
    const SIN_COEFFS: &'static [f64] = &[
        1.0,
        -1.0 / 6.0,
        1.0 / 120.0,
        -1.0 / 5040.0,
        1.0 / 362_880.0,
        -1.0 / 39_916_800.0,
        1.0 / 6_227_020_800.0,
        -1.0 / 1_307_674_368_000.0,
        1.0 / 355_687_428_096_000.0,
    ];
    const COS_COEFFS: &'static [f64] = &[
        1.0,
        -1.0 / 2.0,
        1.0 / 24.0,
        -1.0 / 720.0,
        1.0 / 40_320.0,
        -1.0 / 3_628_800.0,
        1.0 / 479_001_600.0,
        -1.0 / 87_178_291_200.0,
        1.0 / 20_922_789_888_000.0,
        -1.0 / 6_402_373_705_728_000.0,
    ];
    const MIN_POSITIVE: f64 = f64::MIN_POSITIVE;

    #[inline(always)]
    fn lit(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn phase_offset_rad(offset: i64) -> Self {
        // 2π / 2^64
        offset as f64 * 3.406_121_580_086_554_5e-19
    }
}

impl Real for f32 {
    const SIN_COEFFS: &'static [f32] = &[1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362_880.0];
    const COS_COEFFS: &'static [f32] =
        &[1.0, -1.0 / 2.0, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40_320.0, -1.0 / 3_628_800.0];
    const MIN_POSITIVE: f32 = f32::MIN_POSITIVE;

    #[inline(always)]
    fn lit(x: f64) -> Self {
        x as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn phase_offset_rad(offset: i64) -> Self {
        // Keep the top 32 bits: |offset| < 2^61, so the shifted value fits an i32, and
        // i32 -> f32 is one instruction on a Cortex-M4F. 2π / 2^32:
        ((offset >> 32) as i32) as f32 * 1.462_918_1e-9
    }
}

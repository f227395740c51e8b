//! # boucwen-core
//!
//! The `no_std`, allocation-free core of boucwen: the Bouc–Wen model family of
//! Fujii, Tatebatake, Morita and Shiinoki, "A Bouc–Wen Model-Based Compensation of the
//! Frequency-Dependent Hysteresis of a Piezoelectric Actuator Exhibiting Odd Harmonic
//! Oscillation" (Actuators, 2018), its recursive least-squares identification, and the
//! direct-inverse compensator with online odd-harmonic cancellation. The same code runs
//! on a workstation and on a Cortex-M4F; everything is generic over [`Real`] (`f32`,
//! `f64`) and sized by const generics.
//!
//! | module | paper | what it holds |
//! |---|---|---|
//! | [`model`] | eqs. (2), (3), (6), (7) | classic, extended and enhanced models: parameters apart from state, `step(u) -> y` |
//! | [`rls`] | section 2.3 | recursive least squares in Bierman's U-D form, forgetting, windup guard |
//! | [`ident`] | eqs. (8)–(12), section 3 | the regressors: the paper's running sums, or the exact prediction-error gradient |
//! | [`compensator`] | eqs. (16)–(23) | direct inverse `u_f`, harmonic cancellation, output saturation |
//! | [`signal`] | eqs. (4), (5), (13), (24) | phase accumulator and sin/cos that are bit-identical on every target |
//! | [`controllers`] | (peers) | open loop, PI, Li et al.'s repetitive controller, their tuning rule, and the [`Controller`] trait |
//! | [`plant`] | | the [`Plant`] trait: drive in, measurement out |
//!
//! ## Where the code departs from the paper, and why
//!
//! 1. **One form of the structural IIR.** Eq. (3) writes
//!    `y[k] = y[k-1] + c1·y[k-2] + c2·y[k-3] + A1·u[k] - h[k]` (coefficient of `y[k-1]`
//!    fixed to 1), while the regression (9)–(12) estimates free `a1, a2` on `y[k-1], y[k-2]`.
//!    The code uses one form with a free AR part of order `P` (a const generic):
//!    `y[k] = Σ_{j=1..P} a_j·y[k-j] + A1·u[k] - h[k] (+ Σ_n y_n[k])`.
//!    `P = 2` is the regression's form; `P = 3, a = [1, c1, c2]` is eq. (3) exactly
//!    ([`model::ExtendedParams::from_eq3`]). The compensator (eqs. 15–17) is derived for the
//!    same general form, so it reduces to the paper's when `a = [1, c1, c2]`.
//! 2. **The harmonic branch** of eqs. (6)/(7) has the same mismatch: eq. (6) fixes the
//!    coefficient of `y3[k-1]` to 1 and puts `c3, c4` on `y3[k-2], y3[k-3]`; the regression
//!    (10) puts free `a3, a4` on `y3[k-2], y3[k-3]` and nothing on `y3[k-1]`. The code uses a
//!    free AR part of order `Q` on `y_n[k-1..Q]`. The branch is driven only by sin/cos at
//!    `n·f`, so in steady state its AR part is collinear with `α_s, α_c` and cannot be
//!    identified from periodic data; it shapes only the branch's start-up. `Q = 2` gives the
//!    paper's parameter count (11 for one branch); `Q = 0` is the identifiable choice and the
//!    one the host tools use. Branches of any order `n ≥ 2` (odd as in the paper, or even)
//!    and any number `M` of branches are allowed.
//! 3. **Identifiability (section 2.3).** With `u[0] = 0` the regressor `-Σ(u[i]-u[i-1])`
//!    equals `-u[k]`, exactly collinear with the `A1` regressor `u[k]`: the regression only
//!    sees `A1 - A`. In the paper's RLS (P(0) = I, no forgetting) the sum `A1 + A` therefore
//!    never moves from its initial value 0.015, and with forgetting the covariance along that
//!    direction winds up. [`ident::Mode::Paper`] reproduces this as published (and the guard in
//!    [`rls`] bounds the windup); [`ident::Mode::Gradient`] uses the exact gradient of the
//!    prediction, whose `A` component `∂h/∂A` follows the hysteresis saturation and is not
//!    collinear with `u[k]`, so `A` becomes identifiable. The paper's running sums are that
//!    gradient with the sensitivity feedback of `h` dropped (see [`ident`]).
//! 4. **Harmonic cancellation sign (eqs. 22/23).** The paper picks `e = d - y` or `y - d`
//!    from a table (harmonic below or above about 66 Hz). The code adapts the cancellation
//!    weights on a regressor rotated by the identified model's frequency response at `n·f`
//!    (a filtered-regressor RLS), which fixes both sign and phase; the table survives as
//!    [`compensator::PhaseRule::Table`], which rotates by 0 or π only.
//! 5. **Time index.** The paper counts `k = 1, 2, …` and writes `sin(2π f (k-1) Ts)`; the code
//!    counts from 0, so its sample `k` is the paper's `k + 1` and the phase of sample `k` is
//!    `2π f k Ts`.
#![cfg_attr(not(any(test, feature = "std")), no_std)]

pub mod compensator;
pub mod controllers;
pub mod error;
pub mod ident;
pub mod model;
pub mod plant;
pub mod real;
pub mod rls;
pub mod signal;

#[cfg(test)]
pub(crate) mod testing;

pub use controllers::Controller;
pub use error::Error;
pub use plant::Plant;
pub use real::Real;

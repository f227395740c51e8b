//! # boucwen-sim
//!
//! A virtual thin bimorph piezoelectric actuator (the FDK PZBA-00030 class of Fujii et al.,
//! Actuators 2018) for users without an actuator on the bench, for the project's tests and
//! for `boucwen sweep`. It is a physical simulation in continuous time, not one of the
//! core's discrete models: the hysteresis, the phase lag, the polarity inversion past the
//! resonance and the odd harmonic oscillation (OHO) all come out of the physics below.
//!
//! ```
//! use boucwen_sim::{Bimorph, Scenario};
//! let mut plant = Bimorph::new(&Scenario::default())?;
//! let y_um = plant.step(0.5)?; // hold 0.5 V for one sample interval, read the sensor
//! # let _ = y_um;
//! # Ok::<(), boucwen_sim::SimError>(())
//! ```
//!
//! ## Signal chain
//! Every stage is a [`Scenario`] parameter (TOML, see [`scenario`]).
//!
//! 1. **DAC** ([`scenario::Dac`]): `u[k]` (V) saturates at `±range_v`, is quantised to
//!    `bits` over `±range_v` (code `round(u/lsb)`, `lsb = range_v/2^(bits−1)`), and is held
//!    over the interval `[kTs, (k+1)Ts)` (zero-order hold). A non-finite `u[k]` is
//!    rejected with [`SimError::NonFiniteInput`], leaving the plant untouched.
//! 2. **Transport delay** ([`scenario::Delay`]): the held command reaches the driver
//!    `transport_s` later, rounded to the nearest integration step `Ts/substeps`
//!    ([`Bimorph::effective_delay_s`]).
//! 3. **Driver amplifier** ([`scenario::Driver`]): first order with time constant
//!    `τ = 1/(2π·bandwidth_hz)` toward the target `clamp(gain·u_cmd, ±limit_v)`:
//!    `τ·v̇ = clamp(gain·u_cmd, ±limit_v) − v`. Its output `v(t)` is continuous, so `v̇` exists.
//! 4. **Hysteresis** ([`scenario::Hysteresis`]) on the actuator voltage, the continuous
//!    asymmetric Bouc–Wen equation
//!    ```text
//!    ḣ = A·v̇ + A0·|v̇| − γ·|h|·v̇ − β·|v̇|·h          (h in V, γ and β in 1/V)
//!    ```
//!    `A0 ≠ 0` makes the loop asymmetric and off-centre. The equation is rate-independent:
//!    along a monotone voltage path (`s = sgn v̇`, `σ = sgn h` fixed) it is linear in `v`,
//!    `dh/dv = (A + A0·s) − (γ·σ + β·s)·h`, so it is solved in closed form along the
//!    driver's output (which is monotone within an integration step), including the one
//!    possible zero crossing of `h`; the hysteresis adds no integration error.
//! 5. **Creep** ([`scenario::Creep`]): parallel relaxations
//!    `ċ_j = (a_j·(v − h) − c_j)/τ_j` (V). The drive of the structure, in µm of free
//!    deflection, is `w = kp·(v − h + Σ c_j)`.
//! 6. **Structure** ([`scenario::Structure`]): bending modes
//!    ```text
//!    q̈_i + 2ζ_i ω_i q̇_i·(1 + D_i(|q̇_i|)) + ω_i²·(q_i + N_i(q_i)) = ω_i²·φ_i·w,
//!    N_i(q) = q_ref · Σ_p c_{i,p}·(q/q_ref)^p          (stiffening, q in µm)
//!    D_i(s) = Σ_p d_{i,p}·(s/v_ref)^p                   (nonlinear damping, s in µm/s)
//!    ```
//!    `φ_i` is the mode's participation (static deflection per µm of `w`); `c_p` is the
//!    fraction the power-`p` term adds to the linear restoring force at `q = q_ref`, `d_p`
//!    the fraction added to the linear damping at `|q̇| = v_ref`. Odd powers of `N` are
//!    the geometric stiffening of a cantilever at large deflection; even powers model an
//!    asymmetric bimorph. The true deflection is `y = Σ_i q_i`.
//! 7. **Sensor** ([`scenario::Sensor`]): sampled at the end of each interval, so `y[k]`
//!    responds to `u[k]` held during interval `k` (the direct feed-through of the core's
//!    models): `y[k] = Q(y((k+1)Ts) + offset + drift·(k+1)Ts + walk[k] + σ·n[k])`, with `n`
//!    white standard normal, `walk` a random walk of intensity `random_walk_um_per_sqrt_s`
//!    and `Q` rounding to `resolution_um`. Noise and walk come from a seeded
//!    xoshiro256++ generator (Box–Muller normals): the same seed gives the same record.
//!
//! ## Integration
//! Fixed-step classical Runge–Kutta (RK4), `substeps` steps per sample interval (default
//! 8, i.e. 0.125 ms at `Ts` = 1 ms). Within one step the driver target is constant, so
//! `v(t)` is evaluated in closed form and `h(t)` exactly along it; RK4 integrates only the
//! smooth creep and modal states, with the drive known at the stages. A scenario is
//! rejected if a mode's `ω·Ts/substeps` exceeds 1.
//!
//! ## Where the odd harmonics come from
//! The Bouc–Wen loop has odd (and, through `A0`, even) harmonics of its own; the
//! stiffening polynomial adds superharmonic forcing (`q³` mainly at 3f, `q⁵` at 5f and
//! 3f). Whichever lands near the first bending resonance (third harmonic of 23 Hz, fifth of
//! 14 Hz) is amplified by it. The default scenario takes most of the OHO from the
//! stiffening, because a harmonic made only by hysteresis through one resonance is inside
//! the family of the core's extended model and would be fitted away. Its design, and what it
//! measures, are written out in `crates/sim/scenarios/paper.toml`; the table of harmonics
//! of any scenario is printed by
//! `cargo run --release -p boucwen-sim --example harmonics -- [scenario.toml] [volts] [Hz…]`.
//!
//! The same stiffening makes the plant amplitude dependent, as a real hardening beam is:
//! at larger drives the resonance moves up (the 23 Hz third harmonic peaks at 28–30 Hz for
//! 1.5–2 V), and near half the resonance a principal parametric resonance would excite a
//! large second harmonic were it not for the default nonlinear damping.
//!
//! ## Modules
//! | module | what it holds |
//! |---|---|
//! | [`scenario`] | the parameters, TOML reading, validation, switches for tests |
//! | [`bimorph`] | the plant: [`Bimorph::step`], [`Bimorph::step_detail`], [`Bimorph::run`] |
//! | [`measure`] | least-squares harmonic fit of a record (amplitude and phase per order) |
//! | [`oscillator`] | the Bouc–Wen oscillator of the Noël–Schoukens benchmark, its integrator, decimation and inputs |

pub mod bimorph;
mod error;
mod hysteresis;
pub mod measure;
pub mod oscillator;
mod rng;
pub mod scenario;

pub use bimorph::{BIMORPH_NAME, Bimorph, Detail};
pub use error::SimError;
pub use scenario::Scenario;

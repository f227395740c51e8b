//! The simulated actuator: one [`Bimorph::step`] per sample interval.
//!
//! See the crate docs for the equations. Inside one sample interval `k`:
//! 1. the DAC saturates and quantises `u[k]`; the transport delay picks the command that
//!    reaches the driver at each integration step;
//! 2. for each of the `substeps` RK4 steps of length `Δt = ts_s/substeps`, the driver's
//!    target `v_t = clamp(gain·u_cmd, ±limit_v)` is constant, so its output
//!    `v(t) = v_t + (v0 − v_t)·e^{−t/τ}` is evaluated exactly at the RK4 stages
//!    (`0, Δt/2, Δt`), and the hysteresis `h(t)` exactly along it (closed form, see the
//!    crate docs); RK4 then advances the creep terms and the modes with the drive
//!    `w(t) = kp·(v − h + Σ c_j)` known at the stages;
//! 3. the sensor reads `Σ q_i` at the end of the interval, adds offset, drift and noise,
//!    and quantises.

use crate::SimError;
use crate::hysteresis::BoucWen;
use crate::rng::Rng;
use crate::scenario::{MAX_CREEP_TERMS, MAX_DAMPING_POWER, MAX_MODES, MAX_STIFFENING_POWER, Scenario};

/// Internal signals of one sample, for plots and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Detail {
    /// The sensor reading `y[k]`, µm (what [`Bimorph::step`] returns).
    pub y_um: f64,
    /// The true deflection `Σ q_i` at the end of the interval, µm (no sensor effects).
    pub y_true_um: f64,
    /// The DAC output held during the interval (after saturation and quantisation), V.
    pub u_dac_v: f64,
    /// The driver output `v` at the end of the interval, V.
    pub v_v: f64,
    /// The hysteresis state `h` at the end of the interval, V.
    pub h_v: f64,
    /// The sum of the creep states `Σ c_j` at the end of the interval, V.
    pub creep_v: f64,
    /// The modal coordinates `q_i` at the end of the interval, µm (unused modes 0).
    pub q_um: [f64; MAX_MODES],
}

/// Number of continuous states integrated by RK4: creep terms, then the modal
/// coordinates `q_i` from [`Q0`], then the modal velocities `q̇_i` from [`R0`].
const NX: usize = MAX_CREEP_TERMS + 2 * MAX_MODES;
const Q0: usize = MAX_CREEP_TERMS;
const R0: usize = MAX_CREEP_TERMS + MAX_MODES;

/// All running state: what [`Bimorph::reset`] restores.
#[derive(Clone, Copy, Debug)]
struct State {
    v: f64,
    h: f64,
    x: [f64; NX],
}

impl Default for State {
    fn default() -> Self {
        Self { v: 0.0, h: 0.0, x: [0.0; NX] }
    }
}

// The Estrin evaluations below are written out for these sizes.
const _: () = assert!(MAX_STIFFENING_POWER == 9 && MAX_DAMPING_POWER == 4);

/// One mode's constants, precomputed.
#[derive(Clone, Copy, Debug, Default)]
struct ModeK {
    omega2: f64,
    two_zeta_omega: f64,
    /// `ω²·φ·kp`: force per volt of `v − h + Σ c_j`.
    force_per_v: f64,
    /// `k_p = c_p / q_ref^{p−1}` at index `p − 2`, so `N(q) = Σ k_p·q^p`.
    poly: [f64; MAX_STIFFENING_POWER as usize - 1],
    /// Highest power with a nonzero coefficient (0 if linear).
    top_power: usize,
    /// `d_p / v_ref^p` at index `p − 1`, so `D(s) = Σ d_p·s^p`.
    damp: [f64; MAX_DAMPING_POWER as usize],
    /// Highest damping power with a nonzero coefficient (0 if linear).
    top_damp: usize,
}

impl ModeK {
    /// `N(q) = q²·Σ_{p=2..9} k_p·q^{p−2}`, by Estrin's scheme (short dependency chains:
    /// this runs four times per RK4 step).
    #[inline(always)]
    fn stiffening(&self, q: f64) -> f64 {
        if self.top_power < 2 {
            return 0.0;
        }
        let k = &self.poly;
        let q2 = q * q;
        let q4 = q2 * q2;
        let lo = (k[0] + k[1] * q) + q2 * (k[2] + k[3] * q);
        let hi = (k[4] + k[5] * q) + q2 * (k[6] + k[7] * q);
        q2 * (lo + q4 * hi)
    }

    /// `1 + D(|r|)`, `D(s) = s·(d_1 + d_2·s + d_3·s² + d_4·s³)`, by Estrin's scheme.
    #[inline(always)]
    fn damping_factor(&self, r: f64) -> f64 {
        if self.top_damp == 0 {
            return 1.0;
        }
        let d = &self.damp;
        let s = r.abs();
        let s2 = s * s;
        1.0 + s * ((d[0] + d[1] * s) + s2 * (d[2] + d[3] * s))
    }
}

/// The virtual bimorph: a scenario's physics, stepped one sample at a time.
///
/// ```
/// use boucwen_sim::{Bimorph, Scenario};
/// let mut plant = Bimorph::new(&Scenario::default()).unwrap();
/// let y: Vec<f64> = (0..2000)
///     .map(|k| plant.step((std::f64::consts::TAU * 1.0 * k as f64 * 1e-3).sin()).unwrap())
///     .collect();
/// let peak = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
/// assert!(peak > 5.0 && peak < 60.0, "peak {peak} µm");
/// ```
#[derive(Clone, Debug)]
pub struct Bimorph {
    scenario: Scenario,
    ts: f64,
    substeps: usize,
    hsub: f64,
    // DAC
    range_v: f64,
    lsb_v: f64,
    code_min: f64,
    code_max: f64,
    // delay: D = delay_samples·substeps + delay_rem integration steps
    delay_samples: usize,
    delay_rem: usize,
    // driver
    gain: f64,
    limit_v: f64,
    /// `1 − e^{−h/(2τ)}`: fraction of the remaining step the driver covers in half a step.
    drive_half: f64,
    bw: BoucWen,
    creep_gain: [f64; MAX_CREEP_TERMS],
    creep_inv_tau: [f64; MAX_CREEP_TERMS],
    modes: [ModeK; MAX_MODES],
    n_modes: usize,
    // sensor
    noise_um: f64,
    resolution_um: f64,
    offset_um: f64,
    drift_um_per_s: f64,
    walk_step_um: f64,
    // running state
    state: State,
    history: Vec<f64>,
    pos: usize,
    k: u64,
    walk_um: f64,
    noise_rng: Rng,
    walk_rng: Rng,
}

const NOISE_STREAM: u64 = 1;
const WALK_STREAM: u64 = 2;

impl Bimorph {
    /// A plant at rest (`u = v = h = 0`, modes at rest) for a validated scenario.
    pub fn new(scenario: &Scenario) -> Result<Self, SimError> {
        scenario.validate()?;
        let s = scenario;
        let ts = s.sampling.ts_s;
        let substeps = s.sampling.substeps as usize;
        let hsub = ts / substeps as f64;

        let (lsb_v, code_min, code_max) = if s.dac.bits == 0 {
            (0.0, 0.0, 0.0)
        } else {
            let half = 2f64.powi(s.dac.bits as i32 - 1);
            (s.dac.range_v / half, -half, half - 1.0)
        };

        let delay_steps = (s.delay.transport_s / hsub).round() as usize;
        let delay_samples = delay_steps / substeps;
        let delay_rem = delay_steps % substeps;

        let tau = 1.0 / (core::f64::consts::TAU * s.driver.bandwidth_hz);
        let drive_half = -(-0.5 * hsub / tau).exp_m1();

        let mut creep_gain = [0.0; MAX_CREEP_TERMS];
        let mut creep_inv_tau = [0.0; MAX_CREEP_TERMS];
        for (j, t) in s.creep.terms.iter().enumerate() {
            creep_gain[j] = t.amplitude;
            creep_inv_tau[j] = 1.0 / t.tau_s;
        }

        let kp = s.hysteresis.kp_um_per_v;
        let q_ref = s.structure.q_ref_um;
        let v_ref = s.structure.v_ref_um_per_s;
        let mut modes = [ModeK::default(); MAX_MODES];
        for (i, m) in s.structure.modes.iter().enumerate() {
            let omega = core::f64::consts::TAU * m.freq_hz;
            let mk = &mut modes[i];
            mk.omega2 = omega * omega;
            mk.two_zeta_omega = 2.0 * m.damping * omega;
            mk.force_per_v = omega * omega * m.participation * kp;
            for t in &m.stiffening {
                let p = t.power as usize;
                mk.poly[p - 2] = t.coeff / q_ref.powi(t.power as i32 - 1);
                if t.coeff != 0.0 && p > mk.top_power {
                    mk.top_power = p;
                }
            }
            for t in &m.damping_nl {
                let p = t.power as usize;
                mk.damp[p - 1] = t.coeff / v_ref.powi(t.power as i32);
                if t.coeff != 0.0 && p > mk.top_damp {
                    mk.top_damp = p;
                }
            }
        }

        Ok(Self {
            scenario: scenario.clone(),
            ts,
            substeps,
            hsub,
            range_v: s.dac.range_v,
            lsb_v,
            code_min,
            code_max,
            delay_samples,
            delay_rem,
            gain: s.driver.gain,
            limit_v: s.driver.limit_v,
            drive_half,
            bw: BoucWen::new(&s.hysteresis),
            creep_gain,
            creep_inv_tau,
            modes,
            n_modes: s.structure.modes.len(),
            noise_um: s.sensor.noise_um,
            resolution_um: s.sensor.resolution_um,
            offset_um: s.sensor.offset_um,
            drift_um_per_s: s.sensor.drift_um_per_s,
            walk_step_um: s.sensor.random_walk_um_per_sqrt_s * ts.sqrt(),
            state: State::default(),
            history: vec![0.0; delay_samples + 2],
            pos: 0,
            k: 0,
            walk_um: 0.0,
            noise_rng: Rng::new(s.seed, NOISE_STREAM),
            walk_rng: Rng::new(s.seed, WALK_STREAM),
        })
    }

    /// Back to rest at time 0, with the random sources reseeded (the next run repeats
    /// the first one exactly).
    pub fn reset(&mut self) {
        self.state = State::default();
        self.history.iter_mut().for_each(|x| *x = 0.0);
        self.pos = 0;
        self.k = 0;
        self.walk_um = 0.0;
        self.noise_rng = Rng::new(self.scenario.seed, NOISE_STREAM);
        self.walk_rng = Rng::new(self.scenario.seed, WALK_STREAM);
    }

    /// The sample interval `Ts`, s.
    pub fn ts_s(&self) -> f64 {
        self.ts
    }

    /// The scenario this plant was built from.
    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    /// Samples accepted since the start (or the last reset).
    pub fn samples(&self) -> u64 {
        self.k
    }

    /// The transport delay actually simulated (rounded to the integration step), s.
    pub fn effective_delay_s(&self) -> f64 {
        (self.delay_samples * self.substeps + self.delay_rem) as f64 * self.hsub
    }

    /// The DAC: saturation at `±range_v`, then quantisation to the nearest code.
    pub fn dac(&self, u_v: f64) -> f64 {
        let u = u_v.clamp(-self.range_v, self.range_v);
        if self.lsb_v == 0.0 {
            u
        } else {
            (u / self.lsb_v).round().clamp(self.code_min, self.code_max) * self.lsb_v
        }
    }

    /// One sample: holds `u_v` (DAC volts) over the interval and returns the sensor
    /// reading at its end, µm.
    ///
    /// A non-finite `u_v` is rejected ([`SimError::NonFiniteInput`]) and a non-finite
    /// result ([`SimError::Diverged`]) is not committed; either way the plant stays as it
    /// was before the call.
    #[inline]
    pub fn step(&mut self, u_v: f64) -> Result<f64, SimError> {
        self.step_detail(u_v).map(|d| d.y_um)
    }

    /// [`Bimorph::step`] returning the internal signals as well.
    pub fn step_detail(&mut self, u_v: f64) -> Result<Detail, SimError> {
        if !u_v.is_finite() {
            return Err(SimError::NonFiniteInput { sample: self.k });
        }
        let u_dac = self.dac(u_v);
        let len = self.history.len();
        let back =
            |b: usize| -> f64 { if b == 0 { u_dac } else { self.history[(self.pos + len - b) % len] } };
        let cmd_late = back(self.delay_samples);
        let cmd_early = back(self.delay_samples + 1);

        let mut st = self.state;
        for j in 0..self.substeps {
            let cmd = if j < self.delay_rem { cmd_early } else { cmd_late };
            let target = (self.gain * cmd).clamp(-self.limit_v, self.limit_v);
            self.substep(&mut st, target);
        }

        let mut y_true = 0.0;
        for i in 0..self.n_modes {
            y_true += st.x[Q0 + i];
        }
        let check = st.x.iter().fold(st.v + st.h, |acc, x| acc + x);
        if !check.is_finite() {
            return Err(SimError::Diverged { sample: self.k });
        }

        // Commit.
        self.state = st;
        self.history[self.pos] = u_dac;
        self.pos = (self.pos + 1) % len;
        self.k += 1;

        let t_end = self.k as f64 * self.ts;
        if self.walk_step_um != 0.0 {
            self.walk_um += self.walk_step_um * self.walk_rng.normal();
        }
        let mut y = y_true + self.offset_um + self.drift_um_per_s * t_end + self.walk_um;
        if self.noise_um != 0.0 {
            y += self.noise_um * self.noise_rng.normal();
        }
        if self.resolution_um != 0.0 {
            y = (y / self.resolution_um).round() * self.resolution_um;
        }

        let creep_v = st.x[..MAX_CREEP_TERMS].iter().sum();
        let mut q_um = [0.0; MAX_MODES];
        q_um.copy_from_slice(&st.x[Q0..R0]);
        Ok(Detail { y_um: y, y_true_um: y_true, u_dac_v: u_dac, v_v: st.v, h_v: st.h, creep_v, q_um })
    }

    /// Runs a whole input record from the current state; stops at the first error.
    pub fn run(&mut self, u_v: &[f64]) -> Result<Vec<f64>, SimError> {
        let mut y = Vec::with_capacity(u_v.len());
        for &u in u_v {
            y.push(self.step(u)?);
        }
        Ok(y)
    }

    /// One RK4 step of length `hsub` with the driver heading for `target`.
    #[inline(always)]
    fn substep(&self, st: &mut State, target: f64) {
        let v0 = st.v;
        let dv1 = (target - v0) * self.drive_half;
        let v_half = v0 + dv1;
        let dv2 = (target - v_half) * self.drive_half;
        let v1 = v_half + dv2;
        let h0 = st.h;
        let h_half = self.bw.advance(h0, dv1);
        let h1 = self.bw.advance(h_half, dv2);
        let (p0, p_half, p1) = (v0 - h0, v_half - h_half, v1 - h1);

        let hs = self.hsub;
        let x = st.x;
        let stage = |a: f64, d: &[f64; NX]| -> [f64; NX] { core::array::from_fn(|n| x[n] + a * d[n]) };
        let mut k1 = [0.0; NX];
        let mut k2 = [0.0; NX];
        let mut k3 = [0.0; NX];
        let mut k4 = [0.0; NX];
        self.rhs(&x, p0, &mut k1);
        self.rhs(&stage(0.5 * hs, &k1), p_half, &mut k2);
        self.rhs(&stage(0.5 * hs, &k2), p_half, &mut k3);
        self.rhs(&stage(hs, &k3), p1, &mut k4);
        let w = hs / 6.0;
        st.x = core::array::from_fn(|n| x[n] + w * (k1[n] + 2.0 * (k2[n] + k3[n]) + k4[n]));
        st.v = v1;
        st.h = h1;
    }

    /// The derivative of the creep and modal states for `p = v − h`. Unused slots have
    /// zero coefficients and stay at zero.
    #[inline(always)]
    fn rhs(&self, x: &[f64; NX], p: f64, d: &mut [f64; NX]) {
        let mut drive = p;
        for j in 0..MAX_CREEP_TERMS {
            d[j] = (self.creep_gain[j] * p - x[j]) * self.creep_inv_tau[j];
            drive += x[j];
        }
        for i in 0..self.n_modes {
            let m = &self.modes[i];
            let q = x[Q0 + i];
            let r = x[R0 + i];
            d[Q0 + i] = r;
            d[R0 + i] = m.force_per_v * drive
                - m.two_zeta_omega * r * m.damping_factor(r)
                - m.omega2 * (q + m.stiffening(q));
        }
    }
}

/// The [`Plant::name`](boucwen_core::Plant::name) of the virtual bimorph.
pub const BIMORPH_NAME: &str = "virtual bimorph";

/// The virtual bimorph as the core's plant: each step integrates its physics over one
/// sample interval. A non-finite command is [`SimError::NonFiniteInput`], a diverged
/// state [`SimError::Diverged`]; either way the bimorph keeps its state from before the
/// call. `reset` returns it to rest at time 0 with its noise reseeded, so a second run
/// repeats the first exactly.
impl boucwen_core::Plant<f64> for Bimorph {
    type Error = SimError;

    fn step(&mut self, u_v: f64) -> Result<f64, SimError> {
        Bimorph::step(self, u_v)
    }

    fn sample_interval_s(&self) -> f64 {
        self.ts_s()
    }

    fn reset(&mut self) -> Result<(), SimError> {
        Bimorph::reset(self);
        Ok(())
    }

    fn name(&self) -> &str {
        BIMORPH_NAME
    }
}

//! Li et al.'s odd-harmonic repetitive controller: the internal model on its delay line
//! ([`OrcMemory`]) and the controller on the PI ([`OrcController`]).

use super::{ControlOutput, Controller, Past, PiConfig, PiState, check_inputs};
use crate::error::finite;
use crate::signal::Oscillator;
use crate::{Error, Real};

/// A suggested capacity of the ORC delay line: at 1 kHz it reaches down to a 0.98 Hz
/// reference (`N/2 = L0 + μ ≤ 510`), in 2 KiB of `f32`.
pub const ORC_CAPACITY: usize = 512;
/// Where the ORC's output enters the loop (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OrcPlacement {
    /// Added to the PI's output, at the plant input: `u = u_ff + C z⁻¹ e + u_rc`; `u_rc` in
    /// input units, learning through `S·P`.
    PlantInput,
    /// Added to the error at the PI's input (Li et al.'s plug-in form):
    /// `u = u_ff + C z⁻¹ (e + u_rc)`; `u_rc` in output units, learning through `T`.
    PiInput,
}

/// Parameters of the odd-harmonic internal model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrcConfig<T> {
    /// The reference frequency `f` at the sample interval (fixes `L = 1/(2 f Ts)`).
    pub drive: Oscillator,
    /// `a` of `Q = [a, 1-2a, a]`, in `[0, 1/4]` (0: no low-pass, `Q = 1`).
    pub q_coeff: T,
    /// The learning gain: at the plant input `k_r/G0` (input units per output unit,
    /// of the sign of the plant's static gain `G0`); at the PI's input `k_r`. Non-zero.
    pub learning_gain: T,
    /// The phase lead `m` in samples.
    pub lead_samples: u32,
    /// Bound on `|u_rc|` (> 0; input units at the plant input, output units at the PI's).
    pub limit: T,
    /// Where `u_rc` enters the loop.
    pub placement: OrcPlacement,
}

/// The half period `L = 1/(2 f Ts) = 2⁶³/increment` as `(L0, μ)`, `L = L0 + μ`, `0 ≤ μ < 1`.
/// A fraction within 10⁻⁹ of an integer is taken as that integer.
pub fn half_period(drive: Oscillator) -> Result<(usize, f64), Error> {
    let inc = drive.increment();
    if inc == 0 {
        return Err(Error::OutOfRange("ORC reference frequency (must be > 0)"));
    }
    let l = 9_223_372_036_854_775_808.0 / inc as f64;
    // l ≥ 1 and below 2⁶⁴: truncation is the floor (no libm in no_std).
    let mut l0 = (l as u64) as f64;
    let mut mu = l - l0;
    if mu > 1.0 - 1e-9 {
        l0 += 1.0;
        mu = 0.0;
    } else if mu < 1e-9 {
        mu = 0.0;
    }
    if l0 > (usize::MAX / 2) as f64 {
        return Err(Error::OutOfRange("ORC half period (too long)"));
    }
    Ok((l0 as usize, mu))
}

impl<T: Real> OrcConfig<T> {
    /// Checks the gains and that the delay line of capacity `ncap` holds the half period
    /// with this lead: `L0 ≥ m + 2` and `L0 + 2 ≤ ncap`.
    #[allow(clippy::neg_cmp_op_on_partial_ord, reason = "NaN must fail the checks, as `!(x > 0)` does")]
    pub fn validate(&self, ncap: usize) -> Result<(), Error> {
        finite(self.q_coeff, "ORC Q coefficient")?;
        finite(self.learning_gain, "ORC learning gain")?;
        finite(self.limit, "ORC limit")?;
        if !(self.q_coeff >= T::zero() && self.q_coeff <= T::lit(0.25)) {
            return Err(Error::OutOfRange("ORC Q coefficient (must be in 0..=0.25)"));
        }
        if self.learning_gain == T::zero() {
            return Err(Error::OutOfRange("ORC learning gain (must be non-zero)"));
        }
        if !(self.limit > T::zero()) {
            return Err(Error::OutOfRange("ORC limit (must be > 0)"));
        }
        let (l0, _) = half_period(self.drive)?;
        if l0 < self.lead_samples as usize + 2 {
            return Err(Error::OutOfRange(
                "ORC phase lead (must be <= N/2 - 2: reference too fast for this lead)",
            ));
        }
        if l0 + 2 > ncap {
            return Err(Error::OutOfRange(
                "ORC half period (N/2 + 2 exceeds the delay line's capacity: reference too slow)",
            ));
        }
        Ok(())
    }

    /// The four taps `h = [a, 1-2a, a] ∗ [1-μ, μ]` on offsets `L0 - 1 ..= L0 + 2`.
    pub(super) fn taps(&self, mu: T) -> [T; 4] {
        let a = self.q_coeff;
        let c = T::one() - a - a;
        let nu = T::one() - mu;
        [a * nu, c * nu + a * mu, a * nu + c * mu, a * mu]
    }
}

/// The odd-harmonic internal model with its delay line of capacity `NCAP`: learns from
/// `e[k-1]` and produces `u_rc[k]` (see the module docs for the recursion).
#[derive(Clone, Debug, PartialEq)]
pub struct OrcMemory<T, const NCAP: usize> {
    cfg: OrcConfig<T>,
    taps: [T; 4],
    l0: usize,
    mu: T,
    lead: usize,
    /// `buf[(head + NCAP - o) % NCAP] = v[k - o]`, `o = 1..=NCAP`.
    buf: [T; NCAP],
    head: usize,
}

impl<T: Real, const NCAP: usize> OrcMemory<T, NCAP> {
    /// An empty internal model (`v[j] = 0` for `j < 0`) from a validated configuration.
    ///
    /// ```
    /// use boucwen_core::controllers::{OrcConfig, OrcMemory, OrcPlacement};
    /// use boucwen_core::signal::Oscillator;
    /// // 10 Hz at 1 kHz: half period L = 50 samples.
    /// let cfg = OrcConfig { drive: Oscillator::new(10.0, 1e-3)?, q_coeff: 0.1_f64, learning_gain: 0.5,
    ///                       lead_samples: 4, limit: 10.0, placement: OrcPlacement::PlantInput };
    /// let mem = OrcMemory::<f64, 64>::new(cfg)?;
    /// assert_eq!(mem.half_period(), (50, 0.0));
    /// assert!(OrcMemory::<f64, 51>::new(cfg).is_err()); // L + 2 does not fit
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn new(cfg: OrcConfig<T>) -> Result<Self, Error> {
        cfg.validate(NCAP)?;
        let (l0, mu) = half_period(cfg.drive)?;
        Ok(Self {
            taps: cfg.taps(T::lit(mu)),
            cfg,
            l0,
            mu: T::lit(mu),
            lead: cfg.lead_samples as usize,
            buf: [T::zero(); NCAP],
            head: 0,
        })
    }

    #[inline(always)]
    fn slot(&self, offset: usize) -> usize {
        // offset in 1..=NCAP
        (self.head + NCAP - offset) % NCAP
    }

    /// One sample: learn from `e[k-1]` (`None`: no learning this sample), return `u_rc[k]`.
    /// `e` must be finite (the controllers check it).
    #[inline]
    pub fn step(&mut self, e_prev: Option<T>) -> T {
        if let Some(e) = e_prev {
            // v[k-1-m] = u_rc[k-1-m] + (k_r/G0)·e[k-1]
            let s = self.slot(self.lead + 1);
            self.buf[s] += self.cfg.learning_gain * e;
        }
        let mut acc = T::zero();
        for (i, &h) in self.taps.iter().enumerate() {
            acc += h * self.buf[self.slot(self.l0 - 1 + i)];
        }
        let u_rc = (-acc).max(-self.cfg.limit).min(self.cfg.limit);
        self.buf[self.head] = u_rc;
        self.head = (self.head + 1) % NCAP;
        u_rc
    }

    /// The configuration.
    pub fn config(&self) -> &OrcConfig<T> {
        &self.cfg
    }

    /// The half period `(L0, μ)`, `L = L0 + μ` samples.
    pub fn half_period(&self) -> (usize, T) {
        (self.l0, self.mu)
    }

    /// Forgets everything learnt.
    pub fn clear(&mut self) {
        self.buf = [T::zero(); NCAP];
        self.head = 0;
    }
}

/// The ORC of Li et al. on the PI: `u = sat(u_ff + C(z)·z⁻¹·e + u_rc)`.
#[derive(Clone, Debug, PartialEq)]
pub struct OrcController<T, const NCAP: usize> {
    pi_cfg: PiConfig<T>,
    pi: PiState<T>,
    memory: OrcMemory<T, NCAP>,
    past: Past<T>,
    /// `u_rc[k-1]` (used at the PI's input).
    u_rc_prev: T,
}

impl<T: Real, const NCAP: usize> OrcController<T, NCAP> {
    /// The ORC on the PI `pi`, both validated.
    ///
    /// ```
    /// use boucwen_core::compensator::Saturation;
    /// use boucwen_core::controllers::{Controller, OrcConfig, OrcController, OrcPlacement, PiConfig, ORC_CAPACITY};
    /// use boucwen_core::signal::Oscillator;
    /// let pi = PiConfig { kp: 0.0_f64, ki_per_s: 5.0, ts_s: 1e-3, feedforward_gain: 0.0,
    ///                     saturation: Saturation::symmetric(10.0) };
    /// let orc = OrcConfig { drive: Oscillator::new(10.0, 1e-3)?, q_coeff: 0.1, learning_gain: 0.5,
    ///                       lead_samples: 4, limit: 1.0, placement: OrcPlacement::PiInput };
    /// let mut c = OrcController::<f64, ORC_CAPACITY>::new(pi, orc)?;
    /// assert_eq!(c.step(0.0, None)?.u, 0.0);
    /// # Ok::<(), boucwen_core::Error>(())
    /// ```
    pub fn new(pi: PiConfig<T>, orc: OrcConfig<T>) -> Result<Self, Error> {
        pi.validate()?;
        Ok(Self {
            pi_cfg: pi,
            pi: PiState::default(),
            memory: OrcMemory::new(orc)?,
            past: Past::default(),
            u_rc_prev: T::zero(),
        })
    }

    /// One sample with the caller's feedforward `u_ff[k]` in place of `k_ff·d[k]`.
    #[inline]
    pub fn step_with_feedforward(
        &mut self,
        d: T,
        y_prev: Option<T>,
        u_ff: T,
    ) -> Result<ControlOutput<T>, Error> {
        check_inputs(d, y_prev)?;
        finite(u_ff, "u_ff")?;
        let e = self.past.error(y_prev);
        let learn = if self.past.saturated_prev { None } else { e };
        let u_rc = self.memory.step(learn);
        let (u, u_fb, saturated) = match self.memory.cfg.placement {
            // The PI's saturation logic sees the ORC's share as part of the offset.
            OrcPlacement::PlantInput => self.pi_cfg.update(&mut self.pi, e, u_ff + u_rc),
            // ε[k-1] = e[k-1] + u_rc[k-1].
            OrcPlacement::PiInput => self.pi_cfg.update(&mut self.pi, e.map(|e| e + self.u_rc_prev), u_ff),
        };
        self.u_rc_prev = u_rc;
        self.past = Past { d_prev: d, started: true, saturated_prev: saturated };
        Ok(ControlOutput { u, u_ff, u_fb, u_rc, saturated })
    }

    /// The PI configuration.
    pub fn pi_config(&self) -> &PiConfig<T> {
        &self.pi_cfg
    }

    /// The internal model.
    pub fn memory(&self) -> &OrcMemory<T, NCAP> {
        &self.memory
    }
}

impl<T: Real, const NCAP: usize> Controller<T> for OrcController<T, NCAP> {
    #[inline]
    fn step(&mut self, d: T, y_prev: Option<T>) -> Result<ControlOutput<T>, Error> {
        let u_ff = self.pi_cfg.feedforward_gain * d;
        self.step_with_feedforward(d, y_prev, u_ff)
    }

    fn reset(&mut self) {
        self.pi = PiState::default();
        self.memory.clear();
        self.past = Past::default();
        self.u_rc_prev = T::zero();
    }
}

//! Terms beyond the fitted host model, for the diagnosis: saturation, input delay, creep and
//! stiffening, and the joint refinement of a model that carries them.
//!
//! A [`TermModel`] is a [`HostModel`] (the extended or enhanced model fitted by
//! [`crate::fit::fit_oe`]) with [`Terms`] around and inside it:
//!
//! ```text
//! u_s[k] = clamp(u[k], lo_u, hi_u)                       input saturation (an amplifier's rails)
//! u_d    = u_s delayed by d + τ samples                  input delay (d whole samples beyond the host's τ)
//! h[k]   = Bouc–Wen loop of u_d                          (the host's)
//! x[k]   = A1·u_d[k] − h[k] + Σ_n y_n[k]                 (the host's drive and harmonic branches)
//! c_j[k] = λ_j·c_j[k−1] + (1 − λ_j)·g_j·x[k],  λ_j = e^{−Ts/τ_j}     creep: relaxation states
//! p[k]   = a1·ŷ[k−1] + a2·ŷ[k−2] + x[k] + Σ_j c_j[k]     (the host's structure)
//! ŷ[k]   = p[k] − (1 − a1 − a2)·q_ref·Σ_p s_p·(ŷ[k−1]/q_ref)^p        stiffening of the structure
//! y[k]   = clamp(ŷ[k] + drift(t), lo_y, hi_y)            output saturation (a sensor's range)
//! ```
//!
//! Creep follows the model's own drive `x` (the deflection the input asks for) with time
//! constants `τ_j` and gains `g_j`: after a change of the input's level the output relaxes
//! towards `(1 + Σ g_j)` times its immediate value, as a piezo's deflection does. The
//! stiffening is a restoring force polynomial in the deflection, in the units of the
//! structure's own restoring force `(1 − a1 − a2)·ŷ` (its static part), so `s_p` is the
//! fraction the power `p` adds to the linear stiffness at `ŷ = q_ref`: odd powers are a
//! symmetric hardening or softening, even powers an asymmetric stiffness. The force is
//! evaluated on the deflection one sample back, `ŷ[k−1]`, where the structure's recursion
//! has its own stiffness (`a1 = 2 − ω²Ts² − …` in the central-difference form of
//! `m·q̈ + c·q̇ + k·q = F`): the nonlinear part of the restoring force then has the phase of
//! the linear one at every frequency. Evaluated on the current prediction `p[k]` instead (as
//! this module first did) it leads the deflection by a sample, which near the resonance
//! (`ω·Ts` up to about 1 at a 200 Hz mode sampled at 1 kHz) turns part of the stiffening
//! into an amplitude-dependent damping: fitted to the batch's multisines through the
//! resonance, that form could only make the model worse, and the multisine's odd
//! stiffening was found in 15 of 20 records (19 of 20 with `ŷ[k−1]`).
//!
//! With no terms the model is exactly its host ([`TermModel::simulate`] calls
//! [`HostModel::simulate`]).
//!
//!
//! The joint refinement of a model that carries terms is the fit's
//! ([`crate::fit::refine`]).

use super::poles;
use super::{HostModel, MAX_DELAY, ModelError, delayed};
use boucwen_core::signal::{Oscillator, sin_cos};
use serde::{Deserialize, Serialize};

/// A first-order relaxation state of the creep term.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Relaxation {
    /// Time constant (s).
    pub tau_s: f64,
    /// Steady-state gain relative to the immediate drive.
    pub gain: f64,
}

/// One power of the stiffening polynomial.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stiffening {
    /// The power `p ≥ 2`.
    pub power: u32,
    /// The fraction `s_p` it adds to the linear stiffness at `q_ref`.
    pub coeff: f64,
}

/// The terms around and inside a host model (see the module docs). The default carries none.
#[derive(Clone, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Terms {
    /// The drive is clamped to `[lo, hi]` (V) before the model: an amplifier's rails.
    pub input_clamp: Option<[f64; 2]>,
    /// The output is clamped to `[lo, hi]` (µm): a sensor's range.
    pub output_clamp: Option<[f64; 2]>,
    /// Whole samples of input delay before the host's own (fractional) delay.
    pub extra_delay: usize,
    /// Creep: relaxation states on the model's drive.
    pub creep: Vec<Relaxation>,
    /// Stiffening of the structure.
    pub stiffening: Vec<Stiffening>,
    /// Reference deflection of the stiffening (µm; set when a stiffening is added).
    pub q_ref_um: f64,
    /// The range `[lo, hi]` (s) the creep's time constants are kept in by [`refine`].
    pub creep_tau_range_s: [f64; 2],
}

impl Terms {
    /// The input as the host model sees it before its own delay: clamped at the input
    /// saturation and shifted by the extra delay.
    pub fn input(&self, u: &[f64]) -> Vec<f64> {
        let n = u.len();
        let clamped: Vec<f64> = match self.input_clamp {
            Some([lo, hi]) => u.iter().map(|v| v.clamp(lo.min(hi), hi.max(lo))).collect(),
            None => u.to_vec(),
        };
        if self.extra_delay == 0 {
            return clamped;
        }
        (0..n).map(|k| if k >= self.extra_delay { clamped[k - self.extra_delay] } else { 0.0 }).collect()
    }

    /// Whether every term acts on the input only (saturation of the drive, extra delay): a
    /// host model is then fitted to [`Terms::input`] by [`crate::fit::fit_oe`] directly.
    pub fn input_only(&self) -> bool {
        self.output_clamp.is_none() && self.creep.is_empty() && self.stiffening.is_empty()
    }

    /// Whether every term but creep acts on the input only.
    pub fn input_only_but_creep(&self) -> bool {
        self.output_clamp.is_none() && self.stiffening.is_empty()
    }

    /// Whether there is no term.
    pub fn is_empty(&self) -> bool {
        self.input_clamp.is_none()
            && self.output_clamp.is_none()
            && self.extra_delay == 0
            && self.creep.is_empty()
            && self.stiffening.is_empty()
    }
}

/// A host model with terms.
#[derive(Clone, Debug, PartialEq)]
pub struct TermModel {
    /// The fitted host model.
    pub host: HostModel,
    /// The terms.
    pub terms: Terms,
}

impl From<HostModel> for TermModel {
    fn from(host: HostModel) -> Self {
        TermModel { host, terms: Terms::default() }
    }
}

impl TermModel {
    /// The name: the host's ("enhanced(3)+offset"), then the terms ("+saturation(u)",
    /// "+delay(4)", "+creep(2)", "+stiffening(3)").
    pub fn name(&self) -> String {
        let mut s = self.host.name();
        let t = &self.terms;
        if t.input_clamp.is_some() {
            s.push_str("+saturation(u)");
        }
        if t.output_clamp.is_some() {
            s.push_str("+saturation(y)");
        }
        if t.extra_delay > 0 {
            s.push_str(&format!("+delay({})", t.extra_delay));
        }
        if !t.creep.is_empty() {
            s.push_str(&format!("+creep({})", t.creep.len()));
        }
        if !t.stiffening.is_empty() {
            let p: Vec<String> = t.stiffening.iter().map(|p| p.power.to_string()).collect();
            s.push_str(&format!("+stiffening({})", p.join(",")));
        }
        s
    }

    /// The total input delay (samples): the extra whole samples and the host's own.
    pub fn delay_samples(&self) -> f64 {
        self.terms.extra_delay as f64 + self.host.delay
    }

    /// Free-run simulation from rest for the input `u` (see the module docs). An unstable
    /// model's output grows without bound; it is returned as computed.
    pub fn simulate(&self, u: &[f64], ts: f64) -> Result<Vec<f64>, ModelError> {
        if self.terms.is_empty() {
            return self.host.simulate(u, ts);
        }
        let t = &self.terms;
        let n = u.len();
        let ud = delayed(&t.input(u), self.host.delay);
        let host = &self.host;
        let bw = host.ext.bw;
        let [a1, a2] = host.ext.ar;
        let restoring = 1.0 - a1 - a2;
        let q_ref = if t.q_ref_um > 0.0 { t.q_ref_um } else { 1.0 };
        let lambda: Vec<f64> = t.creep.iter().map(|c| (-ts / c.tau_s.max(ts)).exp()).collect();
        let mut c_state = vec![0.0; t.creep.len()];
        let osc = if host.branches.is_empty() { None } else { Some(Oscillator::new(host.drive_hz, ts)?) };
        let mut br_past = vec![[0.0f64; 2]; host.branches.len()];
        let (mut h, mut u_prev, mut y1, mut y2) = (0.0, 0.0, 0.0, 0.0);
        let mut out = Vec::with_capacity(n);
        for (k, &uk) in ud.iter().enumerate() {
            h = bw.h_next(h, uk - u_prev);
            u_prev = uk;
            let mut x = bw.a1 * uk - h;
            if let Some(osc) = &osc {
                let phase = osc.phase_at(k as u64);
                for (b, past) in host.branches.iter().zip(br_past.iter_mut()) {
                    let (s, c) = sin_cos::<f64>(phase.wrapping_mul(u64::from(b.order)));
                    let yn = b.alpha_s * s + b.alpha_c * c + b.ar[0] * past[0] + b.ar[1] * past[1];
                    *past = [yn, past[0]];
                    x += yn;
                }
            }
            let mut creep = 0.0;
            for ((c, l), r) in c_state.iter_mut().zip(&lambda).zip(&t.creep) {
                *c = l * *c + (1.0 - l) * r.gain * x;
                creep += *c;
            }
            let mut p = a1 * y1 + a2 * y2 + x + creep;
            if !t.stiffening.is_empty() {
                // The restoring force of the deflection one sample back, as the stiffness
                // acts in the structure's own recursion (see the module docs).
                let q = y1 / q_ref;
                let force: f64 = t.stiffening.iter().map(|s| s.coeff * q.powi(s.power as i32)).sum();
                p -= restoring * q_ref * force;
            }
            y2 = y1;
            y1 = p;
            let mut yk = p;
            if !host.drift.is_empty() {
                let tk = k as f64 * ts;
                yk += host.drift.iter().rev().fold(0.0, |acc, &c| acc * tk + c);
            }
            if let Some([lo, hi]) = t.output_clamp {
                yk = yk.clamp(lo.min(hi), hi.max(lo));
            }
            out.push(yk);
        }
        Ok(out)
    }
}

/// A parameter of a [`TermModel`] that a refinement ([`crate::fit::refine`]) may move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Param {
    /// AR coefficient `a1` (0) or `a2` (1).
    Ar(usize),
    /// `A1`.
    A1,
    /// `A`.
    A,
    /// `A0`.
    A0,
    /// `γ`.
    Gamma,
    /// `β`.
    Beta,
    /// The host's fractional input delay (samples, kept in `[0, 3]`).
    Delay,
    /// Drift coefficient `i` (0: the offset).
    Drift(usize),
    /// Branch `i`'s sine weight.
    BranchSin(usize),
    /// Branch `i`'s cosine weight.
    BranchCos(usize),
    /// The input clamp's lower (0) or upper (1) level.
    InputClamp(usize),
    /// The output clamp's lower (0) or upper (1) level.
    OutputClamp(usize),
    /// Creep state `j`'s gain.
    CreepGain(usize),
    /// Creep state `j`'s time constant (s).
    CreepTau(usize),
    /// Stiffening power `i`'s coefficient.
    Stiffening(usize),
}

impl TermModel {
    pub(crate) fn get(&self, p: Param) -> f64 {
        let h = &self.host;
        let t = &self.terms;
        match p {
            Param::Ar(i) => h.ext.ar[i],
            Param::A1 => h.ext.bw.a1,
            Param::A => h.ext.bw.a,
            Param::A0 => h.ext.bw.a0,
            Param::Gamma => h.ext.bw.gamma,
            Param::Beta => h.ext.bw.beta,
            Param::Delay => h.delay,
            Param::Drift(i) => h.drift[i],
            Param::BranchSin(i) => h.branches[i].alpha_s,
            Param::BranchCos(i) => h.branches[i].alpha_c,
            Param::InputClamp(i) => t.input_clamp.map_or(0.0, |c| c[i]),
            Param::OutputClamp(i) => t.output_clamp.map_or(0.0, |c| c[i]),
            Param::CreepGain(j) => t.creep[j].gain,
            Param::CreepTau(j) => t.creep[j].tau_s,
            Param::Stiffening(i) => t.stiffening[i].coeff,
        }
    }

    pub(crate) fn set(&mut self, p: Param, v: f64) {
        let h = &mut self.host;
        let t = &mut self.terms;
        match p {
            Param::Ar(i) => h.ext.ar[i] = v,
            Param::A1 => h.ext.bw.a1 = v,
            Param::A => h.ext.bw.a = v,
            Param::A0 => h.ext.bw.a0 = v,
            Param::Gamma => h.ext.bw.gamma = v,
            Param::Beta => h.ext.bw.beta = v,
            Param::Delay => h.delay = v,
            Param::Drift(i) => h.drift[i] = v,
            Param::BranchSin(i) => h.branches[i].alpha_s = v,
            Param::BranchCos(i) => h.branches[i].alpha_c = v,
            Param::InputClamp(i) => {
                if let Some(c) = &mut t.input_clamp {
                    c[i] = v;
                }
            }
            Param::OutputClamp(i) => {
                if let Some(c) = &mut t.output_clamp {
                    c[i] = v;
                }
            }
            Param::CreepGain(j) => t.creep[j].gain = v,
            Param::CreepTau(j) => t.creep[j].tau_s = v,
            Param::Stiffening(i) => t.stiffening[i].coeff = v,
        }
    }

    /// Whether the parameters are admissible: a stable structure, a delay in `[0, 3]`,
    /// positive creep time constants, finite values.
    pub(crate) fn admissible(&self, free: &[Param]) -> bool {
        poles::stable(&self.host.ext.ar)
            && (0.0..=MAX_DELAY).contains(&self.host.delay)
            && self.terms.creep.iter().all(|c| c.tau_s > 0.0)
            && free.iter().all(|&p| self.get(p).is_finite())
    }

    /// Moves the parameters onto their bounds: the host's delay into `[0, 3]` samples, the
    /// creep's gains to at least 0 (creep adds to the deflection) and its time constants
    /// into [`Terms::creep_tau_range_s`].
    pub(crate) fn project(&mut self) {
        self.host.delay = self.host.delay.clamp(0.0, MAX_DELAY);
        let [lo, hi] = self.terms.creep_tau_range_s;
        for c in &mut self.terms.creep {
            c.gain = c.gain.max(0.0);
            if lo > 0.0 && hi >= lo {
                c.tau_s = c.tau_s.clamp(lo, hi);
            }
        }
    }

    /// The parameters of the host model a refinement moves: structure, loop, gains, drift
    /// and branch weights (not the delay, which only the delay term frees).
    pub fn host_params(&self) -> Vec<Param> {
        let mut p =
            vec![Param::Ar(0), Param::Ar(1), Param::A1, Param::A, Param::A0, Param::Gamma, Param::Beta];
        p.extend((0..self.host.drift.len()).map(Param::Drift));
        for i in 0..self.host.branches.len() {
            p.push(Param::BranchSin(i));
            p.push(Param::BranchCos(i));
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Branch;
    use boucwen_core::model::{BoucWenParams, ExtendedParams};
    use std::f64::consts::TAU;

    fn host() -> HostModel {
        let w0 = TAU * 0.07;
        HostModel {
            ext: ExtendedParams {
                bw: BoucWenParams { a1: 0.2, a: 0.06, a0: 0.005, gamma: 0.02, beta: 0.03 },
                ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
            },
            drive_hz: 23.0,
            branches: vec![Branch { order: 3, alpha_s: 0.01, alpha_c: -0.005, ar: [0.0, 0.0] }],
            drift: vec![0.3],
            delay: 0.4,
        }
    }

    fn sine(n: usize, f: f64, amp: f64) -> Vec<f64> {
        (0..n).map(|k| amp * (TAU * f * k as f64 * 1e-3).sin()).collect()
    }

    #[test]
    fn without_terms_the_model_is_its_host() {
        let h = host();
        let u = sine(3000, 23.0, 1.0);
        let a = h.simulate(&u, 1e-3).unwrap();
        // The same model through the term path (an inactive clamp forces it).
        let m = TermModel { host: h, terms: Terms { input_clamp: Some([-10.0, 10.0]), ..Terms::default() } };
        let b = m.simulate(&u, 1e-3).unwrap();
        let d = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(d < 1e-9, "largest difference {d}");
    }

    #[test]
    fn clamps_and_extra_delay_act_where_documented() {
        let mut m = TermModel::from(host());
        m.host.branches.clear();
        m.host.drift.clear();
        m.host.delay = 0.0;
        let u = sine(2000, 5.0, 1.0);
        let base = m.simulate(&u, 1e-3).unwrap();
        m.terms.extra_delay = 3;
        let late = m.simulate(&u, 1e-3).unwrap();
        let d = late[3..].iter().zip(&base).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(d < 1e-9 && late[..3].iter().all(|v| *v == 0.0), "{d}");
        m.terms.extra_delay = 0;
        m.terms.output_clamp = Some([-1.0, 0.5]);
        let clipped = m.simulate(&u, 1e-3).unwrap();
        assert!(clipped.iter().all(|v| (-1.0..=0.5).contains(v)));
        assert!(clipped.iter().filter(|v| **v == 0.5).count() > 100);
    }
}

//! One model structure for every family the project fits: where the hysteresis sits, the
//! linear part's orders, the added terms, one simulator and one parameter list.
//!
//! | family | hysteresis | linear part | module |
//! |---|---|---|---|
//! | [`Model::Actuator`] | at the drive: `y = G(q)·(A1·u − h)` (the paper's bimorph, eqs. 3/9) | 2 poles, no zeros, branches (eqs. 6/7) | [`super::host`], [`super::terms`] |
//! | [`Model::Oscillator`] | a restoring force inside the structure: `m ÿ + c ẏ + k y + z = u` | one mode (mass, damping, stiffness) | [`super::oscillator`] |
//! | [`Model::Linear`] | none | `B(q)/F(q)`, any orders, input delay | [`super::linear`] |
//!
//! Every family runs on the record's units: the drive as imported (V, or the record's own
//! unit of force for an oscillator) and the output in µm. The oscillator's parameters are SI
//! with the displacement in metres (as the Bouc–Wen literature and the benchmark give them);
//! [`Model::simulate`] converts its output to µm. A new family is a new variant here, its
//! simulator, its fit in [`crate::fit`] and its entry in the model file
//! ([`super::file`]); the diagnosis and `identify` compare families through this type.

use super::linear::LinearModel;
use super::oscillator::{InputReconstruction, OscillatorModel};
use super::{ModelError, TermModel};

/// Micrometres per metre: the oscillator runs in metres, records in µm.
pub const UM_PER_M: f64 = 1e6;

/// The model families.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Family {
    /// Hysteresis at the drive (the paper's actuator and its terms).
    Actuator,
    /// Hysteresis as a restoring force (the Bouc–Wen oscillator).
    Oscillator,
    /// No hysteresis: a linear output-error model.
    Linear,
}

impl Family {
    /// Every family, in the order `identify --model auto` fits them.
    pub const ALL: [Family; 3] = [Family::Actuator, Family::Oscillator, Family::Linear];

    /// "actuator", "oscillator", "linear" (the model file's and the JSON's name).
    pub fn name(self) -> &'static str {
        match self {
            Family::Actuator => "actuator",
            Family::Oscillator => "oscillator",
            Family::Linear => "linear",
        }
    }

    /// Where the family puts the hysteresis.
    pub fn hysteresis(self) -> Placement {
        match self {
            Family::Actuator => Placement::Drive,
            Family::Oscillator => Placement::RestoringForce,
            Family::Linear => Placement::None,
        }
    }
}

/// Where a model's hysteresis sits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    /// Applied to the drive before the structure (the paper's bimorph).
    Drive,
    /// A restoring force inside the structure's dynamics (Bouc and Wen's oscillator).
    RestoringForce,
    /// No hysteresis.
    None,
}

impl Placement {
    /// "at the drive", "in the restoring force", "none".
    pub fn name(self) -> &'static str {
        match self {
            Placement::Drive => "at the drive",
            Placement::RestoringForce => "in the restoring force",
            Placement::None => "none",
        }
    }
}

/// A model's structure, as the reports describe it.
#[derive(Clone, Debug, PartialEq)]
pub struct Structure {
    /// The family.
    pub family: Family,
    /// Where the hysteresis sits.
    pub hysteresis: Placement,
    /// Poles of the linear part (its denominator's order).
    pub poles: usize,
    /// Zeros of the linear part (its numerator's order).
    pub zeros: usize,
    /// Input delay (samples).
    pub delay_samples: f64,
    /// The added terms and branches, by name ("branch(3)", "creep(1)", …).
    pub terms: Vec<String>,
}

/// A model of any family (module docs).
#[derive(Clone, Debug, PartialEq)]
pub enum Model {
    /// Hysteresis at the drive.
    Actuator(TermModel),
    /// Hysteresis as a restoring force.
    Oscillator(OscillatorModel),
    /// No hysteresis.
    Linear(LinearModel),
}

impl Model {
    /// The family.
    pub fn family(&self) -> Family {
        match self {
            Model::Actuator(_) => Family::Actuator,
            Model::Oscillator(_) => Family::Oscillator,
            Model::Linear(_) => Family::Linear,
        }
    }

    /// A short name: the actuator's ("enhanced(3)+creep(1)"), "oscillator",
    /// "linear(nb=2,nf=3,nk=1)".
    pub fn name(&self) -> String {
        match self {
            Model::Actuator(m) => m.name(),
            Model::Oscillator(o) if o.params.nu != 1.0 => format!("oscillator(nu={:.3})", o.params.nu),
            Model::Oscillator(_) => "oscillator".to_string(),
            Model::Linear(l) => format!("linear(nb={},nf={},nk={})", l.b.len(), l.f.len(), l.nk),
        }
    }

    /// The structure: family, placement, orders, delay and terms.
    pub fn structure(&self) -> Structure {
        let family = self.family();
        let (poles, zeros, delay_samples, terms) = match self {
            Model::Actuator(m) => {
                let mut terms: Vec<String> =
                    m.host.branches.iter().map(|b| format!("branch({})", b.order)).collect();
                if !m.host.drift.is_empty() {
                    terms.push(format!("drift({})", m.host.drift.len() - 1));
                }
                let t = &m.terms;
                if t.input_clamp.is_some() {
                    terms.push("saturation(u)".into());
                }
                if t.output_clamp.is_some() {
                    terms.push("saturation(y)".into());
                }
                if !t.creep.is_empty() {
                    terms.push(format!("creep({})", t.creep.len()));
                }
                for s in &t.stiffening {
                    terms.push(format!("stiffening({})", s.power));
                }
                (2, 0, m.delay_samples(), terms)
            }
            Model::Oscillator(_) => (2, 0, 0.0, vec![]),
            Model::Linear(l) => (l.f.len(), l.b.len().saturating_sub(1), l.nk as f64, vec![]),
        };
        Structure { family, hysteresis: family.hysteresis(), poles, zeros, delay_samples, terms }
    }

    /// `(name, value)` of every parameter, in the model file's units.
    pub fn parameters(&self) -> Vec<(String, f64)> {
        match self {
            Model::Actuator(m) => {
                let h = &m.host;
                let bw = h.ext.bw;
                let mut p = vec![
                    ("a1".to_string(), h.ext.ar[0]),
                    ("a2".to_string(), h.ext.ar[1]),
                    ("A1".to_string(), bw.a1),
                    ("A".to_string(), bw.a),
                    ("A0".to_string(), bw.a0),
                    ("gamma".to_string(), bw.gamma),
                    ("beta".to_string(), bw.beta),
                ];
                for b in &h.branches {
                    p.push((format!("alpha_s{}", b.order), b.alpha_s));
                    p.push((format!("alpha_c{}", b.order), b.alpha_c));
                }
                for (i, d) in h.drift.iter().enumerate() {
                    p.push((format!("drift{i}"), *d));
                }
                if m.delay_samples() > 0.0 {
                    p.push(("delay".to_string(), m.delay_samples()));
                }
                p
            }
            Model::Oscillator(o) => o.params().into_iter().map(|(n, v)| (n.to_string(), v)).collect(),
            Model::Linear(l) => {
                let mut p: Vec<(String, f64)> =
                    l.b.iter().enumerate().map(|(i, v)| (format!("b{i}"), *v)).collect();
                p.extend(l.f.iter().enumerate().map(|(i, v)| (format!("f{}", i + 1), *v)));
                p
            }
        }
    }

    /// The free-run output (µm) from rest for the drive `u` at interval `ts` (s).
    pub fn simulate(&self, u: &[f64], ts: f64) -> Result<Vec<f64>, ModelError> {
        let y = match self {
            Model::Actuator(m) => m.simulate(u, ts)?,
            Model::Oscillator(o) => o
                .simulate_with(u, ts, InputReconstruction::CubicSpline)?
                .into_iter()
                .map(|v| v * UM_PER_M)
                .collect(),
            Model::Linear(l) => l.simulate(u)?,
        };
        if y.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::Diverges);
        }
        Ok(y)
    }

    /// The steady-state output (µm) over one period `u_period` of a periodic drive: the
    /// period is run `warmup` times from rest first, and the next one is returned. The
    /// oscillator interpolates the period in the DFT domain ([`OscillatorModel::simulate_periodic`]).
    pub fn simulate_periodic(
        &self,
        u_period: &[f64],
        ts: f64,
        warmup: usize,
    ) -> Result<Vec<f64>, ModelError> {
        let n = u_period.len();
        let y = match self {
            Model::Oscillator(o) => {
                o.simulate_periodic(u_period, ts, warmup)?.into_iter().map(|v| v * UM_PER_M).collect()
            }
            _ => {
                let all = self.simulate(&u_period.repeat(warmup + 1), ts)?;
                all[warmup * n..].to_vec()
            }
        };
        if y.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::Diverges);
        }
        Ok(y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::oscillator::{OscillatorParams, OutputSampling};

    #[test]
    fn each_family_says_where_its_hysteresis_sits() {
        let lin = Model::Linear(LinearModel { b: vec![0.0, 0.5], f: vec![-0.5], nk: 1 });
        let s = lin.structure();
        assert_eq!((s.family, s.hysteresis, s.poles, s.zeros), (Family::Linear, Placement::None, 1, 1));
        let osc = Model::Oscillator(OscillatorModel {
            params: OscillatorParams::BENCHMARK,
            substeps: 4,
            output: OutputSampling::Instant,
        });
        assert_eq!(osc.structure().hysteresis, Placement::RestoringForce);
        assert_eq!(osc.parameters().len(), 7);
    }

    #[test]
    fn the_oscillator_runs_in_micrometres_and_its_steady_state_repeats() {
        let o = OscillatorModel {
            params: OscillatorParams::BENCHMARK,
            substeps: 4,
            output: OutputSampling::Instant,
        };
        let ts = 1.0 / 750.0;
        let u: Vec<f64> =
            (0..750).map(|k| 50.0 * (std::f64::consts::TAU * 10.0 * k as f64 * ts).sin()).collect();
        let m = Model::Oscillator(o.clone());
        let y_um = m.simulate(&u, ts).expect("simulate");
        let y_m = o.simulate(&u, ts).expect("simulate");
        assert!((y_um[300] - 1e6 * y_m[300]).abs() < 1e-9 * y_um[300].abs().max(1.0));
        let a = m.simulate_periodic(&u[..75], ts, 20).expect("periodic");
        let b = m.simulate_periodic(&u[..75], ts, 21).expect("periodic");
        let d = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(d < 1e-3 * a.iter().fold(0.0f64, |m, v| m.max(v.abs())), "{d}");
    }
}

//! `identify --model linear|oscillator|auto`: the families fitted on the same split as the
//! paper's model ([`super::prepare`]) and, for `auto`, the one kept held out.
//!
//! **Rule** (`auto`): the paper's actuator (the extended model, hysteresis at the drive) is
//! kept unless the best other family held out has an RMS lower by at least
//! [`FamilyRules::min_gain`](crate::rules::FamilyRules::min_gain) and at most
//! [`FamilyRules::max_noise_ratio`](crate::rules::FamilyRules::max_noise_ratio) times the
//! output's noise floor held out (it explains the record, not only more of it). A family whose fit fails or whose free run diverges is reported with
//! why and not chosen.

use super::{IdentifyError, Options, Structure, identify, prepare};
use crate::fit::family::{fit_family, whole_period};
use crate::model::{Family, Model, TermModel};
use crate::record::Record;
use crate::rules::Rules;
use crate::signal::steady;

/// One family's result on the split.
#[derive(Clone, Debug)]
pub struct Scored {
    /// The family.
    pub family: Family,
    /// The model, or why there is none.
    pub model: Result<Model, String>,
    /// Free-run RMS on the fitted samples (µm).
    pub fit_rms_um: Option<f64>,
    /// Free-run RMS held out (µm); `None` when it diverges or the fit failed.
    pub held_rms_um: Option<f64>,
    /// Wall time (s).
    pub seconds: f64,
}

/// Why `auto` kept the family it kept.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Choice {
    /// One family was asked for.
    Asked,
    /// The paper's actuator: no other family was better held out by `min_gain`.
    PaperModel {
        /// The best other family's gain over it held out (fraction; negative when worse).
        best_other_gain: Option<f64>,
        /// The best other family's held-out RMS in multiples of the noise floor.
        noise_ratio: Option<f64>,
    },
    /// Another family, better held out by `gain` (fraction) and at the noise.
    Better {
        /// Its gain over the paper's actuator.
        gain: f64,
        /// Its held-out RMS in multiples of the noise floor.
        noise_ratio: f64,
    },
    /// The paper's actuator could not be fitted; the best of the others.
    OnlyOther,
}

/// The families fitted and the one kept.
#[derive(Clone, Debug)]
pub struct Compared {
    /// Every family tried, in [`Family::ALL`] order.
    pub scores: Vec<Scored>,
    /// The index of the one kept.
    pub chosen: usize,
    /// Why.
    pub choice: Choice,
    /// The window (s) and the samples fitted and held out.
    pub window_s: [f64; 2],
    /// Samples fitted and held out.
    pub samples: (usize, usize),
    /// The output's noise floor held out (µm).
    pub noise_um: f64,
}

impl Compared {
    /// The model kept.
    pub fn model(&self) -> Option<&Model> {
        self.scores[self.chosen].model.as_ref().ok()
    }
}

/// Fits the paper's actuator (as `identify --model extended`) and scores it.
fn actuator(r: &Record, given: Option<(usize, usize)>, o: &Options, rules: &Rules) -> Scored {
    let t0 = std::time::Instant::now();
    let opts = Options { structure: Structure::Extended, harmonics: vec![], ..o.clone() };
    match identify(r, given, &opts, rules) {
        Ok(id) => Scored {
            family: Family::Actuator,
            held_rms_um: (id.check.unstable.is_none() && id.held_rms_um.is_finite())
                .then_some(id.held_rms_um),
            fit_rms_um: id.fit_rms_um,
            model: Ok(Model::Actuator(TermModel::from(id.model))),
            seconds: t0.elapsed().as_secs_f64(),
        },
        Err(e) => Scored {
            family: Family::Actuator,
            model: Err(e.to_string()),
            fit_rms_um: None,
            held_rms_um: None,
            seconds: t0.elapsed().as_secs_f64(),
        },
    }
}

/// Fits `families` on the record's split and keeps one by the rule of the module docs (or
/// the one asked for, when `families` holds one).
pub fn compare(
    r: &Record,
    given: Option<(usize, usize)>,
    families: &[Family],
    o: &Options,
    rules: &Rules,
) -> Result<Compared, IdentifyError> {
    let p = prepare(r, given, o.fit_fraction, rules)?;
    let (u, y) = p.signals(r);
    let period = p.drive.period_samples.and_then(whole_period);
    let noise_um = steady::noise_floor(&y[p.split..], r.ts, &p.drive, rules).0;
    let mut scores = Vec::new();
    for &family in families {
        let s = match family {
            Family::Actuator => actuator(r, given, o, rules),
            f => match fit_family(f, u, y, r.ts, (p.start, p.split), period, &rules.families) {
                Ok(fit) => Scored {
                    family: f,
                    model: Ok(fit.model),
                    fit_rms_um: Some(fit.fit_rms_um).filter(|v| v.is_finite()),
                    held_rms_um: fit.held_rms_um,
                    seconds: fit.seconds,
                },
                Err(e) => Scored {
                    family: f,
                    model: Err(e.to_string()),
                    fit_rms_um: None,
                    held_rms_um: None,
                    seconds: 0.0,
                },
            },
        };
        scores.push(s);
    }
    let held = |i: usize| scores[i].held_rms_um.filter(|_| scores[i].model.is_ok());
    let best_of = |idx: &mut dyn Iterator<Item = usize>| {
        idx.filter_map(|i| held(i).map(|h| (i, h))).min_by(|a, b| a.1.total_cmp(&b.1))
    };
    let (chosen, choice) = if scores.len() == 1 {
        (0, Choice::Asked)
    } else {
        let paper =
            scores.iter().position(|s| s.family == Family::Actuator).and_then(|i| held(i).map(|h| (i, h)));
        let others = best_of(&mut (0..scores.len()).filter(|&i| scores[i].family != Family::Actuator));
        match (paper, others) {
            (Some((pi, ph)), Some((oi, oh))) => {
                let gain = 1.0 - oh / ph;
                let noise_ratio = oh / noise_um.max(1e-300);
                if gain >= rules.families.min_gain && noise_ratio <= rules.families.max_noise_ratio {
                    (oi, Choice::Better { gain, noise_ratio })
                } else {
                    (pi, Choice::PaperModel { best_other_gain: Some(gain), noise_ratio: Some(noise_ratio) })
                }
            }
            (Some((pi, _)), None) => (pi, Choice::PaperModel { best_other_gain: None, noise_ratio: None }),
            (None, Some((oi, _))) => (oi, Choice::OnlyOther),
            (None, None) => {
                let why: Vec<String> = scores
                    .iter()
                    .map(|s| {
                        format!(
                            "{}: {}",
                            s.family.name(),
                            s.model.as_ref().err().map_or("diverges held out", |e| e)
                        )
                    })
                    .collect();
                return Err(IdentifyError::Option(format!(
                    "no family gave a stable model ({})",
                    why.join("; ")
                )));
            }
        }
    };
    let n = p.window.end - p.window.drive_on;
    Ok(Compared {
        scores,
        chosen,
        choice,
        window_s: p.window_s,
        samples: (p.split - p.start, n - p.split),
        noise_um,
    })
}

//! Stage 4: the terms a record calls for ([`read`]), and the measures the selection holds
//! them to: what a term must carry ([`Read::min_term`]) and how much of a harmonic the
//! drive's own harmonic accounts for ([`Read::drive_share`]).

use super::Context;
use super::baseline::{Baseline, Facts};
use crate::diagnose::causes;
use crate::diagnose::checks;
use crate::diagnose::error::DiagnoseError;
use crate::diagnose::evidence::{Candidate, Kind};
use crate::diagnose::residual::Residual;
use crate::model::HostModel;
use crate::signal::analysis::{self, Tone};
use crate::signal::steady::Drive;

/// What the record offers the selection.
#[derive(Clone, Debug)]
pub struct Read {
    /// The terms to try.
    pub candidates: Vec<Candidate>,
    /// The output's harmonics (µm, phases from the held-out part) the drive's own harmonics
    /// account for through the baseline; empty under a pure drive.
    pub drive_part: Vec<Tone>,
    /// The drive's amplitude (V).
    pub drive_amp_v: f64,
    /// First steady sample of the analysed samples (the output settled).
    pub steady_from: usize,
}

impl Read {
    /// What a term must carry (µm): `terms.min_term_rel` of the output's fundamental RMS, or
    /// for a drift or creep, which does not scale with the drive, `sine.drift_noise_factor`
    /// times the residual's noise if that is less.
    pub fn min_term(&self, cx: &Context<'_>, facts: &Facts, c: &Candidate) -> f64 {
        let t = cx.rules.terms.min_term_rel * facts.out_rms();
        if matches!(c.kind, Kind::Drift | Kind::Creep) {
            t.min(cx.rules.sine.drift_noise_factor * facts.residual.noise_rms_um)
        } else {
            t
        }
    }

    /// The share of the output's harmonic of `c`'s order the drive's own harmonic accounts
    /// for (through the baseline), when it reaches `sine.drive_share_max`; only at an order
    /// the drive itself carries (`sine.drive_distortion_floor`): its other harmonics'
    /// mixing products through the model are the model's business.
    pub fn drive_share(&self, cx: &Context<'_>, facts: &Facts, c: &Candidate) -> Option<f64> {
        let i = c.order? as usize - 1;
        let r = &cx.rules.sine;
        if !matches!(c.kind, Kind::OddHarmonic | Kind::EvenHarmonic)
            || i == 0
            || cx.plan.drive.harmonic_rel(i + 1) < r.drive_distortion_floor
        {
            return None;
        }
        let (d, o) = (self.drive_part.get(i)?.amp, facts.out_harmonics.get(i)?.amp);
        let share = d / o.max(1e-300);
        (share >= r.drive_share_max).then_some(share)
    }
}

/// The terms the record calls for: harmonics and drift from the residual and the output
/// (the output's harmonics less what the drive's own account for), saturation and creep
/// from their signs ([`causes::candidates`]).
pub fn read(cx: &Context<'_>, base: &Baseline, facts: &Facts) -> Result<Read, DiagnoseError> {
    let drive_part = drive_harmonic_part(cx, &base.model, &base.sim, &cx.plan.drive)?;
    let evidence: Vec<Tone> = facts
        .out_harmonics
        .iter()
        .enumerate()
        .map(|(i, t)| match drive_part.get(i) {
            Some(d) if i > 0 => {
                let (a, b) = (
                    t.amp * t.phase.cos() - d.amp * d.phase.cos(),
                    t.amp * t.phase.sin() - d.amp * d.phase.sin(),
                );
                Tone { freq_hz: t.freq_hz, amp: (a * a + b * b).sqrt(), phase: b.atan2(a) }
            }
            _ => *t,
        })
        .collect();
    let floor = cx.rules.terms.min_candidate_rel * facts.out_rms();
    let drift_floor = floor.min(cx.rules.sine.drift_noise_factor * facts.residual.noise_rms_um);
    let mut candidates = harmonics_and_drift(cx, &facts.residual, &evidence, floor, drift_floor);
    let w = &cx.plan.window;
    let steady_from = (w.start - w.drive_on).min(cx.y.len());
    let drive_amp_v = cx.plan.drive.harmonics.first().map_or(0.0, |t| t.amp);
    candidates.extend(causes::candidates(
        &facts.residual,
        &facts.out_harmonics,
        &cx.y[steady_from..],
        facts.noise_um.0,
        (cx.u, drive_amp_v),
        (base.model.ext.ar, cx.ts),
        &cx.rules.causes,
    ));
    Ok(Read { candidates, drive_part, drive_amp_v, steady_from })
}

/// Every harmonic `2..=sine.max_term_order` below Nyquist whose RMS in the output or in the
/// residual reaches `floor` (µm), and the drift if the trend's RMS reaches `drift_floor`.
fn harmonics_and_drift(
    cx: &Context<'_>,
    r: &Residual,
    out: &[Tone],
    floor: f64,
    drift_floor: f64,
) -> Vec<Candidate> {
    let (drive_hz, ts, max_order) = (cx.plan.drive.freq_hz, cx.ts, cx.rules.sine.max_term_order);
    let rms = |t: &Tone| t.amp / std::f64::consts::SQRT_2;
    let power = (r.rms_um * r.rms_um).max(1e-300);
    let mut c: Vec<Candidate> = r
        .harmonics
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(i, h)| rms(h) >= floor || out.get(*i).is_some_and(|o| rms(o) >= floor))
        .map(|(i, h)| {
            let order = (i + 1) as u32;
            Candidate {
                kind: Kind::of_order(order),
                order: Some(order),
                freq_hz: h.freq_hz,
                share: h.amp * h.amp / 2.0 / power,
                amp: h.amp,
                evidence_um: out.get(i).map_or(0.0, rms),
                output_range: None,
            }
        })
        .filter(|c| c.order.is_some_and(|o| o <= max_order && o as f64 * drive_hz < 0.5 / ts))
        .collect();
    if r.trend_rms_um >= drift_floor {
        c.push(Candidate {
            kind: Kind::Drift,
            order: None,
            freq_hz: 0.0,
            share: r.share(r.trend_rms_um),
            amp: r.trend_rms_um,
            evidence_um: r.trend_rms_um,
            output_range: None,
        });
    }
    c
}

/// The output's harmonics (µm, phases from the held-out part) that the drive's own
/// harmonics account for through `model`: its free run on `u` minus its free run on `u`
/// without the drive's harmonics `k ≥ 2`. Empty when the drive carries none worth it
/// (distortion under `sine.drive_distortion_floor`).
fn drive_harmonic_part(
    cx: &Context<'_>,
    model: &HostModel,
    sim: &[f64],
    drive: &Drive,
) -> Result<Vec<Tone>, DiagnoseError> {
    if drive.thd < cx.rules.sine.drive_distortion_floor {
        return Ok(vec![]);
    }
    let (u, ts, order) = (cx.u, cx.ts, cx.rules.sine.max_term_order as usize);
    let n = analysis::whole_periods(u.len(), drive.freq_hz, ts);
    let h = analysis::harmonics(&u[..n], drive.freq_hz, ts, order);
    let mut pure = u.to_vec();
    for t in h.iter().skip(1) {
        analysis::add_tone(&mut pure, &Tone { amp: -t.amp, ..*t }, ts, 0.0);
    }
    let sim_pure = model.simulate(&pure, ts)?;
    if checks::instability(&model.ext.ar, &sim_pure, ts).is_some() {
        // The model's loop runs away on the cleaned drive: no correction can be measured.
        return Ok(vec![]);
    }
    let s = cx.split();
    let d: Vec<f64> = sim[s..].iter().zip(&sim_pure[s..]).map(|(a, b)| a - b).collect();
    Ok(analysis::harmonics(&d, drive.freq_hz, ts, order))
}

//! Property tests of the core's invariants, over random parameters and inputs:
//!
//! * the hysteresis state stays in [`BoucWenParams::h_range`] for bounded input with the
//!   per-sample step that range assumes (classic, extended, enhanced), and the models'
//!   outputs stay within the bound their stable AR part gives;
//! * the RLS covariance, reconstructed from its U-D factors, stays symmetric positive
//!   definite;
//! * the models and the compensator in `f32` agree with `f64` within tolerance;
//! * a loop of any [`Controller`] and a [`Plant`] stays finite for finite references, with
//!   the drive inside the driver's range (a range whose steps keep the plant's own state
//!   bounded).

use boucwen_core::compensator::{
    AnyCompensator, CompensatorConfig, HarmonicSpec, PhaseRule, Saturation, harmonic_response,
};
use boucwen_core::controllers::{
    Controller, ORC_CAPACITY, OpenLoop, OpenLoopConfig, OrcConfig, OrcController, OrcPlacement, PiConfig,
    PiController,
};
use boucwen_core::model::{
    BoucWenParams, Classic, EnhancedParams, ExtendedParams, HarmonicBranch, HysteresisState, Model,
};
use boucwen_core::plant::{ModelPlant, Plant};
use boucwen_core::rls::{Rls, RlsConfig};
use boucwen_core::signal::{Oscillator, Sine};
use boucwen_core::{Real, model};
use nalgebra::{Cholesky, SMatrix, SVector};
use proptest::prelude::*;

const TS: f64 = 1e-3;

/// Hysteresis parameters for which `h_range` is invariant: `A > 0`, `|A0| ≤ A`,
/// `γ, β ≥ 0`, `s = γ + β > 0`, and `β ≥ γ` when `A0 ≠ 0` (see `h_range`'s docs).
fn hysteresis(asymmetric: bool) -> impl Strategy<Value = BoucWenParams<f64>> {
    (0.1f64..10.0, -1.0f64..1.0, 0.05f64..10.0, 0.0f64..1.0, -5.0f64..30.0).prop_map(
        move |(a, a0_rel, s, frac, a1)| {
            // β ≥ γ when there is an asymmetric term, any split otherwise.
            let gamma = if asymmetric { s * 0.5 * frac } else { s * frac };
            BoucWenParams { a1, a, a0: if asymmetric { a * a0_rel } else { 0.0 }, gamma, beta: s - gamma }
        },
    )
}

/// A bounded input with the step `h_range` assumes: `u[k] = clamp(u[k-1] + r_k/(γ + β), ±U)`,
/// `r_k ∈ [-1, 1]`, from `u = 0`.
fn drive(bw: &BoucWenParams<f64>, limit: f64, r: &[f64]) -> Vec<f64> {
    let s = bw.gamma + bw.beta;
    let mut u = 0.0;
    r.iter()
        .map(|&rk| {
            u = (u + rk / s).clamp(-limit, limit);
            u
        })
        .collect()
}

fn steps() -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(-1.0f64..=1.0, 1..600)
}

/// A stable AR part with `Σ|a_j| ≤ 0.9`, so `|y| ≤ B/(1 - Σ|a_j|)` for `|A1·u - h + …| ≤ B`.
fn ar2() -> impl Strategy<Value = [f64; 2]> {
    (-0.45f64..0.45, -0.45f64..0.45).prop_map(|(a, b)| [a, b])
}

fn cast(bw: &BoucWenParams<f64>) -> BoucWenParams<f32> {
    BoucWenParams {
        a1: bw.a1 as f32,
        a: bw.a as f32,
        a0: bw.a0 as f32,
        gamma: bw.gamma as f32,
        beta: bw.beta as f32,
    }
}

/// Checks that `h` stayed inside `[lo, hi]` up to `rel` of the range's width.
fn in_range<T: Real>(h: T, (lo, hi): (T, T), rel: f64) -> Result<(), TestCaseError> {
    let (h, lo, hi) = (h.to_f64(), lo.to_f64(), hi.to_f64());
    let tol = rel * (1.0 + hi - lo);
    prop_assert!(h >= lo - tol && h <= hi + tol, "h = {h} outside [{lo}, {hi}]");
    Ok(())
}

proptest! {
    // Failures print their minimal input; nothing is written next to the sources.
    #![proptest_config(ProptestConfig { failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn classic_hysteresis_stays_in_its_range(bw in hysteresis(false), limit in 0.1f64..50.0, r in steps()) {
        let range = bw.h_range().expect("γ + β > 0");
        let (bw32, range32) = (cast(&bw), cast(&bw).h_range().expect("γ + β > 0"));
        let model = Classic(bw);
        let model32 = Classic(bw32);
        let (mut s, mut s32) = (model.initial_state(), model32.initial_state());
        for u in drive(&bw, limit, &r) {
            let y = model.step(&mut s, u);
            model32.step(&mut s32, u as f32);
            in_range(s.h, range, 1e-9)?;
            in_range(s32.h, range32, 1e-4)?;
            prop_assert!((y - (bw.a1 * u - s.h)).abs() <= 1e-12 * (1.0 + y.abs()));
        }
    }

    #[test]
    fn extended_hysteresis_and_output_stay_bounded(
        bw in hysteresis(true),
        ar in ar2(),
        limit in 0.1f64..50.0,
        r in steps(),
    ) {
        let range = bw.h_range().expect("γ + β > 0");
        let model = ExtendedParams { bw, ar };
        let mut s = model.initial_state();
        let h_max = range.0.abs().max(range.1);
        let bound = (bw.a1.abs() * limit + h_max) / (1.0 - ar[0].abs() - ar[1].abs());
        for u in drive(&bw, limit, &r) {
            let y = model.step(&mut s, u);
            in_range(s.hyst.h, range, 1e-9)?;
            prop_assert!(y.abs() <= bound * (1.0 + 1e-9), "|y| = {} above {bound}", y.abs());
        }
    }

    #[test]
    fn enhanced_output_stays_bounded(
        bw in hysteresis(true),
        ar in ar2(),
        limit in 0.1f64..50.0,
        r in steps(),
        branches in prop::collection::vec((2u32..8, -2.0f64..2.0, -2.0f64..2.0, -0.9f64..0.9), 2),
        freq_hz in 0.5f64..60.0,
    ) {
        let range = bw.h_range().expect("γ + β > 0");
        let branch = |i: usize| {
            let (order, alpha_s, alpha_c, c) = branches[i];
            HarmonicBranch { order, alpha_s, alpha_c, ar: [c] }
        };
        let model = EnhancedParams::<f64, 2, 1, 2> {
            base: ExtendedParams { bw, ar },
            branches: [branch(0), branch(1)],
            drive: Oscillator::new(freq_hz, TS).expect("below Nyquist"),
        };
        let harmonics: f64 =
            model.branches.iter().map(|b| (b.alpha_s.abs() + b.alpha_c.abs()) / (1.0 - b.ar[0].abs())).sum();
        let h_max = range.0.abs().max(range.1);
        let bound = (bw.a1.abs() * limit + h_max + harmonics) / (1.0 - ar[0].abs() - ar[1].abs());
        let mut s = model.initial_state();
        for u in drive(&bw, limit, &r) {
            let y = model.step(&mut s, u);
            in_range(s.base.hyst.h, range, 1e-9)?;
            prop_assert!(y.abs() <= bound * (1.0 + 1e-9), "|y| = {} above {bound}", y.abs());
        }
    }

    #[test]
    fn rls_covariance_stays_symmetric_positive_definite(
        lambda in 0.9f64..=1.0,
        p0 in 1e-3f64..1e3,
        data in prop::collection::vec((prop::array::uniform4(-10.0f64..10.0), -100.0f64..100.0), 1..300),
    ) {
        let mut rls = Rls::<f64, 4>::new(RlsConfig::with_forgetting(lambda, p0), SVector::zeros())
            .expect("valid configuration");
        for (x, y) in &data {
            rls.update(&SVector::from(*x), *y).expect("finite data");
            let p: SMatrix<f64, 4, 4> = rls.covariance();
            let scale = p.amax();
            prop_assert!(scale.is_finite() && scale > 0.0);
            prop_assert!((p - p.transpose()).amax() <= 1e-12 * scale, "P is not symmetric: {p}");
            prop_assert!(Cholesky::new(p).is_some(), "P is not positive definite: {p}");
            prop_assert!((0..4).all(|i| p[(i, i)] > 0.0));
            prop_assert!((rls.trace() - p.trace()).abs() <= 1e-9 * p.trace());
        }
    }

    #[test]
    fn extended_model_in_f32_follows_f64(
        bw in hysteresis(true),
        ar in ar2(),
        limit in 0.1f64..20.0,
        r in steps(),
    ) {
        let model = ExtendedParams { bw, ar };
        let model32 = ExtendedParams { bw: cast(&bw), ar: ar.map(|a| a as f32) };
        let (mut s, mut s32) = (model.initial_state(), model32.initial_state());
        let range = bw.h_range().expect("γ + β > 0");
        let scale = (bw.a1.abs() * limit + range.0.abs().max(range.1)) / (1.0 - ar[0].abs() - ar[1].abs());
        for u in drive(&bw, limit, &r) {
            let y = model.step(&mut s, u);
            let y32 = model32.step(&mut s32, u as f32);
            prop_assert!(
                (y32 as f64 - y).abs() <= 1e-5 * scale,
                "f32 {y32} against f64 {y} (scale {scale})"
            );
        }
    }

    #[test]
    fn compensator_in_f32_follows_f64(
        a in 2.0f64..8.0,
        a0_rel in -0.3f64..0.3,
        ar in ar2(),
        alpha in 5.0f64..20.0,
        freq_hz in 1.0f64..40.0,
        branch in (-0.3f64..0.3, -0.3f64..0.3),
    ) {
        // A loop that is invertible everywhere (A1 larger than every hysteresis slope),
        // a third harmonic in the plant, the compensator cancelling it.
        let bw = BoucWenParams { a1: 20.0, a, a0: a * a0_rel, gamma: 1.0, beta: 2.0 };
        let model = ExtendedParams { bw, ar };
        let drive = Oscillator::new(freq_hz, TS).expect("below Nyquist");
        let spec = HarmonicSpec { order: 3, response: harmonic_response(&model, 3, freq_hz, TS, PhaseRule::Model) };
        let plant = EnhancedParams::<f64, 2, 0, 1> {
            base: model,
            branches: [HarmonicBranch { order: 3, alpha_s: branch.0, alpha_c: branch.1, ar: [] }],
            drive,
        };
        let model32 = ExtendedParams { bw: cast(&bw), ar: ar.map(|a| a as f32) };
        let plant32 = EnhancedParams::<f32, 2, 0, 1> {
            base: model32,
            branches: [HarmonicBranch { order: 3, alpha_s: branch.0 as f32, alpha_c: branch.1 as f32, ar: [] }],
            drive,
        };
        let spec32 = HarmonicSpec {
            order: 3,
            response: nalgebra::Complex::new(spec.response.re as f32, spec.response.im as f32),
        };
        let base = CompensatorConfig {
            model,
            drive,
            harmonics: [],
            rls: RlsConfig::with_forgetting(0.999, 1e-2),
            saturation: Saturation::symmetric(10.0),
            uc_max: 2.0,
        };
        let base32 = CompensatorConfig {
            model: model32,
            drive,
            harmonics: [],
            rls: RlsConfig::with_forgetting(0.999f32, 1e-2),
            saturation: Saturation::symmetric(10.0f32),
            uc_max: 2.0f32,
        };
        let mut c = AnyCompensator::new(base, &[spec]).expect("valid");
        let mut c32 = AnyCompensator::new(base32, &[spec32]).expect("valid");
        let (mut s, mut s32) = (plant.initial_state(), plant32.initial_state());
        let (mut d, mut d32) = (Sine::new(alpha, drive), Sine::new(alpha as f32, drive));
        let (mut y, mut y32) = (None, None);
        for _ in 0..3000 {
            let (dk, dk32) = (d.next_sample(), d32.next_sample());
            let (o, o32) = (c.step(dk, y).expect("finite"), c32.step(dk32, y32).expect("finite"));
            let (yk, yk32) = (plant.step(&mut s, o.u), plant32.step(&mut s32, o32.u));
            // The tracking errors agree to well under the sensor's 10 nm.
            prop_assert!(
                ((yk32 - dk32) as f64 - (yk - dk)).abs() <= 2e-3,
                "tracking error f32 {} against f64 {}", yk32 - dk32, yk - dk
            );
            (y, y32) = (Some(yk), Some(yk32));
        }
    }

    #[test]
    fn any_controller_on_a_plant_stays_finite(
        kind in 0usize..6,
        bw in hysteresis(true),
        ar in ar2(),
        gains in (0.0f64..5.0, 0.0f64..500.0, -1.0f64..1.0),
        orc in (0.0f64..0.25, 0.01f64..2.0, 0u32..8, 0.01f64..20.0, any::<bool>()),
        freq_hz in 2.0f64..40.0,
        limit_rel in 0.01f64..1.0,
        refs in prop::collection::vec((-1e3f64..1e3, 0u8..10), 1..1500),
    ) {
        // A driver range whose largest step, 2·limit, keeps the model's state bounded
        // (|Δu| ≤ 1/(γ + β)): the plant itself then stays finite under any drive in range.
        let limit = limit_rel * 0.5 / (bw.gamma + bw.beta);
        let sat = Saturation::symmetric(limit);
        let model = ExtendedParams { bw, ar };
        let drive = Oscillator::new(freq_hz, TS).expect("below Nyquist");
        let (kp, ki, kff) = gains;
        let pi = PiConfig { kp, ki_per_s: ki.max(1e-3), ts_s: TS, feedforward_gain: kff, saturation: sat };
        let orc = OrcConfig {
            drive,
            q_coeff: orc.0,
            learning_gain: orc.1,
            lead_samples: orc.2,
            limit: orc.3,
            placement: if orc.4 { OrcPlacement::PiInput } else { OrcPlacement::PlantInput },
        };
        let base = CompensatorConfig {
            model,
            drive,
            harmonics: [],
            rls: RlsConfig::with_forgetting(0.999, 1e-2),
            saturation: sat,
            uc_max: 2.0,
        };
        let spec = |order| HarmonicSpec { order, response: harmonic_response(&model, order, freq_hz, TS, PhaseRule::Model) };
        let mut ctrl: Box<dyn Controller<f64>> = match kind {
            0 => Box::new(OpenLoop::new(OpenLoopConfig { static_gain: bw.a1 - bw.a + 1.0, saturation: sat }).expect("valid")),
            1 => Box::new(PiController::new(pi).expect("valid")),
            2 => Box::new(OrcController::<f64, ORC_CAPACITY>::new(pi, orc).expect("valid")),
            k => Box::new(AnyCompensator::new(base, &[spec(3), spec(5)][..k - 3]).expect("valid")),
        };
        let mut plant = ModelPlant::new(model, TS).expect("valid");
        let mut y_prev = None;
        for (d, lose) in refs {
            let out = ctrl.step(d, y_prev).expect("finite inputs");
            prop_assert!(out.u.is_finite() && out.u.abs() <= limit, "u = {}", out.u);
            prop_assert!(out.u_ff.is_finite() && out.u_fb.is_finite() && out.u_rc.is_finite(), "{out:?}");
            let y = plant.step(out.u).expect("finite drive");
            prop_assert!(y.is_finite());
            // One measurement in ten is lost.
            y_prev = (lose != 0).then_some(y);
        }
    }
}

/// The conditions of the range's invariance are needed: with `γ > β` and `A0 > 0` the
/// falling branch's slope is negative near `h_hi`, so a falling input carries `h` past it
/// and on without bound.
#[test]
fn without_beta_at_least_gamma_an_asymmetric_loop_leaves_its_range() {
    let bw = BoucWenParams { a1: 0.0_f64, a: 1.0, a0: 0.5, gamma: 1.0, beta: 0.0 };
    let (_, hi) = bw.h_range().expect("γ + β > 0");
    let mut s = HysteresisState::default();
    let mut u = 0.0;
    for _ in 0..2000 {
        u += 0.01;
        s.step(&bw, u);
    }
    assert!((s.h - hi).abs() < 1e-6, "rising saturates at h_hi: {} vs {hi}", s.h);
    for _ in 0..200 {
        u -= 0.01;
        s.step(&bw, u);
    }
    assert!(s.h > 1.5 * hi, "falling carried h to {} (h_hi = {hi})", s.h);
}

/// The bound of the proptests above is not vacuous: a large input reaches near the range's
/// ends.
#[test]
fn the_range_is_reached() {
    let bw = BoucWenParams { a1: 1.0_f64, a: 2.0, a0: 0.5, gamma: 1.0, beta: 2.0 };
    let (lo, hi) = bw.h_range().expect("γ + β > 0");
    let model = model::Classic(BoucWenParams { a0: 0.0, ..bw });
    let (lo0, hi0) = model.0.h_range().expect("γ + β > 0");
    let mut s = model.initial_state();
    let mut s_ext = HysteresisState::default();
    let (mut h_min, mut h_max) = (0.0f64, 0.0f64);
    for k in 0..20_000 {
        let u = 20.0 * (k as f64 * 2e-3).sin();
        model.step(&mut s, u);
        s_ext.step(&bw, u);
        h_min = h_min.min(s_ext.h);
        h_max = h_max.max(s_ext.h);
    }
    assert!(h_min < 0.99 * lo && h_max > 0.99 * hi, "{h_min}..{h_max} in {lo}..{hi}");
    assert!(s.h >= lo0 && s.h <= hi0);
}

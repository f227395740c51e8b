use super::*;
use crate::compensator::Saturation;
use crate::model::{BoucWenParams, EnhancedParams, ExtendedParams, HarmonicBranch, Model};
use crate::signal::{Oscillator, Sine, sin_cos};
use crate::testing::assert_close;
use nalgebra::Complex;
use nalgebra::Matrix3;

const TS: f64 = 1e-3;

/// The compensator tests' plant: µm per volt, a resonance near 70 Hz, a saturating loop.
fn plant() -> ExtendedParams<f64, 2> {
    let w0 = core::f64::consts::TAU * 70.0 * TS;
    ExtendedParams {
        bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
        ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
    }
}

/// The plant with a third harmonic of the drive `f` (0.12 µm·20 = 2.3 µm... see test).
fn enhanced(f: f64) -> EnhancedParams<f64, 2, 0, 1> {
    EnhancedParams {
        base: plant(),
        branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }],
        drive: Oscillator::new(f, TS).unwrap(),
    }
}

fn sat() -> Saturation<f64> {
    Saturation::symmetric(10.0)
}

fn tuned(f: f64) -> Tuning<f64> {
    tune(&plant(), Oscillator::new(f, TS).unwrap(), TS, sat(), &TuneOptions::default()).unwrap()
}

/// Runs `n` samples of `ctrl` on `plant` tracking `amplitude·sin(2π f k Ts)`; every
/// `lose`-th measurement is lost (0: none). Returns the tracking errors `y - d`.
fn track<C: Controller<f64>>(
    ctrl: &mut C,
    plant: &EnhancedParams<f64, 2, 0, 1>,
    amplitude: f64,
    n: usize,
    lose: usize,
) -> Vec<f64> {
    track_delayed(ctrl, plant, amplitude, n, lose, 0)
}

/// [`track`] with the plant's input delayed by `delay` samples.
fn track_delayed<C: Controller<f64>>(
    ctrl: &mut C,
    plant: &EnhancedParams<f64, 2, 0, 1>,
    amplitude: f64,
    n: usize,
    lose: usize,
    delay: usize,
) -> Vec<f64> {
    let mut s = plant.initial_state();
    let mut d = Sine::new(amplitude, plant.drive);
    let mut y_prev = None;
    let mut line = std::collections::VecDeque::from(std::vec![0.0; delay]);
    (0..n)
        .map(|k| {
            let dk = d.next_sample();
            let meas = if lose > 0 && k % lose == 0 { None } else { y_prev };
            let out = ctrl.step(dk, meas).unwrap();
            line.push_back(out.u);
            let u = line.pop_front().unwrap_or(out.u);
            let y = plant.step(&mut s, u);
            y_prev = Some(y);
            y - dk
        })
        .collect()
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// Amplitude of the component at `freq_hz` (least squares on sin/cos over whole periods).
fn tone(x: &[f64], freq_hz: f64) -> f64 {
    let w = core::f64::consts::TAU * freq_hz * TS;
    let (mut s, mut c) = (0.0, 0.0);
    for (k, v) in x.iter().enumerate() {
        s += v * (w * k as f64).sin();
        c += v * (w * k as f64).cos();
    }
    2.0 * (s * s + c * c).sqrt() / x.len() as f64
}

/// Root-sum-square amplitude of the odd harmonics 1, 3, 5 of `f`.
fn odd_content(x: &[f64], f: f64) -> f64 {
    [1.0, 3.0, 5.0].iter().map(|n| tone(x, n * f).powi(2)).sum::<f64>().sqrt()
}

#[test]
fn open_loop_is_d_over_the_static_gain() {
    let p = plant();
    // Independently: (A1 - A)/(1 - a1 - a2).
    let g0 = 14.0 / (1.0 - p.ar[0] - p.ar[1]);
    let t = tuned(10.0);
    assert_close(t.open_loop.static_gain, g0, 1e-12 * g0);
    let mut ol = OpenLoop::new(t.open_loop).unwrap();
    for k in 0..1000 {
        let d = 300.0 * (k as f64 * 0.013).sin();
        let out = ol.step(d, Some(1.0)).unwrap();
        if (d / g0).abs() <= 10.0 {
            assert_close(out.u, d / g0, 1e-15 * (1.0 + d.abs()));
            assert!(!out.saturated);
        } else {
            assert_eq!((out.u, out.saturated), (10.0f64.copysign(d), true));
        }
    }
}

#[test]
fn half_period_and_taps() {
    assert_eq!(half_period(Oscillator::new(10.0, TS).unwrap()).unwrap(), (50, 0.0));
    assert_eq!(half_period(Oscillator::new(4.0, TS).unwrap()).unwrap(), (125, 0.0));
    let (l0, mu) = half_period(Oscillator::new(23.0, TS).unwrap()).unwrap();
    assert_eq!(l0, 21);
    assert_close(mu, 500.0 / 23.0 - 21.0, 1e-9);
    let cfg = OrcConfig {
        drive: Oscillator::new(23.0, TS).unwrap(),
        q_coeff: 0.1,
        learning_gain: 0.5,
        lead_samples: 3,
        limit: 1.0,
        placement: OrcPlacement::PlantInput,
    };
    let h = cfg.taps(mu);
    assert_close(h.iter().sum::<f64>(), 1.0, 1e-15);
    // [0.1, 0.8, 0.1] * [1-μ, μ]
    assert_close(h[0], 0.1 * (1.0 - mu), 1e-15);
    assert_close(h[3], 0.1 * mu, 1e-15);
    assert_close(h[1], 0.8 * (1.0 - mu) + 0.1 * mu, 1e-15);
    assert!(half_period(Oscillator::from_increment(0)).is_err());
}

#[test]
fn recursion_matches_the_difference_equation() {
    // L = 6.4 (78.125 Hz at 1 kHz), a = 0.2, m = 2, k_r = 0.7: an independent, array-based
    // evaluation of u[k] = -Σ_i h_i (u[k - o_i] + k_r e[k - o_i + m]), o_i = L0 - 1 + i.
    let drive = Oscillator::new(78.125, TS).unwrap();
    let cfg = OrcConfig {
        drive,
        q_coeff: 0.2,
        learning_gain: 0.7,
        lead_samples: 2,
        limit: 1e9,
        placement: OrcPlacement::PlantInput,
    };
    let mut mem = OrcMemory::<f64, 16>::new(cfg).unwrap();
    let (l0, mu) = half_period(drive).unwrap();
    assert_eq!(l0, 6);
    assert_close(mu, 0.4, 1e-9);
    let (a, nu) = (0.2, 1.0 - mu);
    let h = [a * nu, 0.6 * nu + a * mu, a * nu + 0.6 * mu, a * mu];
    let n = 300;
    let e: Vec<f64> = (0..n).map(|k| ((k * 7919) % 101) as f64 / 50.0 - 1.0).collect();
    let mut u = vec![0.0; n];
    for k in 0..n {
        let mut acc = 0.0;
        for (i, hi) in h.iter().enumerate() {
            let o = l0 - 1 + i;
            // Zero initial conditions: u[j] = 0 for j < 0, but e[j + m] exists for j >= -m.
            let past_u = if k >= o { u[k - o] } else { 0.0 };
            if k + 2 >= o {
                acc += hi * (past_u + 0.7 * e[k + 2 - o]);
            }
        }
        u[k] = -acc;
        // The memory learns e[k-1] at step k.
        let got = mem.step(if k > 0 { Some(e[k - 1]) } else { None });
        assert_close(got, u[k], 1e-12 * (1.0 + u[k].abs()));
    }
    assert!(u[n - 50..].iter().any(|x| x.abs() > 0.1), "the check is not vacuous");
}

/// Feeds `e` (as `e[k-1]` at step `k`) to an internal model; returns the largest `|u_rc|`.
fn drive_memory<const N: usize>(cfg: OrcConfig<f64>, e: impl Fn(u64) -> f64, n: u64) -> f64 {
    let mut mem = OrcMemory::<f64, N>::new(cfg).unwrap();
    (0..n).map(|k| mem.step(if k > 0 { Some(e(k - 1)) } else { None }).abs()).fold(0.0, f64::max)
}

#[test]
fn the_internal_model_integrates_odd_harmonics_and_not_even_ones() {
    for f in [10.0, 23.0] {
        let drive = Oscillator::new(f, TS).unwrap();
        // Q = 1, no lead, k_r = 1: the bare internal model -z^{-L}/(1 + z^{-L}).
        let cfg = OrcConfig {
            drive,
            q_coeff: 0.0,
            learning_gain: 1.0,
            lead_samples: 0,
            limit: 1e9,
            placement: OrcPlacement::PlantInput,
        };
        let periods = 40;
        let n = (periods as f64 / (f * TS)) as u64;
        let harmonic =
            |order: u32| move |k: u64| sin_cos::<f64>(drive.phase_at(k).wrapping_mul(order as u64)).0;
        let odd1 = drive_memory::<512>(cfg, harmonic(1), n);
        let odd3 = drive_memory::<512>(cfg, harmonic(3), n);
        let even2 = drive_memory::<512>(cfg, harmonic(2), n);
        let even4 = drive_memory::<512>(cfg, harmonic(4), n);
        let dc = drive_memory::<512>(cfg, |_| 1.0, n);
        // An odd harmonic gains about its amplitude every half period (80 here);
        // an even one or a constant stays within its own amplitude.
        assert!(odd1 > 30.0 && odd3 > 30.0, "{f} Hz: odd harmonics reached {odd1}, {odd3}");
        assert!(
            even2 <= 1.0 + 1e-9 && even4 <= 1.0 + 1e-9 && dc <= 1.0 + 1e-9,
            "{f} Hz: {even2} {even4} {dc}"
        );
    }
}

#[test]
fn the_limit_bounds_the_memory() {
    let drive = Oscillator::new(10.0, TS).unwrap();
    let cfg = OrcConfig {
        drive,
        q_coeff: 0.0,
        learning_gain: 1.0,
        lead_samples: 0,
        limit: 3.0,
        placement: OrcPlacement::PlantInput,
    };
    let big = drive_memory::<512>(cfg, |k| sin_cos::<f64>(drive.phase_at(k)).0, 20_000);
    assert_close(big, 3.0, 0.0);
}

#[test]
fn pi_steps_by_hand_and_anti_windup() {
    let cfg = PiConfig {
        kp: 0.5,
        ki_per_s: 100.0,
        ts_s: TS,
        feedforward_gain: 0.1,
        saturation: Saturation::symmetric(1.0),
    };
    let mut pi = PiController::new(cfg).unwrap();
    // k = 0: no measurement: u = 0.1·2 = 0.2 (the held ε is 0).
    assert_close(pi.step(2.0, Some(5.0)).unwrap().u, 0.2, 1e-15);
    // k = 1: e[0] = 2 - 1.5 = 0.5: I = 0.05, u = 0.1 + 0.25 + 0.05
    let out = pi.step(1.0, Some(1.5)).unwrap();
    assert_close(out.u, 0.4, 1e-15);
    assert_close(out.u_fb, 0.3, 1e-15);
    // k = 2: lost: ε held at 0.5, no integration: u = 0 + 0.25 + 0.05
    assert_close(pi.step(0.0, None).unwrap().u, 0.3, 1e-15);
    // A large persistent error saturates; the integrator does not move while it pushes
    // outward (a plain integrator would gain 100·1e-3·3 = 0.3 per sample).
    let i_before = pi.state().integral;
    for _ in 0..1000 {
        assert!(pi.step(0.0, Some(-3.0)).unwrap().saturated);
    }
    assert_eq!(pi.state().integral, i_before);
    // When the error reverses, the output leaves the limit at once.
    let out = pi.step(0.0, Some(0.5)).unwrap();
    assert!(!out.saturated && out.u < 0.0, "{out:?}");
}

/// The roots of `z³ + c2 z² + c1 z + c0`, by the companion matrix.
fn cubic_roots_max_modulus(c2: f64, c1: f64, c0: f64) -> f64 {
    let m = Matrix3::new(-c2, -c1, -c0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
    m.complex_eigenvalues().iter().map(|z| z.norm_sqr().sqrt()).fold(0.0, f64::max)
}

#[test]
fn the_tuned_pi_is_stable_with_the_stated_margins() {
    let p = plant();
    let d = tune_pi(&p, TS, sat(), &TuneOptions::default()).unwrap();
    let g0 = d.static_gain;
    let (kp, ki) = (d.pi.kp * g0, d.pi.ki_per_s * g0 * TS);
    assert!(ki > 0.0 && kp >= 0.0);
    let dc = 1.0 - p.ar[0] - p.ar[1];
    for kappa in [d.gain_factors.0, 1.0, d.gain_factors.1] {
        // (1 - z⁻¹)(1 - a1 z⁻¹ - a2 z⁻²) + κ·dc·z⁻¹(kp(1 - z⁻¹) + ki) = 0, times z³.
        let g = kappa * dc;
        let c2 = -1.0 - p.ar[0] + g * (kp + ki);
        let c1 = p.ar[0] - p.ar[1] - g * kp;
        let c0 = p.ar[1];
        let r = cubic_roots_max_modulus(c2, c1, c0);
        assert!(r < 1.0, "κ = {kappa}: closed-loop pole at |z| = {r}");
    }
    // |S| on a finer, offset grid stays within Ms (up to the design grid's resolution).
    let mut peak: f64 = 0.0;
    for i in 0..20_000 {
        let w = core::f64::consts::PI * (i as f64 + 0.37) / 20_000.0;
        let zi = Complex::new(w.cos(), -w.sin());
        let pn = Complex::new(dc, 0.0) / (Complex::new(1.0, 0.0) - zi * p.ar[0] - zi * zi * p.ar[1]);
        let l = (Complex::new(kp, 0.0) + Complex::new(ki, 0.0) / (Complex::new(1.0, 0.0) - zi)) * zi * pn;
        for kappa in [d.gain_factors.0, 1.0, d.gain_factors.1] {
            peak = peak.max(1.0 / (Complex::new(1.0, 0.0) + l * kappa).norm_sqr().sqrt());
        }
    }
    assert!(peak <= 1.5 * 1.01, "|S| peaks at {peak}");
    assert!((peak - d.sensitivity_peak).abs() < 0.02, "{peak} vs {}", d.sensitivity_peak);
    // The incremental gain range of this loop: (A1 - slope)/(A1 - A) over h's range.
    assert!(d.gain_factors.0 < 1.0 && d.gain_factors.1 > 1.0);
    assert!(d.crossover_hz > 0.1 && d.crossover_hz < 20.0, "crossover {} Hz", d.crossover_hz);
}

#[test]
fn pi_alone_is_stable_and_tracks_a_slow_sine_with_some_error() {
    let t = tuned(1.0);
    let mut pi = PiController::new(t.pi.pi).unwrap();
    let err = track(&mut pi, &enhanced(1.0), 20.0, 20_000, 0);
    let late = rms(&err[10_000..]);
    let early_max = err.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    assert!(late < 0.5 * 20.0 / core::f64::consts::SQRT_2, "PI leaves {late} µm RMS");
    assert!(late > 0.1, "PI alone should not track perfectly: {late} µm RMS");
    assert!(early_max < 60.0, "bounded: largest error {early_max} µm");
    // A static feedforward takes most of the load.
    let opts = TuneOptions { static_feedforward: true, ..TuneOptions::default() };
    let t = tune(&plant(), Oscillator::new(1.0, TS).unwrap(), TS, sat(), &opts).unwrap();
    let mut pi_ff = PiController::new(t.pi.pi).unwrap();
    let err_ff = track(&mut pi_ff, &enhanced(1.0), 20.0, 20_000, 0);
    assert!(rms(&err_ff[10_000..]) < late, "{} vs {late}", rms(&err_ff[10_000..]));
}

#[test]
fn orc_removes_the_odd_harmonics_that_pi_leaves() {
    for (f, placement) in [
        (5.0, OrcPlacement::PiInput),
        (23.0, OrcPlacement::PiInput),
        (5.0, OrcPlacement::PlantInput),
        (23.0, OrcPlacement::PlantInput),
    ] {
        let opts = TuneOptions { orc_placement: placement, ..TuneOptions::default() };
        let t = tune(&plant(), Oscillator::new(f, TS).unwrap(), TS, sat(), &opts).unwrap();
        assert_eq!(t.orc.orc.placement, placement);
        let plant = enhanced(f);
        let n = 20_000;
        let mut pi = PiController::new(t.pi.pi).unwrap();
        let err_pi = track(&mut pi, &plant, 20.0, n, 0);
        let mut orc = OrcController::<f64, ORC_CAPACITY>::new(t.pi.pi, t.orc.orc).unwrap();
        let err_orc = track(&mut orc, &plant, 20.0, n, 0);
        // Whole periods of f at the end.
        let tail = (10.0 / (f * TS)).round() as usize;
        let (a, b) = (&err_pi[n - tail..], &err_orc[n - tail..]);
        let (odd_pi, odd_orc) = (odd_content(a, f), odd_content(b, f));
        assert!(odd_orc < odd_pi / 20.0, "{f} Hz {placement:?}: odd harmonics {odd_pi} µm -> {odd_orc} µm");
        assert!(rms(b) < rms(a) / 10.0, "{f} Hz {placement:?}: RMS {} -> {}", rms(a), rms(b));
        // The even harmonic (from the loop's asymmetry A0) is outside the internal model.
        let (even_pi, even_orc) = (tone(a, 2.0 * f), tone(b, 2.0 * f));
        assert!(even_orc > 0.2 * even_pi, "{f} Hz {placement:?}: 2nd harmonic {even_pi} -> {even_orc}");
        // Lost measurements (1 in 50) slow the learning but do not break it.
        let mut orc = OrcController::<f64, ORC_CAPACITY>::new(t.pi.pi, t.orc.orc).unwrap();
        let err_lossy = track(&mut orc, &plant, 20.0, n, 50);
        let odd_lossy = odd_content(&err_lossy[n - tail..], f);
        assert!(odd_lossy < odd_pi / 10.0, "{f} Hz {placement:?} with losses: {odd_lossy} µm");
    }
}

#[test]
fn the_tuning_accounts_for_an_input_delay() {
    // The same plant behind a 3-sample transport delay, a 1 kHz loop at 23 Hz.
    let (f, delay) = (23.0, 3);
    let plant = enhanced(f);
    let opts = TuneOptions { input_delay_samples: delay as f64, ..TuneOptions::default() };
    let t = tune(&plant.base, Oscillator::new(f, TS).unwrap(), TS, sat(), &opts).unwrap();
    let t0 = tuned(f);
    // The delay costs phase at the harmonics: more lead.
    assert!(t.orc.orc.lead_samples > t0.orc.orc.lead_samples);
    let n = 20_000;
    let tail = (10.0 / (f * TS)).round() as usize;
    let mut pi = PiController::new(t.pi.pi).unwrap();
    let err_pi = track_delayed(&mut pi, &plant, 20.0, n, 0, delay);
    let mut orc = OrcController::<f64, ORC_CAPACITY>::new(t.pi.pi, t.orc.orc).unwrap();
    let err_orc = track_delayed(&mut orc, &plant, 20.0, n, 0, delay);
    let (odd_pi, odd_orc) = (odd_content(&err_pi[n - tail..], f), odd_content(&err_orc[n - tail..], f));
    assert!(odd_orc < odd_pi / 20.0, "odd harmonics {odd_pi} µm -> {odd_orc} µm");
    assert!(err_orc.iter().all(|e| e.abs() < 100.0), "bounded");
    // The design that ignores the delay diverges on the same plant.
    let mut blind = OrcController::<f64, ORC_CAPACITY>::new(t0.pi.pi, t0.orc.orc).unwrap();
    let err_blind = track_delayed(&mut blind, &plant, 20.0, n, 0, delay);
    let worst = err_blind.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    assert!(worst > 1e3, "the blind design stayed within {worst} µm");
}

#[test]
fn non_finite_inputs_are_rejected_without_change() {
    let t = tuned(23.0);
    let mut orc = OrcController::<f64, ORC_CAPACITY>::new(t.pi.pi, t.orc.orc).unwrap();
    let mut pi = PiController::new(t.pi.pi).unwrap();
    let mut ol = OpenLoop::new(t.open_loop).unwrap();
    for k in 0..300 {
        let d = (k as f64 * 0.1).sin();
        orc.step(d, Some(0.5 * d)).unwrap();
        pi.step(d, Some(0.5 * d)).unwrap();
    }
    let (orc0, pi0, ol0) = (orc.clone(), pi, ol);
    for (d, y) in [(f64::NAN, Some(0.0)), (1.0, Some(f64::INFINITY)), (f64::NEG_INFINITY, None)] {
        let want = if d.is_finite() { Error::NonFinite("y") } else { Error::NonFinite("d") };
        assert_eq!(orc.step(d, y), Err(want));
        assert_eq!(pi.step(d, y), Err(want));
        assert_eq!(ol.step(d, y), Err(want));
    }
    assert_eq!(orc.step_with_feedforward(1.0, None, f64::NAN), Err(Error::NonFinite("u_ff")));
    assert_eq!(pi.step_with_feedforward(1.0, None, f64::NAN), Err(Error::NonFinite("u_ff")));
    assert_eq!((&orc, &pi, &ol), (&orc0, &pi0, &ol0));
    // reset returns to k = 0.
    orc.reset();
    assert_eq!(orc, OrcController::new(t.pi.pi, t.orc.orc).unwrap());
}

#[test]
fn invalid_configurations_are_named() {
    let drive = Oscillator::new(5.0, TS).unwrap(); // L = 100
    let ok = OrcConfig {
        drive,
        q_coeff: 0.1,
        learning_gain: 0.5,
        lead_samples: 4,
        limit: 10.0,
        placement: OrcPlacement::PlantInput,
    };
    assert!(OrcMemory::<f64, 102>::new(ok).is_ok());
    assert_eq!(
        OrcMemory::<f64, 101>::new(ok).err(),
        Some(Error::OutOfRange(
            "ORC half period (N/2 + 2 exceeds the delay line's capacity: reference too slow)"
        ))
    );
    let bad = |c: OrcConfig<f64>| OrcMemory::<f64, 512>::new(c).err();
    assert!(matches!(bad(OrcConfig { lead_samples: 99, ..ok }), Some(Error::OutOfRange(_))));
    assert!(bad(OrcConfig { lead_samples: 98, ..ok }).is_none());
    assert!(matches!(bad(OrcConfig { learning_gain: 0.0, ..ok }), Some(Error::OutOfRange(_))));
    assert!(bad(OrcConfig { learning_gain: -0.5, ..ok }).is_none(), "a negative G0 needs a negative gain");
    assert_eq!(bad(OrcConfig { learning_gain: f64::NAN, ..ok }), Some(Error::NonFinite("ORC learning gain")));
    assert!(matches!(bad(OrcConfig { q_coeff: 0.3, ..ok }), Some(Error::OutOfRange(_))));
    assert!(matches!(bad(OrcConfig { limit: 0.0, ..ok }), Some(Error::OutOfRange(_))));
    assert!(matches!(
        bad(OrcConfig { drive: Oscillator::from_increment(0), ..ok }),
        Some(Error::OutOfRange(_))
    ));

    let pi = PiConfig { kp: 0.1, ki_per_s: 5.0, ts_s: TS, feedforward_gain: 0.0, saturation: sat() };
    assert!(PiController::new(pi).is_ok());
    assert!(PiController::new(PiConfig { kp: -0.1, ..pi }).is_err());
    assert!(PiController::new(PiConfig { kp: 0.0, ki_per_s: 0.0, ..pi }).is_err());
    assert!(PiController::new(PiConfig { ts_s: 0.0, ..pi }).is_err());
    assert_eq!(PiController::new(PiConfig { kp: f64::NAN, ..pi }).err(), Some(Error::NonFinite("PI Kp")));
    assert!(PiController::new(PiConfig { saturation: Saturation { u_min: 1.0, u_max: 0.0 }, ..pi }).is_err());
    assert!(OrcController::<f64, 512>::new(PiConfig { ki_per_s: f64::INFINITY, ..pi }, ok).is_err());

    assert!(OpenLoop::new(OpenLoopConfig { static_gain: 0.0, saturation: sat() }).is_err());
    assert!(OpenLoop::new(OpenLoopConfig { static_gain: f64::NAN, saturation: sat() }).is_err());

    // Tuning refuses models it cannot design on.
    let mut unstable = plant();
    unstable.ar = [1.5, -0.4]; // a root at 1.1
    let opts = TuneOptions::default();
    assert!(matches!(tune(&unstable, drive, TS, sat(), &opts), Err(Error::OutOfRange(_))));
    let mut flat = plant();
    flat.bw.a = flat.bw.a1; // zero small-signal gain
    assert!(tune(&flat, drive, TS, sat(), &opts).is_err());
    assert!(tune(&plant(), drive, TS, sat(), &TuneOptions { max_sensitivity: 1.0, ..opts }).is_err());
    assert!(tune(&plant(), drive, 0.0, sat(), &opts).is_err());
    // 400 Hz at 1 kHz: N/2 = 1.25 samples, too short for the ORC.
    assert!(tune(&plant(), Oscillator::new(400.0, TS).unwrap(), TS, sat(), &opts).is_err());
}

#[test]
fn f32_and_f64_run_and_agree() {
    let f = 23.0;
    let t64 = tuned(f);
    let p = plant();
    let p32 = ExtendedParams {
        bw: BoucWenParams { a1: 20.0f32, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
        ar: p.ar.map(|a| a as f32),
    };
    let drive = Oscillator::new(f, TS).unwrap();
    let t32 = tune(&p32, drive, 1e-3f32, Saturation::symmetric(10.0f32), &TuneOptions::default()).unwrap();
    assert_eq!(t32.orc.orc.lead_samples, t64.orc.orc.lead_samples);
    assert!((t32.orc.orc.q_coeff as f64 - t64.orc.orc.q_coeff).abs() < 1e-8);
    assert!((t32.pi.pi.ki_per_s as f64 / t64.pi.pi.ki_per_s - 1.0).abs() < 1e-3);
    let plant32 = EnhancedParams::<f32, 2, 0, 1> {
        base: p32,
        branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }],
        drive,
    };
    let plant64 = enhanced(f);
    // Both run the same tuned gains (f32's cast from f64's) for comparison.
    let cast_sat = Saturation::symmetric(10.0f32);
    let pi32 = PiConfig {
        kp: t64.pi.pi.kp as f32,
        ki_per_s: t64.pi.pi.ki_per_s as f32,
        ts_s: 1e-3f32,
        feedforward_gain: 0.0,
        saturation: cast_sat,
    };
    let o = t64.orc.orc;
    let orc32 = OrcConfig {
        drive,
        q_coeff: o.q_coeff as f32,
        learning_gain: o.learning_gain as f32,
        lead_samples: o.lead_samples,
        limit: o.limit as f32,
        placement: o.placement,
    };
    let mut c32 = OrcController::<f32, ORC_CAPACITY>::new(pi32, orc32).unwrap();
    let mut c64 = OrcController::<f64, ORC_CAPACITY>::new(t64.pi.pi, o).unwrap();
    let (mut s32, mut s64) = (plant32.initial_state(), plant64.initial_state());
    let (mut d32, mut d64) = (Sine::new(20.0f32, drive), Sine::new(20.0f64, drive));
    let (mut y32, mut y64) = (None, None);
    let mut worst: f64 = 0.0;
    let mut last = (0.0, 0.0);
    for _ in 0..5000 {
        let (a, b) = (d32.next_sample(), d64.next_sample());
        let (o32, o64) = (c32.step(a, y32).unwrap(), c64.step(b, y64).unwrap());
        let (ya, yb) = (plant32.step(&mut s32, o32.u), plant64.step(&mut s64, o64.u));
        assert!(ya.is_finite() && yb.is_finite());
        worst = worst.max(((ya - a) as f64 - (yb - b)).abs());
        last = ((ya - a) as f64, yb - b);
        (y32, y64) = (Some(ya), Some(yb));
    }
    assert!(worst < 0.05, "largest tracking-error gap {worst} µm (last {last:?})");
}

//! Records of an actuator that is not the project's: a piezo stack whose hysteresis is a
//! Prandtl–Ishlinskii sum of play operators (not a Bouc–Wen loop), with a stiff first mode,
//! driven as stacks are on a bench (a unipolar amplifier, 0 to 100 V), sampled at 10 kHz,
//! with sensor noise; a sensor that loses its target now and then. What the diagnosis reads
//! of the drive and the record must not depend on the simulator it was developed against.
//!
//! Each case failed before the change it guards: the drive's mean leaked into its tone
//! (a pure 1 Hz sine about 50 V read as 0.985 Hz with 1.6 % distortion, and its output as
//! settling for 3 s), a 1 Hz triangle over 5 s read as 0.999 Hz (four whole periods became
//! three: "record more periods"), a square's fast harmonics and the dropouts were counted
//! as noise.

use boucwen_lab::diagnose::periodic::Realisation;
use boucwen_lab::diagnose::{self, DiagnoseError, Kind, Outcome};
use boucwen_lab::record::{ImportOptions, import_text};
use boucwen_lab::rules::Rules;
use boucwen_lab::signal::steady::DriveKind;
use std::f64::consts::TAU;
use std::fmt::Write as _;

/// Sampling interval of the stack's records (10 kHz).
const TS: f64 = 1e-4;

/// A stack of 15 µm stroke at 100 V: play operators of radii 0..90 V with weights
/// falling off (12 % hysteresis), a 2nd-order mode at 2 kHz (ζ = 0.05, bilinear), 2 nm of
/// deterministic pseudo-random sensor noise.
fn stack(u: &[f64]) -> Vec<f64> {
    let radii: Vec<f64> = (0..10).map(|i| 10.0 * i as f64).collect();
    let w: Vec<f64> = (0..10).map(|i| (-(i as f64) / 3.0).exp()).collect();
    let wsum: f64 = w.iter().sum();
    let mut z = [0.0f64; 10];
    // The mode: bilinear transform of w²/(s² + 2ζws + w²).
    let wn = TAU * 2000.0;
    let k = 2.0 / TS;
    let (a0, a1, a2) = (
        k * k + 2.0 * 0.05 * wn * k + wn * wn,
        2.0 * wn * wn - 2.0 * k * k,
        k * k - 2.0 * 0.05 * wn * k + wn * wn,
    );
    let b = wn * wn / a0;
    let (mut x1, mut x2, mut y1, mut y2) = (0.0, 0.0, 0.0, 0.0);
    let mut g = 0x2545_f491_4f6c_dd1du64;
    u.iter()
        .map(|&v| {
            for (zi, r) in z.iter_mut().zip(&radii) {
                *zi = (*zi).max(v - r).min(v + r);
            }
            let h: f64 = z.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>() / wsum;
            let x = (0.88 * v + 0.12 * h) * 0.15;
            let y = b * (x + 2.0 * x1 + x2) - (a1 * y1 + a2 * y2) / a0;
            (x2, x1, y2, y1) = (x1, x, y1, y);
            g ^= g << 13;
            g ^= g >> 7;
            g ^= g << 17;
            y + 0.002 * 3f64.sqrt() * (2.0 * (g >> 11) as f64 / (1u64 << 53) as f64 - 1.0)
        })
        .collect()
}

/// The record as a bench writes it: time in s, volts, micrometres, unit-named columns.
fn csv(u: &[f64], y: &[f64]) -> String {
    let mut s = String::from("Time [s],Piezo Voltage (V),Displacement [um]\n");
    for k in 0..u.len() {
        let _ = writeln!(s, "{:.4},{:.6},{:.6}", k as f64 * TS, u[k], y[k]);
    }
    s
}

fn outcome(text: &str) -> Result<Outcome, DiagnoseError> {
    let r = import_text(text, "stack.csv", &ImportOptions::default()).expect("read").record;
    let rec = Realisation { u: &r.u, y: &r.y, t0: r.t0, given: None };
    diagnose::diagnose_drive(&[rec], r.ts, &Rules::default())
}

#[test]
fn a_unipolar_sine_is_a_pure_sine_and_every_period_after_the_first_is_analysed() {
    let u: Vec<f64> = (0..100_000).map(|k| 50.0 - 50.0 * (TAU * k as f64 * TS).cos()).collect();
    let y = stack(&u);
    let Ok(Outcome::Sine(d)) = outcome(&csv(&u, &y)) else { panic!("a sine diagnosis") };
    assert_eq!(d.drive.kind, DriveKind::Sine);
    assert!((d.drive_hz - 1.0).abs() < 1e-6 && d.drive.thd < 1e-4, "{} Hz, {}", d.drive_hz, d.drive.thd);
    // The first period is the loop's virgin branch; the nine after it are whole periods.
    let [w0, w1] = d.window_s();
    assert!((w0 - 1.0).abs() < 0.01 && (w1 - 10.0).abs() < 1e-9, "{w0}–{w1}: {}", d.window.why);
    assert_eq!(d.periods.0 + d.periods.1, 9);
    // The noise floor is the sensor's (2 nm), and the Bouc–Wen loop follows the
    // play operators to within a few times it.
    assert!((d.noise_um.0 - 0.002).abs() < 0.0005, "{}", d.noise_um.0);
    assert!(d.baseline_rms_um < 0.01, "{}", d.baseline_rms_um);
}

#[test]
fn a_triangle_of_five_periods_keeps_its_four_after_the_first() {
    let u: Vec<f64> = (0..50_000)
        .map(|k| {
            let p = (k as f64 * TS) % 1.0;
            100.0 * if p < 0.5 { 2.0 * p } else { 2.0 - 2.0 * p }
        })
        .collect();
    let y = stack(&u);
    let Ok(Outcome::Periodic(d)) = outcome(&csv(&u, &y)) else { panic!("a periodic diagnosis") };
    assert_eq!(d.drive.kind, DriveKind::Periodic);
    assert!((d.drive.freq_hz - 1.0).abs() < 1e-6, "{}", d.drive.freq_hz);
    assert_eq!(d.periods, vec![4]);
    // The corners' harmonics above the 40th repeat from period to period: not noise.
    assert!(d.noise_um < 0.003, "{}", d.noise_um);
}

#[test]
fn a_slow_drive_of_three_periods_is_refused_for_its_own_period() {
    let n = 300_000; // 30 s of 0.1 Hz
    let u: Vec<f64> = (0..n).map(|k| 50.0 - 50.0 * (TAU * 0.1 * k as f64 * TS).cos()).collect();
    let y = stack(&u);
    match outcome(&csv(&u, &y)) {
        Err(e @ DiagnoseError::TooFewPeriods { .. }) => {
            let s = e.to_string();
            assert!(s.contains("of the 0.100 Hz drive") && s.contains("record more periods"), "{s}");
        }
        other => panic!("{:?}", other.map(|o| o.findings().len())),
    }
}

#[test]
fn a_square_drive_s_record_is_at_its_noise_floor_and_the_dropouts_are_not_the_actuator() {
    // 1 Hz between 10 and 90 V, on the sampling clock.
    let u: Vec<f64> = (0..80_000).map(|k| if k % 10_000 < 5_000 { 90.0 } else { 10.0 }).collect();
    let mut y = stack(&u);
    // A sensor that loses its target: nine samples, one pair, 3 to 10 µm off, away from the
    // edges (on the ringing of a step, where the output is not smooth, one is left alone).
    for (k, h) in [
        (12_345, 8.0),
        (23_456, -5.0),
        (34_567, 10.0),
        (34_568, 9.5),
        (45_678, -3.0),
        (56_789, 6.0),
        (61_111, -7.0),
        (70_301, 4.0),
        (76_000, -9.0),
    ] {
        y[k] += h;
    }
    let text = csv(&u, &y);
    let read = import_text(&text, "stack.csv", &ImportOptions::default()).unwrap();
    let spikes = read.info.spikes.as_ref().expect("dropouts repaired");
    assert_eq!(spikes.count, 9, "{spikes:?}");
    let Ok(Outcome::Periodic(d)) = outcome(&text) else { panic!("a periodic diagnosis") };
    assert!(d.noise_um < 0.003, "{}", d.noise_um);
    // Read as it is, the dropouts are its noise.
    let kept =
        import_text(&text, "stack.csv", &ImportOptions { keep_spikes: true, ..ImportOptions::default() })
            .unwrap()
            .record;
    let rec = Realisation { u: &kept.u, y: &kept.y, t0: kept.t0, given: None };
    let Ok(Outcome::Periodic(k)) = diagnose::diagnose_drive(&[rec], kept.ts, &Rules::default()) else {
        panic!("a periodic diagnosis")
    };
    assert!(k.noise_um > 10.0 * d.noise_um, "{} vs {}", k.noise_um, d.noise_um);
    assert!(d.findings.iter().all(|f| f.kind != Kind::Saturation), "{:?}", d.findings);
}

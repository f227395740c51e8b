//! The board's design from records: on an actuator whose model is known (the on-chip
//! actuator of the emulated board) and on the virtual bimorph; the design file read back;
//! the refusals.

use boucwen_core::model::{BoucWenParams, EnhancedParams, ExtendedParams, HarmonicBranch, Model};
use boucwen_core::signal::Oscillator;
use boucwen_lab::design::board::{
    BoardDesignError, DesignFile, DesignOptions, HarmonicChoice, design_from_records,
};
use boucwen_lab::design::closed_loop;
use boucwen_lab::record::Record;
use boucwen_link::message::SafetyParams;
use boucwen_sim::{Bimorph, Scenario};

const TS: f64 = 1e-3;

/// The on-chip actuator of the emulated board (`cargo xtask qemu`'s plant): a resonance near
/// 70 Hz and a third harmonic of 23 Hz.
fn actuator() -> EnhancedParams<f64, 2, 0, 1> {
    let w0 = std::f64::consts::TAU * 70.0 * TS;
    EnhancedParams {
        base: ExtendedParams {
            bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
            ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
        },
        branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }],
        drive: Oscillator::new(23.0, TS).unwrap(),
    }
}

fn record_of(name: &str, u: Vec<f64>, plant: &mut dyn FnMut(f64) -> f64) -> Record {
    let y = u.iter().map(|&v| plant(v)).collect();
    Record::new(name, 0.0, TS, u, y, None).unwrap()
}

fn on_chip_record(amplitude_v: f64, seconds: f64) -> Record {
    let p = actuator();
    let mut s = p.initial_state();
    let u = closed_loop::sine(amplitude_v, 23.0, TS, (seconds / TS) as usize).unwrap();
    record_of("on-chip.csv", u, &mut |v| p.step(&mut s, v))
}

#[test]
fn a_known_actuator_gives_its_model_harmonic_and_a_small_tracking_error() {
    let rec = on_chip_record(1.0, 6.0);
    // 20 µm, where the actuator's third harmonic is worth cancelling (at eq. 25's 116 µm it
    // is under 5 % of the reference).
    let opts = DesignOptions { amplitude_um: Some(20.0), ..DesignOptions::default() };
    let d = design_from_records(&[rec], &opts).unwrap();
    // The extended part is the actuator's up to the harmonic it cannot produce.
    assert!(d.model.fit_pct > 90.0, "{:?}", d.model);
    assert_eq!(d.harmonics_found.iter().map(|h| h.order).collect::<Vec<_>>(), [3]);
    assert_eq!(d.harmonics_cancelled.iter().map(|h| h.order).collect::<Vec<_>>(), [3]);
    assert_eq!(d.prediction.model, "enhanced(3)");
    assert!(d.prediction.fit_pct > 99.0, "{:?}", d.prediction);
    // The cancellation removes most of what u_f leaves.
    assert!(d.prediction.design_rmse_um < 0.3 * d.prediction.uf_rmse_um, "{:?}", d.prediction);
    assert_eq!((d.reference.amplitude_source.as_str(), d.sources[0].role.as_str()), ("requested", "fit"));
    assert_eq!((d.reference.freq_hz, d.sources[0].drive.as_str()), (23.0, "sine 23.0000 Hz"));
    // Left to eq. (25), α is the record's gain times its drive amplitude.
    let d25 = design_from_records(&[on_chip_record(1.0, 6.0)], &DesignOptions::default()).unwrap();
    assert_eq!(d25.reference.amplitude_source, "eq25");
    assert!((d25.reference.amplitude_um - 116.0).abs() < 1.0, "{:?}", d25.reference);
    // The file reads back to the same design, and to the same board parameters bit for bit.
    let back = DesignFile::parse(&d.to_json()).unwrap();
    assert_eq!(back, d);
    assert_eq!(back.board_params().unwrap(), d.board_params().unwrap());
    let (p, s) = d.board_params().unwrap();
    assert_eq!((p.sample_period_us, p.harmonics.len(), s), (1000, 1, SafetyParams::DEFAULT));
}

#[test]
fn the_virtual_bimorph_at_23_hz() {
    let scenario = Scenario::default();
    let mut b = Bimorph::new(&scenario).unwrap();
    let u = closed_loop::sine(1.0, 23.0, TS, 6000).unwrap();
    let rec = record_of("bimorph.csv", u, &mut |v| b.step(v).unwrap());
    let opts = DesignOptions { amplitude_um: Some(20.0), ..DesignOptions::default() };
    let d = design_from_records(&[rec], &opts).unwrap();
    assert!(d.model.fit_pct > 80.0, "{:?}", d.model);
    assert_eq!(d.harmonics_found.first().map(|h| h.order), Some(3), "{:?}", d.harmonics_found);
    assert_eq!(d.reference.amplitude_um, 20.0);
    assert!(d.model.checked_u_v[1] > 0.5 && d.model.min_slope_rel >= 0.05, "{:?}", d.model);
    // The board's controller, as loaded, on the virtual bimorph: the fitted model reproduces
    // the 3rd harmonic through its own resonance, so the design must cancel it anyway (without
    // the cancellation this design tracked 4.06 µm RMS).
    assert_eq!(d.harmonics_cancelled.iter().map(|h| h.order).collect::<Vec<_>>(), vec![3]);
    let (params, _) = d.board_params().unwrap();
    let mut c = boucwen_link::device::Controller::new(&params).unwrap();
    let mut b = Bimorph::new(&scenario).unwrap();
    let (n, settle) = (5000, 1000);
    let (mut y, mut sq) = (None, 0.0);
    for k in 0..n {
        let s = c.step(y).unwrap();
        let yk = b.step(s.out.u as f64).unwrap();
        y = Some(yk as f32);
        if k >= settle {
            sq += (yk - s.d as f64).powi(2);
        }
    }
    let rmse = (sq / (n - settle) as f64).sqrt();
    assert!(
        rmse < 1.0,
        "tracking RMSE {rmse} µm on the virtual bimorph; {:?} {:?} {:?}",
        d.model,
        d.prediction,
        d.harmonics_cancelled
    );
}

#[test]
fn refusals_name_what_is_wrong() {
    let rec = on_chip_record(1.0, 4.0);
    let design = |recs: &[Record], o: &DesignOptions| design_from_records(recs, o).unwrap_err().to_string();
    // A reference the drive limits cannot reach.
    let o = DesignOptions {
        amplitude_um: Some(5000.0),
        harmonics: HarmonicChoice::None,
        ..DesignOptions::default()
    };
    let e = design(std::slice::from_ref(&rec), &o);
    assert!(e.starts_with("tracking 5000.000 µm at 23 Hz needs a drive from"), "{e}");
    assert!(e.contains("beyond the drive limits [-10, 10] V"), "{e}");
    // No record at the frequency asked for.
    let o = DesignOptions { freq_hz: Some(30.0), ..DesignOptions::default() };
    let e = design(std::slice::from_ref(&rec), &o);
    assert!(e.starts_with("no record drives a sine at 30 Hz (found: on-chip.csv sine 23.000 Hz)"), "{e}");
    // Too many harmonics, a harmonic past Nyquist.
    let o = DesignOptions { harmonics: HarmonicChoice::Orders(vec![3, 5, 7]), ..DesignOptions::default() };
    assert!(design(std::slice::from_ref(&rec), &o).contains("at most 2"));
    let o = DesignOptions { harmonics: HarmonicChoice::Orders(vec![30]), ..DesignOptions::default() };
    assert!(design(std::slice::from_ref(&rec), &o).starts_with("harmonic 30:"));
    // Records at different intervals.
    let other = Record::new("slow.csv", 0.0, 2e-3, rec.u.clone(), rec.y.clone(), None).unwrap();
    let e = design(&[rec.clone(), other], &DesignOptions::default());
    assert!(e.starts_with("slow.csv: sampled every 0.002 s"), "{e}");
    // Drive limits the board refuses.
    let o = DesignOptions {
        safety: SafetyParams { u_max: -1.0, ..SafetyParams::DEFAULT },
        ..DesignOptions::default()
    };
    assert!(design(std::slice::from_ref(&rec), &o).contains("drive limit u_max"));
    assert!(matches!(design_from_records(&[], &DesignOptions::default()), Err(BoardDesignError::NoRecords)));
}

#[test]
fn a_design_file_that_is_not_right_is_refused_whole() {
    let d = design_from_records(&[on_chip_record(1.0, 4.0)], &DesignOptions::default()).unwrap();
    let text = d.to_json();
    let e = DesignFile::parse(&text.replace("\"version\": 2", "\"version\": 7")).unwrap_err();
    assert_eq!(e, "version 7: this boucwen reads version 2");
    // A file from before the preview: refused, saying why and what to do.
    let e = DesignFile::parse(&text.replace("\"version\": 2", "\"version\": 1")).unwrap_err();
    assert!(
        e.starts_with("version 1: designed without the actuator's input delay") && e.contains("design again"),
        "{e}"
    );
    let mut bad = d.clone();
    bad.board.preview_samples = 20.0;
    let e = DesignFile::parse(&bad.to_json()).unwrap_err();
    assert!(e.starts_with("board: ") && e.contains("preview"), "{e}");
    let e = DesignFile::parse("{\"format\": \"something else\"}").unwrap_err();
    assert_eq!(e, "format \"something else\", not a boucwen board design");
    let e = DesignFile::parse("{").unwrap_err();
    assert!(e.starts_with("not JSON: EOF while parsing"), "{e}");
    let mut bad = d.clone();
    bad.board.rls[0] = 1.5;
    let e = DesignFile::parse(&bad.to_json()).unwrap_err();
    assert!(e.starts_with("board: ") && e.contains("forgetting factor"), "{e}");
    let mut bad = d.clone();
    bad.board.host_timeout_ms = 5;
    let e = DesignFile::parse(&bad.to_json()).unwrap_err();
    assert!(e.contains("host timeout"), "{e}");
    let e = DesignFile::parse(&text.replace("\"sample_period_us\": 1000", "\"sample_period_us\": -3"))
        .unwrap_err();
    assert!(e.starts_with("board.sample_period_us: invalid value: integer `-3`, expected u32"), "{e}");
}

#[test]
fn board_numbers_survive_the_json_bit_for_bit() {
    // Every f32 the board gets is written in the shortest form that reads back to it.
    let mut x = 0x9E37_79B9u32;
    for _ in 0..200_000 {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        let v = f32::from_bits(x);
        if !v.is_finite() {
            continue;
        }
        let back: f32 = serde_json::from_str(&serde_json::to_string(&v).unwrap()).unwrap();
        assert_eq!(back.to_bits(), v.to_bits(), "{v:e}");
    }
}

#[test]
fn a_sensor_counting_the_stroke_downwards_gives_the_mirrored_design() {
    // The same actuator, its output recorded with the other sign (a laser measuring its
    // distance to the actuator): the model is the mirror (A1, A, A0, γ negated), invertible
    // all the same, and the reference is a sine of the same size.
    let rec = on_chip_record(1.0, 6.0);
    let down =
        Record::new("down.csv", rec.t0, rec.ts, rec.u.clone(), rec.y.iter().map(|y| -y).collect(), None)
            .unwrap();
    let opts = DesignOptions { amplitude_um: None, ..DesignOptions::default() };
    let (up, down) =
        (design_from_records(&[rec], &opts).unwrap(), design_from_records(&[down], &opts).unwrap());
    let [a1, a, a0, gamma, beta] = up.board.bouc_wen;
    let mirrored = [-a1, -a, -a0, -gamma, beta];
    for (x, y) in down.board.bouc_wen.iter().zip(mirrored) {
        assert!(
            (x - y).abs() <= 1e-6 * (1.0 + y.abs()),
            "{:?} against the mirror of {:?}",
            down.board.bouc_wen,
            up.board.bouc_wen
        );
    }
    assert_eq!(down.board.ar, up.board.ar);
    assert_eq!(down.reference.amplitude_um, up.reference.amplitude_um);
    assert!(down.reference.amplitude_um > 0.0);
    assert_eq!(down.model.fit_pct, up.model.fit_pct);
}

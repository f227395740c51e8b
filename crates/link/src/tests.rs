//! Protocol tests: every message round-trips, arbitrary and corrupted byte streams never
//! panic and never yield a wrong packet, and the board's state machine follows its table.

use super::analog::NoFrontEnd;
use super::device::{ClosedLoop, Controller, Device, Reference, TimerRequest};
use super::frame::{MAX_ENCODED, MAX_PAYLOAD};
use super::limits;
use super::message::*;
use super::plant::OnChipPlant;
use super::*;
use boucwen_core::compensator::{HarmonicSpec, Saturation};
use boucwen_core::controllers::OrcPlacement;
use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
use boucwen_core::rls::RlsConfig;
use boucwen_core::signal::Oscillator;
use nalgebra::Complex;
use std::vec::Vec;

/// xorshift64*: a small seeded generator for the property tests.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn chance(&mut self, p: f64) -> bool {
        ((self.next() >> 11) as f64 / (1u64 << 53) as f64) < p
    }
}

fn model() -> ExtendedParams<f32, MAX_AR> {
    let w0 = core::f64::consts::TAU * 70.0e-3;
    ExtendedParams {
        bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
        ar: [(2.0 * 0.97 * w0.cos()) as f32, -0.97 * 0.97, 0.0],
    }
}

pub(crate) fn controller_params(harmonics: &[(u32, f32, f32)]) -> ControllerParams {
    ControllerParams {
        model: model(),
        drive: Oscillator::new(23.0, 1e-3).unwrap(),
        sample_period_us: 1000,
        amplitude_um: 20.0,
        fade_samples: 500,
        harmonics: harmonics
            .iter()
            .map(|&(order, re, im)| HarmonicSpec { order, response: Complex::new(re, im) })
            .collect(),
        rls: RlsConfig::with_forgetting(0.999, 1e-2),
        saturation: Saturation::symmetric(10.0),
        uc_max: 5.0,
        preview_samples: 0.0,
    }
}

pub(crate) fn plant_params() -> PlantParams {
    PlantParams {
        base: model(),
        drive: Oscillator::new(23.0, 1e-3).unwrap(),
        branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }].into_iter().collect(),
    }
}

fn every_message() -> Vec<Message> {
    let mut text = heapless::String::new();
    text.push_str("A1 is not finite").unwrap();
    vec![
        Message::GetStatus,
        Message::SetController(controller_params(&[])),
        Message::SetController(controller_params(&[(3, 1.5, -0.25), (5, -0.0, f32::MIN_POSITIVE)])),
        Message::SetController(ControllerParams {
            preview_samples: 1.3,
            ..controller_params(&[(3, 1.5, -0.25)])
        }),
        Message::SetPlant(plant_params()),
        Message::SetOrc(OrcParams {
            kp: 0.0,
            ki_per_s: 1.25,
            feedforward_gain: -0.5,
            q_coeff: 0.05,
            learning_gain: 0.4,
            lead_samples: 7,
            limit: 3.5,
            placement: OrcPlacement::PiInput,
        }),
        Message::Start { mode: Mode::Control, samples: 5000 },
        Message::Start { mode: Mode::Plant, samples: u32::MAX },
        Message::Stop,
        Message::Measurement { k: 7, y: -3.25e-7 },
        Message::Measurement { k: u32::MAX, y: f32::NAN },
        Message::Command { k: 1, u: 9.5, used: 0xA5A5, flags: command_flags::SATURATED },
        Message::Ack { kind: kind::START, seq: 65_535 },
        Message::Status(Status {
            state: 2,
            mode: 1,
            samples_done: 1,
            samples_total: 2,
            rx_frames: 3,
            rx_bad: 4,
            rx_lost: 5,
            tx_frames: 6,
            measurements_used: 7,
            measurements_missing: 8,
            measurements_stale: 9,
            rx_overflow_bytes: 10,
            tick_overruns: 11,
            compute_errors: u32::MAX,
        }),
        Message::Fault(Fault { code: FaultCode::InvalidParams, seq: 12, text }),
        Message::Fault(Fault::new(FaultCode::BadFrame, 0xFFFF, "ü".repeat(40))),
        Message::Fault(Fault::new(FaultCode::Compute, 3, "x")),
        Message::Start { mode: Mode::Simulated, samples: 2000 },
        Message::Start { mode: Mode::Local, samples: 0 },
        Message::Start { mode: Mode::Lockstep, samples: 7 },
        Message::SetSafety(SafetyParams::DEFAULT),
        Message::GetDiagnostics,
        Message::Telemetry { k: 9, u: -1.5, y: f32::NAN, flags: command_flags::SAFE_RAMP },
        Message::Safe { reason: SafeReason::HostLost as u8, ticks: 351, period_us: 1000 },
        Message::Diagnostics(Diagnostics {
            ticks: 1,
            missed_ticks: 2,
            isr_ticks_max: 3,
            isr_ticks_sum: u64::MAX,
            steps: 5,
            step_ticks_max: 6,
            step_ticks_sum: 7,
            clock_overhead_ticks: 8,
            calib_insns: 9,
            calib_ticks: 10,
            stack_peak_bytes: 11,
            reset_cause: 4,
            bad_frames: 12,
            faults_suppressed: 13,
            tx_dropped: 14,
            safe_reason: 1,
            safe_ticks: 15,
            drive_v: -0.25,
            lockstep_waits: 9,
        }),
    ]
}

/// Bitwise equality (NaN payloads included), through the encoding itself.
fn same(a: &Message, b: &Message) -> bool {
    let (mut x, mut y) = ([0u8; MAX_PAYLOAD], [0u8; MAX_PAYLOAD]);
    let (n, m) = (a.encode_payload(&mut x).unwrap(), b.encode_payload(&mut y).unwrap());
    a.kind() == b.kind() && x[..n] == y[..m]
}

#[test]
fn every_message_roundtrips_bit_for_bit() {
    let mut stream = Vec::new();
    let msgs = every_message();
    for (i, m) in msgs.iter().enumerate() {
        stream.extend_from_slice(&encode(i as u16 * 1000, m).unwrap());
    }
    let mut dec = Decoder::new();
    let got: Vec<Packet> = stream.iter().filter_map(|&b| dec.push(b)).map(|r| r.unwrap()).collect();
    assert_eq!(got.len(), msgs.len());
    for (i, (g, m)) in got.iter().zip(&msgs).enumerate() {
        assert_eq!(g.seq, i as u16 * 1000);
        assert!(same(&g.msg, m), "{m:?} came back as {:?}", g.msg);
        if !matches!(m, Message::Measurement { y, .. } | Message::Telemetry { y, .. } if y.is_nan()) {
            assert_eq!(&g.msg, m);
        }
    }
    // The long fault text was cut on a character boundary.
    let long = msgs.iter().find_map(|m| match m {
        Message::Fault(f) if f.code == FaultCode::BadFrame => Some(f),
        _ => None,
    });
    assert_eq!(long.map(|f| f.text.len()), Some(48));
}

#[test]
fn frame_sizes_match_the_link_budget_in_the_docs() {
    let cmd = encode(0xFFFF, &Message::Command { k: u32::MAX, u: -1.0, used: 0xFFFF, flags: 3 }).unwrap();
    let meas = encode(0xFFFF, &Message::Measurement { k: u32::MAX, y: -1.0 }).unwrap();
    assert_eq!((cmd.len(), meas.len()), (20, 17));
    for m in every_message() {
        assert!(encode(0, &m).unwrap().len() <= MAX_ENCODED);
    }
}

#[test]
fn layouts_are_checked_on_decode() {
    // Wrong lengths, unknown kinds and enumerations.
    assert_eq!(Message::decode(kind::GET_STATUS, &[0]), Err(WireError::BadLength));
    assert_eq!(Message::decode(kind::MEASUREMENT, &[0; 7]), Err(WireError::BadLength));
    assert_eq!(Message::decode(kind::MEASUREMENT, &[0; 9]), Err(WireError::BadLength));
    assert_eq!(Message::decode(0x7F, &[]), Err(WireError::UnknownKind(0x7F)));
    assert_eq!(Message::decode(kind::START, &[6, 0, 0, 0, 0]), Err(WireError::BadValue("start mode")));
    assert_eq!(Message::decode(kind::FAULT, &[9, 0, 0, 0]), Err(WireError::BadValue("fault code")));
    assert_eq!(Message::decode(kind::FAULT, &[1, 0, 0, 2, 0xC3]), Err(WireError::BadLength));
    assert_eq!(
        Message::decode(kind::FAULT, &[1, 0, 0, 1, 0xC3]),
        Err(WireError::BadValue("fault text (not UTF-8)"))
    );
    let mut p = [0u8; MAX_PAYLOAD];
    let n = Message::SetController(controller_params(&[(3, 1.0, 0.0)])).encode_payload(&mut p).unwrap();
    p[52] = 3; // harmonic count
    assert_eq!(Message::decode(kind::SET_CONTROLLER, &p[..n]), Err(WireError::BadValue("harmonic count")));
    let mut too_high = controller_params(&[(300, 1.0, 0.0)]);
    assert!(encode(0, &Message::SetController(too_high.clone())).is_err());
    too_high.harmonics.clear();
    assert!(encode(0, &Message::SetController(too_high)).is_ok());
}

/// Feeds `bytes` through a decoder; returns the packets and the number of rejected frames.
fn decode_stream(bytes: &[u8]) -> (Vec<Packet>, usize) {
    let mut dec = Decoder::new();
    let (mut ok, mut bad) = (Vec::new(), 0);
    for &b in bytes {
        match dec.push(b) {
            Some(Ok(p)) => ok.push(p),
            Some(Err(_)) => bad += 1,
            None => {}
        }
    }
    (ok, bad)
}

#[test]
fn random_bytes_never_panic_and_almost_never_decode() {
    let mut rng = Rng(0x5EED_0001);
    let mut accepted = 0;
    for _ in 0..2_000 {
        let len = rng.below(400) as usize;
        // Mostly random bytes with delimiters sprinkled in, so many candidate frames form.
        let bytes: Vec<u8> = (0..len).map(|_| if rng.chance(0.05) { 0 } else { rng.next() as u8 }).collect();
        accepted += decode_stream(&bytes).0.len();
    }
    // A random candidate frame passes only with a 2^-32 CRC collision and a valid layout.
    assert_eq!(accepted, 0);
}

#[test]
fn corrupted_streams_lose_frames_but_never_deliver_a_wrong_one() {
    let mut rng = Rng(0x5EED_0002);
    let msgs = every_message();
    for round in 0..300 {
        // A stream of known packets...
        let sent: Vec<Packet> = (0..40)
            .map(|i| Packet { seq: i, msg: msgs[rng.below(msgs.len() as u64) as usize].clone() })
            .collect();
        let clean: Vec<u8> = sent.iter().flat_map(|p| encode(p.seq, &p.msg).unwrap()).collect();
        // ... with bytes dropped, flipped, inserted at a per-byte rate up to 5 %.
        let rate = 0.05 * (round % 10) as f64 / 10.0;
        let mut dirty = Vec::new();
        for &b in &clean {
            if rng.chance(rate) {
                match rng.below(3) {
                    0 => continue,
                    1 => dirty.push(b ^ (1 << rng.below(8))),
                    _ => {
                        dirty.push(b);
                        dirty.push(rng.next() as u8);
                    }
                }
            } else {
                dirty.push(b);
            }
        }
        let (got, _bad) = decode_stream(&dirty);
        // Every packet delivered is one that was sent, intact, in order.
        let mut next = 0usize;
        for g in &got {
            let pos = sent[next..].iter().position(|s| s.seq == g.seq).map(|p| p + next);
            let pos = pos.unwrap_or_else(|| panic!("round {round}: seq {} out of order or invented", g.seq));
            assert!(same(&g.msg, &sent[pos].msg), "round {round}: packet {} altered", g.seq);
            next = pos + 1;
        }
        if rate == 0.0 {
            assert_eq!(got.len(), sent.len());
        }
    }
}

#[test]
fn reference_fades_in_and_matches_the_core_sine_after() {
    let p = controller_params(&[]);
    let mut r = Reference::new(&p);
    let mut sine = boucwen_core::signal::Sine::new(p.amplitude_um, p.drive);
    let mut worst_fade_err: f64 = 0.0;
    for k in 0..2000u32 {
        let d = r.next_sample();
        let s = sine.next_sample();
        if k >= p.fade_samples {
            assert_eq!(d.to_bits(), s.to_bits(), "k = {k}");
        } else {
            let w = 0.5 - 0.5 * (core::f64::consts::PI * k as f64 / p.fade_samples as f64).cos();
            let want = w * 20.0 * (core::f64::consts::TAU * 23.0e-3 * k as f64).sin();
            worst_fade_err = worst_fade_err.max((d as f64 - want).abs());
        }
    }
    assert!(worst_fade_err < 1e-5, "fade-in off by {worst_fade_err} µm");
}

#[test]
fn the_preview_is_the_reference_at_k_plus_tau_and_none_is_bit_exact() {
    let p = controller_params(&[]);
    // No preview: d_ahead is d, and the controller steps as without preview, bit for bit.
    let mut r = Reference::new(&p);
    let mut plain = Reference::new(&p);
    for _ in 0..700 {
        let (d, ahead) = r.next_previewed();
        assert_eq!((d.to_bits(), ahead.to_bits()), (plain.next_sample().to_bits(), d.to_bits()));
    }
    // τ = 1.3 samples: the sine and the fade-in at k + τ, within f32 rounding.
    for tau in [1.3f32, 0.5, 3.0, limits::PREVIEW_MAX_SAMPLES] {
        let q = ControllerParams { preview_samples: tau, ..p.clone() };
        let mut r = Reference::new(&q);
        let mut plain = Reference::new(&p);
        let mut worst: f64 = 0.0;
        for k in 0..2000u32 {
            let (d, ahead) = r.next_previewed();
            assert_eq!(d.to_bits(), plain.next_sample().to_bits(), "d[k] changed with the preview");
            let t = k as f64 + tau as f64;
            let kk = p.fade_samples as f64;
            let w = if t < kk { 0.5 - 0.5 * (core::f64::consts::PI * t / kk).cos() } else { 1.0 };
            let want = w * 20.0 * (core::f64::consts::TAU * 23.0e-3 * t).sin();
            worst = worst.max((ahead as f64 - want).abs());
        }
        assert!(worst < 1e-4, "τ = {tau}: preview off by {worst} µm");
    }
    // The controller with τ = 0 is the compensator without preview.
    let mut a = Controller::new(&p).unwrap();
    let mut b = boucwen_core::compensator::Compensator::<f32, MAX_AR, 0>::new(
        boucwen_core::compensator::CompensatorConfig {
            model: p.model,
            drive: p.drive,
            harmonics: [],
            rls: p.rls,
            saturation: p.saturation,
            uc_max: p.uc_max,
        },
    )
    .unwrap();
    let mut plain = Reference::new(&p);
    for k in 0..600 {
        let y = (k > 0).then_some(0.1 * k as f32);
        let s = a.step(y).unwrap();
        let o = b.step(plain.next_sample(), y).unwrap();
        assert_eq!(s.out.u.to_bits(), o.u.to_bits());
    }
}

#[test]
fn the_preview_is_range_checked() {
    for bad in [-0.5f32, 16.5, f32::NAN, f32::INFINITY] {
        let p = ControllerParams { preview_samples: bad, ..controller_params(&[]) };
        assert!(p.validate().is_err(), "τ = {bad} accepted");
        assert!(Controller::new(&p).is_err());
    }
    for good in [0.0f32, 2.75, 16.0] {
        assert!(ControllerParams { preview_samples: good, ..controller_params(&[]) }.validate().is_ok());
    }
}

#[test]
fn the_closed_loop_tracks_and_cancels_the_harmonic() {
    let g = boucwen_core::compensator::harmonic_response(
        &ExtendedParams {
            bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
            ar: [2.0 * 0.97 * (core::f64::consts::TAU * 70.0e-3).cos(), -0.97 * 0.97],
        },
        3,
        23.0,
        1e-3,
        boucwen_core::compensator::PhaseRule::Model,
    );
    let rms_after = |harmonics: &[(u32, f32, f32)]| {
        let ctl = Controller::new(&controller_params(harmonics)).unwrap();
        let mut cl = ClosedLoop::new(ctl, OnChipPlant::new(&plant_params()).unwrap());
        let mut sq = 0.0f64;
        for k in 0..20_000 {
            let s = cl.control().unwrap();
            let y = cl.actuate(s.out.u);
            if k >= 10_000 {
                sq += ((y - s.d) as f64).powi(2);
            }
        }
        (sq / 10_000.0).sqrt()
    };
    let uf = rms_after(&[]);
    let proposed = rms_after(&[(3, g.re as f32, g.im as f32)]);
    assert!(uf > 1.0 && proposed < 0.2, "u_f alone {uf} µm, proposed {proposed} µm");
}

/// Drives a device with messages and collects what it sends.
struct Bench {
    dev: Device,
    seq: u16,
    out: Vec<Packet>,
}

impl Bench {
    fn new() -> Self {
        Self { dev: Device::new(), seq: 0, out: Vec::new() }
    }
    fn sink(out: &mut Vec<Packet>) -> impl FnMut(&[u8]) + '_ {
        |bytes: &[u8]| {
            let mut d = Decoder::new();
            out.extend(bytes.iter().filter_map(|&b| d.push(b)).map(|r| r.unwrap()));
        }
    }
    fn send(&mut self, msg: Message) -> TimerRequest {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        self.dev.on_packet(Ok(Packet { seq, msg }), &mut Self::sink(&mut self.out))
    }
    fn tick(&mut self) -> TimerRequest {
        self.dev.on_tick(0, &mut NoFrontEnd, &|| 0, &mut Self::sink(&mut self.out))
    }
    fn take(&mut self) -> Vec<Message> {
        self.out.drain(..).map(|p| p.msg).collect()
    }
}

#[test]
fn device_configures_validates_and_refuses_out_of_turn() {
    let mut b = Bench::new();
    assert_eq!(b.send(Message::Start { mode: Mode::Control, samples: 3 }), TimerRequest::Keep);
    assert!(matches!(&b.take()[..], [Message::Fault(Fault { code: FaultCode::NotConfigured, seq: 0, .. })]));
    let mut bad = controller_params(&[]);
    bad.model.bw.gamma = f32::INFINITY;
    b.send(Message::SetController(bad));
    match &b.take()[..] {
        [Message::Fault(f)] => {
            assert_eq!((f.code, f.text.as_str()), (FaultCode::InvalidParams, "gamma is not finite"))
        }
        other => panic!("{other:?}"),
    }
    b.send(Message::SetController(controller_params(&[(3, 1.0, 0.5)])));
    assert_eq!(b.take(), [Message::Ack { kind: kind::SET_CONTROLLER, seq: 2 }]);
    assert_eq!(
        b.send(Message::Start { mode: Mode::Control, samples: 3 }),
        TimerRequest::Start { period_us: 1000 }
    );
    assert_eq!(b.take(), [Message::Ack { kind: kind::START, seq: 3 }]);
    b.send(Message::SetPlant(plant_params()));
    assert!(matches!(&b.take()[..], [Message::Fault(Fault { code: FaultCode::Busy, .. })]));
    b.send(Message::Command { k: 0, u: 1.0, used: 0, flags: 0 });
    assert!(matches!(&b.take()[..], [Message::Fault(Fault { code: FaultCode::Unexpected, .. })]));
    b.dev.on_packet(Err(WireError::Crc), &mut Bench::sink(&mut b.out));
    match &b.take()[..] {
        [Message::Fault(f)] => {
            assert_eq!((f.code, f.seq, f.text.as_str()), (FaultCode::BadFrame, 0xFFFF, "frame: CRC mismatch"))
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(b.send(Message::Stop), TimerRequest::Stop);
    match &b.take()[..] {
        [Message::Status(s)] => assert_eq!((s.state, s.rx_bad, s.rx_frames), (RunState::Idle as u8, 1, 3)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn control_run_matches_the_controller_and_reports_measurement_use() {
    let p = controller_params(&[(3, 2.0, -1.0)]);
    let mut b = Bench::new();
    b.send(Message::SetController(p.clone()));
    b.send(Message::Start { mode: Mode::Control, samples: 6 });
    b.take();
    // Reference: the same controller fed what the device is fed.
    let mut reference = Controller::new(&p).unwrap();
    // Measurements for samples 0, 1, 3 arrive in time; 2 never; 4 arrives late.
    let ys = [0.5f32, 1.5, 2.5, 3.5, 4.5];
    let mut expect_used = 0u16;
    for k in 0..6u32 {
        let y_prev = match k {
            1 | 2 | 4 => Some(ys[k as usize - 1]),
            _ => None,
        };
        if k == 5 {
            // y[4] for the tick that has passed already: stale.
            b.send(Message::Measurement { k: 3, y: 9.0 });
        }
        let req = b.tick();
        let want = reference.step(y_prev).unwrap();
        expect_used = (expect_used << 1) | y_prev.is_some() as u16;
        let msgs = b.take();
        match &msgs[0] {
            Message::Command { k: kk, u, used, .. } => {
                assert_eq!((*kk, u.to_bits(), *used), (k, want.out.u.to_bits(), expect_used), "k = {k}");
            }
            other => panic!("{other:?}"),
        }
        if k == 5 {
            assert_eq!(req, TimerRequest::Stop);
            match &msgs[1] {
                Message::Status(s) => {
                    assert_eq!(s.samples_done, 6);
                    assert_eq!(
                        (s.measurements_used, s.measurements_missing, s.measurements_stale),
                        (3, 2, 1)
                    );
                    assert_eq!(s.state, RunState::Idle as u8);
                }
                other => panic!("{other:?}"),
            }
        } else {
            assert_eq!(req, TimerRequest::Keep);
        }
        if matches!(k, 0 | 1 | 3) {
            b.send(Message::Measurement { k, y: ys[k as usize] });
        }
    }
    // A further tick does nothing.
    assert_eq!(b.tick(), TimerRequest::Keep);
    assert!(b.take().is_empty());
}

#[test]
fn lockstep_run_waits_for_each_measurement_within_its_patience() {
    let p = controller_params(&[(3, 2.0, -1.0)]);
    let mut b = Bench::new();
    b.send(Message::SetController(p.clone()));
    assert_eq!(
        b.send(Message::Start { mode: Mode::Lockstep, samples: 4 }),
        TimerRequest::Start { period_us: 1000 }
    );
    b.take();
    let mut reference = Controller::new(&p).unwrap();
    let command = |msgs: &[Message]| match msgs.first() {
        Some(Message::Command { k, u, used, .. }) => (*k, u.to_bits(), *used),
        other => panic!("{other:?}"),
    };
    // Sample 0 needs no measurement: it steps at the first tick.
    b.tick();
    let want = reference.step(None).unwrap();
    assert_eq!(command(&b.take()), (0, want.out.u.to_bits(), 0));
    // y[0] comes three ticks late: the board waits (sends nothing), then steps with it.
    for _ in 0..3 {
        b.tick();
        assert!(b.take().is_empty());
    }
    b.send(Message::Measurement { k: 0, y: 1.25 });
    b.tick();
    let want = reference.step(Some(1.25)).unwrap();
    assert_eq!(command(&b.take()), (1, want.out.u.to_bits(), 0b1));
    // y[1] never comes: after the patience the board steps without it.
    for _ in 0..limits::LOCKSTEP_PATIENCE_TICKS {
        b.tick();
        assert!(b.take().is_empty());
    }
    b.tick();
    let want = reference.step(None).unwrap();
    assert_eq!(command(&b.take()), (2, want.out.u.to_bits(), 0b10));
    // A stale measurement (for sample 1) does not release the wait for y[2].
    b.send(Message::Measurement { k: 1, y: 3.0 });
    b.tick();
    assert!(b.take().is_empty());
    b.send(Message::Measurement { k: 2, y: 2.5 });
    assert_eq!(b.tick(), TimerRequest::Stop);
    let want = reference.step(Some(2.5)).unwrap();
    let msgs = b.take();
    assert_eq!(command(&msgs), (3, want.out.u.to_bits(), 0b101));
    match &msgs[1] {
        Message::Status(s) => {
            assert_eq!((s.mode, s.samples_done), (Mode::Lockstep as u8, 4));
            assert_eq!((s.measurements_used, s.measurements_missing, s.measurements_stale), (2, 1, 1));
        }
        other => panic!("{other:?}"),
    }
    let waits = 3 + limits::LOCKSTEP_PATIENCE_TICKS + 1;
    assert_eq!(b.dev.diagnostics().lockstep_waits, waits);
}

#[test]
fn plant_run_holds_the_last_input_over_lost_commands() {
    let mut b = Bench::new();
    b.send(Message::SetPlant(plant_params()));
    b.send(Message::Start { mode: Mode::Plant, samples: 4 });
    b.take();
    let mut plant = OnChipPlant::new(&plant_params()).unwrap();
    b.send(Message::Command { k: 0, u: 0.25, used: 0, flags: 0 });
    let y0 = plant.step(0.25);
    assert_eq!(b.take(), [Message::Measurement { k: 0, y: y0 }]);
    // Commands 1 and 2 lost: the plant holds 0.25 V through them.
    b.send(Message::Command { k: 3, u: -0.5, used: 0, flags: 0 });
    plant.step(0.25);
    plant.step(0.25);
    let y3 = plant.step(-0.5);
    let msgs = b.take();
    assert_eq!(msgs[0], Message::Measurement { k: 3, y: y3 });
    assert!(matches!(&msgs[1], Message::Status(s) if s.samples_done == 4 && s.state == RunState::Idle as u8));
}

#[test]
fn device_counts_lost_frames_from_sequence_gaps() {
    let mut b = Bench::new();
    b.send(Message::GetStatus); // seq 0
    b.seq = 5; // 1..4 vanished
    b.dev.on_packet(Err(WireError::Crc), &mut Bench::sink(&mut b.out)); // one of them arrived damaged
    b.send(Message::GetStatus);
    let msgs = b.take();
    match msgs.last() {
        Some(Message::Status(s)) => assert_eq!((s.rx_frames, s.rx_bad, s.rx_lost), (2, 1, 3)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_bad_orc_placement_is_rejected_and_the_link_refuses_the_orc() {
    let msg = Message::SetOrc(OrcParams {
        kp: 0.1,
        ki_per_s: 1.0,
        feedforward_gain: 0.0,
        q_coeff: 0.1,
        learning_gain: 0.5,
        lead_samples: 3,
        limit: 1.0,
        placement: OrcPlacement::PlantInput,
    });
    let mut buf = [0u8; MAX_PAYLOAD];
    let n = msg.encode_payload(&mut buf).unwrap();
    buf[n - 1] = 9;
    assert!(matches!(Message::decode(kind::SET_ORC, &buf[..n]), Err(WireError::BadValue("ORC placement"))));
    // A board without the ORC answers SetOrc with a fault, not an Ack; one with it, before
    // the controller's parameters, too.
    let mut dev = Device::new();
    let mut sent = Vec::new();
    dev.on_packet(Ok(Packet { seq: 4, msg }), &mut |b: &[u8]| sent.extend_from_slice(b));
    let mut dec = Decoder::new();
    let answers: Vec<Message> = sent.iter().filter_map(|&b| dec.push(b)).map(|p| p.unwrap().msg).collect();
    assert!(
        matches!(&answers[..], [Message::Fault(f)] if f.seq == 4
            && f.code == if cfg!(feature = "orc") { FaultCode::NotConfigured } else { FaultCode::Unexpected }),
        "{answers:?}"
    );
}

/// A bench whose device has converters, recorded by [`Recorder`].
#[derive(Default)]
struct Recorder {
    driven: Vec<f32>,
    y: Option<f32>,
}

impl crate::analog::FrontEnd for Recorder {
    fn sense(&mut self) -> Option<f32> {
        self.y
    }
    fn drive(&mut self, u: f32) -> f32 {
        self.driven.push(u);
        u
    }
}

impl Bench {
    fn tick_with(&mut self, fe: &mut Recorder) -> TimerRequest {
        self.dev.on_tick(0, fe, &|| 0, &mut Self::sink(&mut self.out))
    }
}

#[test]
fn a_command_far_ahead_is_refused_not_stepped_to() {
    let mut b = Bench::new();
    b.send(Message::SetPlant(plant_params()));
    b.send(Message::Start { mode: Mode::Plant, samples: 0 });
    b.take();
    // Far ahead: refused at once (the plant is not stepped 4·10⁹ times).
    let t = std::time::Instant::now();
    b.send(Message::Command { k: u32::MAX - 1, u: 0.5, used: 0, flags: 0 });
    b.send(Message::Command { k: u32::MAX, u: 0.5, used: 0, flags: 0 });
    b.send(Message::Command { k: limits::MAX_CATCH_UP + 1, u: 0.5, used: 0, flags: 0 });
    assert!(t.elapsed() < std::time::Duration::from_millis(100));
    assert!(b.take().is_empty());
    assert_eq!(b.dev.status().measurements_stale, 3);
    // Within the catch-up window: the plant holds 0 V over the skipped samples.
    b.send(Message::Command { k: limits::MAX_CATCH_UP, u: 0.5, used: 0, flags: 0 });
    let mut plant = OnChipPlant::new(&plant_params()).unwrap();
    for _ in 0..limits::MAX_CATCH_UP {
        plant.step(0.0);
    }
    assert_eq!(b.take(), [Message::Measurement { k: limits::MAX_CATCH_UP, y: plant.step(0.5) }]);
}

#[test]
fn a_plant_input_outside_the_drive_limits_is_refused_and_outputs_stay_finite() {
    let mut b = Bench::new();
    b.send(Message::SetPlant(plant_params()));
    b.send(Message::Start { mode: Mode::Plant, samples: 0 });
    b.take();
    for (k, u) in [(0, 1e20f32), (0, 1e3), (0, f32::NAN), (0, -10.5), (0, f32::NEG_INFINITY)] {
        b.send(Message::Command { k, u, used: 0, flags: 0 });
    }
    assert!(b.take().is_empty());
    assert_eq!(b.dev.status().measurements_stale, 5);
    for k in 0..2000 {
        b.send(Message::Command { k, u: 10.0 * (k as f32 * 0.1445).sin(), used: 0, flags: 0 });
    }
    for m in b.take() {
        match m {
            Message::Measurement { y, .. } => assert!(y.is_finite()),
            other => panic!("{other:?}"),
        }
    }
}

/// The board's check of a controller is `ControllerParams::validate`, the host's too: what
/// one refuses the other refuses, naming the same field (the host's design file used to
/// pass values the board then refused: issue 29, item 1).
#[test]
fn the_host_check_is_the_board_check() {
    type Change = fn(&mut ControllerParams);
    let cases: [(Change, &str); 8] = [
        (|p| p.sample_period_us = 50, "sample period"),
        (|p| p.fade_samples = u32::MAX, "fade-in"),
        (|p| p.amplitude_um = 1e6, "reference amplitude"),
        (|p| p.saturation = Saturation { u_min: -1e6, u_max: 1e6 }, "saturation"),
        (|p| p.uc_max = 1e6, "uc_max"),
        (|p| p.uc_max = f32::INFINITY, "uc_max"),
        (|p| p.model.bw = BoucWenParams { a1: 0.0, a: 0.0, a0: 0.0, gamma: 0.0, beta: 0.0 }, "model gain A1"),
        (|p| p.model.bw.a = 25.0, "not invertible"),
    ];
    for (change, field) in cases {
        let mut p = controller_params(&[]);
        change(&mut p);
        let host = p.validate().expect_err(field).to_string();
        assert!(host.contains(field), "{host} vs {field}");
        let mut b = Bench::new();
        b.send(Message::SetController(p));
        match &b.take()[..] {
            [Message::Fault(f)] => {
                assert_eq!(f.code, FaultCode::InvalidParams);
                assert!(host.starts_with(f.text.as_str()), "board {:?}, host {host:?}", f.text);
            }
            other => panic!("{field}: {other:?}"),
        }
    }
}

/// A model the direct inverse cannot use is refused with the reason (issue 29, item 2):
/// `bouc_wen = [0, 0, 0, 0, 0]` used to load and hold the drive at a saturation bound; a
/// loop whose static part falls as `u` rises at rest (`A1 − A − A0 < 0`) too. The mirrored
/// model of a sensor counting the stroke downwards passes, and the inverse works on it.
#[test]
fn a_model_the_inverse_cannot_use_is_refused_with_the_reason() {
    let zero = ControllerParams {
        model: ExtendedParams { bw: BoucWenParams::default(), ar: [0.0; MAX_AR] },
        ..controller_params(&[])
    };
    let e = zero.validate().unwrap_err().to_string();
    assert!(e.starts_with("model gain A1 (the inverse divides by it"), "{e}");
    assert!(Controller::new(&zero).is_err());
    for (a1, a, a0) in [(20.0, 25.0, 0.0), (20.0, 6.0, 14.5), (20.0, 6.0, -14.5), (1e-9, 0.0, 0.0)] {
        let mut p = controller_params(&[]);
        (p.model.bw.a1, p.model.bw.a, p.model.bw.a0) = (a1, a, a0);
        assert!(p.validate().is_err(), "A1 {a1}, A {a}, A0 {a0} accepted");
    }
    let mut mirrored = controller_params(&[]);
    let bw = mirrored.model.bw;
    mirrored.model.bw = BoucWenParams { a1: -bw.a1, a: -bw.a, a0: -bw.a0, gamma: -bw.gamma, beta: bw.beta };
    assert_eq!(mirrored.validate(), Ok(()));
    let mut c = Controller::new(&mirrored).unwrap();
    let mut b = Bench::new();
    b.send(Message::SetController(mirrored));
    assert!(matches!(&b.take()[..], [Message::Ack { .. }]));
    // Its inverse drives within the range, never sitting at a bound.
    let mut u_max = 0.0f32;
    for _ in 0..1000 {
        u_max = u_max.max(c.step(None).unwrap().out.u.abs());
    }
    assert!(u_max > 0.0 && u_max < 9.0, "{u_max} V");
}

#[test]
fn parameters_out_of_range_are_refused_naming_the_field() {
    let mut b = Bench::new();
    type Change = fn(&mut ControllerParams);
    let cases: [(Change, &str); 5] = [
        (|p| p.sample_period_us = 0, "sample period"),
        (|p| p.sample_period_us = 10_000_000, "sample period"),
        (|p| p.amplitude_um = 1e30, "reference amplitude"),
        (|p| p.fade_samples = u32::MAX, "fade-in"),
        (|p| p.saturation.u_max = 1e9, "saturation"),
    ];
    for (change, field) in cases {
        let mut p = controller_params(&[]);
        change(&mut p);
        b.send(Message::SetController(p));
        match &b.take()[..] {
            [Message::Fault(f)] => {
                assert_eq!(f.code, FaultCode::InvalidParams);
                assert!(f.text.contains(field), "{} vs {field}", f.text);
            }
            other => panic!("{other:?}"),
        }
    }
    let bad_safety = [
        SafetyParams { u_min: 1.0, ..SafetyParams::DEFAULT },
        SafetyParams { u_max: f32::NAN, ..SafetyParams::DEFAULT },
        SafetyParams { slew_v_per_s: 0.0, ..SafetyParams::DEFAULT },
        SafetyParams { host_timeout_ms: 0, ..SafetyParams::DEFAULT },
    ];
    for s in bad_safety {
        b.send(Message::SetSafety(s));
        assert!(matches!(&b.take()[..], [Message::Fault(f)] if f.code == FaultCode::InvalidParams));
    }
}

#[test]
fn bad_frames_are_answered_at_a_bounded_rate_and_all_counted() {
    let mut b = Bench::new();
    for _ in 0..100 {
        b.dev.on_packet(Err(WireError::Crc), &mut Bench::sink(&mut b.out));
    }
    assert_eq!(b.take().len(), limits::FAULT_BURST as usize);
    // One more answer per refill period.
    for _ in 0..(3 * limits::FAULT_REFILL_TICKS) {
        b.tick();
        b.dev.on_packet(Err(WireError::Cobs), &mut Bench::sink(&mut b.out));
    }
    assert_eq!(b.take().len(), 3);
    let d = b.dev.diagnostics();
    assert_eq!((d.bad_frames, d.faults_suppressed), (100 + 3 * limits::FAULT_REFILL_TICKS, 96 + 27));
    assert_eq!(b.dev.status().rx_bad, d.bad_frames);
}

/// The drives a ramp wrote, checked: monotonic towards 0, steps of at most the slew.
fn check_ramp(from: f32, ramp: &[f32], step: f32) {
    let mut prev = from;
    for &v in ramp {
        assert!(v.abs() <= prev.abs() && (v - prev).abs() <= step * 1.0001, "{prev} -> {v}");
        prev = v;
    }
    assert_eq!(ramp.last(), Some(&0.0));
}

#[test]
fn a_silent_host_ends_a_local_run_and_the_drive_ramps_to_zero() {
    let mut b = Bench { dev: Device::new().with_converters(), seq: 0, out: Vec::new() };
    b.send(Message::SetSafety(SafetyParams {
        host_timeout_ms: 20,
        slew_v_per_s: 5.0,
        ..SafetyParams::DEFAULT
    }));
    b.send(Message::SetController(ControllerParams { fade_samples: 0, ..controller_params(&[]) }));
    b.send(Message::Start { mode: Mode::Local, samples: 0 });
    b.take();
    let mut fe = Recorder::default();
    // 20 ticks of the run, the sensor answering; then the host says nothing.
    for k in 0..20 {
        b.tick_with(&mut fe);
        fe.y = Some(k as f32 * 0.1);
    }
    let v_run = *fe.driven.last().unwrap();
    assert!(v_run.abs() > 0.05, "{v_run}");
    let ticks_run = fe.driven.len();
    let mut safe = None;
    for _ in 0..200 {
        b.tick_with(&mut fe);
        for m in b.take() {
            if let Message::Safe { reason, ticks, period_us } = m {
                safe = Some((reason, ticks, period_us));
            }
        }
        if safe.is_some() {
            break;
        }
    }
    let (reason, ticks, period) = safe.expect("the board reports its safe state");
    assert_eq!((reason, period), (SafeReason::HostLost as u8, 1000));
    // Timeout (20 ticks after the last frame; the run's 20 ticks count) then the ramp.
    let ramp = &fe.driven[ticks_run..];
    check_ramp(v_run, ramp, 0.005);
    assert!(ramp.len() > 10, "{ramp:?}");
    assert_eq!(ticks as usize, 20 + ramp.len());
    assert_eq!(b.dev.drive_v(), 0.0);
    assert!(!b.dev.running());
    // A new run can start.
    b.send(Message::Start { mode: Mode::Local, samples: 1 });
    assert!(matches!(&b.take()[..], [Message::Ack { .. }]));
}

#[test]
fn after_a_watchdog_reset_the_drive_ramps_from_where_it_was() {
    let mut b = Bench { dev: Device::new().with_converters(), seq: 0, out: Vec::new() };
    // Saved with a slew of 100 V/s (0.1 V per tick); a saved slew out of range is not used.
    b.dev.begin_safe_state(SafeReason::Watchdog, -7.3, f32::NAN);
    let mut fe = Recorder::default();
    b.send(Message::Start { mode: Mode::Local, samples: 1 });
    assert!(matches!(&b.take()[..], [Message::Fault(f)] if f.code == FaultCode::Busy));
    for _ in 0..100 {
        b.tick_with(&mut fe);
    }
    check_ramp(-7.3, &fe.driven, 0.1);
    assert!((73..=74).contains(&fe.driven.len()), "{}", fe.driven.len());
    let msgs = b.take();
    assert!(msgs.iter().any(|m| matches!(m, Message::Safe { reason: 4, .. })), "{msgs:?}");
    assert_eq!(b.dev.diagnostics().reset_cause, SafeReason::Watchdog as u8);
}

#[test]
fn a_non_finite_step_faults_and_ramps() {
    let mut b = Bench { dev: Device::new().with_converters(), seq: 0, out: Vec::new() };
    let mut p = controller_params(&[]);
    // A model whose inverse explodes: a huge AR gain drives u_f to the rails, then the
    // drive limits clamp it; the output stays finite, so instead break the sensor.
    p.saturation = boucwen_core::compensator::Saturation::symmetric(5.0);
    b.send(Message::SetController(p));
    b.send(Message::Start { mode: Mode::Local, samples: 0 });
    b.take();
    let mut fe = Recorder::default();
    for k in 0..50 {
        fe.y = Some(if k == 30 { f32::NAN } else { 1e9 });
        b.send(Message::GetStatus);
        b.tick_with(&mut fe);
    }
    // Out-of-range or non-finite readings are not used; the run goes on, drive finite.
    assert!(fe.driven.iter().all(|u| u.is_finite() && u.abs() <= 5.0));
    assert!(b.dev.running());
    let tele: Vec<u8> = b
        .take()
        .into_iter()
        .filter_map(|m| if let Message::Telemetry { flags, .. } = m { Some(flags) } else { None })
        .collect();
    assert_eq!(tele.len(), 50);
    assert!(tele.iter().all(|f| f & command_flags::Y_MISSING != 0));
}

#[test]
fn the_simulated_actuator_run_is_the_closed_loop_bit_for_bit() {
    let c = controller_params(&[]);
    let mut b = Bench::new();
    b.send(Message::SetController(c.clone()));
    b.send(Message::SetPlant(plant_params()));
    b.send(Message::Start { mode: Mode::Simulated, samples: 300 });
    b.take();
    let mut cl = ClosedLoop::new(Controller::new(&c).unwrap(), OnChipPlant::new(&plant_params()).unwrap());
    let mut y_prev = f32::NAN;
    for k in 0..300u32 {
        b.send(Message::GetStatus);
        b.tick();
        let s = cl.control().unwrap();
        let y = cl.actuate(s.out.u);
        let tele: Vec<Message> =
            b.take().into_iter().filter(|m| matches!(m, Message::Telemetry { .. })).collect();
        match &tele[..] {
            [Message::Telemetry { k: kk, u, y: yy, .. }] => {
                assert_eq!((*kk, u.to_bits(), yy.to_bits()), (k, s.out.u.to_bits(), y_prev.to_bits()))
            }
            other => panic!("{other:?}"),
        }
        y_prev = y;
    }
}

#[test]
fn new_drive_limits_that_exclude_the_held_drive_are_refused() {
    let mut b = Bench { dev: Device::new().with_converters(), seq: 0, out: Vec::new() };
    b.send(Message::SetController(ControllerParams { fade_samples: 0, ..controller_params(&[]) }));
    b.send(Message::Start { mode: Mode::Local, samples: 30 });
    let mut fe = Recorder { driven: Vec::new(), y: Some(0.5) };
    for _ in 0..30 {
        b.tick_with(&mut fe);
    }
    b.take();
    let held = b.dev.drive_v();
    assert!(!b.dev.running() && held.abs() > 0.01, "{held}");
    // Limits that would leave the held drive outside them: refused, the old ones stay.
    let tight = SafetyParams { u_min: -held.abs() / 2.0, u_max: held.abs() / 2.0, ..SafetyParams::DEFAULT };
    b.send(Message::SetSafety(tight));
    assert!(matches!(&b.take()[..], [Message::Fault(f)] if f.code == FaultCode::Busy), "{held}");
    // Limits that contain it are taken.
    let wide = SafetyParams { u_min: -9.0, u_max: 9.0, ..SafetyParams::DEFAULT };
    b.send(Message::SetSafety(wide));
    assert!(matches!(&b.take()[..], [Message::Ack { kind: kind::SET_SAFETY, .. }]));
}

//! Fuzzing the link: the frame decoder and the board's state machine ([`Device`]) under
//! arbitrary byte streams and under valid frames with hostile fields, with proptest.
//!
//! Two properties, each run for a bounded number of cases (`BOUCWEN_FUZZ_CASES`, else
//! [`DEFAULT_CASES`]; `cargo test -p boucwen-link fuzz -- --nocapture` prints what was
//! tried):
//!
//! * **bytes**: a stream of random bytes, valid frames, frames cut short and frames with
//!   flipped bits, cut at random places into the decoder, its packets (and rejections) to
//!   the device, with ticks in between;
//! * **fields**: sequences of valid frames whose fields are hostile (NaN, ±∞, `f32::MAX`,
//!   subnormals, `u32::MAX`, sample indices far ahead or behind, unknown harmonic orders,
//!   parameters one field off their range, modes in any order), with ticks (some reporting
//!   many missed periods), on a board with or without converters whose sensor reads
//!   hostile values too.
//!
//! After every packet and every tick:
//! * nothing panicked (the tests run with overflow checks);
//! * the handling was bounded: at most [`limits::MAX_CATCH_UP`]` + 1` steps of the on-chip
//!   plant per packet and 1 per tick, at most [`MAX_FRAMES_OUT`] frames sent;
//! * every drive the board put out (in `Command`, `Telemetry`, to the converters, and its
//!   own record of the drive) is finite and within the drive limits in force, and every
//!   plant-mode `Measurement` is finite and within [`limits::Y_MAX_UM`];
//!
//! and at the end of each case the board still answers: a `GetStatus` gets a `Status`, and
//! once the host falls silent the drive reaches 0 V within the host timeout plus the ramp
//! (the bound computed from the safety parameters in force).

use super::analog::FrontEnd;
use super::device::Device;
use super::frame::MAX_ENCODED;
use super::limits;
use super::message::*;
use super::plant::PLANT_STEPS;
use super::tests::{controller_params, plant_params};
use super::{Decoder, Packet, encode};
use boucwen_core::compensator::HarmonicSpec;
use boucwen_core::controllers::OrcPlacement;
use boucwen_core::model::HarmonicBranch;
use boucwen_core::signal::Oscillator;
use nalgebra::Complex;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError, TestRunner};
use std::cell::{Cell, RefCell};
use std::vec::Vec;

/// Cases per property when `BOUCWEN_FUZZ_CASES` is not set (what CI runs).
pub const DEFAULT_CASES: u32 = 300;
/// Most frames one packet or one tick may make the board send.
pub const MAX_FRAMES_OUT: usize = 2;

fn cases() -> u32 {
    std::env::var("BOUCWEN_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(DEFAULT_CASES)
}

fn hostile_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        3 => any::<u32>().prop_map(f32::from_bits),
        1 => prop::sample::select(vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            f32::MAX,
            f32::MIN,
            f32::MIN_POSITIVE,
            1e-45,
            1e20,
            -1e3,
            1e3,
        ]),
        3 => -20.0f32..20.0,
    ]
}

fn hostile_u32() -> impl Strategy<Value = u32> {
    prop_oneof![
        2 => any::<u32>(),
        1 => prop::sample::select(vec![0, 1, 63, 64, 65, 66, u32::MAX - 1, u32::MAX]),
        3 => 0u32..300,
    ]
}

/// A valid controller, or one with one to three fields replaced by hostile values.
fn controller() -> impl Strategy<Value = ControllerParams> {
    let edit = (0u8..24, hostile_f32(), hostile_u32(), any::<u64>());
    let edits = prop_oneof![Just(Vec::new()), prop::collection::vec(edit, 1..4)];
    (edits, any::<bool>()).prop_map(|(edits, two)| {
        let mut p = controller_params(if two { &[(3, 1.0, 0.5), (5, -0.2, 0.1)] } else { &[(3, 1.0, 0.5)] });
        for (field, x, n, w) in edits {
            let bw = &mut p.model.bw;
            match field {
                0 => bw.a1 = x,
                1 => bw.a = x,
                2 => bw.a0 = x,
                3 => bw.gamma = x,
                4 => bw.beta = x,
                5..=7 => p.model.ar[field as usize - 5] = x,
                8 => p.drive = Oscillator::from_increment(w),
                9 => p.sample_period_us = n,
                10 => p.amplitude_um = x,
                11 => p.fade_samples = n,
                12..=14 => {
                    if let Some(h) = p.harmonics.first_mut() {
                        match field {
                            12 => h.order = n % 256,
                            13 => h.response.re = x,
                            _ => h.response.im = x,
                        }
                    }
                }
                15 => p.rls.lambda = x,
                16 => p.rls.p0 = x,
                17 => p.rls.p_max = x,
                18 => p.saturation.u_min = x,
                19 => p.saturation.u_max = x,
                20 => p.uc_max = x,
                21 => p.harmonics.clear(),
                22 => p.preview_samples = x,
                _ => {
                    let _ = p.harmonics.push(HarmonicSpec { order: n % 256, response: Complex::new(x, x) });
                }
            }
        }
        p
    })
}

/// A valid on-chip plant, or one with one to three fields replaced by hostile values.
fn plant() -> impl Strategy<Value = PlantParams> {
    let edit = (0u8..14, hostile_f32(), hostile_u32(), any::<u64>());
    let edits = prop_oneof![Just(Vec::new()), prop::collection::vec(edit, 1..4)];
    edits.prop_map(|edits| {
        let mut p = plant_params();
        for (field, x, n, w) in edits {
            let bw = &mut p.base.bw;
            match field {
                0 => bw.a1 = x,
                1 => bw.a = x,
                2 => bw.a0 = x,
                3 => bw.gamma = x,
                4 => bw.beta = x,
                5..=7 => p.base.ar[field as usize - 5] = x,
                8 => p.drive = Oscillator::from_increment(w),
                9..=11 => {
                    if let Some(b) = p.branches.first_mut() {
                        match field {
                            9 => b.order = n % 256,
                            10 => b.alpha_s = x,
                            _ => b.alpha_c = x,
                        }
                    }
                }
                12 => p.branches.clear(),
                _ => {
                    let _ =
                        p.branches.push(HarmonicBranch { order: n % 256, alpha_s: x, alpha_c: x, ar: [] });
                }
            }
        }
        p
    })
}

/// Safety parameters: in the range the liveness bound allows (timeouts to 1 s, slews from
/// 10 V/s, limits to ±20 V) or with a field off the board's range (refused).
fn safety() -> impl Strategy<Value = SafetyParams> {
    let u_min = prop_oneof![
        2 => -20.0f32..=0.0,
        2 => -0.5f32..=0.0,
        1 => prop::sample::select(vec![f32::NAN, 1.0, -1001.0, f32::NEG_INFINITY]),
    ];
    let u_max = prop_oneof![
        2 => 0.0f32..=20.0,
        2 => 0.0f32..=0.5,
        1 => prop::sample::select(vec![f32::NAN, -1.0, 1001.0, f32::INFINITY]),
    ];
    let slew =
        prop_oneof![3 => 10.0f32..1e5, 1 => prop::sample::select(vec![f32::NAN, 0.0, -5.0, 0.05, 2e5])];
    let timeout = prop_oneof![3 => 10u32..=1000, 1 => prop::sample::select(vec![0, 9, 60_001, u32::MAX])];
    (u_min, u_max, slew, timeout).prop_map(|(u_min, u_max, slew_v_per_s, host_timeout_ms)| SafetyParams {
        u_min,
        u_max,
        slew_v_per_s,
        host_timeout_ms,
    })
}

/// Excitations with hostile amplitudes, periods, fades and increments.
fn excitation() -> impl Strategy<Value = crate::excitation::ExcitationParams> {
    let tone = (any::<u64>(), hostile_f32(), any::<u32>()).prop_map(|(inc, amplitude_v, phase)| {
        crate::excitation::Tone { drive: Oscillator::from_increment(inc), amplitude_v, phase }
    });
    (hostile_u32(), hostile_u32(), prop::collection::vec(tone, 0..=crate::excitation::MAX_TONES)).prop_map(
        |(sample_period_us, fade_samples, tones)| crate::excitation::ExcitationParams {
            sample_period_us,
            fade_samples,
            tones: tones.into_iter().collect(),
        },
    )
}

fn orc() -> impl Strategy<Value = OrcParams> {
    (
        prop::array::uniform5(hostile_f32()),
        any::<u16>(),
        hostile_f32(),
        prop::sample::select(vec![OrcPlacement::PiInput, OrcPlacement::PlantInput]),
    )
        .prop_map(
            |([kp, ki_per_s, feedforward_gain, q_coeff, learning_gain], lead_samples, limit, placement)| {
                OrcParams {
                    kp,
                    ki_per_s,
                    feedforward_gain,
                    q_coeff,
                    learning_gain,
                    lead_samples,
                    limit,
                    placement,
                }
            },
        )
}

fn mode() -> impl Strategy<Value = Mode> {
    prop::sample::select(vec![Mode::Control, Mode::Plant, Mode::Simulated, Mode::Local, Mode::Lockstep])
}

/// Any message with hostile fields, weighted towards what drives a run.
fn message() -> impl Strategy<Value = Message> {
    prop_oneof![
        3 => controller().prop_map(Message::SetController),
        2 => plant().prop_map(Message::SetPlant),
        1 => safety().prop_map(Message::SetSafety),
        1 => orc().prop_map(Message::SetOrc),
        3 => (mode(), hostile_u32()).prop_map(|(mode, samples)| Message::Start { mode, samples }),
        4 => (hostile_u32(), hostile_f32(), any::<u16>(), any::<u8>())
            .prop_map(|(k, u, used, flags)| Message::Command { k, u, used, flags }),
        4 => (hostile_u32(), hostile_f32()).prop_map(|(k, y)| Message::Measurement { k, y }),
        1 => Just(Message::Stop),
        1 => Just(Message::GetStatus),
        1 => Just(Message::GetDiagnostics),
        1 => Just(Message::GetParams),
        1 => excitation().prop_map(Message::SetExcitation),
        1 => (any::<u8>(), any::<u16>()).prop_map(|(kind, seq)| Message::Ack { kind, seq }),
        1 => (hostile_u32(), hostile_f32(), hostile_f32(), any::<u8>())
            .prop_map(|(k, u, y, flags)| Message::Telemetry { k, u, y, flags }),
        1 => (any::<u8>(), hostile_u32(), hostile_u32())
            .prop_map(|(reason, ticks, period_us)| Message::Safe { reason, ticks, period_us }),
    ]
}

/// One step of a fuzz case.
#[derive(Clone, Debug)]
enum Op {
    /// A valid frame (with the sender's next sequence number, or a jump in it).
    Frame(Message, Option<u16>),
    /// A frame with bit `flip` flipped (modulo its length) or cut at `cut`.
    Damaged(Message, usize, bool),
    /// Raw bytes.
    Raw(Vec<u8>),
    /// Ticks, the first reporting this many missed periods; the sensor reads this.
    Tick(u16, u32, Option<f32>),
}

fn op() -> impl Strategy<Value = Op> {
    let missed = prop_oneof![8 => Just(0u32), 2 => 1u32..5, 1 => Just(u32::MAX)];
    let sensor =
        prop_oneof![3 => (-30.0f32..30.0).prop_map(Some), 1 => Just(None), 1 => hostile_f32().prop_map(Some)];
    prop_oneof![
        10 => (message(), prop::option::weighted(0.05, any::<u16>())).prop_map(|(m, s)| Op::Frame(m, s)),
        2 => (message(), any::<usize>(), any::<bool>()).prop_map(|(m, at, cut)| Op::Damaged(m, at, cut)),
        1 => prop::collection::vec(any::<u8>(), 0..64).prop_map(Op::Raw),
        6 => (1u16..60, missed, sensor).prop_map(|(n, m, y)| Op::Tick(n, m, y)),
    ]
}

/// The sensor of a fuzzed board with converters: reads what the case says, records drives.
struct Sensor {
    y: Option<f32>,
    driven: Vec<f32>,
}

impl FrontEnd for Sensor {
    fn sense(&mut self) -> Option<f32> {
        self.y
    }
    fn drive(&mut self, u: f32) -> f32 {
        self.driven.push(u);
        u
    }
}

/// What was tried, summed over the cases.
#[derive(Default, Debug)]
struct Tried {
    cases: u64,
    bytes: u64,
    packets: u64,
    rejected: u64,
    ticks: u64,
    runs_started: u64,
}

/// A board under fuzzing: the device, the decoder in front of it, and the checks.
struct Board {
    dev: Device,
    dec: Decoder,
    fe: Sensor,
    /// The safety parameters in force (tracked from the board's acknowledgements).
    safety: SafetyParams,
    /// Sequence numbers of the SetSafety frames in flight, with their parameters.
    pending_safety: Vec<(u16, SafetyParams)>,
    seq: u16,
}

fn fail(what: String) -> TestCaseError {
    TestCaseError::fail(what)
}

impl Board {
    fn new(converters: bool) -> Self {
        let dev = if converters { Device::new().with_converters() } else { Device::new() };
        Self {
            dev,
            dec: Decoder::new(),
            fe: Sensor { y: None, driven: Vec::new() },
            safety: SafetyParams::DEFAULT,
            pending_safety: Vec::new(),
            seq: 0,
        }
    }

    /// Checks what the board sent (`out`, frames) and its drive after one packet or tick.
    fn check_out(&mut self, out: &[u8], tried: &mut Tried) -> Result<Vec<Message>, TestCaseError> {
        let (lo, hi) = (self.safety.u_min, self.safety.u_max);
        let within = |u: f32| u.is_finite() && u >= lo && u <= hi;
        let mut dec = Decoder::new();
        let mut msgs = Vec::new();
        for &b in out {
            match dec.push(b) {
                Some(Ok(p)) => msgs.push(p.msg),
                Some(Err(e)) => return Err(fail(format!("the board sent a bad frame: {e}"))),
                None => {}
            }
        }
        if msgs.len() > MAX_FRAMES_OUT {
            return Err(fail(format!("{} frames sent for one packet or tick: {msgs:?}", msgs.len())));
        }
        for m in &msgs {
            match *m {
                Message::Command { u, .. } | Message::Telemetry { u, .. } if !within(u) => {
                    return Err(fail(format!("drive {u} V outside [{lo}, {hi}] in {m:?}")));
                }
                Message::Measurement { y, .. } if !(y.is_finite() && y.abs() <= limits::Y_MAX_UM) => {
                    return Err(fail(format!("plant output {y} µm in {m:?}")));
                }
                Message::Ack { kind: kind::SET_SAFETY, seq } => {
                    if let Some(&(_, p)) = self.pending_safety.iter().find(|(s, _)| *s == seq) {
                        self.safety = p;
                    }
                }
                Message::Ack { kind: kind::START, .. } => tried.runs_started += 1,
                _ => {}
            }
        }
        let d = self.dev.drive_v();
        if !(d == 0.0 || within(d)) {
            return Err(fail(format!("drive {d} V outside [{lo}, {hi}]")));
        }
        if let Some(&u) = self.fe.driven.iter().find(|u| !within(**u) && **u != 0.0) {
            return Err(fail(format!("converters driven to {u} V outside [{lo}, {hi}]")));
        }
        self.fe.driven.clear();
        Ok(msgs)
    }

    /// Feeds bytes through the decoder to the device, checking each packet.
    fn bytes(&mut self, bytes: &[u8], tried: &mut Tried) -> Result<(), TestCaseError> {
        tried.bytes += bytes.len() as u64;
        for &b in bytes {
            let Some(packet) = self.dec.push(b) else { continue };
            tried.packets += 1;
            tried.rejected += packet.is_err() as u64;
            if let Ok(Packet { seq, msg: Message::SetSafety(p) }) = &packet {
                self.pending_safety.push((*seq, *p));
            }
            let mut out = Vec::new();
            PLANT_STEPS.with(|c| c.set(0));
            self.dev.on_packet(packet, &mut |f: &[u8]| out.extend_from_slice(f));
            let steps = PLANT_STEPS.with(Cell::get);
            if steps > limits::MAX_CATCH_UP as u64 + 1 {
                return Err(fail(format!("one packet stepped the plant {steps} times")));
            }
            self.check_out(&out, tried)?;
            self.pending_safety.clear();
        }
        Ok(())
    }

    fn frame(&mut self, m: &Message, jump: Option<u16>) -> Vec<u8> {
        if let Some(s) = jump {
            self.seq = s;
        }
        let f = encode(self.seq, m).expect("every message encodes");
        self.seq = self.seq.wrapping_add(1);
        f.to_vec()
    }

    fn tick(&mut self, missed: u32, tried: &mut Tried) -> Result<(), TestCaseError> {
        tried.ticks += 1;
        let mut out = Vec::new();
        PLANT_STEPS.with(|c| c.set(0));
        self.dev.on_tick(missed, &mut self.fe, &|| 0, &mut |f: &[u8]| out.extend_from_slice(f));
        let steps = PLANT_STEPS.with(Cell::get);
        if steps > 1 {
            return Err(fail(format!("one tick stepped the plant {steps} times")));
        }
        self.check_out(&out, tried).map(|_| ())
    }

    fn run(&mut self, ops: &[Op], tried: &mut Tried) -> Result<(), TestCaseError> {
        for op in ops {
            match op {
                Op::Frame(m, jump) => {
                    let f = self.frame(m, *jump);
                    self.bytes(&f, tried)?;
                }
                Op::Damaged(m, at, cut) => {
                    let mut f = self.frame(m, None);
                    let body = f.len() - 1;
                    if *cut {
                        f.truncate(at % body);
                        f.push(0);
                    } else {
                        f[at % body] ^= 1 << (at / body % 8);
                    }
                    self.bytes(&f, tried)?;
                }
                Op::Raw(b) => self.bytes(b, tried)?,
                Op::Tick(n, missed, y) => {
                    self.fe.y = *y;
                    self.tick(*missed, tried)?;
                    for _ in 1..*n {
                        self.tick(0, tried)?;
                    }
                }
            }
        }
        Ok(())
    }

    /// The board still answers, and a silent host brings the drive to 0 V in bounded time.
    fn still_alive(&mut self, tried: &mut Tried) -> Result<(), TestCaseError> {
        // A delimiter ends any half-received frame; then a status request.
        self.bytes(&[0], tried)?;
        let f = self.frame(&Message::GetStatus, None);
        let mut out = Vec::new();
        for &b in &f {
            if let Some(p) = self.dec.push(b) {
                self.dev.on_packet(p, &mut |x: &[u8]| out.extend_from_slice(x));
            }
        }
        let msgs = self.check_out(&out, tried)?;
        if !matches!(msgs[..], [Message::Status(_)]) {
            return Err(fail(format!("GetStatus answered with {msgs:?}")));
        }
        let period_s = self.dev.period_us() as f64 * 1e-6;
        let timeout = (self.safety.host_timeout_ms as f64 * 1e-3 / period_s).ceil();
        let step = self.safety.slew_v_per_s as f64 * period_s;
        let ramp = (self.safety.u_max.abs().max(self.safety.u_min.abs()) as f64 / step).ceil();
        let bound = (timeout + ramp + 3.0) as u64;
        self.fe.y = None;
        for _ in 0..bound {
            self.tick(0, tried)?;
            if self.dev.drive_v() == 0.0 && !self.dev.ramping() {
                return Ok(());
            }
        }
        Err(fail(format!("drive {} V after {bound} ticks of silence", self.dev.drive_v())))
    }
}

fn report(name: &str, t: &Tried) {
    eprintln!(
        "fuzz {name}: {} cases, {} bytes, {} packets ({} rejected), {} ticks, {} runs started",
        t.cases, t.bytes, t.packets, t.rejected, t.ticks, t.runs_started
    );
}

#[test]
fn fuzz_bytes_decoder_and_board_never_panic_stall_or_drive_out_of_range() {
    // Chunks: random bytes, or a valid frame of any message, whole, cut short or bit-flipped.
    let chunk = prop_oneof![
        2 => prop::collection::vec(any::<u8>(), 0..96),
        3 => (message(), any::<usize>(), 0u8..3).prop_map(|(m, at, how)| {
            let mut f = encode(at as u16, &m).expect("every message encodes").to_vec();
            let body = f.len() - 1;
            match how {
                0 => {}
                1 => f.truncate(at % body),
                _ => f[at % body] ^= 1 << (at % 8),
            }
            f
        }),
    ];
    let case = (prop::collection::vec((chunk, 0u8..4), 1..40), any::<bool>());
    let tried = RefCell::new(Tried::default());
    let mut runner = TestRunner::new(Config::with_cases(cases()));
    let result = runner.run(&case, |(chunks, converters)| {
        let tried = &mut *tried.borrow_mut();
        tried.cases += 1;
        let mut b = Board::new(converters);
        for (bytes, ticks) in &chunks {
            if bytes.len() > 4 * MAX_ENCODED {
                return Err(fail("chunk too long".into()));
            }
            b.bytes(bytes, tried)?;
            for _ in 0..*ticks {
                b.tick(0, tried)?;
            }
        }
        b.still_alive(tried)
    });
    report("bytes", &tried.borrow());
    if let Err(e) = result {
        panic!("{e}");
    }
}

#[test]
fn fuzz_fields_board_never_panics_stalls_or_drives_out_of_range() {
    let case = (prop::collection::vec(op(), 1..60), any::<bool>());
    let tried = RefCell::new(Tried::default());
    let mut runner = TestRunner::new(Config::with_cases(cases()));
    let result = runner.run(&case, |(ops, converters)| {
        let tried = &mut *tried.borrow_mut();
        tried.cases += 1;
        let mut b = Board::new(converters);
        b.run(&ops, tried)?;
        b.still_alive(tried)
    });
    report("fields", &tried.borrow());
    if let Err(e) = result {
        panic!("{e}");
    }
}

/// What the host's check accepts the board accepts, and the other way round: a controller
/// with hostile fields is acknowledged by [`Device`] exactly when
/// [`ControllerParams::validate`] passes it (the host validates with it before it sends or
/// writes parameters).
#[test]
fn fuzz_the_board_accepts_exactly_what_the_host_check_accepts() {
    let mut runner = TestRunner::new(Config::with_cases(4 * cases()));
    let result = runner.run(&controller(), |p| {
        let host = p.validate();
        let mut dev = Device::new();
        let mut out = Vec::new();
        let mut sink = |bytes: &[u8]| {
            let mut d = Decoder::new();
            out.extend(bytes.iter().filter_map(|&b| d.push(b)).filter_map(Result::ok).map(|p| p.msg));
        };
        dev.on_packet(Ok(Packet { seq: 0, msg: Message::SetController(p.clone()) }), &mut sink);
        let board_ok = matches!(out[..], [Message::Ack { .. }]);
        if host.is_ok() != board_ok {
            return Err(fail(format!("host {host:?}, board {out:?} for {p:?}")));
        }
        Ok(())
    });
    if let Err(e) = result {
        panic!("{e}");
    }
}

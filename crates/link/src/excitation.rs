//! The board as data acquisition: the excitation generator, and what it reports of its
//! parameters. The parameters are wire payloads, defined with the other messages in
//! [`crate::message`] and re-exported here.
//!
//! * [`ExcitationParams`] ([`super::Message::SetExcitation`]): a sum of up to
//!   [`MAX_TONES`] sines, faded in, that the board drives instead of its controller in the
//!   next runs (any mode that ticks: its converters, the on-chip simulated actuator, or the
//!   host's actuator over the link), reporting each sample as it does for a control run.
//!   [`Excitation`] is the generator, run on the board and (bit for bit) on the host.
//! * [`BoardParams`] ([`super::Message::Params`], the answer to
//!   [`super::Message::GetParams`]): the parameters in force, as the board holds them, so
//!   the host can compare what it sent with what the board has, bit for bit.
//!
//! ## Excitation
//! ```text
//! u[k] = w[k] · Σ_i a_i · sin(2π f_i k Ts + φ_i)
//! ```
//! with the raised-cosine fade-in `w[k] = ½ − ½·cos(π k / K)` for `k < K` (`w = 1` after,
//! as the reference of a control run). `f_i` is the core's integer phase increment
//! ([`boucwen_core::signal::Oscillator`]), `φ_i` a phase in units of 2⁻³² turn, `a_i` in V. The board checks
//! ([`ExcitationParams::validate`]): 1 to [`MAX_TONES`] tones, every amplitude finite,
//! `Σ|a_i|` at most [`crate::limits::U_MAX_V`], the sample period and the fade in
//! the ranges of a control run. The drive limits ([`super::message::SafetyParams`]) clamp
//! the result like any drive (flagged [`super::message::command_flags::LIMITED`]).

pub use crate::message::{Active, BoardParams, ExcitationParams, MAX_TONES, Tone};
use boucwen_core::Error;
use boucwen_core::signal::sin_cos;

/// The excitation generator: `u[k]` of [`ExcitationParams`], sample by sample, with the
/// same bits on every target.
#[derive(Clone, Debug)]
pub struct Excitation {
    tones: [(u64, u64, f32); MAX_TONES],
    count: usize,
    fade_samples: u32,
    fade_increment: u64,
    k: u32,
}

impl Excitation {
    /// The generator of `p` at `k = 0`, validated.
    pub fn new(p: &ExcitationParams) -> Result<Self, Error> {
        p.validate()?;
        let mut tones = [(0u64, 0u64, 0.0f32); MAX_TONES];
        for (slot, t) in tones.iter_mut().zip(&p.tones) {
            *slot = ((t.phase as u64) << 32, t.drive.increment(), t.amplitude_v);
        }
        let fade_increment = if p.fade_samples > 0 { (1u64 << 63) / p.fade_samples as u64 } else { 0 };
        Ok(Self { tones, count: p.tones.len(), fade_samples: p.fade_samples, fade_increment, k: 0 })
    }

    /// The next sample index.
    pub fn next_k(&self) -> u32 {
        self.k
    }

    /// `(k, u[k])`; advances `k`.
    #[inline]
    pub fn next_sample(&mut self) -> (u32, f32) {
        let mut u = 0.0f32;
        for (phase, inc, amp) in &mut self.tones[..self.count] {
            let (s, _) = sin_cos::<f32>(*phase);
            u += *amp * s;
            *phase = phase.wrapping_add(*inc);
        }
        if self.k < self.fade_samples {
            let (_, c) = sin_cos::<f32>((self.k as u64).wrapping_mul(self.fade_increment));
            u *= 0.5 - 0.5 * c;
        }
        let k = self.k;
        self.k = self.k.saturating_add(1);
        (k, u)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::WireError;
    use crate::message::EXCITATION_LEN;
    use crate::message::Message;
    use crate::tests::controller_params;
    use crate::{Decoder, encode};
    use boucwen_core::signal::Oscillator;
    use std::vec::Vec as StdVec;

    fn params(tones: &[(f64, f32, u32)]) -> ExcitationParams {
        ExcitationParams {
            sample_period_us: 1000,
            fade_samples: 100,
            tones: tones
                .iter()
                .map(|&(f, a, phase)| Tone {
                    drive: Oscillator::new(f, 1e-3).unwrap(),
                    amplitude_v: a,
                    phase,
                })
                .collect(),
        }
    }

    fn round_trip(m: &Message) -> Message {
        let bytes = encode(7, m).unwrap();
        let mut d = Decoder::new();
        let got: StdVec<_> = bytes.iter().filter_map(|&b| d.push(b)).collect();
        assert_eq!(got.len(), 1);
        got.into_iter().next().unwrap().unwrap().msg
    }

    #[test]
    fn excitation_and_params_round_trip_bit_for_bit() {
        let e = Message::SetExcitation(params(&[(23.0, 1.0, 0), (61.0, -0.25, 0x8000_0000)]));
        assert_eq!(round_trip(&e), e);
        let full = Message::SetExcitation(params(&[(1.0, 0.1, 1); MAX_TONES]));
        assert_eq!(round_trip(&full), full);
        for (active, controller) in
            [(Active::Controller, Some(controller_params(&[(3, 0.2, -0.1)]))), (Active::None, None)]
        {
            let p = Message::Params(BoardParams {
                active,
                controller,
                safety: crate::message::SafetyParams::DEFAULT,
            });
            assert_eq!(round_trip(&p), p);
        }
        assert_eq!(round_trip(&Message::GetParams), Message::GetParams);
    }

    #[test]
    fn hostile_payloads_are_rejected_not_misread() {
        let mut payload = [0u8; crate::frame::MAX_PAYLOAD];
        let n = Message::SetExcitation(params(&[(23.0, 1.0, 0)])).encode_payload(&mut payload).unwrap();
        assert_eq!(n, EXCITATION_LEN);
        let mut bad = payload;
        bad[8] = MAX_TONES as u8 + 1;
        assert_eq!(
            Message::decode(crate::message::kind::SET_EXCITATION, &bad[..n]),
            Err(WireError::BadValue("tone count"))
        );
        assert_eq!(
            Message::decode(crate::message::kind::SET_EXCITATION, &payload[..n - 1]),
            Err(WireError::BadLength)
        );
        let n = Message::Params(BoardParams {
            active: Active::None,
            controller: None,
            safety: crate::message::SafetyParams::DEFAULT,
        })
        .encode_payload(&mut payload)
        .unwrap();
        let mut bad = payload;
        bad[0] = 9;
        assert_eq!(
            Message::decode(crate::message::kind::PARAMS, &bad[..n]),
            Err(WireError::BadValue("active parameters"))
        );
    }

    #[test]
    fn the_generator_sums_its_tones_and_fades_in() {
        let p = params(&[(23.0, 1.0, 0), (50.0, 0.5, 0x4000_0000)]);
        let mut e = Excitation::new(&p).unwrap();
        let mut max_after = 0.0f32;
        for k in 0..2000u32 {
            let (kk, u) = e.next_sample();
            assert_eq!(kk, k);
            let t = k as f64 * 1e-3;
            let w = if k < 100 { 0.5 - 0.5 * (core::f64::consts::PI * k as f64 / 100.0).cos() } else { 1.0 };
            let want = w
                * ((core::f64::consts::TAU * 23.0 * t).sin()
                    + 0.5 * (core::f64::consts::TAU * 50.0 * t + core::f64::consts::FRAC_PI_2).sin());
            assert!((u as f64 - want).abs() < 1e-4, "k {k}: {u} vs {want}");
            if k >= 100 {
                max_after = max_after.max(u.abs());
            }
        }
        assert!(max_after > 1.2 && max_after <= 1.5);
    }

    /// Feeds `msgs` to `dev`; returns what it answered.
    fn feed(dev: &mut crate::device::Device, msgs: &[Message]) -> StdVec<Message> {
        let mut out = StdVec::new();
        for (seq, m) in msgs.iter().enumerate() {
            dev.on_packet(Ok(crate::Packet { seq: seq as u16, msg: m.clone() }), &mut |b: &[u8]| {
                out.extend_from_slice(b)
            });
        }
        decode_all(&out)
    }

    fn decode_all(bytes: &[u8]) -> StdVec<Message> {
        let mut d = Decoder::new();
        bytes.iter().filter_map(|&b| d.push(b)).map(|r| r.unwrap().msg).collect()
    }

    #[test]
    fn the_board_drives_the_excitation_and_reports_its_parameters() {
        use crate::analog::NoFrontEnd;
        use crate::message::{Mode, kind};
        let mut dev = crate::device::Device::new();
        let c = controller_params(&[(3, 0.2, -0.1)]);
        let e = params(&[(23.0, 1.0, 0), (61.0, 0.3, 7)]);
        let got = feed(
            &mut dev,
            &[
                Message::GetParams,
                Message::SetController(c.clone()),
                Message::SetPlant(crate::tests::plant_params()),
                Message::SetExcitation(e.clone()),
                Message::GetParams,
                Message::Start { mode: Mode::Simulated, samples: 300 },
            ],
        );
        let safety = crate::message::SafetyParams::DEFAULT;
        assert_eq!(got[0], Message::Params(BoardParams { active: Active::None, controller: None, safety }));
        assert_eq!(got[3], Message::Ack { kind: kind::SET_EXCITATION, seq: 3 });
        assert_eq!(
            got[4],
            Message::Params(BoardParams { active: Active::Excitation, controller: Some(c.clone()), safety })
        );
        assert!(matches!(got[5], Message::Ack { kind: kind::START, .. }));
        // The run drives the excitation, bit for bit the host's generator, into the on-chip
        // actuator, whose outputs come back as the measurements.
        let mut generator = Excitation::new(&e).unwrap();
        let mut plant = crate::plant::OnChipPlant::new(&crate::tests::plant_params()).unwrap();
        let mut y_prev = f32::NAN;
        for k in 0..300u32 {
            // The host keeps the board from declaring it lost.
            dev.on_packet(Ok(crate::Packet { seq: 0xFFFF, msg: Message::GetStatus }), &mut |_: &[u8]| {});
            let mut out = StdVec::new();
            dev.on_tick(0, &mut NoFrontEnd, &|| 0, &mut |b: &[u8]| out.extend_from_slice(b));
            let msgs = decode_all(&out);
            let (kk, u) = generator.next_sample();
            let Message::Telemetry { k: tk, u: tu, y, flags } = msgs[0] else { panic!("{msgs:?}") };
            assert_eq!((tk, tu.to_bits()), (kk, u.to_bits()), "sample {k}");
            assert_eq!(y.to_bits(), y_prev.to_bits(), "sample {k}");
            assert_eq!(flags & !crate::message::command_flags::Y_MISSING, 0);
            y_prev = plant.step(u);
        }
        // SetController makes the controller active again, and an excitation that is not
        // valid is refused with its reason.
        let mut bad = e.clone();
        bad.tones[0].amplitude_v = f32::NAN;
        let got = feed(
            &mut dev,
            &[Message::SetController(c.clone()), Message::SetExcitation(bad), Message::GetParams],
        );
        assert!(matches!(got[0], Message::Ack { kind: kind::SET_CONTROLLER, .. }));
        let Message::Fault(f) = &got[1] else { panic!("{got:?}") };
        assert!(f.text.contains("excitation amplitude"), "{}", f.text);
        assert_eq!(
            got[2],
            Message::Params(BoardParams { active: Active::Controller, controller: Some(c), safety })
        );
    }

    #[test]
    fn validation_names_the_parameter() {
        let ok = params(&[(23.0, 1.0, 0)]);
        let check = |f: &dyn Fn(&mut ExcitationParams), want: &str| {
            let mut p = ok.clone();
            f(&mut p);
            let e = p.validate().unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        };
        check(&|p| p.sample_period_us = 50, "sample period");
        check(&|p| p.fade_samples = u32::MAX, "fade-in");
        check(&|p| p.tones.clear(), "tones");
        check(&|p| p.tones[0].amplitude_v = f32::INFINITY, "excitation amplitude");
        check(&|p| p.tones[0].amplitude_v = 2000.0, "excitation amplitude");
    }
}

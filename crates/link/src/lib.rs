//! # boucwen-link
//!
//! The wire protocol between the host and the driver board (`no_std`, no allocation),
//! and the board's side of it: the firmware and the host's tools depend on this crate
//! alike, so both ends run the same code.
//!
//! ## Layers
//! 1. **Bytes** ([`cobs`]): each frame is COBS-coded and followed by a `0x00` delimiter, so
//!    a receiver that lost or mangled bytes resynchronises at the next delimiter.
//! 2. **Frames** ([`frame`]): `seq (u16 LE) | kind (u8) | payload | CRC-32C (u32 LE)`. The
//!    CRC ([`crc`]) covers everything before it; each sender numbers its frames `0, 1, …`
//!    (wrapping), so the receiver counts frames that vanished ([`frame::SeqTracker`]).
//! 3. **Messages** ([`message`]): fixed little-endian layouts, floats as IEEE 754 bits.
//! 4. **The board's side** ([`device`]): the state machine the firmware runs (parameters,
//!    runs, the per-sample control step, counters), also run on the host in tests and as the
//!    bit-exact reference of `cargo xtask qemu`.
//!
//! A frame is rejected, never half-used, when its COBS coding, CRC, length, kind or an
//! enumerated field is wrong ([`WireError`]). Decoding never panics, whatever the bytes
//! (tested with seeded random and corrupted streams).
//!
//! ## A control run (the board is the controller, the host drives the actuator)
//! ```text
//! host                                   board (ticks every sample_period_us)
//! SetController(params)  ───────────▶    Ack
//! Start{Control, n}      ───────────▶    Ack, then at tick k = 0, 1, …, n-1:
//!                        ◀───────────    Command{k, u[k], used, flags}
//! apply u[k], measure y[k]
//! Measurement{k, y[k]}   ───────────▶    (used by the step at tick k+1 if it arrived)
//!                        ◀───────────    Status (after the last sample)
//! ```
//! The board never waits: a measurement that has not arrived by the next tick is missing
//! (the compensator steps without it, as for a lost sample), and each command reports in
//! `used` which of the last 16 steps had their measurement.
//!
//! ## Link budget
//! A command is 20 bytes on the wire and a measurement 17 (COBS and the delimiter
//! included; the test `frame_sizes_match_the_link_budget_in_the_docs` pins them), so a
//! 1 kHz control run needs 200 kbit/s from the board and 170 kbit/s to it (10 bits per
//! byte). At 460,800 baud the command takes 0.43 ms and the measurement 0.37 ms: of the
//! 1 ms period 0.20 ms are left for the host to apply the input and answer. A host that
//! cannot (a simulation on a desktop OS, or a board in an emulator whose clock follows the
//! host's) runs the loop in lockstep ([`message::Mode::Lockstep`]): each step waits for its
//! measurement, boundedly.

#![cfg_attr(not(test), no_std)]

pub mod analog;
pub mod cobs;
pub mod crc;
pub mod device;
pub mod excitation;
pub mod frame;
pub mod limits;
pub mod message;
pub mod plant;

use core::fmt;
use frame::{EncodedFrame, FrameDecoder, MAX_PAYLOAD};
pub use message::Message;

/// Why bytes were not a valid frame or message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireError {
    /// The COBS coding is broken (a code byte runs past the frame's end).
    Cobs,
    /// The CRC does not match.
    Crc,
    /// Longer than the longest frame (or a payload too long to encode).
    TooLong,
    /// Shorter than a header and a CRC.
    TooShort,
    /// A message kind this protocol does not have.
    UnknownKind(u8),
    /// The payload's length does not match its kind's layout.
    BadLength,
    /// A field out of its range; names the field.
    BadValue(&'static str),
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WireError::Cobs => f.write_str("frame: broken COBS coding"),
            WireError::Crc => f.write_str("frame: CRC mismatch"),
            WireError::TooLong => f.write_str("frame: too long"),
            WireError::TooShort => f.write_str("frame: too short"),
            WireError::UnknownKind(k) => write!(f, "frame: unknown message kind 0x{k:02x}"),
            WireError::BadLength => f.write_str("message: payload length does not match its kind"),
            WireError::BadValue(what) => write!(f, "message: {what} out of range"),
        }
    }
}

impl core::error::Error for WireError {}

/// A message with its sender's sequence number.
#[derive(Clone, Debug, PartialEq)]
pub struct Packet {
    /// The sender's sequence number.
    pub seq: u16,
    /// The message.
    pub msg: Message,
}

/// Encodes `msg` as frame number `seq`, ready to send.
///
/// ```
/// use boucwen_link::{encode, Decoder, Message, Packet};
/// let bytes = encode(3, &Message::Measurement { k: 41, y: 12.5 })?;
/// let mut dec = Decoder::new();
/// let got: Vec<_> = bytes.iter().filter_map(|&b| dec.push(b)).collect();
/// assert_eq!(got, [Ok(Packet { seq: 3, msg: Message::Measurement { k: 41, y: 12.5 } })]);
/// # Ok::<(), boucwen_link::WireError>(())
/// ```
pub fn encode(seq: u16, msg: &Message) -> Result<EncodedFrame, WireError> {
    let mut payload = [0u8; MAX_PAYLOAD];
    let n = msg.encode_payload(&mut payload)?;
    frame::encode(seq, msg.kind(), &payload[..n])
}

/// Turns a byte stream into packets: frame decoding and message decoding in one.
#[derive(Clone, Debug, Default)]
pub struct Decoder {
    frames: FrameDecoder,
}

impl Decoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self { frames: FrameDecoder::new() }
    }

    /// Feeds one byte; at a frame's end returns the packet or why the frame was rejected.
    pub fn push(&mut self, byte: u8) -> Option<Result<Packet, WireError>> {
        let frame = match self.frames.push(byte)? {
            Ok(f) => f,
            Err(e) => return Some(Err(e)),
        };
        Some(Message::decode(frame.kind, &frame.payload).map(|msg| Packet { seq: frame.seq, msg }))
    }

    /// Drops a partly received frame.
    pub fn reset(&mut self) {
        self.frames.reset();
    }

    /// Bytes of the frame being received.
    pub fn pending(&self) -> usize {
        self.frames.pending()
    }
}

#[cfg(test)]
mod fuzz;
#[cfg(test)]
mod tests;

//! Frames: header, payload and CRC, COBS-coded and `0x00`-delimited.
//!
//! ```text
//! raw frame   = seq (u16 LE) | kind (u8) | payload (0..=MAX_PAYLOAD bytes) | crc (u32 LE)
//! crc         = CRC-32C over seq | kind | payload
//! on the wire = COBS(raw frame) | 0x00
//! ```
//! [`FrameDecoder`] takes the byte stream one byte at a time and yields a result at every
//! delimiter: a checked [`RawFrame`] or the [`WireError`] that rejected it. A frame longer
//! than the longest legal one is discarded up to the next delimiter. Nothing here
//! allocates or panics, whatever the bytes.

use super::WireError;
use super::cobs;
use super::crc::Crc32c;
use heapless::Vec;

/// Bytes of `seq` and `kind` before the payload.
pub const HEADER_LEN: usize = 3;
/// Bytes of the CRC after the payload.
pub const CRC_LEN: usize = 4;
/// The longest payload of any message.
pub const MAX_PAYLOAD: usize = 120;
/// The longest raw frame.
pub const MAX_RAW: usize = HEADER_LEN + MAX_PAYLOAD + CRC_LEN;
/// The longest frame on the wire, delimiter included.
pub const MAX_ENCODED: usize = cobs::max_encoded_len(MAX_RAW) + 1;

/// One encoded frame, ready to send (delimiter included).
pub type EncodedFrame = Vec<u8, MAX_ENCODED>;

/// A frame that passed the COBS and CRC checks; its payload is not interpreted yet.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawFrame {
    /// The sender's sequence number.
    pub seq: u16,
    /// The message kind.
    pub kind: u8,
    /// The message body.
    pub payload: Vec<u8, MAX_PAYLOAD>,
}

/// Encodes a frame. Fails only if `payload` is longer than [`MAX_PAYLOAD`].
///
/// ```
/// use boucwen_link::frame::{encode, FrameDecoder};
/// let bytes = encode(7, 0x42, &[1, 0, 2])?;
/// assert_eq!(bytes.last(), Some(&0));
/// let mut dec = FrameDecoder::new();
/// let mut got = None;
/// for &b in &bytes {
///     if let Some(r) = dec.push(b) {
///         got = Some(r?);
///     }
/// }
/// let frame = got.unwrap();
/// assert_eq!((frame.seq, frame.kind, &frame.payload[..]), (7, 0x42, &[1, 0, 2][..]));
/// # Ok::<(), boucwen_link::WireError>(())
/// ```
pub fn encode(seq: u16, kind: u8, payload: &[u8]) -> Result<EncodedFrame, WireError> {
    if payload.len() > MAX_PAYLOAD {
        return Err(WireError::TooLong);
    }
    let mut raw = [0u8; MAX_RAW];
    raw[..2].copy_from_slice(&seq.to_le_bytes());
    raw[2] = kind;
    let end = HEADER_LEN + payload.len();
    raw[HEADER_LEN..end].copy_from_slice(payload);
    let crc = Crc32c::checksum(&raw[..end]);
    raw[end..end + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let mut out = [0u8; MAX_ENCODED];
    let n = cobs::encode(&raw[..end + CRC_LEN], &mut out[..MAX_ENCODED - 1]).ok_or(WireError::TooLong)?;
    out[n] = 0;
    Vec::from_slice(&out[..n + 1]).map_err(|_| WireError::TooLong)
}

/// Checks and splits one decoded raw frame.
pub fn parse_raw(raw: &[u8]) -> Result<RawFrame, WireError> {
    if raw.len() < HEADER_LEN + CRC_LEN {
        return Err(WireError::TooShort);
    }
    let body = raw.len() - CRC_LEN;
    let mut crc = [0u8; CRC_LEN];
    crc.copy_from_slice(&raw[body..]);
    let found = u32::from_le_bytes(crc);
    let expected = Crc32c::checksum(&raw[..body]);
    if found != expected {
        return Err(WireError::Crc);
    }
    let payload = Vec::from_slice(&raw[HEADER_LEN..body]).map_err(|_| WireError::TooLong)?;
    Ok(RawFrame { seq: u16::from_le_bytes([raw[0], raw[1]]), kind: raw[2], payload })
}

/// Splits a byte stream at `0x00` delimiters and checks each frame.
#[derive(Clone, Debug, Default)]
pub struct FrameDecoder {
    buf: Vec<u8, { MAX_ENCODED - 1 }>,
    overflow: bool,
}

impl FrameDecoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self { buf: Vec::new(), overflow: false }
    }

    /// Feeds one byte; at a delimiter returns the frame it ended, or why it was rejected.
    /// Empty frames (two delimiters in a row) are skipped silently: senders may put a
    /// delimiter before a frame to flush a half-received one at the receiver.
    pub fn push(&mut self, byte: u8) -> Option<Result<RawFrame, WireError>> {
        if byte != 0 {
            if !self.overflow && self.buf.push(byte).is_err() {
                self.overflow = true;
            }
            return None;
        }
        if self.overflow {
            self.overflow = false;
            self.buf.clear();
            return Some(Err(WireError::TooLong));
        }
        if self.buf.is_empty() {
            return None;
        }
        let mut raw = [0u8; MAX_RAW];
        let result = cobs::decode(&self.buf, &mut raw).and_then(|n| parse_raw(&raw[..n]));
        self.buf.clear();
        Some(result)
    }

    /// Drops a partly received frame (after a timeout, say).
    pub fn reset(&mut self) {
        self.buf.clear();
        self.overflow = false;
    }

    /// Bytes of the frame being received.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }
}

/// What a received sequence number says about the frames before it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeqGap {
    /// The first frame seen, or the sender restarted its numbering (a jump of more than
    /// [`SeqTracker::MAX_GAP`]): nothing can be said about earlier frames.
    Sync,
    /// `n` frames were sent between the previous frame and this one and did not arrive
    /// intact (0: none).
    Missed(u16),
}

/// Follows a peer's sequence numbers (`u16`, wrapping) to count frames that went missing.
#[derive(Clone, Copy, Debug, Default)]
pub struct SeqTracker {
    expected: Option<u16>,
}

impl SeqTracker {
    /// A jump larger than this is taken as a restart of the sender, not a loss.
    pub const MAX_GAP: u16 = 4096;

    /// A tracker that has not seen a frame yet.
    pub const fn new() -> Self {
        Self { expected: None }
    }

    /// Notes the sequence number of an intact frame.
    ///
    /// ```
    /// use boucwen_link::frame::{SeqGap, SeqTracker};
    /// let mut t = SeqTracker::new();
    /// assert_eq!(t.observe(65_534), SeqGap::Sync);
    /// assert_eq!(t.observe(65_535), SeqGap::Missed(0));
    /// assert_eq!(t.observe(2), SeqGap::Missed(2)); // 0 and 1 were lost
    /// ```
    pub fn observe(&mut self, seq: u16) -> SeqGap {
        let gap = match self.expected {
            None => SeqGap::Sync,
            Some(e) => match seq.wrapping_sub(e) {
                g if g <= Self::MAX_GAP => SeqGap::Missed(g),
                _ => SeqGap::Sync,
            },
        };
        self.expected = Some(seq.wrapping_add(1));
        gap
    }

    /// Forgets the peer's numbering (the next frame gives [`SeqGap::Sync`]).
    pub fn reset(&mut self) {
        self.expected = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(bytes: &[u8]) -> std::vec::Vec<Result<RawFrame, WireError>> {
        let mut d = FrameDecoder::new();
        bytes.iter().filter_map(|&b| d.push(b)).collect()
    }

    #[test]
    fn frames_roundtrip_back_to_back() {
        let mut stream = std::vec::Vec::new();
        let payloads: [&[u8]; 4] = [&[], &[0, 0, 0], &[0xFF; MAX_PAYLOAD], &[1, 2, 3, 0, 5]];
        for (i, p) in payloads.iter().enumerate() {
            stream.extend_from_slice(&encode(i as u16, i as u8 + 1, p).unwrap());
        }
        let got = decode_all(&stream);
        assert_eq!(got.len(), 4);
        for (i, (g, p)) in got.iter().zip(payloads).enumerate() {
            let f = g.as_ref().unwrap();
            assert_eq!((f.seq, f.kind, &f.payload[..]), (i as u16, i as u8 + 1, p));
        }
        assert_eq!(encode(0, 0, &[0; MAX_PAYLOAD + 1]), Err(WireError::TooLong));
    }

    #[test]
    fn every_single_bit_flip_and_byte_drop_is_detected() {
        let good = encode(0x1234, 9, &[10, 20, 0, 30, 40, 50, 60, 70, 80]).unwrap();
        let body = &good[..good.len() - 1];
        for i in 0..body.len() {
            for bit in 0..8 {
                let mut bad = body.to_vec();
                bad[i] ^= 1 << bit;
                bad.push(0);
                // A flip may create a zero (splitting the frame): every piece must fail.
                for r in decode_all(&bad) {
                    assert!(r.is_err(), "flip of bit {bit} of byte {i} passed");
                }
            }
            let mut dropped = body.to_vec();
            dropped.remove(i);
            dropped.push(0);
            for r in decode_all(&dropped) {
                assert!(r.is_err(), "drop of byte {i} passed");
            }
        }
    }

    #[test]
    fn overlong_garbage_is_one_error_and_the_next_frame_decodes() {
        let mut stream = vec![0x55u8; 3 * MAX_ENCODED];
        stream.push(0);
        stream.extend_from_slice(&encode(1, 2, &[3]).unwrap());
        let got = decode_all(&stream);
        assert_eq!(got[0], Err(WireError::TooLong));
        assert_eq!(got[1].as_ref().unwrap().payload[..], [3]);
        assert_eq!(decode_all(&[0x01, 0x00]), [Err(WireError::TooShort)]);
    }

    #[test]
    fn sequence_gaps() {
        let mut t = SeqTracker::new();
        assert_eq!(t.observe(10), SeqGap::Sync);
        assert_eq!(t.observe(11), SeqGap::Missed(0));
        assert_eq!(t.observe(15), SeqGap::Missed(3));
        assert_eq!(t.observe(14), SeqGap::Sync, "going back is a restart");
        assert_eq!(t.observe(15 + SeqTracker::MAX_GAP), SeqGap::Missed(SeqTracker::MAX_GAP));
        t.reset();
        assert_eq!(t.observe(0), SeqGap::Sync);
    }
}

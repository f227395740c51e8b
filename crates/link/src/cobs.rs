//! Consistent Overhead Byte Stuffing (Cheshire and Baker, 1999): a frame's bytes re-coded so
//! that none is `0x00`, which is then free to delimit frames on the byte stream.
//!
//! The encoding splits the data at each zero byte; each piece (at most 254 non-zero bytes)
//! is sent as a code byte `1 + its length` followed by the piece, where a code below `0xFF`
//! stands for "piece, then a zero" and the final zero is implied. Encoding `n` bytes adds
//! at most `1 + n/254` bytes ([`max_encoded_len`]). A receiver that loses or corrupts
//! bytes resynchronises at the next `0x00`.

use super::WireError;

/// The longest encoding of `n` bytes (without the `0x00` delimiter).
pub const fn max_encoded_len(n: usize) -> usize {
    n + n / 254 + 1
}

/// Encodes `data` into `out` and returns the encoded length; `None` if `out` is too short
/// (it needs [`max_encoded_len`]`(data.len())` bytes to be sure).
///
/// ```
/// use boucwen_link::cobs::{decode, encode};
/// let mut enc = [0u8; 8];
/// let n = encode(&[0x11, 0x00, 0x22], &mut enc).unwrap();
/// assert_eq!(&enc[..n], &[0x02, 0x11, 0x02, 0x22]);
/// let mut dec = [0u8; 8];
/// let m = decode(&enc[..n], &mut dec).unwrap();
/// assert_eq!(&dec[..m], &[0x11, 0x00, 0x22]);
/// ```
pub fn encode(data: &[u8], out: &mut [u8]) -> Option<usize> {
    let mut code_at = 0usize;
    let mut w = 1usize;
    let mut code = 1u8;
    *out.get_mut(code_at)? = 0;
    for (i, &b) in data.iter().enumerate() {
        if b != 0 {
            *out.get_mut(w)? = b;
            w += 1;
            code += 1;
        }
        // A zero ends the piece; so does a full piece (254 bytes) with more data to come.
        if b == 0 || (code == 0xFF && i + 1 < data.len()) {
            *out.get_mut(code_at)? = code;
            code_at = w;
            *out.get_mut(code_at)? = 0;
            w += 1;
            code = 1;
        }
    }
    *out.get_mut(code_at)? = code;
    Some(w)
}

/// Decodes one frame `enc` (the bytes between two `0x00` delimiters) into `out` and returns
/// the decoded length.
///
/// Fails with [`WireError::Cobs`] on a zero byte or a code that runs past the end, and with
/// [`WireError::TooLong`] if `out` is too short. Never panics.
pub fn decode(enc: &[u8], out: &mut [u8]) -> Result<usize, WireError> {
    let mut r = 0usize;
    let mut w = 0usize;
    while r < enc.len() {
        let code = enc[r];
        if code == 0 {
            return Err(WireError::Cobs);
        }
        r += 1;
        let run = code as usize - 1;
        let piece = enc.get(r..r + run).ok_or(WireError::Cobs)?;
        if piece.contains(&0) {
            return Err(WireError::Cobs);
        }
        out.get_mut(w..w + run).ok_or(WireError::TooLong)?.copy_from_slice(piece);
        w += run;
        r += run;
        if code != 0xFF && r < enc.len() {
            *out.get_mut(w).ok_or(WireError::TooLong)? = 0;
            w += 1;
        }
    }
    Ok(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn roundtrip(data: &[u8]) -> Vec<u8> {
        let mut enc = vec![0u8; max_encoded_len(data.len())];
        let n = encode(data, &mut enc).unwrap();
        assert!(!enc[..n].contains(&0), "encoding contains a zero: {:?}", &enc[..n]);
        let mut dec = vec![0u8; data.len()];
        let m = decode(&enc[..n], &mut dec).unwrap();
        assert_eq!(&dec[..m], data);
        enc.truncate(n);
        enc
    }

    #[test]
    fn paper_examples() {
        // Examples of Cheshire and Baker's paper / the usual reference table.
        assert_eq!(roundtrip(&[]), [0x01]);
        assert_eq!(roundtrip(&[0x00]), [0x01, 0x01]);
        assert_eq!(roundtrip(&[0x00, 0x00]), [0x01, 0x01, 0x01]);
        assert_eq!(roundtrip(&[0x11, 0x22, 0x00, 0x33]), [0x03, 0x11, 0x22, 0x02, 0x33]);
        assert_eq!(roundtrip(&[0x11, 0x22, 0x33, 0x44]), [0x05, 0x11, 0x22, 0x33, 0x44]);
        assert_eq!(roundtrip(&[0x11, 0x00, 0x00, 0x00]), [0x02, 0x11, 0x01, 0x01, 0x01]);
        let run: Vec<u8> = (1..=254).collect();
        let enc = roundtrip(&run);
        assert_eq!((enc[0], enc.len()), (0xFF, 255));
        let run: Vec<u8> = (1..=255).collect();
        let enc = roundtrip(&run);
        assert_eq!((enc[0], enc[255], enc[256], enc.len()), (0xFF, 0x02, 0xFF, 257));
    }

    #[test]
    fn roundtrips_every_length_and_zero_pattern() {
        let mut x = 0x9E37_79B9u32;
        for len in 0..700usize {
            let data: Vec<u8> = (0..len)
                .map(|_| {
                    x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    // About one byte in eight is zero.
                    if (x >> 29) == 0 { 0 } else { (x >> 8) as u8 }
                })
                .collect();
            let enc = roundtrip(&data);
            assert!(enc.len() <= max_encoded_len(len));
        }
    }

    #[test]
    fn short_buffers_fail_cleanly() {
        let mut enc = [0u8; 3];
        assert_eq!(encode(&[1, 2, 3], &mut enc), None);
        let mut dec = [0u8; 2];
        assert_eq!(decode(&[0x04, 1, 2, 3], &mut dec), Err(WireError::TooLong));
        assert_eq!(decode(&[0x05, 1, 2], &mut dec), Err(WireError::Cobs));
        assert_eq!(decode(&[0x02, 0, 1], &mut [0u8; 8]), Err(WireError::Cobs));
        assert_eq!(decode(&[], &mut dec), Ok(0));
    }
}

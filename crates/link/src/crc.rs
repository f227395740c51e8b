//! CRC-32C (Castagnoli), the frame check of the wire protocol.
//!
//! Polynomial `0x1EDC6F41` (reflected `0x82F63B78`), initial value and final XOR
//! `0xFFFF_FFFF`, bits reflected in and out (the "CRC-32/ISCSI" of the CRC catalogue; check
//! value `0xE306_9283` for the ASCII bytes `123456789`). Its Hamming distance stays at 6 up
//! to 5,243 data bits (the frames here are at most 1,000 bits), so every error of up to 5
//! flipped bits and every burst up to 32 bits long is detected; a random corruption passes
//! with probability 2⁻³².
//!
//! A 16-entry table (64 bytes of flash) processes a nibble per step: two table lookups per
//! byte, a compromise between the 1 KiB byte table and the bit-by-bit loop.

/// `TABLE[i]`: the register `i` after four steps of the reflected polynomial division.
const TABLE: [u32; 16] = {
    let mut t = [0u32; 16];
    let mut i = 0;
    while i < 16 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 4 {
            c = if c & 1 != 0 { (c >> 1) ^ 0x82F6_3B78 } else { c >> 1 };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
};

/// An incremental CRC-32C.
///
/// ```
/// use boucwen_link::crc::Crc32c;
/// let mut c = Crc32c::new();
/// c.update(b"1234");
/// c.update(b"56789");
/// assert_eq!(c.finish(), 0xE306_9283);
/// assert_eq!(Crc32c::checksum(b"123456789"), 0xE306_9283);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Crc32c {
    state: u32,
}

impl Default for Crc32c {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32c {
    /// A fresh CRC.
    pub const fn new() -> Self {
        Self { state: 0xFFFF_FFFF }
    }

    /// Feeds `bytes`.
    pub fn update(&mut self, bytes: &[u8]) {
        let mut c = self.state;
        for &b in bytes {
            c ^= b as u32;
            c = (c >> 4) ^ TABLE[(c & 0xF) as usize];
            c = (c >> 4) ^ TABLE[(c & 0xF) as usize];
        }
        self.state = c;
    }

    /// The CRC of everything fed so far.
    pub const fn finish(&self) -> u32 {
        self.state ^ 0xFFFF_FFFF
    }

    /// The CRC of `bytes`.
    pub fn checksum(bytes: &[u8]) -> u32 {
        let mut c = Self::new();
        c.update(bytes);
        c.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bit-by-bit reference, written from the definition.
    fn reference(bytes: &[u8]) -> u32 {
        let mut c = 0xFFFF_FFFFu32;
        for &b in bytes {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 { (c >> 1) ^ 0x82F6_3B78 } else { c >> 1 };
            }
        }
        !c
    }

    #[test]
    fn catalogue_check_value_and_known_vectors() {
        assert_eq!(Crc32c::checksum(b"123456789"), 0xE306_9283);
        assert_eq!(Crc32c::checksum(b""), 0);
        // RFC 3720 (iSCSI) appendix B.4: 32 bytes of zeros and of 0xFF.
        assert_eq!(Crc32c::checksum(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(Crc32c::checksum(&[0xFFu8; 32]), 0x62A8_AB43);
        let inc: [u8; 32] = core::array::from_fn(|i| i as u8);
        assert_eq!(Crc32c::checksum(&inc), 0x46DD_794E);
    }

    #[test]
    fn nibble_table_matches_the_bitwise_definition() {
        let mut x = 0x1234_5678_9ABC_DEF0u64;
        for len in 0..200usize {
            let bytes: Vec<u8> = (0..len)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    x as u8
                })
                .collect();
            assert_eq!(Crc32c::checksum(&bytes), reference(&bytes), "length {len}");
        }
    }
}

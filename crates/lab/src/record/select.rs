//! The `rank`-th smallest of `len` values computed on demand, without storing them: the
//! median of a record's time steps or of its residues, where a copy of a 10⁷-sample signal
//! would cost 80 MB.
//!
//! Radix selection on the values' order keys (the `f64` bits mapped so that unsigned order
//! is [`f64::total_cmp`]'s), 16 bits per pass: four passes over the values, each counting
//! the keys that share the digits found so far. The result is the value (bit for bit)
//! that sorting by `total_cmp` puts at `rank`, as `select_nth_unstable_by(rank,
//! f64::total_cmp)` gives it.

/// The order key of `x`: unsigned order of keys is `total_cmp` order of values.
fn key(x: f64) -> u64 {
    let b = x.to_bits();
    if b >> 63 == 1 { !b } else { b | 1 << 63 }
}

/// The value of a key.
fn value(k: u64) -> f64 {
    f64::from_bits(if k >> 63 == 1 { k & !(1 << 63) } else { !k })
}

/// The value of rank `rank` (from 0) in `total_cmp` order among `at(0), …, at(len − 1)`;
/// `at` is called `4·len` times. NaN if `rank >= len`.
pub(crate) fn nth(len: usize, rank: usize, at: impl Fn(usize) -> f64) -> f64 {
    if rank >= len {
        return f64::NAN;
    }
    let mut prefix = 0u64;
    let mut rank = rank;
    let mut counts = vec![0usize; 1 << 16];
    for pass in 0..4 {
        let shift = 48 - 16 * pass;
        // The digits above this pass's must be the prefix's.
        let high_mask = if pass == 0 { 0 } else { u64::MAX << (shift + 16) };
        counts.fill(0);
        for i in 0..len {
            let k = key(at(i));
            if k & high_mask == prefix {
                counts[((k >> shift) & 0xFFFF) as usize] += 1;
            }
        }
        let mut digit = 0;
        for (d, &c) in counts.iter().enumerate() {
            if rank < c {
                digit = d;
                break;
            }
            rank -= c;
        }
        prefix |= (digit as u64) << shift;
    }
    value(prefix)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nth_is_select_nth_unstable_bit_for_bit() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for len in [1usize, 2, 3, 10, 257, 1000] {
            let v: Vec<f64> = (0..len)
                .map(|i| match next() % 6 {
                    0 => f64::from_bits(next()),
                    1 => -0.0,
                    2 => 0.0,
                    3 => (i % 7) as f64 * 1e-3,
                    4 => -1.5,
                    _ => (next() % 1000) as f64 * 0.1 - 50.0,
                })
                .filter(|v| !v.is_nan())
                .collect();
            for rank in [0, v.len() / 3, v.len() / 2, v.len().saturating_sub(1)] {
                if rank >= v.len() {
                    continue;
                }
                let mut s = v.clone();
                let want = *s.select_nth_unstable_by(rank, f64::total_cmp).1;
                assert_eq!(nth(v.len(), rank, |i| v[i]).to_bits(), want.to_bits(), "{len} {rank}");
            }
        }
        assert!(nth(0, 0, |_| 1.0).is_nan());
    }
}

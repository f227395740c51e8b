//! The simulator's seeded random source: the project's one generator, xoshiro256++
//! (Blackman and Vigna, from `rand_xoshiro`, seeded through SplitMix64), and standard normal
//! deviates by the Box–Muller transform.
//!
//! Enough for sensor noise and drift; not for cryptography. The sequence depends only on
//! the seed, so a scenario with the same seed reproduces the same record.

use rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// xoshiro256++ with a cached second Box–Muller deviate.
#[derive(Clone, Debug)]
pub(crate) struct Rng {
    source: Xoshiro256PlusPlus,
    spare: Option<f64>,
}

impl Rng {
    /// A generator for `seed` and an independent `stream` number (different streams of
    /// one seed give unrelated sequences).
    pub(crate) fn new(seed: u64, stream: u64) -> Self {
        let source = Xoshiro256PlusPlus::seed_from_u64(seed ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03));
        Self { source, spare: None }
    }

    /// Uniform in `(0, 1]` (53 random bits; never 0, so its logarithm is finite).
    pub(crate) fn uniform_open0(&mut self) -> f64 {
        ((self.source.next_u64() >> 11) + 1) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A standard normal deviate (mean 0, variance 1).
    pub(crate) fn normal(&mut self) -> f64 {
        if let Some(z) = self.spare.take() {
            return z;
        }
        let r = (-2.0 * self.uniform_open0().ln()).sqrt();
        let (s, c) = (core::f64::consts::TAU * self.uniform_open0()).sin_cos();
        self.spare = Some(r * s);
        r * c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stream_is_xoshiro256pp_seeded_by_splitmix64() {
        // Seeding: four outputs of SplitMix64 (Vigna, splitmix64.c; seed 0 gives
        // 0xE220A8397B1DCDAF first). Then xoshiro256++'s recurrence, written out here.
        let mut x = 0u64;
        let mut splitmix = || {
            x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = x;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        let mut s = [splitmix(), splitmix(), splitmix(), splitmix()];
        assert_eq!(s[0], 0xE220_A839_7B1D_CDAF);
        let mut rng = Rng::new(0, 0);
        for _ in 0..100 {
            let want = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
            let t = s[1] << 17;
            s[2] ^= s[0];
            s[3] ^= s[1];
            s[1] ^= s[2];
            s[0] ^= s[3];
            s[2] ^= t;
            s[3] = s[3].rotate_left(45);
            assert_eq!(rng.source.next_u64(), want);
        }
    }

    #[test]
    fn normal_deviates_have_unit_variance() {
        let mut rng = Rng::new(7, 0);
        let n = 200_000;
        let (mut s1, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let z = rng.normal();
            s1 += z;
            s2 += z * z;
        }
        let mean = s1 / n as f64;
        let var = s2 / n as f64 - mean * mean;
        // Standard errors: mean 1/sqrt(n) = 0.0022, variance sqrt(2/n) = 0.0032.
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.015, "variance {var}");
    }

    #[test]
    fn streams_differ() {
        let mut a = Rng::new(1, 0);
        let mut b = Rng::new(1, 1);
        assert_ne!(a.source.next_u64(), b.source.next_u64());
    }
}

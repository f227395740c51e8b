//! Periodic excitations for nonlinear system identification: odd random-phase multisines and
//! triangles, on a whole number of samples per period so that every period's DFT holds the
//! excited lines exactly.
//!
//! An **odd random-phase multisine** (Pintelon and Schoukens, *System Identification: A
//! Frequency Domain Approach*, 2nd ed., ch. 3) excites odd lines `k` of the base frequency
//! `f0 = 1/(N·Ts)` with equal amplitudes and independent uniform random phases, and leaves
//! one odd line out of each group of consecutive odd lines (drawn at random within the
//! group). Then an even nonlinearity shows at the even lines and an odd one at the odd lines
//! left out; a new draw of the phases is a new *realisation* with the same lines.
//!
//! ```
//! use boucwen_lab::signal::excitation::Multisine;
//! let ms = Multisine::odd_random_phase(1000, 1, 60, 4, 7);
//! assert!(ms.lines.iter().all(|k| k % 2 == 1));
//! let u = ms.signal(0.5, 3); // three periods, peak 0.5 V
//! assert_eq!(u.len(), 3000);
//! assert!((u.iter().fold(0.0f64, |m, v| m.max(v.abs())) - 0.5).abs() < 1e-12);
//! assert!((u[17] - u[1017]).abs() < 1e-12);
//! ```

use rand_core::{RngCore, SeedableRng};
use std::f64::consts::TAU;

/// Seeded draws for phases and the fixtures' scenarios: SplitMix64 from `rand_xoshiro`, the
/// workspace's one generator crate (the simulator's noise is its xoshiro256++, seeded
/// through this same SplitMix64). The same seed gives the same sequence on every platform.
#[derive(Clone, Debug)]
pub struct Draws(rand_xoshiro::SplitMix64);

impl Draws {
    /// A generator from `seed` (the state starts at `seed`).
    pub fn new(seed: u64) -> Self {
        Self(rand_xoshiro::SplitMix64::seed_from_u64(seed))
    }

    /// The next 64 bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform on `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Log-uniform on `[lo, hi)` (`0 < lo ≤ hi`).
    pub fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.uniform(lo.ln(), hi.ln()).exp()
    }

    /// A uniform index in `0..n` (`n ≥ 1`).
    pub fn index(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    /// `+1` or `−1`, even odds.
    pub fn sign(&mut self) -> f64 {
        if self.next_u64() & 1 == 0 { 1.0 } else { -1.0 }
    }
}

/// A multisine: lines `k` of `f0 = 1/(period_samples·Ts)` with amplitudes and phases.
#[derive(Clone, Debug, PartialEq)]
pub struct Multisine {
    /// Samples per period `N`.
    pub period_samples: usize,
    /// The excited lines (multiples of `f0`), increasing.
    pub lines: Vec<u32>,
    /// Relative amplitude of each line.
    pub amplitudes: Vec<f64>,
    /// Phase of each line (rad).
    pub phases: Vec<f64>,
}

impl Multisine {
    /// An odd random-phase multisine over the odd lines `first..=last` (`first` rounded up
    /// to odd), one line of every `group` consecutive odd lines left out at random, equal
    /// amplitudes, uniform random phases; `seed` draws both (see the module docs). Lines at
    /// or above `N/2` are left out.
    pub fn odd_random_phase(period_samples: usize, first: u32, last: u32, group: usize, seed: u64) -> Self {
        let mut g = Draws::new(seed);
        let first = first.max(1) | 1;
        let top = last.min((period_samples as u32).saturating_sub(1) / 2);
        let odd: Vec<u32> = (first..=top).filter(|k| k % 2 == 1).collect();
        let mut lines = vec![];
        for chunk in odd.chunks(group.max(1)) {
            let out = if group >= 2 && chunk.len() == group { Some(g.index(chunk.len())) } else { None };
            lines.extend(chunk.iter().enumerate().filter(|(i, _)| Some(*i) != out).map(|(_, &k)| k));
        }
        let phases = lines.iter().map(|_| g.uniform(0.0, TAU)).collect();
        let amplitudes = vec![1.0; lines.len()];
        Multisine { period_samples, lines, amplitudes, phases }
    }

    /// The same lines and amplitudes with new random phases: another realisation.
    pub fn realisation(&self, seed: u64) -> Self {
        let mut g = Draws::new(seed);
        Multisine { phases: self.lines.iter().map(|_| g.uniform(0.0, TAU)).collect(), ..self.clone() }
    }

    /// The odd lines of `first..=last` that are not excited (left out of their group).
    pub fn left_out(&self, first: u32, last: u32) -> Vec<u32> {
        (first.max(1) | 1..=last).filter(|k| k % 2 == 1 && !self.lines.contains(k)).collect()
    }

    /// One period, scaled to a peak of `peak` (V).
    pub fn period(&self, peak: f64) -> Vec<f64> {
        let n = self.period_samples;
        let mut x: Vec<f64> = (0..n)
            .map(|i| {
                self.lines
                    .iter()
                    .zip(&self.amplitudes)
                    .zip(&self.phases)
                    .map(|((&k, a), p)| a * (TAU * f64::from(k) * i as f64 / n as f64 + p).sin())
                    .sum()
            })
            .collect();
        let top = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if top > 0.0 {
            x.iter_mut().for_each(|v| *v *= peak / top);
        }
        x
    }

    /// `periods` periods, peak `peak` (V).
    pub fn signal(&self, peak: f64, periods: usize) -> Vec<f64> {
        let one = self.period(peak);
        one.iter().copied().cycle().take(one.len() * periods).collect()
    }
}

/// A symmetric triangle of peak `amplitude` (V) and `period_samples` samples per period,
/// `n` samples, starting at 0 and rising (its harmonics are the odd ones, falling as `1/k²`).
pub fn triangle(amplitude: f64, period_samples: usize, n: usize) -> Vec<f64> {
    let p = period_samples.max(4) as f64;
    (0..n)
        .map(|k| {
            let x = (k as f64 / p + 0.25).fract(); // phase in periods, 0.25 at k = 0
            amplitude * if x < 0.5 { 4.0 * x - 1.0 } else { 3.0 - 4.0 * x }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_draws_are_splitmix64() {
        // Vigna's splitmix64.c from state 0: the draws every fixture was generated with.
        let mut d = Draws::new(0);
        assert_eq!(d.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(d.next_u64(), 0x6E78_9E6A_A1B9_65F4);
    }

    use super::*;
    use crate::signal::analysis;

    #[test]
    fn odd_random_phase_leaves_one_line_per_group_out() {
        let ms = Multisine::odd_random_phase(2000, 1, 79, 4, 3);
        let out = ms.left_out(1, 79);
        assert_eq!(out.len(), 10, "{out:?}");
        assert_eq!(ms.lines.len(), 30);
        for chunk in (1..=79u32).filter(|k| k % 2 == 1).collect::<Vec<_>>().chunks(4) {
            assert_eq!(chunk.iter().filter(|k| out.contains(k)).count(), 1, "{chunk:?}");
        }
        // The DFT of one period holds exactly the excited lines.
        let x = ms.period(1.0);
        for k in 1..100u32 {
            let t = analysis::tone(&x, f64::from(k), 1.0 / 2000.0);
            if ms.lines.contains(&k) {
                assert!(t.amp > 0.05, "line {k}: {}", t.amp);
            } else {
                assert!(t.amp < 1e-12, "line {k}: {}", t.amp);
            }
        }
        let other = ms.realisation(9);
        assert_eq!(other.lines, ms.lines);
        assert_ne!(other.phases, ms.phases);
    }

    #[test]
    fn a_triangle_has_odd_harmonics_falling_as_one_over_k_squared() {
        let x = triangle(2.0, 200, 2000);
        assert!((x[0]).abs() < 1e-12 && (x[50] - 2.0).abs() < 1e-12 && (x[150] + 2.0).abs() < 1e-12);
        let h = analysis::harmonics(&x, 5.0, 1e-3, 6);
        let a1 = 8.0 * 2.0 / std::f64::consts::PI.powi(2);
        assert!((h[0].amp - a1).abs() < 1e-3 * a1, "{}", h[0].amp);
        assert!((h[2].amp - a1 / 9.0).abs() < 1e-3 * a1, "{}", h[2].amp);
        assert!(h[1].amp < 1e-9 && h[3].amp < 1e-9);
    }
}

//! Tolerance helpers and seeded test data for the unit tests.

/// Asserts `|got - want| <= tol`, printing both.
#[track_caller]
pub fn assert_close(got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "got {got}, want {want} (tolerance {tol}, diff {})",
        (got - want).abs()
    );
}

/// Seeded test data uniform in `[-1, 1)`, from the project's one generator (xoshiro256++).
pub(crate) struct Noise(rand_xoshiro::Xoshiro256PlusPlus);

impl Noise {
    pub(crate) fn new(seed: u64) -> Self {
        Self(rand_core::SeedableRng::seed_from_u64(seed))
    }

    pub(crate) fn next_f64(&mut self) -> f64 {
        (rand_core::RngCore::next_u64(&mut self.0) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}

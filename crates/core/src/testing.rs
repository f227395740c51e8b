//! Tolerance helpers for the unit tests.

/// Asserts `|got - want| <= tol`, printing both.
#[track_caller]
pub fn assert_close(got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "got {got}, want {want} (tolerance {tol}, diff {})",
        (got - want).abs()
    );
}

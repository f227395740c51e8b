//! Any diagnosis as text and JSON.

use super::{periodic_json, periodic_text, sine_json, sine_text};
use crate::diagnose::Outcome;
use crate::rules::Rules;
use serde_json::{Value, json};

/// The JSON object of a diagnosis, with `analysis`: `sine` or `periodic`, and the rules it
/// was made with (`rules`).
pub fn json(o: &Outcome, r: &Rules) -> Value {
    let (mut j, kind) = match o {
        Outcome::Sine(d) => (sine_json(d, r), "sine"),
        Outcome::Periodic(d) => (periodic_json(d), "periodic"),
    };
    j["analysis"] = json!(kind);
    j["rules"] = r.to_json();
    j
}

/// The terminal report of a diagnosis.
pub fn text(o: &Outcome, source: &str, r: &Rules) -> String {
    match o {
        Outcome::Sine(d) => sine_text(d, source, r),
        Outcome::Periodic(d) => periodic_text(d, source, r),
    }
}

//! Writes the records of the fit comparison with the Python peer (`benches/peers/README.md`):
//! cases of the virtual bimorph with a hidden effect ([`boucwen_lab::fixtures::hidden::Case`]),
//! 20 s (20,000 samples at 1 kHz) each.
//!
//! `cargo run --release --example peer_records -- DIR`

use boucwen_lab::fixtures::hidden::{Case, Effect};

/// The records: effect and seed.
const RECORDS: [(Effect, u64); 7] = [
    (Effect::OddHarmonic(3), 1),
    (Effect::OddHarmonic(5), 1),
    (Effect::OddHarmonic(7), 2),
    (Effect::EvenHarmonic(2), 1),
    (Effect::Drift, 1),
    (Effect::Clean, 1),
    (Effect::Clean, 2),
];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).ok_or("usage: peer_records DIR")?);
    std::fs::create_dir_all(&dir)?;
    for (effect, seed) in RECORDS {
        let mut case = Case::generate(effect, seed)?;
        case.seconds = 20.0;
        let rec = case.record()?;
        let path = dir.join(format!("{}-{seed}.csv", effect.name()));
        rec.write(&path)?;
        println!("{}: drive {:.2} Hz, resonance {:.1} Hz", path.display(), case.drive_hz, case.resonance_hz);
    }
    Ok(())
}

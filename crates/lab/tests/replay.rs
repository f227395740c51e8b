//! The workflow of a user without hardware: run the virtual bimorph, save the record, read
//! it back, replay it with the input check on.

use boucwen_core::Plant;
use boucwen_lab::record::{Record, Replay, ReplayError};
use boucwen_sim::{Bimorph, Scenario};

#[test]
fn simulated_record_written_read_and_replayed() {
    let mut bimorph = Bimorph::new(&Scenario::default()).unwrap();
    let ts = Plant::sample_interval_s(&bimorph);
    let u: Vec<f64> =
        (0..2000).map(|k| 1.5 * (2.0 * std::f64::consts::PI * 23.0 * k as f64 * ts).sin()).collect();
    let mut y = vec![0.0; u.len()];
    bimorph.run_into(&u, &mut y).unwrap();
    let rec = Record::new("sim", 0.0, ts, u.clone(), y.clone(), None).unwrap();
    rec.validate_for_fit(1000).unwrap();
    let dir = std::env::temp_dir().join(format!("boucwen-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("sim.csv");
    rec.write(&path).unwrap();
    let back = Record::read(&path).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let mut replay = Replay::new(back);
    assert_eq!(replay.sample_interval_s(), ts);
    let mut y2 = vec![0.0; u.len()];
    replay.run_into(&u, &mut y2).unwrap();
    assert_eq!(y2, y);
    assert!(matches!(replay.step(0.0), Err(ReplayError::EndOfRecord { samples: 2000, .. })));
}

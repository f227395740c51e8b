//! The importer never panics: arbitrary bytes, and valid records mutated byte by byte, line
//! by line and field by field, read with and without flags, give a record or an error whose
//! message is one line (control characters shown as `?`) of under 600 bytes (every quoted
//! field at most 24 characters, at most 8 columns listed).
//!
//! Cases per property: `PROPTEST_CASES` (proptest's default, 256; the book's
//! `docs/book/src/records.md` gives a longer run).

use boucwen_lab::record::{ColumnMap, ImportOptions, LengthUnit, VoltUnit, import_text};
use proptest::prelude::*;

/// A valid record in one of the layouts the importer reads.
fn valid(layout: u8, rows: usize) -> String {
    let mut s = String::new();
    let row = |k: usize| {
        let t = k as f64 * 1e-3;
        let u = (std::f64::consts::TAU * 20.0 * t).sin();
        (t, u, 10.0 * u + 0.01 * (k % 7) as f64)
    };
    match layout % 6 {
        0 => {
            s.push_str("# comment\nt,u,y\n");
            for k in 0..rows {
                let (t, u, y) = row(k);
                s.push_str(&format!("{t},{u},{y}\n"));
            }
        }
        1 => {
            s.push_str("Time (s)\tVoltage\tdisp_mm\n");
            for k in 0..rows {
                let (t, u, y) = row(k);
                s.push_str(&format!("{t}\t{u}\t{}\n", y * 1e-3));
            }
        }
        2 => {
            for k in 0..rows {
                let (_, u, y) = row(k);
                s.push_str(&format!("  {u}   {y}\n"));
            }
        }
        3 => {
            s.push_str(",y,t,u\r\n");
            for k in 0..rows {
                let (t, u, y) = row(k);
                s.push_str(&format!("{k},{y},{t},{u}\r\n"));
            }
        }
        4 => {
            // A spreadsheet's export with decimal commas and quoted names.
            s.push_str("\"Time, s\";\"Voltage, V\";\"Position, um\"\n");
            for k in 0..rows {
                let (t, u, y) = row(k);
                s.push_str(&format!("{t};{u};{y}\n").replace('.', ","));
            }
        }
        _ => {
            // An instrument's preamble, then a header naming a column no row fills.
            s.push_str("LabVIEW Measurement\nWriter_Version\t2\n***End_of_Header***\nX_Value\tVoltage\tDisplacement\tComment\n");
            for k in 0..rows {
                let (t, u, y) = row(k);
                s.push_str(&format!("{t}\t{u}\t{y}\n"));
            }
        }
    }
    s
}

fn options(which: u8) -> ImportOptions {
    match which % 5 {
        0 => ImportOptions::default(),
        1 => ImportOptions {
            columns: Some("u=1,y=2".parse().unwrap()),
            sample_rate_hz: Some(1000.0),
            ..Default::default()
        },
        2 => ImportOptions {
            y_unit: Some(LengthUnit::M),
            u_unit: Some(VoltUnit::MilliV),
            ..Default::default()
        },
        3 => ImportOptions {
            columns: Some("t=Time,u=2,y=DISP_MM".parse::<ColumnMap>().unwrap()),
            ..Default::default()
        },
        _ => ImportOptions {
            sample_rate_hz: Some(1e-9),
            columns: Some("t=9,u=1,y=1".parse().unwrap()),
            ..Default::default()
        },
    }
}

/// The importer's answer must be a record or a one-line error of bounded length.
fn check(text: &str, which: u8) -> Result<(), TestCaseError> {
    match import_text(text, "fuzz.csv", &options(which)) {
        Ok(i) => {
            let r = i.record;
            prop_assert!(r.u.iter().chain(&r.y).all(|v| v.is_finite()));
            prop_assert!(r.ts > 0.0 && r.len() >= 2);
        }
        Err(e) => {
            let msg = e.to_string();
            prop_assert!(!msg.contains(['\n', '\r']), "{msg}");
            prop_assert!(
                msg.len() < 600,
                "{} bytes: {}",
                msg.len(),
                msg.chars().take(200).collect::<String>()
            );
        }
    }
    Ok(())
}

/// A mutation of a text: (kind, position, payload).
fn mutate(text: &str, muts: &[(u8, usize, Vec<u8>)]) -> String {
    let mut b = text.as_bytes().to_vec();
    for (kind, pos, payload) in muts {
        if b.is_empty() {
            b.extend_from_slice(payload);
            continue;
        }
        let p = pos % b.len();
        match kind % 6 {
            0 => b[p] = payload.first().copied().unwrap_or(b'x'),
            1 => {
                b.splice(p..p, payload.iter().copied());
            }
            2 => {
                let end = (p + payload.len().max(1)).min(b.len());
                b.drain(p..end);
            }
            3 => {
                // Duplicate a line.
                let start = b[..p].iter().rposition(|&c| c == b'\n').map_or(0, |i| i + 1);
                let end = b[p..].iter().position(|&c| c == b'\n').map_or(b.len(), |i| p + i + 1);
                let line = b[start..end].to_vec();
                b.splice(start..start, line);
            }
            4 => {
                // A field replaced by hostile text.
                let hostile: &[&[u8]] = &[
                    b"NaN",
                    b"inf",
                    b"-0",
                    b"1e400",
                    b"5e-324",
                    b"",
                    b"\xff\xfe",
                    b",,,,",
                    b"\t",
                    b"1e-310",
                    b"9999999",
                ];
                let h = hostile[payload.len() % hostile.len()];
                b.splice(p..p, h.iter().copied());
            }
            _ => b.truncate(p),
        }
    }
    String::from_utf8_lossy(&b).into_owned()
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..4096), which in any::<u8>()) {
        check(&String::from_utf8_lossy(&bytes), which)?;
    }

    #[test]
    fn arbitrary_text_of_record_characters_never_panics(
        text in "[-0-9eE.,;\t \r\n#%a-zA-Z()\\[\\]_µ]{0,3000}",
        which in any::<u8>(),
    ) {
        check(&text, which)?;
    }

    #[test]
    fn mutated_valid_records_never_panic(
        layout in any::<u8>(),
        rows in 2usize..600,
        muts in proptest::collection::vec((any::<u8>(), any::<usize>(), proptest::collection::vec(any::<u8>(), 0..12)), 1..8),
        which in any::<u8>(),
    ) {
        let text = mutate(&valid(layout, rows), &muts);
        check(&text, which)?;
    }
}

#[test]
fn the_unmutated_layouts_are_read() {
    for layout in 0..6 {
        let opts = if layout == 2 { options(1) } else { ImportOptions::default() };
        let r = import_text(&valid(layout, 500), "v.csv", &opts)
            .unwrap_or_else(|e| panic!("layout {layout}: {e}"));
        assert_eq!(r.record.len(), 500);
        assert!((r.record.ts - 1e-3).abs() < 1e-12);
    }
}

//! The design file as `boucwen board load` reads it (issue 29): the host refuses what the
//! board would refuse, with the reason and the field, and nothing more; whatever the host
//! accepts the board's state machine ([`Device`]) accepts (a property test over hostile
//! numbers); sizes are bounded before anything is stored.
//!
//! The files here are written by hand (no design is run), so the tests are fast.

use boucwen_lab::design::board::{self as board_design, DesignFile};
use boucwen_link::device::Device;
use boucwen_link::message::{Message, SafetyParams};
use boucwen_link::{Decoder, Packet};
use proptest::prelude::*;

/// A design file as `boucwen board design` writes one (the on-chip actuator at 23 Hz, the
/// third harmonic cancelled), with `board` replaced by `board` when given.
fn file(board: Option<&str>) -> String {
    let board = board.unwrap_or(BOARD);
    format!(
        r#"{{
  "format": "boucwen-board-design",
  "version": 2,
  "created_by": "boucwen 0.1.0",
  "sources": [
    {{ "path": "on-chip.csv", "samples": 6000, "ts_s": 0.001, "drive": "sine 23.0000 Hz", "role": "fit", "fit_pct": 99.1 }}
  ],
  "model": {{
    "inverted": "extended", "ar": [1.79, -0.94], "a1": 20.0, "a": 6.0, "a0": 0.5, "gamma": 2.0,
    "beta": 3.0, "delay_samples": 0.0, "resonance_hz": 70.0, "fit_pct": 99.1,
    "held_out_rms_um": 0.02, "checked_u_v": [-1.2, 1.2], "min_slope_rel": 0.6
  }},
  "harmonics_found": [ {{ "order": 3, "freq_hz": 69.0, "amplitude": 5.1, "gain_um_per_v": null, "phase_deg": null }} ],
  "harmonics_cancelled": [ {{ "order": 3, "freq_hz": 69.0, "amplitude": 0.4, "gain_um_per_v": 1.1, "phase_deg": 26.6 }} ],
  "reference": {{ "freq_hz": 23.0, "amplitude_um": 20.0, "amplitude_source": "requested", "fade_s": 0.5 }},
  "prediction": {{
    "model": "enhanced(3)", "branches": [ {{ "order": 3, "alpha_s": 0.1, "alpha_c": -0.06 }} ],
    "fit_pct": 99.9, "seconds": 5.0, "settle_s": 1.0, "uf_rmse_um": 1.2, "design_rmse_um": 0.2
  }},
  "board": {board}
}}
"#
    )
}

const BOARD: &str = r#"{
    "sample_period_us": 1000,
    "freq_hz": 23.0,
    "amplitude_um": 20.0,
    "fade_samples": 500,
    "bouc_wen": [20.0, 6.0, 0.5, 2.0, 3.0],
    "ar": [1.79, -0.94, 0.0],
    "harmonics": [ { "order": 3, "re": 1.0, "im": 0.5 } ],
    "rls": [0.999, 0.01, 1000000.0],
    "saturation": [-10.0, 10.0],
    "uc_max_v": 2.0,
    "preview_samples": 0.0,
    "drive_limits_v": [-10.0, 10.0],
    "slew_v_per_s": 100.0,
    "host_timeout_ms": 250
  }"#;

/// The file with one line of the board section replaced (the key's line).
fn with_board(key: &str, value: &str) -> String {
    let board: Vec<String> = BOARD
        .lines()
        .map(|l| {
            if l.trim_start().starts_with(&format!("\"{key}\":")) {
                let comma = if l.trim_end().ends_with(',') { "," } else { "" };
                format!("    \"{key}\": {value}{comma}")
            } else {
                l.to_string()
            }
        })
        .collect();
    file(Some(&board.join("\n")))
}

/// Whether the board's state machine acknowledges the file's safety and controller
/// parameters.
fn board_accepts(d: &DesignFile) -> Result<(), String> {
    let (p, s) = d.board_params().map_err(|e| format!("board_params after parse: {e}"))?;
    let mut dev = Device::new();
    let mut out = Vec::new();
    for (seq, msg) in [Message::SetSafety(s), Message::SetController(p)].into_iter().enumerate() {
        let mut sink = |bytes: &[u8]| {
            let mut dec = Decoder::new();
            out.extend(bytes.iter().filter_map(|&b| dec.push(b)).filter_map(Result::ok).map(|p| p.msg));
        };
        dev.on_packet(Ok(Packet { seq: seq as u16, msg }), &mut sink);
    }
    match &out[..] {
        [Message::Ack { .. }, Message::Ack { .. }] => Ok(()),
        other => Err(format!("the board answered {other:?}")),
    }
}

#[test]
fn the_hand_written_file_is_read_and_the_board_accepts_it() {
    let d = DesignFile::parse(&file(None)).unwrap();
    assert_eq!(d.board.sample_period_us, 1000);
    board_accepts(&d).unwrap();
    let (_, s) = d.board_params().unwrap();
    assert_eq!(s, SafetyParams::DEFAULT);
}

/// Issue 29, item 1: each of these loaded on the host and the board answered
/// `Fault(InvalidParams)`.
#[test]
fn what_the_board_refuses_the_host_refuses_naming_it() {
    let cases = [
        ("sample_period_us", "50", "sample period"),
        ("fade_samples", "4294967295", "fade-in"),
        ("amplitude_um", "1e6", "reference amplitude"),
        ("saturation", "[-1e6, 1e6]", "saturation"),
        ("uc_max_v", "1e6", "uc_max"),
    ];
    for (key, value, field) in cases {
        let e = DesignFile::parse(&with_board(key, value)).unwrap_err();
        assert!(e.starts_with("board: ") && e.contains(field), "{key} = {value}: {e}");
    }
    // 1e39 is a finite f64 that becomes +inf as f32: refused where it is written.
    let e = DesignFile::parse(&with_board("uc_max_v", "1e39")).unwrap_err();
    assert!(
        e.starts_with("board.uc_max_v: 1e39 does not fit the board's f32 (at most 3.4028235e38 in size)"),
        "{e}"
    );
    let e = DesignFile::parse(&with_board("bouc_wen", "[20.0, 6.0, 1e-50, 2.0, 3.0]")).unwrap_err();
    assert!(e.starts_with("board.bouc_wen: 1e-50 is too small for the board's f32"), "{e}");
    // A key given twice: the first value is not silently replaced by the second.
    let twice = file(None)
        .replace("\"sample_period_us\": 1000,", "\"sample_period_us\": 1000, \"sample_period_us\": 50,");
    let e = DesignFile::parse(&twice).unwrap_err();
    assert!(e.starts_with("board: duplicate field `sample_period_us`"), "{e}");
    let twice = file(None).replace("\"version\": 2,", "\"version\": 2, \"version\": 2,");
    let e = DesignFile::parse(&twice).unwrap_err();
    assert!(e.starts_with("duplicate field `version`"), "{e}");
}

/// Issue 29, item 2: a model the inverse cannot use loaded, and the run sat at ±10 V.
#[test]
fn a_model_the_inverse_cannot_use_is_refused_with_the_reason() {
    let e = DesignFile::parse(&with_board("bouc_wen", "[0, 0, 0, 0, 0]")).unwrap_err();
    assert!(e.starts_with("board: model gain A1 (the inverse divides by it"), "{e}");
    let e = DesignFile::parse(&with_board("bouc_wen", "[20.0, 25.0, 0.0, 2.0, 3.0]")).unwrap_err();
    assert!(e.starts_with("board: model's slope at rest (not invertible"), "{e}");
    // The mirror of a sensor counting the stroke downwards is a model the inverse uses.
    let d = DesignFile::parse(&with_board("bouc_wen", "[-20.0, -6.0, -0.5, -2.0, 3.0]")).unwrap();
    board_accepts(&d).unwrap();
}

/// Issue 29, item 3: long lists were read whole (10⁶ harmonics: 820 MB) before being
/// refused, or accepted; a list is now refused at its first item beyond a design's, and a
/// file beyond [`board_design::MAX_FILE_BYTES`] before it is read.
#[test]
fn long_lists_and_long_files_are_refused_before_they_are_stored() {
    let many = |n: usize, item: &str| format!("[{}]", vec![item; n].join(", "));
    let e = DesignFile::parse(&with_board("harmonics", &many(3, r#"{ "order": 3, "re": 1.0, "im": 0.5 }"#)))
        .unwrap_err();
    assert!(e.starts_with("board.harmonics: more than 2 items: a design has at most 2"), "{e}");
    let cancelled = many(
        3,
        r#"{ "order": 3, "freq_hz": 69.0, "amplitude": 0.4, "gain_um_per_v": 1.1, "phase_deg": 26.6 }"#,
    );
    let text = file(None).replacen(
        "\"harmonics_cancelled\": [",
        &format!("\"harmonics_cancelled\": {cancelled}, \"x\": ["),
        1,
    );
    let e = DesignFile::parse(&text).unwrap_err();
    assert!(e.starts_with("harmonics_cancelled: more than 2 items"), "{e}");
    // A list of 30 000 items in a file under the size limit is refused at its third item.
    let long = with_board("harmonics", &many(30_000, r#"{"order":3,"re":1,"im":1}"#));
    assert!(long.len() < board_design::MAX_FILE_BYTES as usize);
    let e = DesignFile::parse(&long).unwrap_err();
    assert!(e.starts_with("board.harmonics: more than 2 items"), "{e}");
    // A file over the limit: refused unread.
    let dir = std::env::temp_dir().join(format!("boucwen-design-file-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("huge.json");
    let mut text = file(None);
    text.push_str(&" ".repeat(board_design::MAX_FILE_BYTES as usize));
    std::fs::write(&path, &text).unwrap();
    let e = DesignFile::read(&path).unwrap_err().to_string();
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(e.ends_with("huge.json: longer than 1024 KiB: not a design file (one is a few KiB)"), "{e}");
    assert!(DesignFile::parse(&text).unwrap_err().starts_with("longer than 1024 KiB"));
}

/// Issue 29, item 4: what was found is said; a byte-order mark is skipped.
#[test]
fn messages_say_what_was_found() {
    let text = file(None);
    let version = |v: &str| {
        DesignFile::parse(&text.replace("\"version\": 2", &format!("\"version\": {v}"))).unwrap_err()
    };
    assert_eq!(version("-1"), "version -1: this boucwen reads version 2");
    assert_eq!(version("\"2\""), "version \"2\" (a string): this boucwen reads version 2 (a number)");
    assert_eq!(version("2.0"), "version 2.0: not a whole number; this boucwen reads version 2");
    assert_eq!(version("null"), "version null: this boucwen reads version 2 (a number)");
    assert_eq!(version("7"), "version 7: this boucwen reads version 2");
    let e = DesignFile::parse(&text.replace("  \"version\": 2,\n", "")).unwrap_err();
    assert_eq!(e, "no \"version\": this boucwen reads version 2");
    let e = DesignFile::parse(&text.replace("\"boucwen-board-design\"", "3")).unwrap_err();
    assert_eq!(e, "format 3, not a boucwen board design (\"boucwen-board-design\")");
    let e = DesignFile::parse("[1, 2]").unwrap_err();
    assert_eq!(e, "a JSON array, not an object: not a boucwen board design");
    let e = DesignFile::parse("3").unwrap_err();
    assert!(
        e.starts_with("invalid type: integer `3`, expected a JSON object (a boucwen board design)"),
        "{e}"
    );
    // A byte-order mark, as a Windows editor saves the file.
    let d = DesignFile::parse(&format!("\u{feff}{text}")).unwrap();
    assert_eq!(d, DesignFile::parse(&text).unwrap());
}

/// A number as the JSON of a board field may hold it: a value in range, one at an edge of
/// a range, one beyond, one that does not fit an f32, a negative, a huge integer.
fn hostile_number() -> impl Strategy<Value = String> {
    prop_oneof![
        3 => (-30.0f64..30.0).prop_map(|x| format!("{x}")),
        1 => (0u64..2_000_000).prop_map(|x| x.to_string()),
        2 => prop::sample::select(vec![
            "0", "-0", "1", "-1", "50", "99", "100", "100000", "100001", "250", "10", "9", "60000",
            "60001", "500", "10000000", "10000001", "4294967295", "1e4", "1.0001e4", "1000", "1000.0001",
            "-1000", "-1000.0001", "16", "16.0001", "1e6", "-1e6", "1e39", "-1e39", "3.4028235e38",
            "3.4028236e38", "1e-50", "1e-45", "1e-40", "0.999", "1.5", "0.1", "0.05", "1e5", "1.0001e5",
            "2", "1e-6", "1e-7",
        ])
        .prop_map(String::from),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]
    /// Whatever the host accepts, the board's state machine accepts.
    #[test]
    fn whatever_the_host_accepts_the_board_accepts(
        edits in prop::collection::vec((0usize..23, hostile_number()), 1..5),
        harmonics in 0usize..4,
    ) {
        let mut numbers: Vec<String> = [
            "1000", "23.0", "20.0", "500", "20.0", "6.0", "0.5", "2.0", "3.0", "1.79", "-0.94", "0.0", "0.999",
            "0.01", "1000000.0", "-10.0", "10.0", "2.0", "0.0", "-10.0", "10.0", "100.0", "250",
        ]
        .map(String::from)
        .to_vec();
        for (i, v) in edits {
            numbers[i] = v;
        }
        let n = &numbers;
        let harmonic = |order: u32| format!(r#"{{ "order": {order}, "re": {}, "im": 0.5 }}"#, n[11]);
        let list: Vec<String> = (0..harmonics).map(|i| harmonic(3 + 2 * i as u32)).collect();
        let board = format!(
            r#"{{ "sample_period_us": {}, "freq_hz": {}, "amplitude_um": {}, "fade_samples": {},
                "bouc_wen": [{}, {}, {}, {}, {}], "ar": [{}, {}, {}], "harmonics": [{}],
                "rls": [{}, {}, {}], "saturation": [{}, {}], "uc_max_v": {}, "preview_samples": {},
                "drive_limits_v": [{}, {}], "slew_v_per_s": {}, "host_timeout_ms": {} }}"#,
            n[0], n[1], n[2], n[3], n[4], n[5], n[6], n[7], n[8], n[9], n[10], n[11], list.join(", "),
            n[12], n[13], n[14], n[15], n[16], n[17], n[18], n[19], n[20], n[21], n[22],
        );
        if let Ok(d) = DesignFile::parse(&file(Some(&board))) {
            prop_assert!(board_accepts(&d).is_ok(), "{:?} for {board}", board_accepts(&d));
        }
    }
}

//! Tests of reading and writing records.

use super::import::last_digit_unit;
use super::*;

fn parse_err(text: &str) -> RecordError {
    Record::parse(text, "data.csv").expect_err("the text must be rejected")
}

/// A temporary directory unique to one test, removed at drop.
struct TempDir(std::path::PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("boucwen-record-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
    fn entries(&self) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(&self.0)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[test]
fn parses_columns_in_any_order_with_reference() {
    let r = Record::parse("d,y,t,u\n1,2,0.5,3\n4,5,0.502,6\n7,8,0.504,9\n", "x.csv").unwrap();
    assert_eq!(r.u, [3.0, 6.0, 9.0]);
    assert_eq!(r.y, [2.0, 5.0, 8.0]);
    assert_eq!(r.d.as_deref(), Some(&[1.0, 4.0, 7.0][..]));
    assert_eq!(r.t0, 0.5);
    assert!((r.ts - 0.002).abs() < 1e-15);
    assert_eq!(r.source, "x.csv");
}

#[test]
fn crlf_bom_whitespace_comments_blank_lines() {
    let text = "\u{feff}# bench 2024-05-01\r\n  t , u ,y \r\n\r\n0, 0.5 ,1\r\n# pause\r\n 0.001 ,-0.5,2 \r\n0.002,0,3\r\n\r\n\r\n";
    let r = Record::parse(text, "x.csv").unwrap();
    assert_eq!(r.u, [0.5, -0.5, 0.0]);
    assert_eq!(r.y, [1.0, 2.0, 3.0]);
    assert!((r.ts - 1e-3).abs() < 1e-15);
}

#[test]
fn empty_file() {
    for text in ["", "\n\n  \r\n", "# only a comment\n"] {
        let e = parse_err(text);
        assert!(matches!(e.kind, ErrorKind::Empty), "{e}");
        assert_eq!(e.to_string(), "data.csv: no header: the file is empty or only comments");
    }
}

#[test]
fn missing_header() {
    let e = parse_err("0,0,0\n0.001,1,1\n");
    assert!(matches!(e.kind, ErrorKind::MissingHeader { fields: 3 }));
    assert!(
        e.to_string().starts_with(
            "data.csv:1: no header: the first line is 3 numbers; name the columns with --columns"
        ),
        "{e}"
    );
}

#[test]
fn missing_required_column() {
    let e = parse_err("t,u\n0,0\n0.001,1\n");
    assert!(matches!(e.kind, ErrorKind::MissingColumn { role: "y", .. }));
    assert_eq!(
        e.to_string(),
        "data.csv:1: no column for y (columns found: t, u); name it with --columns y=NAME|N"
    );
}

#[test]
fn duplicate_column() {
    let e = parse_err("# c\nt,u,y,U\n0,0,0,0\n");
    assert_eq!(
        e.to_string(),
        "data.csv:2: more than one column could be u (columns found: t, u, y, U); choose with --columns u=NAME|N"
    );
}

#[test]
fn unknown_column_names_the_columns_and_the_flag() {
    let e = parse_err("t,u,y,temp\n0,0,0,20\n0.001,1,1,20\n");
    assert!(matches!(e.kind, ErrorKind::UnknownColumn { .. }), "{e}");
    assert_eq!(
        e.to_string(),
        "data.csv:1: column \"temp\" is not one of t, u, y, d (columns found: t, u, y, temp); choose the columns \
         with --columns t=NAME|N,u=NAME|N,y=NAME|N"
    );
    // With --columns, other columns are ignored.
    let opts = ImportOptions { columns: Some("t=t,u=u,y=y".parse().unwrap()), ..ImportOptions::default() };
    let r = import_text("t,u,y,temp\n0,0,0,20\n0.001,1,1,20\n", "x", &opts).unwrap().record;
    assert_eq!(r.y, [0.0, 1.0]);
}

#[test]
fn non_numeric_value() {
    let e = parse_err("t,u,y\n0,0,0\n0.001,0,abc\n");
    assert_eq!(e.to_string(), r#"data.csv:3: column "y": "abc" is not a number"#);
    let e = parse_err("t,u,y\n0,,0\n");
    assert_eq!(e.to_string(), r#"data.csv:2: column "u": empty field"#);
}

#[test]
fn non_finite_values() {
    for (bad, col) in [("NaN", "u"), ("inf", "y"), ("-infinity", "t")] {
        let row = match col {
            "u" => format!("0.001,{bad},0"),
            "y" => format!("0.001,0,{bad}"),
            _ => format!("{bad},0,0"),
        };
        let e = parse_err(&format!("t,u,y\n0,0,0\n{row}\n"));
        assert!(matches!(e.kind, ErrorKind::NotFinite { .. }), "{e}");
        assert_eq!(e.to_string(), format!(r#"data.csv:3: column "{col}": "{bad}" is not finite"#));
    }
}

#[test]
fn values_beyond_physical_range() {
    let e = parse_err("t,u,y\n0,0,0\n0.001,1000.5,0\n");
    assert_eq!(
        e.to_string(),
        r#"data.csv:3: column "u": 1000.5 is beyond ±1000 V (if u is in mV, give --u-unit mV)"#
    );
    let e = parse_err("t,u,y,d\n0,0,0,0\n0.001,0,0,-2e5\n");
    assert_eq!(
        e.to_string(),
        r#"data.csv:3: column "d": -200000 is beyond ±100000 µm (if d is in nm, give --y-unit nm)"#
    );
    // At the limits is accepted.
    Record::parse("t,u,y\n0,-1000,1e5\n0.001,1000,1e5\n", "x").unwrap();
}

#[test]
fn ragged_rows() {
    let e = parse_err("t,u,y\n0,0,0\n0.001,0\n");
    assert_eq!(e.to_string(), "data.csv:3: 2 fields, but the header has 3");
    let e = parse_err("t,u,y\n0,0,0,7,8\n");
    assert_eq!(e.to_string(), "data.csv:2: 5 fields, but the header has 3");
}

#[test]
fn time_not_increasing() {
    let e = parse_err("t,u,y\n0,0,0\n0.001,0,0\n0.001,0,0\n");
    assert!(matches!(e.kind, ErrorKind::TimeNotIncreasing { .. }));
    assert_eq!(
        e.to_string(),
        r#"data.csv:4: column "t": 0.001 does not increase from the previous row's 0.001"#
    );
    let e = parse_err("t,u,y\n0.002,0,0\n0.001,0,0\n");
    assert!(e.to_string().starts_with("data.csv:3: column \"t\""), "{e}");
}

/// Issue 29, item 4: numbers are written for people (`t = 1e300` was printed with 301
/// digits), and no message carries a line or paragraph separator (U+2028, U+2029) from a
/// file's text: the header's names are shown with `?` for them, as for control characters.
#[test]
fn messages_write_numbers_for_people_and_stay_one_line() {
    let e = parse_err("t,u,y\n1e300,0,0\n1,0,0\n");
    assert_eq!(e.to_string(), r#"data.csv:3: column "t": 1 does not increase from the previous row's 1e300"#);
    let e = parse_err("t,u,y\n0,0,0\n0.001,1e-300,2.5e-9\n0.002,1500,0\n");
    assert_eq!(
        e.to_string(),
        r#"data.csv:4: column "u": 1500 is beyond ±1000 V (if u is in mV, give --u-unit mV)"#
    );
    let e = parse_err("t,u,y\n0,0,0\n1,1,1e20\n");
    assert!(
        e.to_string().ends_with(r#"column "y": 1e20 is beyond ±100000 µm (if y is in nm, give --y-unit nm)"#),
        "{e}"
    );
    let e = parse_err("t,u,y\n0,0,0\n1e17,0,1\n2e17,1,0\n");
    assert!(e.to_string().contains("whole numbers 1e17 apart"), "{e}");
    let text = "t,u,y,dis\u{2028}p\u{2029}\u{202e}x\n0,0,0,1\n0.001,1,1,2\n";
    let e = parse_err(text).to_string();
    assert!(!e.contains(['\u{2028}', '\u{2029}', '\u{202e}']), "{e:?}");
    assert!(e.contains("dis?p??x"), "{e}");
    let opts = ImportOptions { columns: Some("u=u,y=nope".parse().unwrap()), ..ImportOptions::default() };
    let e = import_text(text, "data.csv", &opts).unwrap_err().to_string();
    assert!(e.contains("(columns found: t, u, y, dis?p??x)"), "{e:?}");
}

/// Issue 29, item 6: with `--columns` the unit comes from the header all the same (the
/// times of `Zeit [ms]` were refused as unit-less, and `mV`, `nm` dropped).
#[test]
fn columns_given_by_position_keep_the_headers_units() {
    let text = "Zeit [ms];Spannung (mV);Weg_nm\n0;0;0\n1;500;1000\n2;-500;-1000\n3;0;0\n";
    let opts = ImportOptions { columns: Some("t=1,u=2,y=3".parse().unwrap()), ..ImportOptions::default() };
    let i = import_with(text, &opts).unwrap();
    assert_eq!((i.record.ts, i.record.u[1], i.record.y[1]), (1e-3, 0.5, 1.0));
    assert_eq!(
        (i.info.t_unit, i.info.u_unit, i.info.y_unit),
        (TimeUnit::Ms, VoltUnit::MilliV, LengthUnit::Nm)
    );
    // The same by name, and a name that is only a unit.
    let opts = ImportOptions {
        columns: Some("t=zeit [ms],u=Spannung (mV),y=weg_nm".parse().unwrap()),
        ..ImportOptions::default()
    };
    assert_eq!(import_with(text, &opts).unwrap().record.ts, 1e-3);
    let opts = ImportOptions { columns: Some("t=1,u=2,y=3".parse().unwrap()), ..ImportOptions::default() };
    let r = import_with("ms,V,um\n0,0,0\n1,1,1\n2,0,0\n", &opts).unwrap().record;
    assert_eq!((r.ts, r.u[1], r.y[1]), (1e-3, 1.0, 1.0));
    // A flag still overrides the header.
    let opts = ImportOptions { t_unit: Some(TimeUnit::Us), ..opts };
    assert_eq!(import_with("ms,V,um\n0,0,0\n1,1,1\n2,0,0\n", &opts).unwrap().record.ts, 1e-6);
}

#[test]
fn non_uniform_sampling_and_dropped_sample() {
    // A dropped sample (the step at line 5 is 2 ms).
    let e = parse_err("t,u,y\n0.000,0,0\n0.001,0,0\n0.002,0,0\n0.004,0,0\n0.005,0,0\n");
    assert!(matches!(e.kind, ErrorKind::NonUniform { .. }), "{e}");
    assert!(e.to_string().starts_with("data.csv:5: column \"t\": step 2e-3 s"), "{e}");
    // Jitter of 2 % with times written to 1 µs is too much.
    let e = parse_err("t,u,y\n0.000000,0,0\n0.001000,0,0\n0.002020,0,0\n0.003020,0,0\n");
    assert!(e.to_string().starts_with("data.csv:4:"), "{e}");
    // Jitter of 0.5 % is within the tolerance.
    Record::parse("t,u,y\n0.000000,0,0\n0.001000,0,0\n0.002005,0,0\n0.003005,0,0\n", "x").unwrap();
}

#[test]
fn times_rounded_when_written_are_uniform() {
    // 3 kHz written with four decimals: steps of 0.0003 and 0.0004 s.
    let mut text = String::from("t,u,y\n");
    for k in 0..3000 {
        text.push_str(&format!("{:.4},0,0\n", k as f64 / 3000.0));
    }
    let r = Record::parse(&text, "x").unwrap();
    assert!((r.ts - 1.0 / 3000.0).abs() < 1e-4 / 2999.0);
    // 1024 Hz written with six decimals, starting at a Unix time.
    let mut text = String::from("t,u,y\n");
    for k in 0..1024 {
        text.push_str(&format!("{:.6},0,0\n", 1.7e9 + k as f64 / 1024.0));
    }
    let r = Record::parse(&text, "x").unwrap();
    assert!((r.ts - 1.0 / 1024.0).abs() < 1e-6);
    assert_eq!(r.t0, 1.7e9);
}

#[test]
fn too_few_samples() {
    let e = parse_err("t,u,y\n0,0,0\n");
    assert_eq!(e.to_string(), "data.csv: too few samples: 1, at least 2 needed");
    let e = parse_err("t,u,y\n");
    assert!(matches!(e.kind, ErrorKind::TooFewSamples { found: 0, needed: 2 }));
    let r = Record::parse("t,u,y\n0,0,0\n0.001,1,0\n0.002,0,0\n", "x.csv").unwrap();
    let e = r.validate_for_fit(100).unwrap_err();
    assert_eq!(e.to_string(), "x.csv: too few samples: 3, at least 100 needed");
    assert!(r.validate_for_fit(3).is_ok());
}

#[test]
fn sample_interval_limits() {
    let e = parse_err("t,u,y\n0.0,0,0\n20.0,0,0\n");
    assert_eq!(e.to_string(), "data.csv: sample interval 2e1 s is outside 1e-6 s to 10 s");
    let e = parse_err("t,u,y\n0,0,0\n1e-7,0,0\n");
    assert!(matches!(e.kind, ErrorKind::SampleInterval(_)));
    Record::parse("t,u,y\n0,0,0\n1e-6,0,0\n", "x").unwrap();
}

#[test]
fn no_excitation() {
    let r = Record::parse("t,u,y\n0,1.5,0\n0.001,1.5,1\n0.002,1.5004,2\n", "flat.csv").unwrap();
    let e = r.check_excitation().unwrap_err();
    assert!(matches!(e.kind, ErrorKind::NoExcitation { .. }));
    assert!(e.to_string().starts_with("flat.csv: no excitation: u is constant"), "{e}");
    let r = Record::parse("t,u,y\n0,0,0\n0.001,0.01,1\n0.002,-0.01,2\n", "x").unwrap();
    r.check_excitation().unwrap();
}

#[test]
fn not_utf8_names_the_line() {
    let dir = TempDir::new("utf8");
    let path = dir.0.join("bin.csv");
    std::fs::write(&path, b"t,u,y\n0,0,0\n0.001,\xff,0\n").unwrap();
    let e = Record::read(&path).unwrap_err();
    assert_eq!(e.to_string(), format!("{}:3: not UTF-8 text", path.display()));
    let missing = dir.0.join("missing.csv");
    let e = Record::read(&missing).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Io(_)));
    assert!(e.to_string().starts_with(&format!("{}: ", missing.display())), "{e}");
}

#[test]
fn new_checks_lengths_and_values() {
    let e = Record::new("sim", 0.0, 1e-3, vec![0.0; 3], vec![0.0; 2], None).unwrap_err();
    assert_eq!(e.to_string(), r#"sim: column "y" has 2 samples, the first column 3"#);
    let e = Record::new("sim", 0.0, 1e-3, vec![0.0; 2], vec![0.0, f64::NAN], None).unwrap_err();
    assert_eq!(e.to_string(), r#"sim: sample 1: column "y": "NaN" is not finite"#);
    let e = Record::new("sim", 0.0, 0.0, vec![0.0; 2], vec![0.0; 2], None).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::SampleInterval(_)));
}

/// A record with awkward values: irrational interval, offset start, tiny and large values.
fn awkward(n: usize, with_d: bool) -> Record {
    let ts = 1.0 / 3000.0;
    let u: Vec<f64> = (0..n).map(|k| 3.0 * (0.7 * k as f64).sin() + 1e-17 * k as f64).collect();
    let y: Vec<f64> = (0..n).map(|k| 123.456789 * (0.3 * k as f64).cos() / 7.0).collect();
    let d = with_d.then(|| (0..n).map(|k| -(k as f64) / 3.0).collect());
    Record::new("mem", 12.345678901, ts, u, y, d).unwrap()
}

#[test]
fn round_trip() {
    let dir = TempDir::new("roundtrip");
    for with_d in [false, true] {
        let r = awkward(5000, with_d);
        let path = dir.0.join("r.csv");
        r.write(&path).unwrap();
        let back = Record::read(&path).unwrap();
        assert_eq!(back.u, r.u, "u round-trips exactly");
        assert_eq!(back.y, r.y, "y round-trips exactly");
        assert_eq!(back.d, r.d, "d round-trips exactly");
        assert!((back.ts - r.ts).abs() <= 1e-9 * r.ts, "{} vs {}", back.ts, r.ts);
        assert!((back.t0 - r.t0).abs() <= 1e-9 * r.ts);
        assert_eq!(back.source, path.display().to_string());
    }
    assert_eq!(dir.entries(), ["r.csv"], "no temporary file left");
}

#[test]
fn writer_time_column_is_short_and_exact_enough() {
    let r = Record::new("m", 0.0, 1e-3, vec![0.0, 1.0, 2.0], vec![0.5; 3], None).unwrap();
    let dir = TempDir::new("short");
    let path = dir.0.join("s.csv");
    r.write(&path).unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "t,u,y\n0,0,0.5\n0.001,1,0.5\n0.002,2,0.5\n");
}

#[test]
fn write_errors_leave_nothing_behind() {
    let dir = TempDir::new("atomic");
    let path = dir.0.join("t.csv");
    write_columns(&path, &[("a", &[1.0, 2.0])]).unwrap();
    // Bad inputs: the existing file stays as it was.
    let e = write_columns(&path, &[("a", &[1.0]), ("b", &[1.0, 2.0])]).unwrap_err();
    assert_eq!(e.to_string(), format!(r#"{}: column "b" has 2 samples, the first column 1"#, path.display()));
    let e = write_columns(&path, &[("a", &[1.0, f64::INFINITY])]).unwrap_err();
    assert_eq!(e.to_string(), format!(r#"{}: sample 1: column "a": "inf" is not finite"#, path.display()));
    for bad in ["", "a,b", " a", "#a", "a\"", "x\ny"] {
        let e = write_columns(&path, &[(bad, &[1.0])]).unwrap_err();
        assert!(matches!(e.kind, ErrorKind::BadColumnName(_)), "{bad:?}: {e}");
    }
    let e = write_columns(&path, &[("a", &[1.0]), ("a", &[1.0])]).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::DuplicateColumn(_)));
    assert!(matches!(write_columns(&path, &[]).unwrap_err().kind, ErrorKind::NoColumns));
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "a\n1\n2\n");
    // A directory in the way of the rename: an I/O error, the temporary file removed.
    let blocked = dir.0.join("sub");
    std::fs::create_dir(&blocked).unwrap();
    std::fs::write(blocked.join("x"), "keep").unwrap();
    let e = write_columns(&blocked, &[("a", &[1.0])]).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Io(_)), "{e}");
    assert!(e.to_string().starts_with(&blocked.display().to_string()));
    // Into a directory that does not exist.
    let e = write_columns(dir.0.join("nope").join("x.csv"), &[("a", &[1.0])]).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::Io(_)));
    assert_eq!(dir.entries(), ["sub", "t.csv"], "no temporary file left");
    // An invalid record is not written.
    let mut r = awkward(10, false);
    r.y[3] = f64::NAN;
    let e = r.write(dir.0.join("bad.csv")).unwrap_err();
    assert!(e.to_string().starts_with(&format!("{}: sample 3:", dir.0.join("bad.csv").display())), "{e}");
    assert_eq!(dir.entries(), ["sub", "t.csv"]);
}

#[test]
fn large_file_parses() {
    // 100k rows at 10 kHz with a reference; no timing assertion (benches do timing).
    let r = awkward(100_000, true);
    let dir = TempDir::new("large");
    let path = dir.0.join("big.csv");
    r.write(&path).unwrap();
    let back = Record::read(&path).unwrap();
    assert_eq!(back.len(), 100_000);
    assert_eq!(back.y, r.y);
}

#[test]
fn last_digit_units() {
    assert_eq!(last_digit_unit("0.0003"), 1e-4);
    assert_eq!(last_digit_unit("1.5e-3"), 1e-4);
    assert_eq!(last_digit_unit("12"), 1.0);
    assert_eq!(last_digit_unit("-2.50E+2"), 1.0);
}

fn import_with(text: &str, opts: &ImportOptions) -> Result<Imported, RecordError> {
    import_text(text, "bench.txt", opts)
}

#[test]
fn other_names_order_separators_and_units_from_the_header() {
    // Tab-separated, an empty first column, other names and order, units in the header.
    let text = "\tDisp [mm]\tTime (ms)\tVoltage\n\t0.001\t0\t0.5\n\t0.002\t1\t-0.5\n\t0.003\t2\t0\n";
    let i = import_with(text, &ImportOptions::default()).unwrap();
    assert_eq!(i.record.y, [1.0, 2.0, 3.0]);
    assert_eq!(i.record.u, [0.5, -0.5, 0.0]);
    assert!((i.record.ts - 1e-3).abs() < 1e-15);
    assert_eq!(i.info.separator, Separator::Tab);
    assert_eq!(i.info.y_unit, LengthUnit::Mm);
    assert_eq!(
        i.info.describe(),
        r#"tab-separated, with a header; t = "Time (ms)" in ms, u = "Voltage", y = "Disp [mm]" in mm"#
    );
    // Whitespace-separated with aligned columns; semicolons; a trailing comma on rows.
    let r = Record::parse("  time    volt     disp\n  0.000   0.1      2.0\n  0.001  -0.1      2.5\n", "x")
        .unwrap();
    assert_eq!(r.u, [0.1, -0.1]);
    let r = Record::parse("t;u;y\n0;1;2\n0.001;2;3\n", "x").unwrap();
    assert_eq!(r.y, [2.0, 3.0]);
    let r = Record::parse("t,u,y\n0,1,2,\n0.001,2,3,\n", "x").unwrap();
    assert_eq!(r.y, [2.0, 3.0]);
}

#[test]
fn names_of_several_words_and_names_that_are_units() {
    // Each word of the name names the same role; a unit alone names its quantity.
    let i = import_with(
        "Time [ms],Piezo Voltage (V),Measured Position (nm)\n0,1,5\n1,2,6\n",
        &ImportOptions::default(),
    )
    .unwrap();
    assert_eq!((i.record.u.clone(), i.record.y.clone()), (vec![1.0, 2.0], vec![0.005, 0.006]));
    let i = import_with("s,V,um\n0,1,5\n0.002,2,6\n", &ImportOptions::default()).unwrap();
    assert_eq!((i.record.u.clone(), i.record.y.clone()), (vec![1.0, 2.0], vec![5.0, 6.0]));
    assert!((i.record.ts - 2e-3).abs() < 1e-15);
    let i = import_with("ms,mV,nm\n0,1000,5\n1,2000,6\n", &ImportOptions::default()).unwrap();
    assert_eq!((i.record.u.clone(), i.record.y.clone()), (vec![1.0, 2.0], vec![0.005, 0.006]));
    // A column named exactly comes before one whose words name the role; words that name two
    // roles name none (is "output voltage" the drive or a sensor's voltage?).
    let e = import_with("t,u,y,y_filtered\n0,1,5,5\n0.001,2,6,6\n", &ImportOptions::default()).unwrap_err();
    assert!(e.to_string().contains("y_filtered"), "{e}");
    let e = import_with("t,output voltage,y\n0,1,5\n0.001,2,6\n", &ImportOptions::default()).unwrap_err();
    assert!(e.to_string().contains("--columns"), "{e}");
}

#[test]
fn columns_flag_by_name_or_position_without_header_or_time() {
    let opts = ImportOptions { columns: Some("u=VOLTAGE,y=3".parse().unwrap()), ..ImportOptions::default() };
    let i = import_with("time,voltage,laser\n0,1,5\n0.002,2,6\n", &opts).unwrap();
    assert_eq!((i.record.u.clone(), i.record.y.clone()), (vec![1.0, 2.0], vec![5.0, 6.0]));
    assert!((i.record.ts - 2e-3).abs() < 1e-15, "t found by its name");
    // No header: positions and a sample rate; an empty first column counts as column 1.
    let opts = ImportOptions {
        columns: Some("u=2,y=3".parse().unwrap()),
        sample_rate_hz: Some(500.0),
        ..ImportOptions::default()
    };
    let i = import_with(",1,5\n,2,6\n,3,7\n", &opts).unwrap();
    assert_eq!(i.record.y, [5.0, 6.0, 7.0]);
    assert_eq!((i.record.t0, i.record.ts), (0.0, 2e-3));
    assert_eq!(i.info.time, TimeSource::SampleRate(500.0));
    // A column that is not there, and one too far.
    let opts = ImportOptions { columns: Some("u=volts,y=2".parse().unwrap()), ..ImportOptions::default() };
    let e = import_with("t,u,y\n0,1,5\n0.001,2,6\n", &opts).unwrap_err();
    assert_eq!(e.to_string(), "bench.txt:1: --columns u=volts: no such column (columns found: t, u, y)");
    let opts = ImportOptions { columns: Some("u=2,y=7".parse().unwrap()), ..ImportOptions::default() };
    let e = import_with("0 1 5\n0.001 2 6\n", &opts).unwrap_err();
    assert_eq!(e.to_string(), "bench.txt:1: --columns y=7: no such column (columns found: 1, 2, 3)");
}

#[test]
fn time_from_the_column_or_the_rate_never_both_disagreeing() {
    let e = import_with("u,y\n1,5\n2,6\n", &ImportOptions::default()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "bench.txt:1: no time column (columns found: u, y); give --sample-rate HZ, or name it with --columns t=NAME|N"
    );
    let opts = ImportOptions { sample_rate_hz: Some(500.0), ..ImportOptions::default() };
    let e = import_with("t,u,y\n0,1,5\n0.001,2,6\n", &opts).unwrap_err();
    assert!(matches!(e.kind, ErrorKind::RateMismatch { .. }), "{e}");
    let opts = ImportOptions { sample_rate_hz: Some(1000.0), ..ImportOptions::default() };
    import_with("t,u,y\n0,1,5\n0.001,2,6\n", &opts).unwrap();
    let opts = ImportOptions {
        sample_rate_hz: Some(1000.0),
        columns: Some("t=1,u=2,y=3".parse().unwrap()),
        ..ImportOptions::default()
    };
    assert!(matches!(
        import_with("t,u,y\n0,1,5\n0.001,2,6\n", &opts).unwrap_err().kind,
        ErrorKind::TimeTwice
    ));
    // A sample rate that gives an interval out of range.
    let opts = ImportOptions { sample_rate_hz: Some(0.0), ..ImportOptions::default() };
    assert!(matches!(import_with("u,y\n1,5\n2,6\n", &opts).unwrap_err().kind, ErrorKind::SampleInterval(_)));
}

#[test]
fn an_output_in_metres_is_named_with_the_flag_and_read_with_it() {
    let text = "t,u,y\n0,0,1.0e-6\n0.001,1,2.0e-5\n0.002,0,-1.0e-5\n";
    let e = import_with(text, &ImportOptions::default()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "bench.txt: column \"y\": the output spans 3.000e-5 µm, less than 1 nm; if y is in m, give --y-unit m"
    );
    let opts = ImportOptions { y_unit: Some(LengthUnit::M), ..ImportOptions::default() };
    let r = import_with(text, &opts).unwrap().record;
    assert!((r.y[1] - 20.0).abs() < 1e-9);
    // Millimetres written as micrometres are fine; nanometres of a 20 mm span are not.
    let e = import_with("t,u,y\n0,0,0\n0.001,1,2e4\n", &ImportOptions::default()).unwrap_err();
    assert!(e.to_string().ends_with("more than 10 mm; if y is in nm, give --y-unit nm"), "{e}");
    // A span no unit makes plausible.
    let e = import_with("t,u,y\n0,0,0\n0.001,1,1e-290\n", &ImportOptions::default()).unwrap_err();
    assert!(e.to_string().contains("no unit of --y-unit"), "{e}");
    // mV for u.
    let opts = ImportOptions { u_unit: Some(VoltUnit::MilliV), ..ImportOptions::default() };
    assert_eq!(import_with("t,u,y\n0,500,0\n0.001,-500,1\n", &opts).unwrap().record.u, [0.5, -0.5]);
}

#[test]
fn subnormal_values_are_zero() {
    let r = Record::parse("t,u,y\n0,0,5e-324\n0.001,1,1\n0.002,0,-2e-320\n", "x").unwrap();
    assert_eq!(r.y, [0.0, 1.0, 0.0]);
}

#[test]
fn an_offending_field_is_quoted_short() {
    let long = "x".repeat(1_000_000);
    let e = parse_err(&format!("t,u,y\n0,0,0\n0.001,{long},0\n"));
    let msg = e.to_string();
    assert!(msg.len() < 120, "{} bytes", msg.len());
    assert_eq!(msg, format!("data.csv:3: column \"u\": \"{}…\" is not a number", "x".repeat(EXCERPT_CHARS)));
    let e = parse_err(&format!("t,u,{long}\n0,0,0\n"));
    assert!(e.to_string().len() < 300, "{e}");
    assert_eq!(excerpt("µµµ"), "µµµ");
}

#[test]
fn flags_are_checked() {
    for bad in ["", "u", "u=", "q=1", "u=0", "u=1,u=2"] {
        let e = bad.parse::<ColumnMap>().unwrap_err();
        assert!(e.to_string().starts_with("--columns"), "{e}");
    }
    assert_eq!("um".parse::<LengthUnit>().unwrap(), LengthUnit::Um);
    assert_eq!("µm".parse::<LengthUnit>().unwrap(), LengthUnit::Um);
    assert_eq!("mV".parse::<VoltUnit>().unwrap(), VoltUnit::MilliV);
    assert_eq!(
        "furlong".parse::<LengthUnit>().unwrap_err().to_string(),
        r#"--y-unit "furlong": expected m, mm, um or nm"#
    );
}

#[test]
fn a_message_lists_at_most_eight_columns() {
    let header: Vec<String> = (0..500).map(|i| format!("column_with_a_long_name_{i}")).collect();
    let e = parse_err(&format!("{}\n", header.join(",")));
    let msg = e.to_string();
    assert!(msg.contains("… 500 in all"), "{msg}");
    assert!(msg.len() < 400, "{} bytes", msg.len());
}

#[test]
fn decimal_commas_under_semicolons_tabs_and_spaces() {
    let by_position =
        ImportOptions { columns: Some("t=1,u=2,y=3".parse().unwrap()), ..ImportOptions::default() };
    // A spreadsheet's export where the comma is the decimal mark; the header names nothing
    // the importer knows, so the columns are given.
    let text = "Zeit [s];Spannung [V];Weg [µm]\n0;0;0,25\n0,001;-1,5;12,5\n0,002;1,5e-1;-3\n";
    let i = import_with(text, &by_position).unwrap();
    assert_eq!(i.record.u, [0.0, -1.5, 0.15]);
    assert_eq!(i.record.y, [0.25, 12.5, -3.0]);
    assert_eq!(i.record.ts, 0.001);
    assert!(i.info.decimal_comma);
    assert!(
        i.info.describe().starts_with("semicolon-separated with decimal commas, with a header"),
        "{}",
        i.info.describe()
    );
    // The first rows may be integers: the mark comes from the first number with a fraction.
    let i = import_with("t [ms]\tu\ty\n0\t0\t0\n1\t0\t0\n2\t0,5\t1,25\n", &ImportOptions::default()).unwrap();
    assert_eq!((i.info.separator, i.info.decimal_comma), (Separator::Tab, true));
    assert_eq!(i.record.y, [0.0, 0.0, 1.25]);
    // Between spaces, with no header.
    let i = import_with("0,000  0,5  1,25\n0,001  -0,5  2\n0,002  0  3,5\n", &by_position).unwrap();
    assert_eq!((i.info.separator, i.info.decimal_comma), (Separator::Whitespace, true));
    assert_eq!(i.record.y, [1.25, 2.0, 3.5]);
    // Under commas a comma separates; a point with a decimal comma, or two commas, is no number.
    let i = import_with("t,u,y\n0,0,1\n0.001,1,2\n", &ImportOptions::default()).unwrap();
    assert!(!i.info.decimal_comma);
    let e = import_with("t;u;y\n0;0,5;1\n0,001;1.000,5;2\n", &ImportOptions::default()).unwrap_err();
    assert_eq!(e.to_string(), "bench.txt:3: column \"u\": \"1.000,5\" is not a number");
}

#[test]
fn quoted_fields() {
    // A spreadsheet quotes names and values; a separator between quotes is the field's.
    let text =
        "\"Time (s)\",\"Voltage, V\",\"Displacement (um)\"\n\"0\",\"0.5\",\"1\"\n\"0.001\",\"-0.5\",\"2\"\n";
    let i = import_with(text, &ImportOptions::default()).unwrap();
    assert_eq!(i.record.u, [0.5, -0.5]);
    assert_eq!(i.record.y, [1.0, 2.0]);
    assert_eq!(i.info.columns[1], ("u", "\"Voltage, V\"".to_string()));
    let text = "\"Time, ms\";\"Voltage, mV\";\"Position, nm\"\n0;500;1000\n1;-500;2000\n";
    let i = import_with(text, &ImportOptions::default()).unwrap();
    assert_eq!(
        (i.record.ts, i.record.u.clone(), i.record.y.clone()),
        (0.001, vec![0.5, -0.5], vec![1.0, 2.0])
    );
}

#[test]
fn an_instruments_preamble_is_skipped_and_said() {
    // A LabVIEW-style file: lines of metadata, then the header (naming a `Comment` column no
    // row fills), then the rows.
    let text = "LabVIEW Measurement\nWriter_Version\t2\nDate\t2024/05/01\n***End_of_Header***\n\
                X_Value\tVoltage\tDisplacement\tComment\n0.000\t0\t1\n0.001\t0.5\t2\n0.002\t-0.5\t3\n0.003\t0\t4\n";
    let i = import_with(text, &ImportOptions::default()).unwrap();
    assert_eq!(i.record.y, [1.0, 2.0, 3.0, 4.0]);
    assert_eq!(i.info.preamble, Some(Preamble { lines: 4, table_line: 5 }));
    assert_eq!(
        i.info.describe(),
        "tab-separated, with a header from line 5 (4 lines before it skipped: they belong to no table); \
         t = \"X_Value\", u = \"Voltage\", y = \"Displacement\""
    );
    // Without a header after the preamble, the columns are given.
    let text = "Keyence LK-G5000\nSampling cycle: 1 ms\n0.000,0,1\n0.001,0.5,2\n0.002,-0.5,3\n";
    let opts = ImportOptions { columns: Some("t=1,u=2,y=3".parse().unwrap()), ..ImportOptions::default() };
    let i = import_with(text, &opts).unwrap();
    assert_eq!((i.info.header, i.info.preamble), (false, Some(Preamble { lines: 2, table_line: 3 })));
    // A column empty on every row is not a signal, one with values still needs a name.
    let i = import_with("t,u,y,note\n0,0,1,\n0.001,1,2,\n", &ImportOptions::default()).unwrap();
    assert_eq!(i.record.y, [1.0, 2.0]);
    assert!(import_with("t,u,y,note\n0,0,1,\n0.001,1,2,a\n", &ImportOptions::default()).is_err());
}

#[test]
fn a_malformed_row_is_never_a_reason_to_skip_lines() {
    // Rows after a normal header: the bad row is the error, nothing before it is skipped.
    let e = parse_err("t,u,y\n0,0,0\nabc\n0.002,1,1\n0.003,1,1\n0.004,1,1\n");
    assert_eq!(e.to_string(), "data.csv:3: 1 fields, but the header has 3");
    let e = parse_err("note\n0,0,0\nabc\n0.002,1,1\n0.003,1,1\n0.004,1,1\n");
    assert!(e.to_string().starts_with("data.csv:1:"), "{e}");
}

#[test]
fn a_unix_time_axis_gives_the_interval_as_written() {
    let text: String = std::iter::once("timestamp,u,y\n".to_string())
        .chain((0..2000).map(|k| format!("{:.3},{},{}\n", 1_764_720_000.0 + k as f64 * 1e-3, k % 7, k % 5)))
        .collect();
    let r = Record::parse(&text, "x").unwrap();
    assert_eq!(r.ts, 0.001);
    // 1024 Hz written to the microsecond keeps its digits.
    let text: String = std::iter::once("t,u,y\n".to_string())
        .chain((0..2048).map(|k| format!("{:.6},{},{}\n", k as f64 / 1024.0, k % 7, k % 5)))
        .collect();
    let r = Record::parse(&text, "x").unwrap();
    assert!((r.ts - 1.0 / 1024.0).abs() < 1e-9, "{}", r.ts);
}

#[test]
fn whole_number_times_need_their_unit_and_counters_are_no_signal() {
    // Milliseconds without a unit would read as a record sampled every second.
    let text: String = std::iter::once("Sample No.,time,u,y\n".to_string())
        .chain((0..500).map(|k| format!("{k},{k},{},{}\n", k % 7, k % 5)))
        .collect();
    let e = import_with(&text, &ImportOptions::default()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "bench.txt: column \"time\": the times are whole numbers 1 apart and the header gives no unit; \
         if t is in ms, give --t-unit ms (us for µs; s if it really is sampled every 1 s)"
    );
    let ms = ImportOptions { t_unit: Some(TimeUnit::Ms), ..ImportOptions::default() };
    let i = import_with(&text, &ms).unwrap();
    assert_eq!((i.record.ts, i.info.t_unit), (0.001, TimeUnit::Ms));
    assert!(i.info.describe().contains(r#"t = "time" in ms"#), "{}", i.info.describe());
    let s = ImportOptions { t_unit: Some(TimeUnit::S), ..ImportOptions::default() };
    assert_eq!(import_with(&text, &s).unwrap().record.ts, 1.0);
    // Seconds with decimals, or a unit in the header, need nothing.
    assert_eq!(import_with("t,u,y\n0.5,0,1\n1.0,1,2\n", &ImportOptions::default()).unwrap().record.ts, 0.5);
    assert_eq!(
        import_with("time_ms,u,y\n0,0,1\n2,1,2\n", &ImportOptions::default()).unwrap().record.ts,
        0.002
    );
    assert_eq!("µs".parse::<TimeUnit>(), Ok(TimeUnit::Us));
    assert!("h".parse::<TimeUnit>().is_err());
}

#[test]
fn a_file_that_stops_inside_its_last_row_loses_that_row_and_says_so() {
    let i = import_with("t,u,y\n0,0,1\n0.001,1,2\n0.002,1", &ImportOptions::default()).unwrap();
    assert_eq!((i.record.len(), i.info.cut_short), (2, Some(4)));
    assert!(
        i.info.describe().ends_with("; line 4 left out: the file stops inside it"),
        "{}",
        i.info.describe()
    );
    // With its line end the row is ragged, not cut: an error as any other.
    let e = import_with("t,u,y\n0,0,1\n0.001,1,2\n0.002,1\n", &ImportOptions::default()).unwrap_err();
    assert_eq!(e.to_string(), "bench.txt:4: 2 fields, but the header has 3");
    // Only the last line.
    let e = import_with("t,u,y\n0,0,1\n0.001,1\n0.002,1,2", &ImportOptions::default()).unwrap_err();
    assert_eq!(e.to_string(), "bench.txt:3: 2 fields, but the header has 3");
}

#[test]
fn a_few_missing_samples_of_the_output_are_filled_and_said() {
    // A smooth output (a cubic in k) with a sensor's out-of-range samples: one NaN, one empty
    // field, and a run of two.
    let y = |k: usize| {
        let x = k as f64 * 0.01;
        1.0 + x - 0.5 * x * x + 0.1 * x * x * x
    };
    let text = |gaps: &[usize], how: &str| -> String {
        std::iter::once("t,u,y\n".to_string())
            .chain((0..400).map(|k| {
                let v = if gaps.contains(&k) { how.to_string() } else { y(k).to_string() };
                format!("{},{},{v}\n", k as f64 * 1e-3, (k % 7) as f64)
            }))
            .collect()
    };
    for (gaps, how) in [(&[10usize, 200, 201][..], "NaN"), (&[50, 300][..], "")] {
        let i = import_with(&text(gaps, how), &ImportOptions::default()).unwrap();
        for &k in gaps {
            assert!((i.record.y[k] - y(k)).abs() < 1e-12, "{k}: {} against {}", i.record.y[k], y(k));
        }
        let m = i.info.missing.unwrap();
        assert_eq!((m.count, m.first_s), (gaps.len(), gaps[0] as f64 * 1e-3));
        assert!(
            i.info
                .describe()
                .contains(&format!("; y: {} missing samples (NaN or empty, the first at", gaps.len()))
        );
    }
    // A run of three, one at the edge, or more than 1 % of the samples: an error at the first.
    for (gaps, line) in [
        (&[100usize, 101, 102][..], 102),
        (&[1][..], 3),
        (&(100..105).step_by(1).collect::<Vec<_>>()[..], 102),
    ] {
        let e = import_with(&text(gaps, "NaN"), &ImportOptions::default()).unwrap_err();
        assert_eq!(e.to_string(), format!("bench.txt:{line}: column \"y\": \"NaN\" is not finite"));
    }
    let many: Vec<usize> = (10..400).step_by(50).collect();
    assert!(
        import_with(&text(&many, ""), &ImportOptions::default())
            .unwrap_err()
            .to_string()
            .contains("empty field")
    );
    // The drive is never filled.
    let e = import_with("t,u,y\n0,NaN,1\n0.001,1,2\n", &ImportOptions::default()).unwrap_err();
    assert_eq!(e.to_string(), "bench.txt:2: column \"u\": \"NaN\" is not finite");
}

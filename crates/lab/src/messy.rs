//! Messy records: the cases of [`crate::hidden`] recorded and written the way bench records
//! come, for testing the import and the diagnosis' front end (feature `fixtures`).
//!
//! Each [`Mess`] changes one thing a user meets; the effect hidden in the actuator
//! ([`Effect`]) is still known only to the caller:
//!
//! | mess | what the record looks like | what the user passes |
//! |---|---|---|
//! | [`Mess::LeadIn`] | 0.5–3.5 s idle at 0 V, then the drive steps onto the sine at a drawn phase within ±0.4 rad of a zero crossing (the actuator rings), 0–1 s idle at the end | nothing |
//! | [`Mess::FewPeriods`] | a slow drive (0.5–1.5 Hz, as the 1 Hz bench record of issue 12), 5 to 8 periods after 0.3 s | nothing |
//! | [`Mess::Renamed`] | an unnamed index column first, then `Displacement (um)`, `Time`, `Voltage` | nothing |
//! | [`Mess::NoHeader`] | no header, no time column, `u` and `y` separated by tabs | `--columns u=1,y=2 --sample-rate HZ` |
//! | [`Mess::Metres`] | `y` in metres | `--y-unit m` |
//! | [`Mess::Whitespace`] | comment lines, columns aligned with spaces, output in nm | `--y-unit nm` |
//! | [`Mess::DriveHarmonics`] | the drive carries its own 2nd and 3rd harmonics (0.5–3 % each) | nothing |
//! | [`Mess::SecondInput`] | the actuator is also driven by a second sine (1–1.5 times the drive, at 0.3–0.45 of its frequency) that the record does not carry | nothing |
//! | [`Mess::Spreadsheet`] | a spreadsheet's export: semicolons, decimal commas, quoted names with their units after a comma (`"Time, ms"`, `"Position, µm"`), times in whole milliseconds, a sample counter first | nothing |
//! | [`Mess::Instrument`] | an instrument's (LabVIEW-style) export: a preamble of 20 lines, tabs, a `Comment` column no row fills, and the file stopping inside its last row | nothing |
//! | [`Mess::Dropouts`] | 5 to 20 samples of `y` (a quarter of them in pairs) off by 0.3 to 2 times the output's amplitude, as a laser sensor that loses its target reads | nothing |
//!
//! [`Mess::SecondInput`] is drawn on a clean actuator; its truth is that another input
//! drives the output ([`Truth::OtherInput`]). [`Mess::FewPeriods`] is drawn for clean and
//! drift cases only (a hidden harmonic needs a resonance near `n·f`, above 40 Hz).

use crate::diagnose::{Diagnosis, Kind};
use crate::hidden::{Case, CaseError, Effect};
use crate::record::{ImportOptions, LengthUnit, Record};
use boucwen_sim::Bimorph;
use std::f64::consts::TAU;
use std::fmt::Write as _;

/// What is messy about a record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mess {
    /// Idle lead-in, a step onto the drive, idle lead-out.
    LeadIn,
    /// A slow drive and few periods.
    FewPeriods,
    /// Other column names and order, an unnamed index column.
    Renamed,
    /// No header and no time column.
    NoHeader,
    /// The output in metres.
    Metres,
    /// Whitespace-separated with comments, the output in nanometres.
    Whitespace,
    /// A drive with harmonics of its own.
    DriveHarmonics,
    /// A second input the record does not carry.
    SecondInput,
    /// A sensor that loses its target for a sample or two now and then.
    Dropouts,
    /// A spreadsheet's export: semicolons, decimal commas, quoted names, whole milliseconds.
    Spreadsheet,
    /// An instrument's export: a preamble, a `Comment` column, a cut last row.
    Instrument,
}

impl Mess {
    /// Every mess.
    pub const ALL: [Mess; 11] = [
        Mess::LeadIn,
        Mess::FewPeriods,
        Mess::Renamed,
        Mess::NoHeader,
        Mess::Metres,
        Mess::Whitespace,
        Mess::DriveHarmonics,
        Mess::SecondInput,
        Mess::Dropouts,
        Mess::Spreadsheet,
        Mess::Instrument,
    ];

    /// A short name: "lead-in", "few-periods", ….
    pub fn name(self) -> &'static str {
        match self {
            Mess::LeadIn => "lead-in",
            Mess::FewPeriods => "few-periods",
            Mess::Renamed => "renamed",
            Mess::NoHeader => "no-header",
            Mess::Metres => "metres",
            Mess::Whitespace => "whitespace",
            Mess::DriveHarmonics => "drive-harmonics",
            Mess::SecondInput => "second-input",
            Mess::Dropouts => "dropouts",
            Mess::Spreadsheet => "spreadsheet",
            Mess::Instrument => "instrument",
        }
    }

    /// The effects this mess is drawn with.
    pub fn effects(self) -> &'static [Effect] {
        const ALL: [Effect; 6] = [
            Effect::OddHarmonic(3),
            Effect::OddHarmonic(5),
            Effect::EvenHarmonic(2),
            Effect::Drift,
            Effect::Clean,
            Effect::Clean,
        ];
        match self {
            Mess::FewPeriods => &[Effect::Clean, Effect::Drift],
            Mess::SecondInput => &[Effect::Clean],
            _ => &ALL,
        }
    }
}

/// What a right diagnosis of a messy record says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Truth {
    /// The hidden effect of the actuator (first finding, as in `diagnose_batch`).
    Effect(Effect),
    /// Another input drives the output.
    OtherInput,
}

/// A messy record: the file's text and what a user passes to read it.
#[derive(Clone, Debug)]
pub struct Messy {
    /// What is messy.
    pub mess: Mess,
    /// The case of the virtual bimorph behind it.
    pub case: Case,
    /// The drive frequency (Hz) of the record (the case's, or a slow one).
    pub drive_hz: f64,
    /// The file's text.
    pub text: String,
    /// The flags a user passes (as [`ImportOptions`]).
    pub opts: ImportOptions,
    /// The same as command-line flags.
    pub flags: Vec<String>,
    /// What a right diagnosis says.
    pub truth: Truth,
    /// Where the steady drive starts and ends (s), as generated.
    pub drive_s: (f64, f64),
}

/// SplitMix64 draws for the mess (apart from the case's).
struct Draw(u64);

impl Draw {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

impl Messy {
    /// Draws a messy record with `effect` hidden in the actuator, from `seed`.
    pub fn generate(mess: Mess, effect: Effect, seed: u64) -> Result<Messy, CaseError> {
        let case = Case::generate(effect, seed)?;
        let mut d = Draw(seed ^ 0xD1CE_5EED ^ (mess as u64).wrapping_mul(0x1234_5678_9ABC));
        let ts = case.scenario.sampling.ts_s;
        let a = case.amplitude_v;
        let mut f = case.drive_hz;
        let sine = |f: f64, n: usize, phase: f64| -> Vec<f64> {
            (0..n).map(|k| a * (TAU * f * k as f64 * ts + phase).sin()).collect::<Vec<f64>>()
        };
        let n_main = (case.seconds / ts).round() as usize;
        let mut truth = Truth::Effect(effect);
        let mut drive_s = (0.0, case.seconds);
        // The drive, and what the actuator sees beyond it.
        let (u, extra): (Vec<f64>, Option<Vec<f64>>) = match mess {
            Mess::LeadIn => {
                let lead = (d.uniform(0.5, 3.5) / ts).round() as usize;
                let tail = (d.uniform(0.0, 1.0) / ts).round() as usize;
                // A jump of up to 40 % of the amplitude: a larger one drives the hidden
                // stiffening polynomial far beyond the range it was shaped for.
                let phase = d.uniform(-0.4, 0.4);
                let mut u = vec![0.0; lead];
                u.extend(sine(f, n_main, phase));
                u.extend(vec![0.0; tail]);
                drive_s = (lead as f64 * ts, (lead + n_main) as f64 * ts);
                (u, None)
            }
            Mess::FewPeriods => {
                f = d.uniform(0.5, 1.5);
                let periods = d.uniform(5.0, 8.0);
                let n = ((0.3 + periods / f) / ts).round() as usize;
                drive_s = (0.0, n as f64 * ts);
                (sine(f, n, 0.0), None)
            }
            Mess::DriveHarmonics => {
                let (a2, a3) = (d.uniform(0.005, 0.03), d.uniform(0.005, 0.03));
                let (p2, p3) = (d.uniform(0.0, TAU), d.uniform(0.0, TAU));
                let u = (0..n_main)
                    .map(|k| {
                        let th = TAU * f * k as f64 * ts;
                        a * (th.sin() + a2 * (2.0 * th + p2).sin() + a3 * (3.0 * th + p3).sin())
                    })
                    .collect();
                (u, None)
            }
            Mess::SecondInput => {
                let (ratio, f2) = (d.uniform(1.0, 1.5), f * d.uniform(0.3, 0.45));
                let v = (0..n_main).map(|k| ratio * a * (TAU * f2 * k as f64 * ts + 0.7).sin()).collect();
                truth = Truth::OtherInput;
                (sine(f, n_main, 0.0), Some(v))
            }
            _ => (sine(f, n_main, 0.0), None),
        };
        let seen: Vec<f64> = match &extra {
            Some(v) => u.iter().zip(v).map(|(a, b)| a + b).collect(),
            None => u.clone(),
        };
        let mut y = Bimorph::new(&case.scenario)?.run(&seen)?;
        if mess == Mess::Dropouts {
            let (lo, hi) = crate::analysis::extent(&y);
            let amp = 0.5 * (hi - lo);
            let n = y.len();
            let count = d.uniform(5.0, 21.0) as usize;
            for _ in 0..count {
                let k = d.uniform(10.0, (n - 10) as f64) as usize;
                let h = amp * d.uniform(0.3, 2.0) * if d.uniform(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
                y[k] += h;
                if d.uniform(0.0, 1.0) < 0.25 {
                    y[k + 1] += h * d.uniform(0.8, 1.2);
                }
            }
        }
        let name = format!("{}-{}-{}", mess.name(), effect.name(), seed);
        let rec = Record::new(&name, 0.0, ts, u, y, None).map_err(CaseError::Record)?;
        let (text, opts, flags) = write(mess, &rec);
        Ok(Messy { mess, case, drive_hz: f, text, opts, flags, truth, drive_s })
    }

    /// A file name for it: "lead-in-odd3-7.csv".
    pub fn file_name(&self) -> String {
        format!("{}-{}-{}.csv", self.mess.name(), self.case.effect.name(), self.case.seed)
    }
}

/// The start of an instrument's (LabVIEW-style) file, before the channels' sample counts.
const INSTRUMENT_PREAMBLE: &str = "LabVIEW Measurement\t\nWriter_Version\t2\nReader_Version\t2\nSeparator\tTab\n\
    Decimal_Separator\t.\nMultiple_Headers\tNo\nX_Columns\tOne\nTime_Pref\tRelative\nOperator\tbench 3\n\
    Date\t2026/11/30\nTime\t14:02:11.5\n***End_of_Header***\t\n\nChannels\t2\n\
    Date\t2026/11/30\t2026/11/30\nTime\t14:02:11.5\t14:02:11.5\nX_Dimension\tTime\tTime\nX0\t0.0E+0\t0.0E+0\n";

/// The record as the mess writes it, the options and the flags to read it.
fn write(mess: Mess, r: &Record) -> (String, ImportOptions, Vec<String>) {
    let mut s = String::with_capacity(r.len() * 40);
    let mut opts = ImportOptions::default();
    let mut flags = vec![];
    let t = |k: usize| r.t0 + k as f64 * r.ts;
    match mess {
        Mess::Renamed => {
            s.push_str(",Displacement (um),Time,Voltage\n");
            for k in 0..r.len() {
                let _ = writeln!(s, "{k},{},{:.6},{}", r.y[k], t(k), r.u[k]);
            }
        }
        Mess::NoHeader => {
            for k in 0..r.len() {
                let _ = writeln!(s, "{}\t{}", r.u[k], r.y[k]);
            }
            let hz = 1.0 / r.ts;
            opts.columns = Some("u=1,y=2".parse().expect("a valid column map"));
            opts.sample_rate_hz = Some(hz);
            flags = vec!["--columns".into(), "u=1,y=2".into(), "--sample-rate".into(), format!("{hz}")];
        }
        Mess::Metres => {
            s.push_str("t,u,y\n");
            for k in 0..r.len() {
                let _ = writeln!(s, "{:.6},{},{:e}", t(k), r.u[k], r.y[k] * 1e-6);
            }
            opts.y_unit = Some(LengthUnit::M);
            flags = vec!["--y-unit".into(), "m".into()];
        }
        Mess::Whitespace => {
            s.push_str("# bench 3, laser vibrometer\n#   time        volt          disp\n");
            s.push_str("    time        volt          disp\n");
            for k in 0..r.len() {
                let _ = writeln!(s, "  {:10.6}  {:12.8}  {:14.3}", t(k), r.u[k], r.y[k] * 1e3);
            }
            opts.y_unit = Some(LengthUnit::Nm);
            flags = vec!["--y-unit".into(), "nm".into()];
        }
        Mess::Spreadsheet => {
            s.push_str("\"Sample No.\";\"Time, ms\";\"Voltage, V\";\"Position, µm\"\n");
            for k in 0..r.len() {
                let ms = format!("{:.6}", t(k) * 1e3);
                let ms = ms.trim_end_matches('0').trim_end_matches('.');
                let row = format!("{};{ms};{};{}", k + 1, r.u[k], r.y[k]);
                let _ = writeln!(s, "{}", row.replace('.', ","));
            }
        }
        Mess::Instrument => {
            s.push_str(INSTRUMENT_PREAMBLE);
            let _ = writeln!(s, "Samples\t{}\t{}\nDelta_X\t{:.6}\t{:.6}", r.len(), r.len(), r.ts, r.ts);
            s.push_str("***End_of_Header***\t\nX_Value\tVoltage\tDisplacement\tComment\n");
            for k in 0..r.len() {
                let _ = writeln!(s, "{:.6}\t{}\t{}", t(k), r.u[k], r.y[k]);
            }
            // The logger stopped inside the last row: its output and line end are missing.
            s.truncate(s.trim_end().rfind('\t').unwrap_or(s.len()));
        }
        _ => {
            s.push_str("t,u,y\n");
            for k in 0..r.len() {
                let _ = writeln!(s, "{:.6},{},{}", t(k), r.u[k], r.y[k]);
            }
        }
    }
    (s, opts, flags)
}

impl Messy {
    /// Whether a diagnosis of this record is right, by the rule of `diagnose_batch`: the
    /// first finding names the hidden effect (kind, order, frequency within 2 Hz) and the
    /// extended model lowers the held-out RMS by at least 50 %; a clean record has no
    /// finding; a record with a second input says that another input drives the output.
    pub fn is_right(&self, d: &Diagnosis) -> bool {
        let first = d.findings.first();
        let named = |kind: Kind, order: Option<u32>, freq: f64| {
            first.is_some_and(|f| f.kind == kind && f.order == order && (f.freq_hz - freq).abs() <= 2.0)
                && d.gain_pct() >= 50.0
        };
        match self.truth {
            Truth::OtherInput => first.is_some_and(|f| f.kind == Kind::OtherInput),
            Truth::Effect(Effect::Clean) => d.findings.is_empty(),
            Truth::Effect(Effect::OddHarmonic(n)) => {
                named(Kind::OddHarmonic, Some(n), f64::from(n) * self.drive_hz)
            }
            Truth::Effect(Effect::EvenHarmonic(n)) => {
                named(Kind::EvenHarmonic, Some(n), f64::from(n) * self.drive_hz)
            }
            Truth::Effect(Effect::Drift) => named(Kind::Drift, None, 0.0),
        }
    }
}

/// A record on which the paper's RLS identifies an extended model whose free run diverges:
/// the default actuator driven by a 1 V sine at 40 Hz for 15 s (the sweep's frequency where
/// the RLS model is unstable).
pub fn unstable_rls_record() -> Result<Record, CaseError> {
    let s = boucwen_sim::Scenario::default();
    let ts = s.sampling.ts_s;
    let u: Vec<f64> = (0..(15.0 / ts) as usize).map(|k| (TAU * 40.0 * k as f64 * ts).sin()).collect();
    let y = Bimorph::new(&s)?.run(&u)?;
    Record::new("rls-40hz", 0.0, ts, u, y, None).map_err(CaseError::Record)
}

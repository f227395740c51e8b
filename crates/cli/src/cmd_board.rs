//! `boucwen board`: from a measured record to a running board, and back.
//!
//! ```text
//! boucwen board excite --port P --sine F:AMP | --multisine FLO:FHI:TONES:AMP --seconds S -o rec.csv
//! boucwen board design REC.csv… -o design.json [--amplitude UM] [--harmonics auto|none|3,5]
//! boucwen board load --port P design.json
//! boucwen board run --port P --reference sine:23Hz:20um --seconds S -o run.csv
//! ```
//!
//! * `excite`: the board drives the excitation ([`boucwen_link::excitation`]) and records
//!   the response; the record (`t,u,y`) is what `identify`, `diagnose` and `design` read.
//! * `design`: the compensator from the records ([`boucwen_lab::design::board`]), written
//!   as a versioned design file; refused, with the reason, when the model cannot be
//!   inverted over the range the tracking needs.
//! * `load`: the design's parameters and drive limits to the board, read back and compared
//!   bit for bit ([`boucwen_hal::board::load`]).
//! * `run`: the board runs the loaded compensator on its own; every sample (`t,u,y,d,flags`)
//!   is written to the record the moment it is complete, one write per line, so the record
//!   keeps every sample received if the host is killed, the cable pulled or the board
//!   reset. The end prints the tracking RMSE after the transient and the samples accounted
//!   for.
//!
//! `--actuator` says what the board drives: `converters` (its DAC and ADC, a bench),
//! `on-chip` (its simulated actuator, as in QEMU) or `bimorph` (the virtual bimorph on the
//! host, over the link, in lockstep).

use anyhow::{Context, anyhow, bail};
use boucwen_core::signal::Oscillator;
use boucwen_hal::board::{
    self, Actuator, BoardSample, RunEnd, RunReport, SampleSink, StreamOptions, host_flags,
};
use boucwen_hal::hil;
use boucwen_hal::transport::{Link, SerialPort, open_serial};
use boucwen_lab::design::board::{self as board_design, DesignFile, DesignOptions, HarmonicChoice};
use boucwen_lab::record::Record;
use boucwen_link::excitation::{ExcitationParams, MAX_TONES, Tone};
use boucwen_link::message::SafetyParams;
use boucwen_sim::{Bimorph, Scenario};
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct BoardArgs {
    #[command(subcommand)]
    command: BoardCommand,
}

#[derive(clap::Subcommand)]
enum BoardCommand {
    /// The board as the data acquisition: drive a sine or a multisine, record the response
    /// (t, u, y) for identify, diagnose and design.
    Excite(ExciteArgs),
    /// Identify the actuator from records and design the board's compensator; write the
    /// design file.
    Design(DesignArgs),
    /// Send a design file's parameters to the board and verify them (read back, bit for bit).
    Load(LoadArgs),
    /// Run the loaded compensator on the board; stream its telemetry into a record.
    Run(RunArgs),
}

#[derive(clap::Args)]
struct PortArgs {
    /// The board's serial device (e.g. /dev/ttyUSB0, or QEMU's /dev/pts/N).
    #[arg(long)]
    port: String,
    /// Line speed (ignored by pseudo-terminals).
    #[arg(long, default_value_t = 460_800)]
    baud: u32,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ActuatorKind {
    /// The board's DAC and ADC (a bench).
    Converters,
    /// The board's on-chip simulated actuator (QEMU).
    OnChip,
    /// The virtual bimorph on the host, over the link, in lockstep with the board.
    Bimorph,
}

#[derive(clap::Args)]
struct ActuatorArgs {
    /// What the board drives.
    #[arg(long, value_enum, default_value = "converters")]
    actuator: ActuatorKind,
    /// Scenario of the virtual bimorph (`--actuator bimorph`); the paper's actuator if omitted.
    #[arg(long)]
    scenario: Option<PathBuf>,
}

#[derive(clap::Args)]
struct ExciteArgs {
    #[command(flatten)]
    port: PortArgs,
    #[command(flatten)]
    actuator: ActuatorArgs,
    /// A sine: frequency and amplitude, e.g. 23:1 or 23Hz:500mV.
    #[arg(long, value_name = "F:AMP", conflicts_with = "multisine")]
    sine: Option<String>,
    /// Log-spaced tones from FLO to FHI, each on whole cycles of the record, Schroeder
    /// phases, peak AMP: e.g. 2:200:6:0.2V (at most 6 tones).
    #[arg(long, value_name = "FLO:FHI:TONES:AMP")]
    multisine: Option<String>,
    /// Length of the record, s.
    #[arg(long)]
    seconds: f64,
    /// The record (t, u, y).
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    /// Sample rate, Hz (the board's period is a whole number of µs).
    #[arg(long, default_value_t = 1000.0)]
    sample_rate: f64,
    /// Raised-cosine fade-in of the excitation, s.
    #[arg(long, default_value_t = 0.5)]
    fade: f64,
    /// The board's drive limits for the excitation, V (LO:HI); the board's own if omitted.
    #[arg(long, value_name = "LO:HI")]
    drive_limits: Option<String>,
    /// The board declares the host lost after this long without a frame, ms; the board's own
    /// if omitted (with --drive-limits, the default 250 ms).
    #[arg(long)]
    host_timeout_ms: Option<u32>,
    /// End with one JSON line.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct DesignArgs {
    /// The records (t, u, y): at least one sine at the frequency to track; a broadband one
    /// (multisine) sets the structure.
    #[arg(required = true)]
    records: Vec<PathBuf>,
    /// The design file to write.
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    /// Frequency to track, Hz (default: the first sine record's).
    #[arg(long)]
    freq: Option<f64>,
    /// Reference amplitude, µm (default: eq. 25 on the sine record).
    #[arg(long)]
    amplitude: Option<f64>,
    /// Cancelled harmonics: auto (the one that stands out under u_f), none, or orders (3,5).
    #[arg(long, default_value = "auto")]
    harmonics: String,
    /// Drive limits, V (LO:HI; also the compensator's range).
    #[arg(long, value_name = "LO:HI", default_value = "-10:10")]
    drive_limits: String,
    /// Slew of the ramp to 0 V in the safe state, V/s.
    #[arg(long, default_value_t = 100.0)]
    slew: f64,
    /// The board declares the host lost after this long without a frame, ms.
    #[arg(long, default_value_t = 250)]
    host_timeout_ms: u32,
    /// Raised-cosine fade-in of the reference, s.
    #[arg(long, default_value_t = 0.5)]
    fade: f64,
    /// Length of the predicted run on the model, s (the RMSE after its first fifth).
    #[arg(long, default_value_t = board_design::PREDICT_SECONDS)]
    predict_seconds: f64,
    /// End with one JSON line.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct LoadArgs {
    #[command(flatten)]
    port: PortArgs,
    /// The design file.
    design: PathBuf,
}

#[derive(clap::Args)]
struct RunArgs {
    #[command(flatten)]
    port: PortArgs,
    #[command(flatten)]
    actuator: ActuatorArgs,
    /// The reference: sine:F:AMP, e.g. sine:23Hz:20um (the frequency must be the design's).
    #[arg(long)]
    reference: String,
    /// Length of the run, s.
    #[arg(long)]
    seconds: f64,
    /// The record (t, u, y, d, flags), written as the samples arrive.
    #[arg(short = 'o', long = "out")]
    out: PathBuf,
    /// End with one JSON line.
    #[arg(long)]
    json: bool,
}

pub fn run(a: BoardArgs) -> anyhow::Result<()> {
    match a.command {
        BoardCommand::Excite(a) => excite(a),
        BoardCommand::Design(a) => design(a),
        BoardCommand::Load(a) => load(a),
        BoardCommand::Run(a) => run_board(a),
    }
}

/// A number with an optional unit from `units` (name, scale); the first unit is the default.
fn quantity(text: &str, what: &str, units: &[(&str, f64)]) -> anyhow::Result<f64> {
    let t = text.trim();
    let (num, scale) = units
        .iter()
        .filter(|(u, _)| !u.is_empty())
        .find_map(|&(u, s)| t.strip_suffix(u).map(|n| (n.trim(), s)))
        .unwrap_or((t, 1.0));
    let v: f64 = num.parse().map_err(|_| {
        let shown: String = text.chars().take(40).collect();
        let names: Vec<&str> = units.iter().map(|u| u.0).filter(|u| !u.is_empty()).collect();
        anyhow!("{what} {shown:?}: expected a number, optionally in {}", names.join(", "))
    })?;
    let v = v * scale;
    if !v.is_finite() {
        bail!("{what} {text:?}: not a finite number");
    }
    Ok(v)
}

const HZ: &[(&str, f64)] = &[("kHz", 1e3), ("Hz", 1.0)];
const VOLTS: &[(&str, f64)] = &[("mV", 1e-3), ("V", 1.0)];
const MICRONS: &[(&str, f64)] = &[("nm", 1e-3), ("um", 1.0), ("µm", 1.0), ("mm", 1e3)];

/// `LO:HI` volts.
fn drive_limits(text: &str, flag: &str) -> anyhow::Result<(f32, f32)> {
    let Some((lo, hi)) = text.split_once(':') else {
        bail!("{flag} {text:?}: expected LO:HI in V, e.g. -10:10");
    };
    let (lo, hi) = (quantity(lo, flag, VOLTS)?, quantity(hi, flag, VOLTS)?);
    Ok((lo as f32, hi as f32))
}

fn open(p: &PortArgs) -> anyhow::Result<Link<SerialPort>> {
    Ok(Link::new(open_serial(&p.port, p.baud)?))
}

fn scenario(a: &ActuatorArgs) -> anyhow::Result<Scenario> {
    Ok(match &a.scenario {
        Some(p) => Scenario::from_path(p)?,
        None => Scenario::default(),
    })
}

/// The record being written as the samples arrive: created at the first sample (so a run
/// refused before it starts leaves an existing file alone), each line written with one
/// `write` call straight to the file (nothing waits in a buffer).
struct StreamedRecord {
    path: PathBuf,
    header: String,
    file: Option<File>,
    ts: f64,
    decimals: usize,
    with_reference: bool,
    /// What arrived: `(y, d)` per sample, for the summary.
    kept: Vec<(Option<f64>, Option<f32>)>,
    line: String,
}

impl StreamedRecord {
    fn new(path: &Path, comments: &[String], ts: f64, with_reference: bool) -> Self {
        let mut header: String = comments.iter().map(|c| format!("# {c}\n")).collect();
        header.push_str(if with_reference { "t,u,y,d,flags\n" } else { "t,u,y\n" });
        Self {
            path: path.to_path_buf(),
            header,
            file: None,
            ts,
            // Time rounded to 1e-9·Ts or finer, as the project's records are written.
            decimals: ((-ts.log10()).ceil() + 9.0).clamp(0.0, 20.0) as usize,
            with_reference,
            kept: Vec::new(),
            line: String::new(),
        }
    }
}

impl SampleSink for StreamedRecord {
    fn sample(&mut self, s: &BoardSample) -> std::io::Result<()> {
        use std::fmt::Write as _;
        if self.file.is_none() {
            let mut f = File::create(&self.path)?;
            f.write_all(self.header.as_bytes())?;
            self.file = Some(f);
        }
        self.line.clear();
        let t = format!("{:.*}", self.decimals, s.k as f64 * self.ts);
        let t = if t.contains('.') { t.trim_end_matches('0').trim_end_matches('.') } else { &t };
        let num = |v: Option<f64>| v.map_or("nan".to_string(), |x| x.to_string());
        let u = (s.flags & host_flags::LOST == 0).then_some(s.u_v as f64);
        let _ = write!(self.line, "{t},{},{}", num(u), num(s.y_um));
        if self.with_reference {
            let _ = write!(self.line, ",{},{}", num(s.d_um.map(f64::from)), s.flags);
        }
        self.line.push('\n');
        if let Some(f) = &mut self.file {
            f.write_all(self.line.as_bytes())?;
        }
        self.kept.push((s.y_um, s.d_um));
        Ok(())
    }
}

const FLAGS_DOC: &str = "flags: 1 compensator saturated, 2 inverse guarded, 4 ramp to 0 V, 8 no measurement, 16 clamped to the drive limits, 64 lost on the link, 128 input held by the host";

/// Runs `f` with the actuator the board drives.
fn with_actuator<T>(
    a: &ActuatorArgs,
    ts: f64,
    f: impl FnOnce(Actuator<'_>) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    match a.actuator {
        ActuatorKind::Converters => f(Actuator::Converters),
        ActuatorKind::OnChip => f(Actuator::OnChip),
        ActuatorKind::Bimorph => {
            let s = scenario(a)?;
            if ((s.sampling.ts_s - ts) / ts).abs() > 1e-9 {
                bail!(
                    "the virtual bimorph samples every {} s, the board every {ts} s: give a scenario at the board's rate",
                    s.sampling.ts_s
                );
            }
            let mut b = Bimorph::new(&s)?;
            let mut plant =
                |u: f64| -> Result<f64, Box<dyn std::error::Error + Send + Sync>> { Ok(b.step(u)?) };
            f(Actuator::Host(&mut plant))
        }
    }
}

fn actuator_name(a: &ActuatorArgs) -> &'static str {
    match a.actuator {
        ActuatorKind::Converters => "the board's converters",
        ActuatorKind::OnChip => "the board's on-chip simulated actuator",
        ActuatorKind::Bimorph => "the virtual bimorph over the link",
    }
}

fn samples_of(seconds: f64, ts: f64) -> anyhow::Result<u32> {
    let n = seconds / ts;
    if !(seconds.is_finite() && (2.0..1e9).contains(&n)) {
        bail!("--seconds {seconds}: at least two samples ({} s) and at most 1e9", 2.0 * ts);
    }
    Ok(n.round() as u32)
}

/// The excitation of `--sine` or `--multisine` over `n` samples at `ts`.
fn excitation(a: &ExciteArgs, ts: f64, period_us: u32, n: u32) -> anyhow::Result<ExcitationParams> {
    let nyquist = 0.5 / ts;
    let freq = |text: &str| -> anyhow::Result<f64> {
        let f = quantity(text, "frequency", HZ)?;
        if !(f > 0.0 && f < nyquist) {
            bail!("frequency {text:?}: above 0 and below the Nyquist frequency ({nyquist} Hz)");
        }
        Ok(f)
    };
    let tone = |f: f64, amplitude_v: f64, phase_turns: f64| -> anyhow::Result<Tone> {
        Ok(Tone {
            drive: Oscillator::new(f, ts)?,
            amplitude_v: amplitude_v as f32,
            phase: (phase_turns.rem_euclid(1.0) * 4_294_967_296.0) as u64 as u32,
        })
    };
    let tones: Vec<Tone> = match (&a.sine, &a.multisine) {
        (Some(s), None) => {
            let Some((f, amp)) = s.split_once(':') else {
                bail!("--sine {s:?}: expected F:AMP, e.g. 23Hz:1V");
            };
            vec![tone(freq(f)?, quantity(amp, "--sine amplitude", VOLTS)?, 0.0)?]
        }
        (None, Some(m)) => {
            let parts: Vec<&str> = m.split(':').collect();
            let [lo, hi, count, amp] = parts[..] else {
                bail!("--multisine {m:?}: expected FLO:FHI:TONES:AMP, e.g. 2:200:6:0.2V");
            };
            let (lo, hi) = (freq(lo)?, freq(hi)?);
            let count: usize = count.trim().parse().ok().filter(|c| (2..=MAX_TONES).contains(c)).ok_or_else(
                || anyhow!("--multisine {m:?}: TONES must be 2 to {MAX_TONES} (the board sums at most {MAX_TONES})"),
            )?;
            if lo >= hi {
                bail!("--multisine {m:?}: FLO must be below FHI");
            }
            let peak = quantity(amp, "--multisine amplitude", VOLTS)?;
            // Log-spaced, each on a whole number of cycles of the record.
            let len_s = n as f64 * ts;
            let mut fs: Vec<f64> = (0..count)
                .map(|i| {
                    let f = lo * (hi / lo).powf(i as f64 / (count - 1) as f64);
                    (f * len_s).round().max(1.0) / len_s
                })
                .collect();
            fs.dedup_by(|x, y| (*x - *y).abs() < 0.5 / len_s);
            if fs.len() < count {
                bail!(
                    "--multisine {m:?}: tones closer than the record resolves; a longer record or a wider band"
                );
            }
            let phases: Vec<f64> = (0..count).map(|i| -0.5 * (i * (i + 1)) as f64 / count as f64).collect();
            // Scaled so the sum peaks at AMP over the record.
            let sum_peak = (0..n)
                .map(|k| {
                    let t = k as f64 * ts;
                    fs.iter()
                        .zip(&phases)
                        .map(|(f, p)| (std::f64::consts::TAU * (f * t + p)).sin())
                        .sum::<f64>()
                        .abs()
                })
                .fold(0.0f64, f64::max);
            let a = peak / sum_peak.max(1e-12);
            fs.iter().zip(&phases).map(|(&f, &p)| tone(f, a, p)).collect::<anyhow::Result<_>>()?
        }
        _ => bail!("give --sine F:AMP or --multisine FLO:FHI:TONES:AMP"),
    };
    if !(a.fade.is_finite() && a.fade >= 0.0 && a.fade <= 60.0) {
        bail!("--fade {}: 0 to 60 s", a.fade);
    }
    let p = ExcitationParams {
        sample_period_us: period_us,
        fade_samples: (a.fade / ts).round() as u32,
        tones: tones.into_iter().collect(),
    };
    p.validate().map_err(|e| anyhow!("excitation: {e}"))?;
    Ok(p)
}

fn excite(a: ExciteArgs) -> anyhow::Result<()> {
    let rate = a.sample_rate;
    let period = 1e6 / rate;
    if !(rate.is_finite() && (period - period.round()).abs() < 1e-6 && (100.0..=100_000.0).contains(&period))
    {
        bail!("--sample-rate {rate}: a period of a whole number of µs from 100 to 100000");
    }
    let (period_us, ts) = (period.round() as u32, period.round() * 1e-6);
    let n = samples_of(a.seconds, ts)?;
    let e = excitation(&a, ts, period_us, n)?;
    let safety = match (&a.drive_limits, a.host_timeout_ms) {
        (None, None) => None,
        (limits, timeout) => {
            let mut s = SafetyParams::DEFAULT;
            if let Some(t) = limits {
                (s.u_min, s.u_max) = drive_limits(t, "--drive-limits")?;
            }
            s.host_timeout_ms = timeout.unwrap_or(s.host_timeout_ms);
            Some(s)
        }
    };
    let what = match (&a.sine, &a.multisine) {
        (Some(s), _) => format!("sine {s}"),
        (_, Some(m)) => format!("multisine {m}"),
        _ => unreachable!("checked by excitation()"),
    };
    let comments = vec![
        format!("boucwen board excite: {what}, {n} samples at {ts} s, {}", actuator_name(&a.actuator)),
        format!("board {}: t (s), u (V, as applied), y (µm)", a.port.port),
    ];
    let mut rec = StreamedRecord::new(&a.out, &comments, ts, false);
    let mut link = open(&a.port)?;
    let opts = StreamOptions::default();
    let report = with_actuator(&a.actuator, ts, |act| {
        Ok(board::excite(&mut link, &e, safety.as_ref(), act, n, &mut rec, &opts)?)
    })
    .with_context(|| a.port.port.clone())?;
    let incomplete = report.samples_incomplete;
    println!(
        "{}: {} of {} samples recorded ({}), {} clamped to the drive limits",
        a.out.display(),
        report.samples_logged,
        n,
        report.end,
        report.limited
    );
    if a.json {
        println!(
            "{}",
            serde_json::json!({
                "samples_expected": report.samples_expected,
                "samples_logged": report.samples_logged,
                "samples_incomplete": incomplete,
                "limited": report.limited,
                "board_tx_dropped": report.tx_dropped,
                "end": report.end.to_string(),
            })
        );
    }
    finish(&report, &a.out)
}

/// The run's verdict: non-zero unless every sample arrived complete.
fn finish(report: &RunReport, out: &Path) -> anyhow::Result<()> {
    if let Some(n @ 1..) = report.tx_dropped {
        eprintln!(
            "boucwen: the board dropped {n} frames: its transmit queue was full (the line or the host too slow)"
        );
    }
    if report.end != RunEnd::Complete {
        bail!("{}; {} holds the {} samples received", report.end, out.display(), report.samples_logged);
    }
    if report.samples_logged != report.samples_expected {
        bail!(
            "{} of {} samples arrived complete ({} lost or without a measurement; flagged in {})",
            report.samples_logged,
            report.samples_expected,
            report.samples_incomplete,
            out.display()
        );
    }
    Ok(())
}

fn harmonic_choice(text: &str) -> anyhow::Result<HarmonicChoice> {
    Ok(match text.trim() {
        "auto" => HarmonicChoice::Auto,
        "none" => HarmonicChoice::None,
        list => HarmonicChoice::Orders(
            list.split(',')
                .map(|o| o.trim().parse::<u32>())
                .collect::<Result<_, _>>()
                .map_err(|_| anyhow!("--harmonics {text:?}: auto, none, or orders like 3,5"))?,
        ),
    })
}

fn design(a: DesignArgs) -> anyhow::Result<()> {
    let (u_min, u_max) = drive_limits(&a.drive_limits, "--drive-limits")?;
    if !a.slew.is_finite() {
        bail!("--slew {}: not a finite number", a.slew);
    }
    let opts = DesignOptions {
        freq_hz: a.freq,
        amplitude_um: a.amplitude,
        harmonics: harmonic_choice(&a.harmonics)?,
        safety: SafetyParams {
            u_min,
            u_max,
            slew_v_per_s: a.slew as f32,
            host_timeout_ms: a.host_timeout_ms,
        },
        fade_s: a.fade,
        predict_seconds: a.predict_seconds,
    };
    let records: Vec<Record> = a.records.iter().map(Record::read).collect::<Result<_, _>>()?;
    let d = board_design::design_from_records(&records, &opts)?;
    d.write(&a.out)?;
    print!("{}", summary(&d));
    println!("wrote {}", a.out.display());
    if a.json {
        println!(
            "{}",
            serde_json::json!({
                "design_rmse_um": d.prediction.design_rmse_um,
                "uf_rmse_um": d.prediction.uf_rmse_um,
                "fit_pct": d.model.fit_pct,
                "amplitude_um": d.reference.amplitude_um,
                "freq_hz": d.reference.freq_hz,
                "harmonics": d.harmonics_cancelled.iter().map(|h| h.order).collect::<Vec<_>>(),
            })
        );
    }
    Ok(())
}

fn summary(d: &DesignFile) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    for r in &d.sources {
        let pct = r.fit_pct.map_or(String::new(), |p| format!(", fit {p:.1} %"));
        let _ = writeln!(s, "{}: {} samples, {} ({}){pct}", r.path, r.samples, r.drive, r.role);
    }
    let m = &d.model;
    let _ = writeln!(
        s,
        "inverted: {}: fit {:.2} % held out ({:.4} µm RMS), A1 = {:.4} µm/V{}, input delay {:.3} samples (the board previews the reference by it), invertible over {:.3}..{:.3} V (slope ≥ {:.2}·A1)",
        m.inverted,
        m.fit_pct,
        m.held_out_rms_um,
        m.a1,
        m.resonance_hz.map_or(String::new(), |r| format!(", resonance {r:.1} Hz")),
        m.delay_samples,
        m.checked_u_v[0],
        m.checked_u_v[1],
        m.min_slope_rel
    );
    let found: Vec<String> = d
        .harmonics_found
        .iter()
        .map(|h| format!("{} ({:.1} % of the fundamental)", h.order, h.amplitude))
        .collect();
    let _ = writeln!(
        s,
        "odd harmonics in the output: {}",
        if found.is_empty() { "none above 2 %".into() } else { found.join(", ") }
    );
    let r = &d.reference;
    let _ = writeln!(
        s,
        "reference: {} Hz, {:.3} µm ({}), fade-in {} s",
        r.freq_hz, r.amplitude_um, r.amplitude_source, r.fade_s
    );
    if d.harmonics_cancelled.is_empty() {
        let _ = writeln!(s, "cancelled: none (no odd harmonic stands out under u_f): u_f alone");
    }
    for h in &d.harmonics_cancelled {
        let _ = writeln!(
            s,
            "cancelled: harmonic {} at {:.1} Hz ({:.3} µm under u_f), response {:.2} µm/V at {:.1}°",
            h.order,
            h.freq_hz,
            h.amplitude,
            h.gain_um_per_v.unwrap_or(f64::NAN),
            h.phase_deg.unwrap_or(f64::NAN)
        );
    }
    let p = &d.prediction;
    let _ = writeln!(
        s,
        "predicted on the {} model (fit {:.2} %): tracking RMSE {:.4} µm (u_f alone {:.4} µm) after {} s of {} s",
        p.model, p.fit_pct, p.design_rmse_um, p.uf_rmse_um, p.settle_s, p.seconds
    );
    s
}

fn load(a: LoadArgs) -> anyhow::Result<()> {
    let d = DesignFile::read(&a.design)?;
    let (params, safety) = d.board_params().map_err(|e| anyhow!("{}: board: {e}", a.design.display()))?;
    let mut link = open(&a.port)?;
    let r = board::load(&mut link, &safety, &params, &StreamOptions::default())
        .with_context(|| a.port.port.clone())?;
    println!(
        "{}: loaded {} ({} Hz, {:.3} µm, {} harmonic(s) cancelled, drive limits {}..{} V); read back, {} fields equal bit for bit",
        a.port.port,
        a.design.display(),
        d.board.freq_hz,
        d.board.amplitude_um,
        d.board.harmonics.len(),
        safety.u_min,
        safety.u_max,
        r.fields_compared
    );
    Ok(())
}

/// `sine:F:AMP`.
fn reference(text: &str) -> anyhow::Result<(f64, f64)> {
    let parts: Vec<&str> = text.split(':').collect();
    let ["sine", f, amp] = parts[..] else {
        let shown: String = text.chars().take(40).collect();
        bail!("--reference {shown:?}: expected sine:F:AMP, e.g. sine:23Hz:20um");
    };
    let f = quantity(f, "--reference frequency", HZ)?;
    let amp = quantity(amp, "--reference amplitude", MICRONS)?;
    if !(f > 0.0 && amp > 0.0) {
        bail!("--reference {text:?}: frequency and amplitude above 0");
    }
    Ok((f, amp))
}

fn run_board(a: RunArgs) -> anyhow::Result<()> {
    let (freq, amp) = reference(&a.reference)?;
    let mut link = open(&a.port)?;
    let opts = StreamOptions::default();
    let port = a.port.port.clone();
    let loaded = board::read_params(&mut link, &opts).with_context(|| port.clone())?;
    let Some(c) = &loaded.controller else {
        bail!("{port}: the board holds no compensator: load a design first (boucwen board load)");
    };
    let ts = c.sample_period_us as f64 * 1e-6;
    let n = samples_of(a.seconds, ts)?;
    let comments = vec![
        format!(
            "boucwen board run: reference {}, {n} samples at {ts} s, {}",
            a.reference,
            actuator_name(&a.actuator)
        ),
        format!("board {port}: t (s), u (V, as applied), y (µm), d (µm, the reference), flags"),
        FLAGS_DOC.to_string(),
    ];
    let mut rec = StreamedRecord::new(&a.out, &comments, ts, true);
    let report =
        with_actuator(&a.actuator, ts, |act| Ok(board::run(&mut link, freq, amp, act, n, &mut rec, &opts)?))
            .with_context(|| port.clone())?;
    let params = report.params.clone().ok_or_else(|| anyhow!("{port}: the run reported no parameters"))?;
    let settle = board_design::settle_samples(n, params.fade_samples) as usize;
    let tail: Vec<f64> = rec.kept[settle.min(rec.kept.len())..]
        .iter()
        .filter_map(|(y, d)| Some(y.as_ref()? - *d.as_ref()? as f64))
        .collect();
    let rmse = (tail.iter().map(|e| e * e).sum::<f64>() / tail.len().max(1) as f64).sqrt();
    let inprocess = match a.actuator.actuator {
        ActuatorKind::Bimorph => {
            let mut b = Bimorph::new(&scenario(&a.actuator)?)?;
            Some(hil::without_link(&mut b, &params, n, settle as u32)?)
        }
        _ => None,
    };
    println!(
        "{}: {} of {} samples recorded complete ({} incomplete), run {}",
        a.out.display(),
        report.samples_logged,
        n,
        report.samples_incomplete,
        report.end
    );
    println!(
        "tracking RMSE after {:.3} s: {rmse:.4} µm over {} samples; {} saturated, {} clamped to the drive limits",
        settle as f64 * ts,
        tail.len(),
        report.saturated,
        report.limited
    );
    if let Some(x) = inprocess {
        println!("the same compensator on the virtual bimorph in-process: {x:.4} µm");
    }
    if let Some(s) = &report.safe {
        println!(
            "after the run: the drive ramped to 0 V in {} steps, {:.0} ms after the host's last frame",
            s.ramp_steps, s.board_ms
        );
    }
    if a.json {
        println!(
            "{}",
            serde_json::json!({
                "samples_expected": report.samples_expected,
                "samples_logged": report.samples_logged,
                "samples_incomplete": report.samples_incomplete,
                "rmse_um": rmse,
                "settle_s": settle as f64 * ts,
                "inprocess_rmse_um": inprocess,
                "saturated": report.saturated,
                "limited": report.limited,
                "safe_state_ms": report.safe.map(|s| s.board_ms),
                "board_tx_dropped": report.tx_dropped,
                "end": report.end.to_string(),
            })
        );
    }
    finish(&report, &a.out)
}

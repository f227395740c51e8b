//! The board as the host uses it on a bench: load a design and verify it, run the board's
//! own loop with its telemetry streamed into a record as it arrives, and excite the
//! actuator with the board as the data acquisition.
//!
//! * [`load`]: sends the drive limits ([`SafetyParams`]) and the compensator
//!   ([`ControllerParams`]), reads them back ([`Message::GetParams`]) and compares them with
//!   what was sent bit for bit; a difference names the first field that differs.
//! * [`run`]: the board runs the loaded compensator on its actuator; the reference's
//!   amplitude may be set for the run (its frequency is the design's: the cancelled
//!   harmonics' responses belong to it). Every sample goes to a [`SampleSink`] the moment
//!   its last part arrives.
//! * [`excite`]: the board drives an [`ExcitationParams`] (a sine or a multisine) instead
//!   of its controller and reports the response, sample by sample, the same way.
//!
//! ## Actuators
//! | [`Actuator`] | board mode | the samples |
//! |---|---|---|
//! | [`Actuator::Converters`] | [`Mode::Local`]: the board's DAC and ADC | `Telemetry{k, u[k], y[k-1]}` |
//! | [`Actuator::OnChip`] | [`Mode::Simulated`]: the on-chip simulated actuator (QEMU's stand-in) | `Telemetry{k, u[k], y[k-1]}` |
//! | [`Actuator::Host`] | [`Mode::Lockstep`]: the host's plant over the link (the virtual bimorph) | `Command{k, u[k]}`, the host applies it and answers `Measurement{k, y[k]}` |
//!
//! On the board's own actuator the measurement of sample `k` arrives with the telemetry of
//! sample `k + 1`, so the board runs one tick more than the samples logged and sample `k`
//! is complete when the telemetry of `k + 1` arrives. The host keeps the board from
//! declaring it lost with a [`Message::GetStatus`] every [`KEEPALIVE`], and no more often
//! than every [`KEEPALIVE_SAMPLES`] of the board's samples while its telemetry comes (the
//! answer also shows the board's progress).
//!
//! ## What a record keeps when things go wrong
//! A sample goes to the sink as soon as it is complete, and the sink writes it through
//! (the CLI's writes each line with one `write` call), so a host that is killed, a cable
//! that is pulled or a board that resets leaves a record of every sample received until
//! then. A telemetry frame that is lost leaves its sample's drive or measurement unknown:
//! the sample is still written, flagged [`host_flags::LOST`], so the record's time stays
//! uniform. The run ends when the board reports the run done, enters its safe state, or
//! falls silent for [`StreamOptions::silence`]; [`RunReport::end`] says which.
//!
//! After a complete run the host stays silent and watches the board take its drive to 0 V
//! (the lost-host timeout of its [`SafetyParams`], then the ramp), reported in
//! [`RunReport::safe`].

use crate::transport::{Link, Port, TransportError};
use boucwen_link::device::Reference;
use boucwen_link::excitation::{Active, BoardParams, ExcitationParams};
use boucwen_link::message::{
    ControllerParams, Fault, FaultCode, Message, Mode, RunState, SafeReason, SafetyParams, Status,
    command_flags,
};
use std::fmt;
use std::io;
use std::time::{Duration, Instant};

/// How often the host shows the board it is there during a run on the board's actuator:
/// at most once in this much of the host's time, and, while telemetry comes, once in
/// [`KEEPALIVE_SAMPLES`] of the board's.
pub const KEEPALIVE: Duration = Duration::from_millis(50);

/// The board's samples between two keepalives while its telemetry comes (50 ms at 1 kHz).
/// Each keepalive's answer takes the line's time of a few telemetry frames; paced by the
/// host's clock alone, a board whose clock runs slower than the host's (an emulator on a
/// loaded machine) would get more of them per second of its own than its line can answer
/// beside the telemetry, and drop telemetry frames (61–161 of 5,000 per run in QEMU with
/// the machine's cores otherwise busy).
pub const KEEPALIVE_SAMPLES: u32 = 50;

/// Flags the host adds to a sample's board flags ([`command_flags`] use the low five bits).
pub mod host_flags {
    /// The sample's telemetry (or command) never arrived: its values are not known.
    pub const LOST: u8 = 0x40;
    /// The host's plant held the last input at this sample (its command was lost).
    pub const HELD: u8 = 0x80;
}

/// One sample of a run, as logged.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoardSample {
    /// Sample index from the run's start.
    pub k: u32,
    /// The drive applied, V (NaN when [`host_flags::LOST`]).
    pub u_v: f32,
    /// The measurement, µm (`None` when there is none: the sensor had none, or it was lost).
    pub y_um: Option<f64>,
    /// The reference, µm (a control run; `None` for an excitation).
    pub d_um: Option<f32>,
    /// The board's [`command_flags`] and the host's [`host_flags`].
    pub flags: u8,
}

/// Where the samples of a run go, as they arrive.
pub trait SampleSink {
    /// Takes one sample (in order of `k`, each once).
    fn sample(&mut self, s: &BoardSample) -> io::Result<()>;
}

impl<F: FnMut(&BoardSample) -> io::Result<()>> SampleSink for F {
    fn sample(&mut self, s: &BoardSample) -> io::Result<()> {
        self(s)
    }
}

/// The plant of [`Actuator::Host`]: `u` (V) in, `y` (µm) out.
pub type HostPlant<'a> = &'a mut dyn FnMut(f64) -> Result<f64, Box<dyn std::error::Error + Send + Sync>>;

/// What the board drives.
pub enum Actuator<'a> {
    /// The board's converters (its DAC and ADC).
    Converters,
    /// The board's on-chip simulated actuator (its plant parameters set beforehand).
    OnChip,
    /// A plant on the host, over the link, in lockstep with the board.
    Host(HostPlant<'a>),
}

impl Actuator<'_> {
    fn mode(&self) -> Mode {
        match self {
            Actuator::Converters => Mode::Local,
            Actuator::OnChip => Mode::Simulated,
            Actuator::Host(_) => Mode::Lockstep,
        }
    }
}

/// Timeouts of the exchanges.
#[derive(Clone, Copy, Debug)]
pub struct StreamOptions {
    /// Wait for an answer to a request (three attempts).
    pub reply: Duration,
    /// No frame at all for this long during a run: the board is gone (reset, cable).
    pub silence: Duration,
    /// How long a configuration request may be refused because the drive is still on its
    /// way to 0 V before giving up.
    pub busy: Duration,
    /// After a complete run, how long to watch for the ramp to 0 V (0: do not watch).
    pub watch_safe: Duration,
}

impl Default for StreamOptions {
    /// 0.5 s per request, 2 s of silence, 5 s of a busy board, 5 s for the safe state.
    fn default() -> Self {
        Self {
            reply: Duration::from_millis(500),
            silence: Duration::from_secs(2),
            busy: Duration::from_secs(5),
            watch_safe: Duration::from_secs(5),
        }
    }
}

/// Why the board could not be used.
#[derive(Debug)]
pub enum BoardError {
    /// The link failed.
    Link(TransportError),
    /// The board did not answer a request.
    NoAnswer {
        /// The port.
        port: String,
        /// What was asked.
        request: &'static str,
    },
    /// The board refused a request.
    Refused {
        /// What was asked.
        request: &'static str,
        /// The board's fault.
        fault: Fault,
    },
    /// What the board read back differs from what was sent.
    Mismatch {
        /// The first field that differs.
        field: &'static str,
        /// Sent.
        sent: String,
        /// Read back.
        board: String,
    },
    /// The board holds no compensator (load a design first) or runs something else.
    NotLoaded(String),
    /// The reference asked for does not fit the loaded design.
    Reference(String),
    /// The parameters are not valid (checked before sending).
    Params(boucwen_core::Error),
    /// The sink failed (e.g. the record's disk is full); the run was stopped.
    Sink(io::Error),
    /// The host's plant failed; the run was stopped.
    Plant {
        /// The sample.
        k: u32,
        /// The plant's error.
        error: Box<dyn std::error::Error + Send + Sync>,
    },
    /// Fewer than 2 samples asked for, or more than a run can hold.
    Samples(u64),
}

impl fmt::Display for BoardError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BoardError::Link(e) => write!(f, "{e}"),
            BoardError::NoAnswer { port, request } => {
                write!(f, "{port}: no answer from the board to {request}")
            }
            BoardError::Refused { request, fault } => {
                write!(f, "the board refused {request}: {:?}: {}", fault.code, fault.text)
            }
            BoardError::Mismatch { field, sent, board } => {
                write!(f, "read back: {field} is {board} on the board, {sent} sent")
            }
            BoardError::NotLoaded(what) => f.write_str(what),
            BoardError::Reference(what) => f.write_str(what),
            BoardError::Params(e) => write!(f, "parameters: {e}"),
            BoardError::Sink(e) => write!(f, "writing the record: {e}"),
            BoardError::Plant { k, error } => write!(f, "the host's plant at sample {k}: {error}"),
            BoardError::Samples(n) => write!(f, "{n} samples: a run logs 2 to {} samples", u32::MAX - 1),
        }
    }
}

impl std::error::Error for BoardError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            BoardError::Link(e) => Some(e),
            BoardError::Params(e) => Some(e),
            BoardError::Sink(e) => Some(e),
            BoardError::Plant { error, .. } => Some(error.as_ref()),
            _ => None,
        }
    }
}

impl From<TransportError> for BoardError {
    fn from(e: TransportError) -> Self {
        BoardError::Link(e)
    }
}

/// Drops half-received frames on both sides and ends any run (answered by `Status`).
fn connect<P: Port>(link: &mut Link<P>, opts: &StreamOptions) -> Result<Status, BoardError> {
    link.flush_peer()?;
    link.discard_input();
    link.request(&Message::Stop, 3, opts.reply, |_, m| match m {
        Message::Status(s) => Some(*s),
        _ => None,
    })?
    .ok_or_else(|| BoardError::NoAnswer { port: link.port_name(), request: "Stop" })
}

/// Sends `msg` and waits for its `Ack`; a board still ramping its drive to 0 V answers
/// `Busy`, and the request is repeated until [`StreamOptions::busy`] has passed.
fn configure<P: Port>(
    link: &mut Link<P>,
    msg: &Message,
    request: &'static str,
    opts: &StreamOptions,
) -> Result<(), BoardError> {
    let want = msg.kind();
    let until = Instant::now() + opts.busy;
    loop {
        let answer = link.request(msg, 3, opts.reply, |seq, m| match m {
            Message::Ack { kind, seq: s } if *kind == want && *s == seq => Some(Ok(())),
            Message::Fault(f) if f.seq == seq => Some(Err(f.clone())),
            _ => None,
        })?;
        match answer {
            Some(Ok(())) => return Ok(()),
            Some(Err(fault)) if fault.code == FaultCode::Busy && Instant::now() < until => {
                std::thread::sleep(Duration::from_millis(50));
            }
            Some(Err(fault)) => return Err(BoardError::Refused { request, fault }),
            None => return Err(BoardError::NoAnswer { port: link.port_name(), request }),
        }
    }
}

/// The parameters in force on the board.
pub fn read_params<P: Port>(link: &mut Link<P>, opts: &StreamOptions) -> Result<BoardParams, BoardError> {
    link.request(&Message::GetParams, 3, opts.reply, |_, m| match m {
        Message::Params(p) => Some(p.clone()),
        _ => None,
    })?
    .ok_or_else(|| BoardError::NoAnswer { port: link.port_name(), request: "GetParams" })
}

/// Every field of a [`ControllerParams`] as it goes on the wire: its name and its bits.
fn controller_fields(p: &ControllerParams) -> Vec<(&'static str, u64)> {
    let b = |v: f32| u64::from(v.to_bits());
    let m = &p.model;
    let mut v = vec![
        ("model A1", b(m.bw.a1)),
        ("model A", b(m.bw.a)),
        ("model A0", b(m.bw.a0)),
        ("model gamma", b(m.bw.gamma)),
        ("model beta", b(m.bw.beta)),
        ("model a1", b(m.ar[0])),
        ("model a2", b(m.ar[1])),
        ("model a3", b(m.ar[2])),
        ("drive frequency (phase increment)", p.drive.increment()),
        ("sample period", u64::from(p.sample_period_us)),
        ("reference amplitude", b(p.amplitude_um)),
        ("fade-in", u64::from(p.fade_samples)),
        ("harmonic count", p.harmonics.len() as u64),
    ];
    const NAMES: [(&str, &str, &str); 2] = [
        ("harmonic 1 order", "harmonic 1 response (re)", "harmonic 1 response (im)"),
        ("harmonic 2 order", "harmonic 2 response (re)", "harmonic 2 response (im)"),
    ];
    for (h, names) in p.harmonics.iter().zip(NAMES) {
        v.push((names.0, u64::from(h.order)));
        v.push((names.1, b(h.response.re)));
        v.push((names.2, b(h.response.im)));
    }
    v.extend([
        ("RLS forgetting factor", b(p.rls.lambda)),
        ("RLS initial covariance", b(p.rls.p0)),
        ("RLS covariance bound", b(p.rls.p_max)),
        ("saturation u_min", b(p.saturation.u_min)),
        ("saturation u_max", b(p.saturation.u_max)),
        ("uc_max", b(p.uc_max)),
        ("preview", b(p.preview_samples)),
    ]);
    v
}

fn safety_fields(s: &SafetyParams) -> [(&'static str, u64); 4] {
    let b = |v: f32| u64::from(v.to_bits());
    [
        ("drive limit u_min", b(s.u_min)),
        ("drive limit u_max", b(s.u_max)),
        ("slew", b(s.slew_v_per_s)),
        ("host timeout", u64::from(s.host_timeout_ms)),
    ]
}

/// The first field whose bits differ.
fn first_difference(sent: &[(&'static str, u64)], board: &[(&'static str, u64)]) -> Option<BoardError> {
    let show = |x: Option<&(&str, u64)>| x.map_or("missing".to_string(), |&(_, v)| format!("0x{v:x}"));
    (0..sent.len().max(board.len())).find_map(|i| {
        let (a, b) = (sent.get(i), board.get(i));
        (a != b).then(|| BoardError::Mismatch {
            field: a.or(b).map_or("?", |x| x.0),
            sent: show(a),
            board: show(b),
        })
    })
}

/// Compares what the board holds with what was sent, bit for bit.
pub fn verify(
    board: &BoardParams,
    safety: &SafetyParams,
    params: &ControllerParams,
) -> Result<(), BoardError> {
    let Some(c) = &board.controller else {
        return Err(BoardError::NotLoaded("read back: the board holds no compensator".into()));
    };
    if let Some(e) = first_difference(&safety_fields(safety), &safety_fields(&board.safety)) {
        return Err(e);
    }
    if let Some(e) = first_difference(&controller_fields(params), &controller_fields(c)) {
        return Err(e);
    }
    if board.active != Active::Controller {
        return Err(BoardError::NotLoaded("read back: the board would not run the compensator next".into()));
    }
    Ok(())
}

/// What [`load`] did.
#[derive(Clone, Debug)]
pub struct LoadReport {
    /// The board's status before (its run, if one was going on, was stopped).
    pub before: Status,
    /// Fields compared bit for bit.
    pub fields_compared: usize,
}

/// Sends the drive limits and the compensator and verifies them by reading them back.
pub fn load<P: Port>(
    link: &mut Link<P>,
    safety: &SafetyParams,
    params: &ControllerParams,
    opts: &StreamOptions,
) -> Result<LoadReport, BoardError> {
    params.validate().map_err(BoardError::Params)?;
    boucwen_link::device::check_safety(safety).map_err(BoardError::Params)?;
    let before = connect(link, opts)?;
    configure(link, &Message::SetSafety(*safety), "SetSafety", opts)?;
    configure(link, &Message::SetController(params.clone()), "SetController", opts)?;
    let back = read_params(link, opts)?;
    verify(&back, safety, params)?;
    Ok(LoadReport { before, fields_compared: controller_fields(params).len() + 4 })
}

/// How a run ended.
#[derive(Clone, Debug, PartialEq)]
pub enum RunEnd {
    /// The board ran every sample and said so.
    Complete,
    /// The board ended the run early (its status after it).
    Stopped(Status),
    /// The board entered its safe state during the run.
    SafeState(Option<SafeReason>),
    /// The board refused to go on (a fault during the run).
    Fault(Fault),
    /// Nothing came from the board for [`StreamOptions::silence`] (a reset, a pulled cable).
    Silent,
    /// The port failed (a USB adapter unplugged).
    LinkLost(String),
}

impl fmt::Display for RunEnd {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RunEnd::Complete => f.write_str("complete"),
            RunEnd::Stopped(s) => {
                write!(f, "the board stopped after {} of {} samples", s.samples_done, s.samples_total)
            }
            RunEnd::SafeState(r) => write!(f, "the board went to its safe state during the run ({r:?})"),
            RunEnd::Fault(x) => {
                write!(f, "the board reported a fault during the run: {:?}: {}", x.code, x.text)
            }
            RunEnd::Silent => f.write_str("the board fell silent during the run (reset, or the cable?)"),
            RunEnd::LinkLost(e) => write!(f, "the link failed during the run: {e}"),
        }
    }
}

/// The board taking its drive to 0 V after a run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SafeAfter {
    /// Why (the lost host, after a run the host leaves).
    pub reason: Option<SafeReason>,
    /// From the board's last intact frame to 0 V, as it counted, ms.
    pub board_ms: f64,
    /// Ramp steps seen.
    pub ramp_steps: u32,
}

/// What a run (or an excitation) did.
#[derive(Clone, Debug)]
pub struct RunReport {
    /// Samples asked for.
    pub samples_expected: u32,
    /// Samples given to the sink with their drive and measurement.
    pub samples_logged: u32,
    /// Samples given to the sink flagged [`host_flags::LOST`] (or without a measurement).
    pub samples_incomplete: u32,
    /// How it ended.
    pub end: RunEnd,
    /// The board's counters after the run (`None` if it did not answer).
    pub board: Option<Status>,
    /// Samples whose drive the board clamped to its drive limits.
    pub limited: u32,
    /// Samples where the compensator's output saturated.
    pub saturated: u32,
    /// The controller run (a control run), with the reference the samples carry.
    pub params: Option<ControllerParams>,
    /// The ramp to 0 V after the run, if watched and seen.
    pub safe: Option<SafeAfter>,
    /// Frames the board could not queue for sending during the run (its transmit queue was
    /// full: the line, or the host, was slower than the telemetry); `None` if it did not
    /// say.
    pub tx_dropped: Option<u32>,
}

/// Runs the loaded compensator on `actuator` for `samples` samples, tracking a sine of
/// `freq_hz` (which must be the loaded design's) and `amplitude_um`; every sample goes to
/// `sink` as it arrives. The board's parameters are read back first; if the amplitude
/// differs from the loaded one, the compensator is sent again with it and verified.
pub fn run<P: Port>(
    link: &mut Link<P>,
    freq_hz: f64,
    amplitude_um: f64,
    actuator: Actuator<'_>,
    samples: u32,
    sink: &mut dyn SampleSink,
    opts: &StreamOptions,
) -> Result<RunReport, BoardError> {
    check_samples(samples)?;
    connect(link, opts)?;
    let board = read_params(link, opts)?;
    let Some(loaded) = board.controller.clone() else {
        return Err(BoardError::NotLoaded("the board holds no compensator: load a design first".into()));
    };
    let ts = loaded.sample_period_us as f64 * 1e-6;
    let loaded_hz = loaded.drive.increment() as f64 / 2f64.powi(64) / ts;
    // The loaded design's frequency is kept: a reference within a millionth of it is it.
    if !(freq_hz.is_finite() && (freq_hz - loaded_hz).abs() <= 1e-6 * loaded_hz) {
        return Err(BoardError::Reference(format!(
            "the reference's {freq_hz} Hz is not the loaded design's {loaded_hz:.6} Hz (its harmonics' responses are for that frequency): design for {freq_hz} Hz and load it"
        )));
    }
    let mut params = loaded.clone();
    params.amplitude_um = amplitude_um as f32;
    params.validate().map_err(BoardError::Params)?;
    if params != loaded || board.active != Active::Controller {
        configure(link, &Message::SetController(params.clone()), "SetController", opts)?;
        verify(&read_params(link, opts)?, &board.safety, &params)?;
    }
    let reference = Reference::new(&params);
    let mut report = stream(link, actuator, samples, Some(reference), sink, opts)?;
    report.params = Some(params);
    Ok(report)
}

/// The board as the data acquisition: it drives `excitation` into `actuator` for `samples`
/// samples and reports the response; every sample goes to `sink` as it arrives.
pub fn excite<P: Port>(
    link: &mut Link<P>,
    excitation: &ExcitationParams,
    safety: Option<&SafetyParams>,
    actuator: Actuator<'_>,
    samples: u32,
    sink: &mut dyn SampleSink,
    opts: &StreamOptions,
) -> Result<RunReport, BoardError> {
    check_samples(samples)?;
    excitation.validate().map_err(BoardError::Params)?;
    connect(link, opts)?;
    if let Some(s) = safety {
        boucwen_link::device::check_safety(s).map_err(BoardError::Params)?;
        configure(link, &Message::SetSafety(*s), "SetSafety", opts)?;
    }
    configure(link, &Message::SetExcitation(excitation.clone()), "SetExcitation", opts)?;
    stream(link, actuator, samples, None, sink, opts)
}

fn check_samples(samples: u32) -> Result<(), BoardError> {
    if (2..u32::MAX).contains(&samples) { Ok(()) } else { Err(BoardError::Samples(samples as u64)) }
}

/// What the stream keeps of the last telemetry frame, waiting for its measurement.
#[derive(Clone, Copy)]
struct Pending {
    k: u32,
    u: f32,
    flags: u8,
}

struct Streamer<'a> {
    sink: &'a mut dyn SampleSink,
    reference: Option<Reference>,
    /// The next sample to log.
    next: u32,
    samples: u32,
    logged: u32,
    incomplete: u32,
    limited: u32,
    saturated: u32,
}

impl Streamer<'_> {
    fn emit(&mut self, k: u32, u_v: f32, y_um: Option<f64>, flags: u8) -> Result<(), BoardError> {
        debug_assert_eq!(k, self.next);
        let d_um = self.reference.as_mut().map(Reference::next_sample);
        let s = BoardSample { k, u_v, y_um, d_um, flags };
        if y_um.is_some() && flags & host_flags::LOST == 0 {
            self.logged += 1;
        } else {
            self.incomplete += 1;
        }
        self.limited += u32::from(flags & command_flags::LIMITED != 0);
        self.saturated += u32::from(flags & command_flags::SATURATED != 0);
        self.next += 1;
        self.sink.sample(&s).map_err(BoardError::Sink)
    }

    /// Logs samples `next..k` as lost.
    fn lost_until(&mut self, k: u32) -> Result<(), BoardError> {
        while self.next < k.min(self.samples) {
            self.emit(self.next, f32::NAN, None, host_flags::LOST)?;
        }
        Ok(())
    }

    fn done(&self) -> bool {
        self.next >= self.samples
    }
}

/// Starts a run on `actuator` and logs `samples` samples as they arrive.
fn stream<P: Port>(
    link: &mut Link<P>,
    mut actuator: Actuator<'_>,
    samples: u32,
    reference: Option<Reference>,
    sink: &mut dyn SampleSink,
    opts: &StreamOptions,
) -> Result<RunReport, BoardError> {
    let host = matches!(actuator, Actuator::Host(_));
    // On the board's actuator sample k's measurement comes with the telemetry of k + 1.
    let ticks = if host { samples } else { samples + 1 };
    let dropped_before = diagnostics(link, opts)?.map(|d| d.tx_dropped);
    configure(link, &Message::Start { mode: actuator.mode(), samples: ticks }, "Start", opts)?;
    let mut st =
        Streamer { sink, reference, next: 0, samples, logged: 0, incomplete: 0, limited: 0, saturated: 0 };
    let mut pending: Option<Pending> = None;
    let mut last_u = 0.0f32;
    let mut last_heard = Instant::now();
    let mut next_keepalive = Instant::now() + KEEPALIVE;
    // The telemetry heard since the last keepalive: frames, and the last sample index.
    let (mut heard_frames, mut heard_k, mut keepalive_k) = (0u32, 0u32, 0u32);
    let mut end = None;
    while end.is_none() {
        let now = Instant::now();
        let board_time = heard_frames == 0 || heard_k.saturating_sub(keepalive_k) >= KEEPALIVE_SAMPLES;
        if !host && now >= next_keepalive && board_time {
            if let Err(e) = link.send(&Message::GetStatus) {
                end = Some(RunEnd::LinkLost(e.to_string()));
                break;
            }
            next_keepalive = now + KEEPALIVE;
            (heard_frames, keepalive_k) = (0, heard_k);
        }
        let silent_at = last_heard + opts.silence;
        // A keepalive waiting for the board's time waits for its telemetry.
        let waits = host || (now >= next_keepalive && !board_time);
        let deadline = if waits { silent_at } else { silent_at.min(next_keepalive) };
        let received = match link.recv(deadline) {
            Ok(r) => r,
            Err(e) => {
                end = Some(RunEnd::LinkLost(e.to_string()));
                break;
            }
        };
        let Some(r) = received else {
            if Instant::now() >= last_heard + opts.silence {
                end = Some(RunEnd::Silent);
            }
            continue;
        };
        last_heard = Instant::now();
        let Ok(p) = r else { continue };
        match p.msg {
            Message::Telemetry { flags, .. } if flags & command_flags::SAFE_RAMP != 0 => {
                end = Some(RunEnd::SafeState(None));
            }
            Message::Telemetry { k, u, y, flags } if !host => {
                heard_frames += 1;
                heard_k = heard_k.max(k);
                if let Some(prev) = pending.take().filter(|p| p.k == st.next && k > p.k) {
                    if k == prev.k + 1 {
                        let y = (flags & command_flags::Y_MISSING == 0 && y.is_finite()).then_some(y as f64);
                        let f = (prev.flags & !command_flags::Y_MISSING) | (flags & command_flags::Y_MISSING);
                        st.emit(
                            prev.k,
                            prev.u,
                            y,
                            if y.is_none() { f | command_flags::Y_MISSING } else { f },
                        )?;
                    } else {
                        // The frame with its measurement was lost.
                        st.emit(prev.k, prev.u, None, prev.flags | host_flags::LOST)?;
                    }
                }
                // Samples before k whose telemetry (or the next one's) never came.
                st.lost_until(k)?;
                if st.done() {
                    continue;
                }
                pending = Some(Pending { k, u, flags });
            }
            Message::Command { k, u, flags, .. } if host => {
                if k < st.next || k >= samples {
                    continue;
                }
                let Actuator::Host(plant) = &mut actuator else { continue };
                // Commands that never came: the host's actuator holds the last input.
                while st.next < k {
                    let y = plant(last_u as f64).map_err(|error| BoardError::Plant { k: st.next, error })?;
                    st.emit(st.next, last_u, Some(y), host_flags::HELD | host_flags::LOST)?;
                }
                let y = match plant(u as f64) {
                    Ok(y) => y,
                    Err(error) => {
                        let _ = link.send(&Message::Stop);
                        return Err(BoardError::Plant { k, error });
                    }
                };
                last_u = u;
                st.emit(k, u, Some(y), flags)?;
                if k + 1 < samples {
                    if let Err(e) = link.send(&Message::Measurement { k, y: y as f32 }) {
                        end = Some(RunEnd::LinkLost(e.to_string()));
                    }
                }
            }
            Message::Status(s) if s.state != RunState::Running as u8 => {
                end = Some(if s.samples_done >= ticks { RunEnd::Complete } else { RunEnd::Stopped(s) });
            }
            Message::Safe { reason, .. } => end = Some(RunEnd::SafeState(SafeReason::from_u8(reason))),
            Message::Fault(f) if f.code == FaultCode::Compute => end = Some(RunEnd::Fault(f)),
            _ => {}
        }
    }
    let end = end.unwrap_or(RunEnd::Silent);
    let complete = end == RunEnd::Complete;
    if complete {
        // Every telemetry frame arrived or is logged as lost; the last sample's measurement
        // came with the run's last frame.
        if let Some(prev) = pending.take() {
            st.lost_until(prev.k)?;
        }
        st.lost_until(samples)?;
    }
    // Afterwards: the board's counters (over a quiet link), then the ramp to 0 V.
    let board = if matches!(end, RunEnd::Silent | RunEnd::LinkLost(_)) {
        None
    } else {
        link.request(&Message::GetStatus, 3, opts.reply, |_, m| match m {
            Message::Status(s) => Some(*s),
            _ => None,
        })?
    };
    let tx_dropped = match (dropped_before, &board) {
        (Some(before), Some(_)) => diagnostics(link, opts)?.map(|d| d.tx_dropped.wrapping_sub(before)),
        _ => None,
    };
    let safe = if complete && !opts.watch_safe.is_zero() { watch_safe(link, opts.watch_safe)? } else { None };
    Ok(RunReport {
        samples_expected: samples,
        samples_logged: st.logged,
        samples_incomplete: st.incomplete,
        end,
        board,
        limited: st.limited,
        saturated: st.saturated,
        params: None,
        safe,
        tx_dropped,
    })
}

/// The board's diagnostics, if it answers.
fn diagnostics<P: Port>(
    link: &mut Link<P>,
    opts: &StreamOptions,
) -> Result<Option<boucwen_link::message::Diagnostics>, BoardError> {
    Ok(link.request(&Message::GetDiagnostics, 3, opts.reply, |_, m| match m {
        Message::Diagnostics(d) => Some(*d),
        _ => None,
    })?)
}

/// Stays silent and waits up to `patience` for the board's `Safe`.
fn watch_safe<P: Port>(link: &mut Link<P>, patience: Duration) -> Result<Option<SafeAfter>, BoardError> {
    let deadline = Instant::now() + patience;
    let mut steps = 0;
    while let Some(r) = link.recv(deadline)? {
        match r.map(|p| p.msg) {
            Ok(Message::Telemetry { flags, .. }) if flags & command_flags::SAFE_RAMP != 0 => steps += 1,
            Ok(Message::Safe { reason, ticks, period_us }) => {
                return Ok(Some(SafeAfter {
                    reason: SafeReason::from_u8(reason),
                    board_ms: ticks as f64 * period_us as f64 * 1e-3,
                    ramp_steps: steps,
                }));
            }
            _ => {}
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::{MemoryPort, test_board};
    use boucwen_core::compensator::{HarmonicSpec, PhaseRule, Saturation, harmonic_response};
    use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
    use boucwen_core::rls::RlsConfig;
    use boucwen_core::signal::Oscillator;
    use boucwen_link::analog::NoFrontEnd;
    use boucwen_link::device::Device;
    use boucwen_link::excitation::{Excitation, Tone};
    use boucwen_link::message::{MAX_AR, PlantParams};
    use boucwen_link::plant::OnChipPlant;
    use boucwen_link::{Decoder, Packet};
    use nalgebra::Complex;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU32, Ordering};

    fn ext() -> ExtendedParams<f64, 2> {
        let w0 = std::f64::consts::TAU * 70.0e-3;
        ExtendedParams {
            bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
            ar: [2.0 * 0.97 * w0.cos(), -0.97 * 0.97],
        }
    }

    fn params() -> ControllerParams {
        let e = ext();
        let g = harmonic_response(&e, 3, 23.0, 1e-3, PhaseRule::Model);
        let mut ar = [0.0f32; MAX_AR];
        ar[0] = e.ar[0] as f32;
        ar[1] = e.ar[1] as f32;
        ControllerParams {
            model: ExtendedParams {
                bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
                ar,
            },
            drive: Oscillator::new(23.0, 1e-3).unwrap(),
            sample_period_us: 1000,
            amplitude_um: 20.0,
            fade_samples: 500,
            harmonics: [HarmonicSpec { order: 3, response: Complex::new(g.re as f32, g.im as f32) }]
                .into_iter()
                .collect(),
            rls: RlsConfig::with_forgetting(0.999, 1e-2),
            saturation: Saturation::symmetric(10.0),
            uc_max: 5.0,
            preview_samples: 0.0,
        }
    }

    fn plant() -> PlantParams {
        let c = params();
        PlantParams {
            base: c.model,
            drive: c.drive,
            branches: [HarmonicBranch { order: 3, alpha_s: 0.10, alpha_c: -0.06, ar: [] }]
                .into_iter()
                .collect(),
        }
    }

    /// A 0.8 V sine at 23 Hz, sampled at 1 kHz, faded in over `fade_samples`.
    fn sine_excitation(fade_samples: u32) -> ExcitationParams {
        ExcitationParams {
            sample_period_us: 1000,
            fade_samples,
            tones: [Tone { drive: Oscillator::new(23.0, 1e-3).unwrap(), amplitude_v: 0.8, phase: 0 }]
                .into_iter()
                .collect(),
        }
    }

    /// A board (the firmware's `Device`) in a thread, ticking every millisecond.
    fn board() -> (Link<MemoryPort>, impl FnOnce()) {
        let (host, dev) = MemoryPort::pair();
        let (stop, h) = test_board::spawn(dev, Duration::from_millis(1));
        let mut link = Link::new(host);
        let opts = StreamOptions::default();
        configure(&mut link, &Message::SetPlant(plant()), "SetPlant", &opts).unwrap();
        (link, move || {
            stop.store(true, Ordering::Relaxed);
            h.join().unwrap();
        })
    }

    /// What the board computes in a `Simulated` run of `ticks` ticks after `msgs`, on the
    /// host: its telemetry `(k, u, y)`.
    fn reference_run(msgs: &[Message], ticks: u32) -> Vec<(u32, f32, f32)> {
        let mut dev = Device::new();
        let mut out = Vec::new();
        for (seq, m) in msgs.iter().enumerate() {
            dev.on_packet(Ok(Packet { seq: seq as u16, msg: m.clone() }), &mut |_: &[u8]| {});
        }
        dev.on_packet(
            Ok(Packet { seq: 99, msg: Message::Start { mode: Mode::Simulated, samples: ticks } }),
            &mut |_: &[u8]| {},
        );
        for _ in 0..ticks {
            dev.on_packet(Ok(Packet { seq: 0xFFFF, msg: Message::GetStatus }), &mut |_: &[u8]| {});
            dev.on_tick(0, &mut NoFrontEnd, &|| 0, &mut |b: &[u8]| out.extend_from_slice(b));
        }
        let mut d = Decoder::new();
        out.iter()
            .filter_map(|&b| d.push(b))
            .filter_map(|r| match r.ok()?.msg {
                Message::Telemetry { k, u, y, .. } => Some((k, u, y)),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn load_verifies_bit_for_bit_and_run_streams_every_sample() {
        let (mut link, done) = board();
        let opts = StreamOptions { watch_safe: Duration::from_secs(3), ..StreamOptions::default() };
        let safety = SafetyParams { host_timeout_ms: 100, ..SafetyParams::DEFAULT };
        let r = load(&mut link, &safety, &params(), &opts).unwrap();
        assert_eq!(r.fields_compared, 27);
        // A run at 15 µm: the amplitude is set for the run and verified again.
        let mut got = Vec::new();
        let mut sink = |s: &BoardSample| {
            got.push(*s);
            Ok(())
        };
        let n = 1500;
        let rep = run(&mut link, 23.0, 15.0, Actuator::OnChip, n, &mut sink, &opts).unwrap();
        assert_eq!(rep.end, RunEnd::Complete, "{rep:?}");
        assert_eq!((rep.samples_expected, rep.samples_logged, rep.samples_incomplete), (n, n, 0));
        let mut run_params = params();
        run_params.amplitude_um = 15.0;
        assert_eq!(rep.params.as_ref(), Some(&run_params));
        // The same run on the host, bit for bit: sample k's measurement is the telemetry
        // of k + 1's.
        let want = reference_run(
            &[
                Message::SetPlant(plant()),
                Message::SetSafety(safety),
                Message::SetController(run_params.clone()),
            ],
            n + 1,
        );
        let mut reference = Reference::new(&run_params);
        for (k, s) in got.iter().enumerate() {
            assert_eq!(s.k as usize, k);
            assert_eq!(s.u_v.to_bits(), want[k].1.to_bits(), "u at {k}");
            assert_eq!(s.y_um, Some(want[k + 1].2 as f64), "y at {k}");
            assert_eq!(s.d_um.map(f32::to_bits), Some(reference.next_sample().to_bits()));
        }
        // Then the host fell silent and the board took its drive to 0 V.
        let safe = rep.safe.expect("the ramp to 0 V after the run");
        assert_eq!(safe.reason, Some(SafeReason::HostLost));
        assert!(safe.board_ms >= 100.0, "{safe:?}");
        done();
    }

    #[test]
    fn excite_drives_the_excitation_and_records_the_response() {
        let (mut link, done) = board();
        let e = sine_excitation(200);
        let mut got = Vec::new();
        let mut sink = |s: &BoardSample| {
            got.push(*s);
            Ok(())
        };
        let opts = StreamOptions { watch_safe: Duration::ZERO, ..StreamOptions::default() };
        let rep = excite(&mut link, &e, None, Actuator::OnChip, 800, &mut sink, &opts).unwrap();
        assert_eq!((rep.end, rep.samples_logged), (RunEnd::Complete, 800));
        let mut generator = Excitation::new(&e).unwrap();
        let mut plant = OnChipPlant::new(&plant()).unwrap();
        for s in &got {
            let (k, u) = generator.next_sample();
            assert_eq!((s.k, s.u_v.to_bits(), s.d_um), (k, u.to_bits(), None));
            assert_eq!(s.y_um, Some(plant.step(u) as f64), "sample {k}");
        }
        // The board now runs the excitation, not a compensator: a run refuses.
        let err = run(&mut link, 23.0, 20.0, Actuator::OnChip, 100, &mut |_: &BoardSample| Ok(()), &opts)
            .unwrap_err();
        assert_eq!(err.to_string(), "the board holds no compensator: load a design first");
        done();
    }

    /// A port that counts the `GetStatus` requests the host writes.
    struct CountingPort {
        inner: MemoryPort,
        dec: Decoder,
        get_status: Arc<AtomicU32>,
    }

    impl Port for CountingPort {
        fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
            for &b in bytes {
                if let Some(Ok(Packet { msg: Message::GetStatus, .. })) = self.dec.push(b) {
                    self.get_status.fetch_add(1, Ordering::Relaxed);
                }
            }
            self.inner.write_all(bytes)
        }
        fn read_timeout(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
            self.inner.read_timeout(buf, timeout)
        }
        fn name(&self) -> String {
            self.inner.name()
        }
    }

    #[test]
    fn keepalives_follow_a_board_slower_than_the_host() {
        // A board whose 1 ms samples take 10 ms of the host's (an emulator on a loaded
        // machine): keepalives on the host's clock alone would be one every 5 of its samples.
        let (host, dev) = MemoryPort::pair();
        let (stop, h) = test_board::spawn(dev, Duration::from_millis(10));
        let get_status = Arc::new(AtomicU32::new(0));
        let port = CountingPort { inner: host, dec: Decoder::new(), get_status: get_status.clone() };
        let mut link = Link::new(port);
        let opts = StreamOptions { watch_safe: Duration::ZERO, ..StreamOptions::default() };
        configure(&mut link, &Message::SetPlant(plant()), "SetPlant", &opts).unwrap();
        let e = sine_excitation(50);
        let before = get_status.load(Ordering::Relaxed);
        let n = 300;
        let t0 = Instant::now();
        let rep =
            excite(&mut link, &e, None, Actuator::OnChip, n, &mut |_: &BoardSample| Ok(()), &opts).unwrap();
        let wall = t0.elapsed();
        assert_eq!((&rep.end, rep.samples_logged), (&RunEnd::Complete, n), "{rep:?}");
        let sent = get_status.load(Ordering::Relaxed) - before;
        // One per KEEPALIVE_SAMPLES of the board's, and the requests around the run (the
        // status at its end, at most three tries).
        assert!(sent <= n / KEEPALIVE_SAMPLES + 4, "{sent} GetStatus in {wall:?} for {n} samples");
        assert!(wall >= Duration::from_millis(n as u64 * 9), "the board ticked faster than asked: {wall:?}");
        stop.store(true, Ordering::Relaxed);
        h.join().unwrap();
    }

    #[test]
    fn a_run_against_a_host_plant_is_the_loop_in_process() {
        let (mut link, done) = board();
        let opts = StreamOptions { watch_safe: Duration::ZERO, ..StreamOptions::default() };
        load(&mut link, &SafetyParams::DEFAULT, &params(), &opts).unwrap();
        let mut model = OnChipPlant::new(&plant()).unwrap();
        let mut host = |u: f64| -> Result<f64, Box<dyn std::error::Error + Send + Sync>> {
            Ok(model.step(u as f32) as f64)
        };
        let mut got = Vec::new();
        let mut sink = |s: &BoardSample| {
            got.push(*s);
            Ok(())
        };
        let rep = run(&mut link, 23.0, 20.0, Actuator::Host(&mut host), 1000, &mut sink, &opts).unwrap();
        assert_eq!((rep.end, rep.samples_logged), (RunEnd::Complete, 1000));
        // Lockstep: every measurement was used, so the samples are the in-process loop's.
        let mut c = boucwen_link::device::Controller::new(&params()).unwrap();
        let mut p = OnChipPlant::new(&plant()).unwrap();
        let mut y_prev = None;
        for s in &got {
            let step = c.step(y_prev).unwrap();
            let y = p.step(step.out.u);
            y_prev = Some(y);
            assert_eq!(
                (s.u_v.to_bits(), s.y_um, s.flags & host_flags::LOST),
                (step.out.u.to_bits(), Some(y as f64), 0)
            );
        }
        done();
    }

    #[test]
    fn refusals_name_what_is_wrong() {
        let (mut link, done) = board();
        let opts = StreamOptions { watch_safe: Duration::ZERO, ..StreamOptions::default() };
        load(&mut link, &SafetyParams::DEFAULT, &params(), &opts).unwrap();
        let mut sink = |_: &BoardSample| Ok(());
        let e = run(&mut link, 24.0, 20.0, Actuator::OnChip, 100, &mut sink, &opts).unwrap_err();
        assert!(
            e.to_string().starts_with("the reference's 24 Hz is not the loaded design's 23.000000 Hz"),
            "{e}"
        );
        let e = run(&mut link, 23.0, f64::NAN, Actuator::OnChip, 100, &mut sink, &opts).unwrap_err();
        assert!(e.to_string().contains("reference amplitude"), "{e}");
        let e = run(&mut link, 23.0, 20.0, Actuator::Converters, 100, &mut sink, &opts).unwrap_err();
        assert!(e.to_string().contains("this board has no converters"), "{e}");
        let e = run(&mut link, 23.0, 20.0, Actuator::OnChip, 1, &mut sink, &opts).unwrap_err();
        assert!(e.to_string().starts_with("1 samples"), "{e}");
        // Read back, a field that differs is named.
        let mut back = read_params(&mut link, &opts).unwrap();
        let im = &mut back.controller.as_mut().unwrap().harmonics[0].response.im;
        *im = f32::from_bits(im.to_bits() + 1);
        let e = verify(&back, &SafetyParams::DEFAULT, &params()).unwrap_err();
        assert!(e.to_string().starts_with("read back: harmonic 1 response (im) is 0x"), "{e}");
        back.safety.slew_v_per_s = 50.0;
        let e = verify(&back, &SafetyParams::DEFAULT, &params()).unwrap_err();
        assert!(e.to_string().starts_with("read back: slew is 0x"), "{e}");
        done();
    }

    #[test]
    fn a_board_that_goes_away_ends_the_run_and_keeps_what_came() {
        let (mut link, done) = board();
        let opts = StreamOptions { silence: Duration::from_millis(300), ..StreamOptions::default() };
        load(&mut link, &SafetyParams::DEFAULT, &params(), &opts).unwrap();
        let mut got = 0u32;
        let mut kill = Some(done);
        let mut sink = |s: &BoardSample| {
            assert_eq!(s.k, got);
            got += 1;
            if got == 200 {
                // The board goes away (its thread ends: a reset, a pulled cable).
                if let Some(k) = kill.take() {
                    k();
                }
            }
            Ok(())
        };
        let rep = run(&mut link, 23.0, 20.0, Actuator::OnChip, 5000, &mut sink, &opts).unwrap();
        // The in-process pipe reports its other end gone, as a serial adapter pulled out does.
        assert!(matches!(rep.end, RunEnd::LinkLost(_)), "{:?}", rep.end);
        assert!(rep.samples_logged >= 200 && rep.samples_logged < 5000, "{rep:?}");
        assert_eq!(rep.samples_logged, got);
        assert!(rep.board.is_none());
    }
}

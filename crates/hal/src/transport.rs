//! The host's end of the serial link: ports, fault injection and a framed [`Link`].
//!
//! * [`Port`]: a byte pipe with a read timeout. Implemented for the `serialport` crate's
//!   ports ([`open_serial`]: a USB-serial adapter, or the pseudo-terminal QEMU gives the
//!   emulated board with `-serial pty`), and for [`MemoryPort`], an in-process pair for
//!   tests.
//! * [`FaultInjector`]: damages a byte stream on purpose. Each byte is hit independently
//!   with probability `rate`; a hit byte is dropped or has one random bit flipped (even
//!   odds). Seeded, so a run can be repeated.
//! * [`Link`]: sends and receives [`Message`]s over a port with the wire protocol: numbers
//!   outgoing frames, decodes incoming ones, counts intact, rejected and missing frames
//!   ([`LinkStats`]), and passes both directions through an optional fault injector (bytes
//!   sent are damaged before they are written, bytes received before they are decoded).
//! * [`BoardPlant`]: the board as a [`Plant`] the host drives sample by sample (the board's
//!   plant mode: `Command{k, u}` answered by `Measurement{k, y}`), with retries that the
//!   board answers idempotently.

use boucwen_core::Plant;
use boucwen_link::frame::{SeqGap, SeqTracker};
use boucwen_link::message::{Mode, PlantParams, RunState, kind};
use boucwen_link::{self as wire, Decoder, Message, Packet, WireError};
use rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::VecDeque;
use std::fmt;
use std::io::{self, Read, Write};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// What went wrong on the link.
#[derive(Debug)]
pub enum TransportError {
    /// The port could not be opened.
    Open {
        /// The port's path.
        path: String,
        /// Why.
        error: serialport::Error,
    },
    /// Reading or writing failed (not a timeout).
    Io {
        /// The port.
        port: String,
        /// The error.
        error: io::Error,
    },
    /// A message could not be encoded (a parameter out of the wire format's range).
    Encode(WireError),
}

impl fmt::Display for TransportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TransportError::Open { path, error } => write!(f, "{path}: cannot open: {error}"),
            TransportError::Io { port, error } => write!(f, "{port}: {error}"),
            TransportError::Encode(e) => write!(f, "encoding a message: {e}"),
        }
    }
}

impl std::error::Error for TransportError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            TransportError::Open { error, .. } => Some(error),
            TransportError::Io { error, .. } => Some(error),
            TransportError::Encode(e) => Some(e),
        }
    }
}

/// A byte pipe with a read timeout.
pub trait Port {
    /// Writes all of `bytes`.
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads the bytes available, waiting up to `timeout` for the first; `Ok(0)` on timeout.
    fn read_timeout(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
    /// A name for messages.
    fn name(&self) -> String;
}

/// A port of the `serialport` crate.
pub struct SerialPort {
    port: Box<dyn serialport::SerialPort>,
    name: String,
}

/// Opens the serial device `path` (8N1, no flow control; `baud` is ignored by
/// pseudo-terminals).
pub fn open_serial(path: &str, baud: u32) -> Result<SerialPort, TransportError> {
    let port = serialport::new(path, baud)
        .timeout(Duration::from_millis(10))
        .open()
        .map_err(|error| TransportError::Open { path: path.to_owned(), error })?;
    Ok(SerialPort { port, name: path.to_owned() })
}

impl SerialPort {
    /// Wraps an opened port (e.g. one end of `serialport::TTYPort::pair`).
    pub fn from_port(port: Box<dyn serialport::SerialPort>, name: &str) -> Self {
        Self { port, name: name.to_owned() }
    }
}

impl Port for SerialPort {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.port.set_timeout(Duration::from_secs(1)).map_err(io::Error::from)?;
        Write::write_all(&mut self.port, bytes)
    }

    fn read_timeout(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.port.set_timeout(timeout.max(Duration::from_micros(1))).map_err(io::Error::from)?;
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock) => Ok(0),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(e),
        }
    }

    fn name(&self) -> String {
        self.name.clone()
    }
}

/// One end of an in-process byte pipe (for tests and simulations).
pub struct MemoryPort {
    tx: mpsc::Sender<Vec<u8>>,
    rx: mpsc::Receiver<Vec<u8>>,
    pending: VecDeque<u8>,
    name: String,
}

impl MemoryPort {
    /// Two connected ends: what one writes, the other reads.
    pub fn pair() -> (MemoryPort, MemoryPort) {
        let (a_tx, b_rx) = mpsc::channel();
        let (b_tx, a_rx) = mpsc::channel();
        (
            MemoryPort { tx: a_tx, rx: a_rx, pending: VecDeque::new(), name: "memory port A".into() },
            MemoryPort { tx: b_tx, rx: b_rx, pending: VecDeque::new(), name: "memory port B".into() },
        )
    }
}

impl Port for MemoryPort {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.tx
            .send(bytes.to_vec())
            .map_err(|_| io::Error::new(io::ErrorKind::BrokenPipe, "the other end is gone"))
    }

    fn read_timeout(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        if self.pending.is_empty() {
            match self.rx.recv_timeout(timeout) {
                Ok(chunk) => self.pending.extend(chunk),
                Err(mpsc::RecvTimeoutError::Timeout) => return Ok(0),
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    return Err(io::Error::new(io::ErrorKind::BrokenPipe, "the other end is gone"));
                }
            }
        }
        while let Ok(chunk) = self.rx.try_recv() {
            self.pending.extend(chunk);
        }
        let n = buf.len().min(self.pending.len());
        for (b, p) in buf.iter_mut().zip(self.pending.drain(..n)) {
            *b = p;
        }
        Ok(n)
    }

    fn name(&self) -> String {
        self.name.clone()
    }
}

/// The fault injector's seeded generator: the project's one generator, xoshiro256++.
#[derive(Clone, Debug)]
struct Rng(Xoshiro256PlusPlus);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(Xoshiro256PlusPlus::seed_from_u64(seed))
    }
    fn next(&mut self) -> u64 {
        self.0.next_u64()
    }
    /// Uniform in `[0, 1)`.
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Counts of what a [`FaultInjector`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultCounts {
    /// Bytes seen.
    pub bytes: u64,
    /// Bytes dropped.
    pub dropped: u64,
    /// Bytes with a bit flipped.
    pub corrupted: u64,
}

/// Damages bytes at a given rate.
#[derive(Clone, Debug)]
pub struct FaultInjector {
    rate: f64,
    rng: Rng,
    counts: FaultCounts,
}

impl FaultInjector {
    /// Hits each byte with probability `rate` (clamped to `[0, 1]`; NaN is 0).
    pub fn new(rate: f64, seed: u64) -> Self {
        let rate = if rate.is_nan() { 0.0 } else { rate.clamp(0.0, 1.0) };
        Self { rate, rng: Rng::new(seed), counts: FaultCounts::default() }
    }

    /// One byte through the injector: what comes out (`None`: dropped) and whether it
    /// was hit.
    pub fn damage(&mut self, b: u8) -> (Option<u8>, bool) {
        self.counts.bytes += 1;
        if self.rate > 0.0 && self.rng.unit() < self.rate {
            if self.rng.next() & 1 == 0 {
                self.counts.dropped += 1;
                (None, true)
            } else {
                self.counts.corrupted += 1;
                (Some(b ^ (1 << (self.rng.next() % 8))), true)
            }
        } else {
            (Some(b), false)
        }
    }

    /// Appends `bytes`, damaged, to `out`; returns whether any byte was hit.
    pub fn apply(&mut self, bytes: &[u8], out: &mut Vec<u8>) -> bool {
        let mut hit = false;
        for &b in bytes {
            let (o, h) = self.damage(b);
            out.extend(o);
            hit |= h;
        }
        hit
    }

    /// What it did so far.
    pub fn counts(&self) -> FaultCounts {
        self.counts
    }
}

/// Counters of a [`Link`]'s receiving and sending.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Frames sent.
    pub tx_frames: u64,
    /// Intact frames received.
    pub rx_frames: u64,
    /// Frames received and rejected (COBS, CRC, length, kind, value).
    pub rx_bad: u64,
    /// Frames missing from the peer's sequence numbers that never arrived, not even as
    /// rejected frames.
    pub rx_lost: u64,
    /// Frames received with bytes the fault injector damaged (dropped or flipped), as the
    /// decoder delimited them.
    pub rx_damaged: u64,
    /// Of those, frames the checks passed as intact: a damaged frame taken for a good one
    /// (0 unless the frame checks fail).
    pub rx_undetected: u64,
}

/// A frame as received: intact, or rejected with the reason.
pub type Received = Result<Packet, WireError>;

/// Messages over a [`Port`] with the wire protocol.
pub struct Link<P: Port> {
    port: P,
    decoder: Decoder,
    tx_seq: u16,
    rx_seq: SeqTracker,
    bad_since_good: u64,
    inbox: VecDeque<Received>,
    stats: LinkStats,
    tx_faults: Option<FaultInjector>,
    rx_faults: Option<FaultInjector>,
    /// What injectors that were switched off did: `(sent, received)`.
    faults_done: (FaultCounts, FaultCounts),
    /// The frame being received has bytes the injector damaged.
    rx_tainted: bool,
    /// The last frame sent had bytes the injector damaged.
    last_tx_damaged: bool,
    /// Bytes received after the injector: each byte (`None`: dropped) and whether it was hit.
    buf: Vec<(Option<u8>, bool)>,
}

impl<P: Port> Link<P> {
    /// A link over `port`, without fault injection.
    pub fn new(port: P) -> Self {
        Self {
            port,
            decoder: Decoder::new(),
            tx_seq: 0,
            rx_seq: SeqTracker::new(),
            bad_since_good: 0,
            inbox: VecDeque::new(),
            stats: LinkStats::default(),
            tx_faults: None,
            rx_faults: None,
            faults_done: (FaultCounts::default(), FaultCounts::default()),
            rx_tainted: false,
            last_tx_damaged: false,
            buf: Vec::new(),
        }
    }

    /// Starts damaging both directions at `rate` per byte (seeded), or stops (`None`).
    /// [`Link::fault_counts`] keeps counting across switches.
    pub fn inject_faults(&mut self, rate: Option<f64>, seed: u64) {
        self.faults_done = self.fault_counts();
        self.tx_faults = rate.map(|r| FaultInjector::new(r, seed));
        self.rx_faults = rate.map(|r| FaultInjector::new(r, seed ^ 0x5DEE_CE66_D1CE_4E5B));
    }

    /// Bytes damaged so far: `(sent, received)`.
    pub fn fault_counts(&self) -> (FaultCounts, FaultCounts) {
        let add = |a: FaultCounts, b: Option<&FaultInjector>| {
            let b = b.map_or(FaultCounts::default(), FaultInjector::counts);
            FaultCounts {
                bytes: a.bytes + b.bytes,
                dropped: a.dropped + b.dropped,
                corrupted: a.corrupted + b.corrupted,
            }
        };
        (add(self.faults_done.0, self.tx_faults.as_ref()), add(self.faults_done.1, self.rx_faults.as_ref()))
    }

    /// The counters.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// The port's name.
    pub fn port_name(&self) -> String {
        self.port.name()
    }

    fn io(&self, error: io::Error) -> TransportError {
        TransportError::Io { port: self.port.name(), error }
    }

    /// Sends `msg` (through the fault injector if on); returns its sequence number.
    pub fn send(&mut self, msg: &Message) -> Result<u16, TransportError> {
        let seq = self.tx_seq;
        let frame = wire::encode(seq, msg).map_err(TransportError::Encode)?;
        self.tx_seq = self.tx_seq.wrapping_add(1);
        self.stats.tx_frames += 1;
        self.last_tx_damaged = false;
        let result = match &mut self.tx_faults {
            Some(f) => {
                let mut damaged = Vec::with_capacity(frame.len());
                self.last_tx_damaged = f.apply(&frame, &mut damaged);
                self.port.write_all(&damaged)
            }
            None => self.port.write_all(&frame),
        };
        result.map_err(|e| self.io(e))?;
        Ok(seq)
    }

    /// Whether the fault injector damaged the last frame [`Link::send`] sent (so the peer
    /// must not take it for an intact one).
    pub fn last_sent_damaged(&self) -> bool {
        self.last_tx_damaged
    }

    /// The next frame received before `deadline`: `Ok(None)` if none came in time.
    ///
    /// With fault injection on, each frame is marked damaged when a byte of it was
    /// dropped or flipped, including its delimiter (two frames then arrive as one) and a
    /// byte flipped into a delimiter (the frame is cut, and the rest arrives as a frame of
    /// its own, damaged too); [`LinkStats::rx_undetected`] counts damaged frames that
    /// passed the checks.
    pub fn recv(&mut self, deadline: Instant) -> Result<Option<Received>, TransportError> {
        loop {
            if let Some(r) = self.inbox.pop_front() {
                return Ok(Some(r));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            let mut raw = [0u8; 512];
            let n = self.port.read_timeout(&mut raw, deadline - now).map_err(|e| self.io(e))?;
            self.buf.clear();
            match &mut self.rx_faults {
                Some(f) => self.buf.extend(raw[..n].iter().map(|&b| f.damage(b))),
                None => self.buf.extend(raw[..n].iter().map(|&b| (Some(b), false))),
            }
            for i in 0..self.buf.len() {
                let (byte, hit) = self.buf[i];
                // A dropped or flipped byte damages the frame it belongs to.
                self.rx_tainted |= hit;
                let Some(b) = byte else { continue };
                let result = self.decoder.push(b);
                if let Some(r) = result {
                    let damaged = self.rx_tainted;
                    self.note(&r, damaged);
                    self.inbox.push_back(r);
                }
                if b == 0 {
                    // A delimiter the injector made cuts a frame: the rest is damaged too.
                    self.rx_tainted = hit;
                }
            }
        }
    }

    fn note(&mut self, r: &Received, damaged: bool) {
        if damaged {
            self.stats.rx_damaged += 1;
            if r.is_ok() {
                self.stats.rx_undetected += 1;
            }
        }
        match r {
            Ok(p) => {
                self.stats.rx_frames += 1;
                if let SeqGap::Missed(n) = self.rx_seq.observe(p.seq) {
                    self.stats.rx_lost += (n as u64).saturating_sub(self.bad_since_good);
                }
                self.bad_since_good = 0;
            }
            Err(_) => {
                self.stats.rx_bad += 1;
                self.bad_since_good += 1;
            }
        }
    }

    /// Writes `bytes` as they are (no framing, no fault injection): for tests that send
    /// damaged frames on purpose.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.port.write_all(bytes).map_err(|e| self.io(e))
    }

    /// Writes a lone delimiter (never damaged), so the peer drops any half-received frame
    /// and the next frame starts clean.
    pub fn flush_peer(&mut self) -> Result<(), TransportError> {
        self.port.write_all(&[0]).map_err(|e| self.io(e))
    }

    /// Drops everything received but not yet returned, and any half-received frame.
    pub fn discard_input(&mut self) {
        self.inbox.clear();
        self.decoder.reset();
        self.rx_tainted = false;
    }

    /// Sends `msg` and waits for the first intact answer that `accept` takes (returning
    /// `Some`), trying `attempts` times with `timeout` each. Other frames are skipped.
    pub fn request<T>(
        &mut self,
        msg: &Message,
        attempts: u32,
        timeout: Duration,
        mut accept: impl FnMut(u16, &Message) -> Option<T>,
    ) -> Result<Option<T>, TransportError> {
        for _ in 0..attempts.max(1) {
            let seq = self.send(msg)?;
            let deadline = Instant::now() + timeout;
            while let Some(r) = self.recv(deadline)? {
                if let Ok(p) = r {
                    if let Some(t) = accept(seq, &p.msg) {
                        return Ok(Some(t));
                    }
                }
            }
        }
        Ok(None)
    }

    /// [`Link::request`] for set-up exchanges, where a lost answer costs a retry and not a
    /// sample: attempt `i` waits `timeout·2^i`, at most [`MAX_BACKOFF`] times `timeout`, so
    /// a busy host or a board that answers late is waited for rather than given up on.
    pub fn request_patiently<T>(
        &mut self,
        msg: &Message,
        attempts: u32,
        timeout: Duration,
        mut accept: impl FnMut(u16, &Message) -> Option<T>,
    ) -> Result<Option<T>, TransportError> {
        for i in 0..attempts.max(1) {
            let wait = timeout * (1u32 << i.min(MAX_BACKOFF.trailing_zeros()));
            if let Some(t) = self.request(msg, 1, wait, &mut accept)? {
                return Ok(Some(t));
            }
        }
        Ok(None)
    }
}

/// The longest wait of [`Link::request_patiently`], in units of its timeout (a power of 2).
pub const MAX_BACKOFF: u32 = 8;

/// The driver board as a [`Plant`]: each [`Plant::step`] sends `Command{k, u[k]}` and waits
/// for `Measurement{k, y[k]}` (the board's plant mode). On QEMU's `mps2-an386` the board's
/// on-chip model ([`boucwen_link::plant::OnChipPlant`], configured by [`PlantParams`])
/// stands for its DAC, actuator and sensor.
///
/// A step whose answer does not come within the timeout is sent again, up to the number of
/// attempts (at once when a damaged frame or the board's negative acknowledge shows the
/// exchange failed); the board answers a repeated command with the measurement it already
/// took, so a retry never steps the plant twice. A step that gets no answer at all is
/// [`BoardError::NoMeasurement`]; the next step then sends the next sample and the board holds
/// the last input over the sample it missed.
pub struct BoardPlant<P: Port> {
    link: Link<P>,
    params: PlantParams,
    ts_s: f64,
    k: u32,
    timeout: Duration,
    attempts: u32,
    name: String,
}

/// Why the board, driven as a plant, did not give a measurement.
#[derive(Debug)]
pub enum BoardError {
    /// The command was NaN or infinite; nothing was sent.
    NonFiniteInput {
        /// The sample, counting from 0.
        sample: u32,
    },
    /// The link failed.
    Link(TransportError),
    /// The board refused a request.
    Refused {
        /// The port.
        port: String,
        /// The board's fault text.
        fault: String,
    },
    /// The board did not answer a request.
    NoAnswer {
        /// The port.
        port: String,
        /// The request: `Stop`, or the kind byte of the message.
        request: Request,
    },
    /// No measurement came back for a sample after every attempt.
    NoMeasurement {
        /// The sample.
        sample: u32,
        /// Attempts made.
        attempts: u32,
    },
}

impl fmt::Display for BoardError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BoardError::NonFiniteInput { sample } => {
                write!(f, "sample {sample}: the command u is not finite")
            }
            BoardError::Link(e) => write!(f, "{e}"),
            BoardError::Refused { port, fault } => write!(f, "{port}: the board refused: {fault}"),
            BoardError::NoAnswer { port, request: Request::Stop } => write!(f, "{port}: no answer to Stop"),
            BoardError::NoAnswer { port, request: Request::Kind(kind) } => {
                write!(f, "{port}: no answer to message 0x{kind:02x}")
            }
            BoardError::NoMeasurement { sample, attempts } => {
                write!(f, "sample {sample}: no measurement after {attempts} attempts")
            }
        }
    }
}

impl std::error::Error for BoardError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            BoardError::Link(e) => Some(e),
            _ => None,
        }
    }
}

/// A request to the board that went unanswered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Request {
    /// `Stop`.
    Stop,
    /// A configuration message of this kind byte.
    Kind(u8),
}

impl From<TransportError> for BoardError {
    fn from(e: TransportError) -> Self {
        BoardError::Link(e)
    }
}

impl<P: Port> BoardPlant<P> {
    /// Configures the board's plant and starts an open-ended plant run; `ts_s` is the
    /// sample interval the plant stands for. A step's answer is awaited `timeout`, `attempts`
    /// times; the set-up's (here and in [`Plant::reset`]) with the wait doubled on each
    /// retry ([`Link::request_patiently`]).
    pub fn start(
        link: Link<P>,
        params: PlantParams,
        ts_s: f64,
        timeout: Duration,
        attempts: u32,
    ) -> Result<Self, BoardError> {
        let name = link.port_name();
        let mut p = Self { link, params, ts_s, k: 0, timeout, attempts: attempts.max(1), name };
        p.begin()?;
        Ok(p)
    }

    fn begin(&mut self) -> Result<(), BoardError> {
        let (timeout, attempts, name) = (self.timeout, self.attempts, &self.name);
        let link = &mut self.link;
        link.flush_peer()?;
        link.discard_input();
        // The answer to `Stop` is a status that says the run is over (a status that still says
        // running is not its answer).
        link.request_patiently(&Message::Stop, attempts, timeout, |_, m| {
            matches!(m, Message::Status(s) if s.state != RunState::Running as u8).then_some(())
        })?
        .ok_or_else(|| BoardError::NoAnswer { port: name.clone(), request: Request::Stop })?;
        for (msg, want) in [
            (Message::SetPlant(self.params.clone()), kind::SET_PLANT),
            (Message::Start { mode: Mode::Plant, samples: 0 }, kind::START),
        ] {
            let mut busy = 0;
            loop {
                let answer = link.request_patiently(&msg, attempts, timeout, |seq, m| match m {
                    Message::Ack { kind, seq: s } if *kind == want && *s == seq => Some(Ok(())),
                    Message::Fault(f) if f.seq == seq => Some(Err((f.code, f.text.to_string()))),
                    _ => None,
                })?;
                match answer {
                    Some(Ok(())) => break,
                    // A `Start` whose answer was lost on the way and was sent again is refused
                    // as busy by the run it started: the board's status tells. After `Stop`
                    // the board may still be ramping its drive to 0 V: wait and ask again.
                    Some(Err((boucwen_link::message::FaultCode::Busy, _))) if busy + 1 < attempts => {
                        busy += 1;
                        if want == kind::START {
                            let status = link.request_patiently(
                                &Message::GetStatus,
                                attempts,
                                timeout,
                                |_, m| match m {
                                    Message::Status(st) => Some(*st),
                                    _ => None,
                                },
                            )?;
                            if status.is_some_and(|st| {
                                st.state == RunState::Running as u8 && st.mode == Mode::Plant as u8
                            }) {
                                break;
                            }
                        }
                        std::thread::sleep(timeout);
                    }
                    Some(Err((_, text))) => {
                        return Err(BoardError::Refused { port: name.clone(), fault: text });
                    }
                    None => {
                        return Err(BoardError::NoAnswer {
                            port: name.clone(),
                            request: Request::Kind(want),
                        });
                    }
                }
            }
        }
        self.k = 0;
        Ok(())
    }

    /// The link (for its counters).
    pub fn link(&self) -> &Link<P> {
        &self.link
    }
}

impl<P: Port> Plant<f64> for BoardPlant<P> {
    type Error = BoardError;

    fn step(&mut self, u_v: f64) -> Result<f64, BoardError> {
        let k = self.k;
        if !u_v.is_finite() {
            return Err(BoardError::NonFiniteInput { sample: k });
        }
        let u = u_v as f32;
        let msg = Message::Command { k, u, used: 0, flags: 0 };
        for _ in 0..self.attempts {
            self.link.send(&msg)?;
            let deadline = Instant::now() + self.timeout;
            // A damaged frame or the board's negative acknowledge means the exchange failed:
            // try again at once rather than waiting out the timeout.
            while let Some(r) = self.link.recv(deadline)? {
                match r.map(|p| p.msg) {
                    Ok(Message::Measurement { k: kk, y }) if kk == k => {
                        self.k = self.k.wrapping_add(1);
                        return Ok(y as f64);
                    }
                    Ok(Message::Fault(f)) if f.code == boucwen_link::message::FaultCode::BadFrame => break,
                    Err(_) => break,
                    Ok(_) => {}
                }
            }
        }
        self.k = self.k.wrapping_add(1);
        Err(BoardError::NoMeasurement { sample: k, attempts: self.attempts })
    }

    fn sample_interval_s(&self) -> f64 {
        self.ts_s
    }

    fn reset(&mut self) -> Result<(), BoardError> {
        self.begin()
    }

    fn name(&self) -> &str {
        &self.name
    }
}

/// A board in a thread for the tests: the firmware's protocol code on a port.
#[cfg(test)]
pub(crate) mod test_board {
    use super::Port;
    use boucwen_link::Decoder;
    use boucwen_link::Message;
    use boucwen_link::device::{Device, TimerRequest};
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::time::{Duration, Instant};

    /// A board in a thread: the firmware's `Device` on `port`. It ticks as soon as the
    /// measurement of its last command is in, or `patience` after the last tick (so the
    /// test runs at the host's pace and a lost measurement costs only `patience`).
    pub(crate) fn spawn<P: Port + Send + 'static>(
        mut port: P,
        patience: Duration,
    ) -> (Arc<AtomicBool>, std::thread::JoinHandle<()>) {
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let h = std::thread::spawn(move || {
            let mut dev = Device::new();
            let mut dec = Decoder::new();
            let mut ticking = false;
            let mut last_tick = Instant::now();
            let mut buf = [0u8; 256];
            while !stop2.load(Ordering::Relaxed) {
                let n = match port.read_timeout(&mut buf, Duration::from_micros(200)) {
                    Ok(n) => n,
                    Err(_) => return,
                };
                let mut out = Vec::new();
                let mut send = |b: &[u8]| out.extend_from_slice(b);
                for &b in &buf[..n] {
                    if let Some(p) = dec.push(b) {
                        let measured = matches!(&p, Ok(pk) if matches!(pk.msg, Message::Measurement { .. }));
                        match dev.on_packet(p, &mut send) {
                            TimerRequest::Start { .. } => {
                                ticking = true;
                                last_tick = Instant::now() - patience;
                            }
                            TimerRequest::Stop => ticking = false,
                            TimerRequest::Keep => {}
                        }
                        if measured {
                            // Time to tick: force it below.
                            last_tick = Instant::now() - patience;
                        }
                    }
                }
                // Between runs the board ticks every millisecond, as the firmware does (its
                // safe state runs on the tick).
                let period = if ticking { patience } else { Duration::from_millis(1) };
                if last_tick.elapsed() >= period {
                    last_tick = Instant::now();
                    if dev.on_tick(0, &mut boucwen_link::analog::NoFrontEnd, &|| 0, &mut send)
                        == TimerRequest::Stop
                    {
                        ticking = false;
                    }
                }
                if !out.is_empty() && port.write_all(&out).is_err() {
                    return;
                }
            }
        });
        (stop, h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use boucwen_core::model::{BoucWenParams, ExtendedParams, HarmonicBranch};
    use boucwen_core::signal::Oscillator;
    use boucwen_link::plant::OnChipPlant;
    use std::sync::atomic::Ordering;

    fn plant_params() -> PlantParams {
        PlantParams {
            base: ExtendedParams {
                bw: BoucWenParams { a1: 20.0, a: 6.0, a0: 0.5, gamma: 2.0, beta: 3.0 },
                ar: [1.6, -0.7, 0.0],
            },
            drive: Oscillator::new(23.0, 1e-3).unwrap(),
            branches: [HarmonicBranch { order: 3, alpha_s: 0.1, alpha_c: -0.05, ar: [] }]
                .into_iter()
                .collect(),
        }
    }

    #[test]
    fn fault_injector_rate_and_repeatability() {
        let data = vec![0x55u8; 200_000];
        let (mut a, mut b) = (FaultInjector::new(0.01, 3), FaultInjector::new(0.01, 3));
        let (mut out_a, mut out_b) = (Vec::new(), Vec::new());
        a.apply(&data, &mut out_a);
        b.apply(&data, &mut out_b);
        assert_eq!(out_a, out_b, "same seed, same damage");
        let c = a.counts();
        let hit = (c.dropped + c.corrupted) as f64 / c.bytes as f64;
        assert!((hit - 0.01).abs() < 0.001, "hit rate {hit}");
        assert_eq!(out_a.len() as u64, c.bytes - c.dropped);
        assert_eq!(out_a.iter().filter(|&&x| x != 0x55).count() as u64, c.corrupted);
        let mut none = FaultInjector::new(f64::NAN, 1);
        let mut out = Vec::new();
        none.apply(&data[..100], &mut out);
        assert_eq!(out, data[..100]);
    }

    #[test]
    fn damaged_frames_received_are_marked_and_all_rejected() {
        let (mut peer, host) = MemoryPort::pair();
        let mut link = Link::new(host);
        link.inject_faults(Some(0.01), 5);
        let n = 3000u32;
        for k in 0..n {
            let frame = wire::encode(k as u16, &Message::Measurement { k, y: k as f32 }).unwrap();
            peer.write_all(&frame).unwrap();
        }
        let mut intact = 0u64;
        while let Some(r) = link.recv(Instant::now() + Duration::from_millis(50)).unwrap() {
            if let Ok(p) = r {
                // What passed is what was sent.
                let Message::Measurement { k, y } = p.msg else { panic!("{:?}", p.msg) };
                assert_eq!((p.seq, y), (k as u16, k as f32));
                intact += 1;
            }
        }
        let s = link.stats();
        let (_, rx) = link.fault_counts();
        assert!(rx.dropped > 0 && rx.corrupted > 0, "{rx:?}");
        // Every rejected frame was marked damaged and every damaged one was rejected: the
        // marking has neither misses nor false alarms on an intact frame.
        assert!(s.rx_bad > 0);
        assert_eq!((s.rx_damaged, s.rx_undetected), (s.rx_bad, 0), "{s:?}");
        assert_eq!(s.rx_frames, intact);
        assert!(intact + s.rx_lost + s.rx_bad >= n as u64, "{s:?}");
    }

    #[test]
    fn frames_sent_damaged_are_known_to_the_sender() {
        let (host, mut peer) = MemoryPort::pair();
        let mut link = Link::new(host);
        link.inject_faults(Some(0.01), 9);
        let mut damaged = std::collections::HashSet::new();
        for k in 0..3000u32 {
            let seq = link.send(&Message::Measurement { k, y: 1.5 }).unwrap();
            if link.last_sent_damaged() {
                damaged.insert(seq);
            }
        }
        let mut buf = [0u8; 4096];
        let mut dec = Decoder::new();
        let (mut ok, mut bad) = (0, 0);
        while let Ok(n @ 1..) = peer.read_timeout(&mut buf, Duration::from_millis(20)) {
            for &b in &buf[..n] {
                match dec.push(b) {
                    Some(Ok(p)) => {
                        assert!(!damaged.contains(&p.seq), "damaged frame {} arrived intact", p.seq);
                        ok += 1;
                    }
                    Some(Err(_)) => bad += 1,
                    None => {}
                }
            }
        }
        assert!(!damaged.is_empty() && bad > 0);
        // Frames not damaged arrive unless a damaged neighbour took their delimiter.
        assert!(ok + 2 * damaged.len() >= 3000, "{ok} intact, {} damaged", damaged.len());
    }

    #[test]
    fn board_plant_matches_the_on_chip_model_even_over_a_damaged_link() {
        for rate in [0.0, 0.02] {
            let (host, dev) = MemoryPort::pair();
            let (stop, h) = test_board::spawn(dev, Duration::from_millis(3));
            let mut link = Link::new(host);
            link.inject_faults(Some(rate), 11);
            let mut plant =
                BoardPlant::start(link, plant_params(), 1e-3, Duration::from_millis(30), 20).unwrap();
            let mut reference = OnChipPlant::new(&plant_params()).unwrap();
            for k in 0..1000 {
                let u = 0.3 * (k as f64 * 0.05).sin();
                let y = plant.step(u).unwrap();
                // Retries never step the board's plant twice: bit-exact with the model.
                assert_eq!(y, reference.step(u as f32) as f64, "rate {rate}, sample {k}");
            }
            if rate > 0.0 {
                let s = plant.link().stats();
                assert!(s.rx_bad > 0, "{s:?}");
            }
            // Reset restarts the plant at rest.
            plant.reset().unwrap();
            let mut fresh = OnChipPlant::new(&plant_params()).unwrap();
            assert_eq!(plant.step(0.1).unwrap(), fresh.step(0.1) as f64);
            assert!(plant.step(f64::NAN).is_err());
            stop.store(true, Ordering::Relaxed);
            drop(plant);
            h.join().unwrap();
        }
    }

    #[test]
    fn a_silent_board_plant_is_a_device_error() {
        let (host, _dev) = MemoryPort::pair();
        let e = BoardPlant::start(Link::new(host), plant_params(), 1e-3, Duration::from_millis(5), 2)
            .err()
            .unwrap();
        assert_eq!(e.to_string(), "memory port A: no answer to Stop");
    }
}

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

use crate::wire::frame::{SeqGap, SeqTracker};
use crate::wire::{self, Decoder, Message, Packet, WireError};
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

/// SplitMix64 then xorshift: the fault injector's seeded generator.
#[derive(Clone, Debug)]
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        Self((z ^ (z >> 31)) | 1)
    }
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
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

    /// Appends `bytes`, damaged, to `out`.
    pub fn apply(&mut self, bytes: &[u8], out: &mut Vec<u8>) {
        for &b in bytes {
            self.counts.bytes += 1;
            if self.rate > 0.0 && self.rng.unit() < self.rate {
                if self.rng.next() & 1 == 0 {
                    self.counts.dropped += 1;
                } else {
                    self.counts.corrupted += 1;
                    out.push(b ^ (1 << (self.rng.next() % 8)));
                }
            } else {
                out.push(b);
            }
        }
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
    buf: Vec<u8>,
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
        let result = match &mut self.tx_faults {
            Some(f) => {
                let mut damaged = Vec::with_capacity(frame.len());
                f.apply(&frame, &mut damaged);
                self.port.write_all(&damaged)
            }
            None => self.port.write_all(&frame),
        };
        result.map_err(|e| self.io(e))?;
        Ok(seq)
    }

    /// The next frame received before `deadline`: `Ok(None)` if none came in time.
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
                Some(f) => f.apply(&raw[..n], &mut self.buf),
                None => self.buf.extend_from_slice(&raw[..n]),
            }
            for i in 0..self.buf.len() {
                if let Some(r) = self.decoder.push(self.buf[i]) {
                    self.note(&r);
                    self.inbox.push_back(r);
                }
            }
        }
    }

    fn note(&mut self, r: &Received) {
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

    /// Writes a lone delimiter (never damaged), so the peer drops any half-received frame
    /// and the next frame starts clean.
    pub fn flush_peer(&mut self) -> Result<(), TransportError> {
        self.port.write_all(&[0]).map_err(|e| self.io(e))
    }

    /// Drops everything received but not yet returned, and any half-received frame.
    pub fn discard_input(&mut self) {
        self.inbox.clear();
        self.decoder.reset();
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
}

//! A board in QEMU with its link on a pseudo-terminal, and the host's end of that link.

use crate::tools::{self, Board, QEMU};
use boucwen_hal::transport::{self, Link};
use boucwen_link::Message;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// QEMU running the firmware; killed when dropped.
pub struct Session {
    child: Child,
    /// The pseudo-terminal of the board's link.
    pub pty: String,
    readers: Vec<std::thread::JoinHandle<()>>,
}

impl Session {
    /// Starts QEMU on `board` with `elf` (`virtual_only`: see [`tools::qemu_command`]) and waits for it to name the pseudo-terminal.
    pub fn start(board: Board, elf: &Path, virtual_only: bool) -> Result<Self, String> {
        let mut qemu = tools::qemu_command(board, elf, virtual_only);
        let mut child = qemu
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("cannot start {}: {e}", QEMU.path))?;
        // QEMU names the pseudo-terminal on stdout or stderr (depending on the version).
        let (tx, rx) = mpsc::channel::<String>();
        let mut readers = Vec::new();
        for stream in [
            child.stdout.take().map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
            child.stderr.take().map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
        ]
        .into_iter()
        .flatten()
        {
            let tx = tx.clone();
            readers.push(std::thread::spawn(move || {
                for line in BufReader::new(stream).lines().map_while(Result::ok) {
                    let _ = tx.send(line);
                }
            }));
        }
        drop(tx);
        let mut lines = Vec::new();
        while let Ok(line) = rx.recv_timeout(Duration::from_secs(10)) {
            if let Some(at) = line.find("/dev/pts/") {
                let pty: String = line[at..].chars().take_while(|c| !c.is_whitespace()).collect();
                return Ok(Self { child, pty, readers });
            }
            lines.push(line);
        }
        let _ = child.kill();
        let _ = child.wait();
        Err(format!("QEMU did not report its pseudo-terminal; it said: {}", lines.join(" | ")))
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
    }
}

/// Sends `m` and waits for its `Ack` (a `Fault` naming it, or no answer, is an error).
pub fn request_ok<P: transport::Port>(link: &mut Link<P>, m: &Message) -> Result<(), String> {
    let want = m.kind();
    let r = link
        .request(m, 3, Duration::from_secs(2), |seq, a| match a {
            Message::Ack { kind, seq: s } if *kind == want && *s == seq => Some(Ok(())),
            Message::Fault(f) if f.seq == seq => Some(Err(format!("{:?}: {}", f.code, f.text))),
            _ => None,
        })
        .map_err(|e| e.to_string())?;
    match r {
        Some(Ok(())) => Ok(()),
        Some(Err(e)) => Err(format!("the board refused kind 0x{want:02x}: {e}")),
        None => Err(format!("no answer to kind 0x{want:02x}")),
    }
}

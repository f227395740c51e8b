//! The self-test: the compensator (or, with the `orc` feature and a `SetOrc` frame, the
//! odd-harmonic repetitive controller) against the on-chip plant, every output printed as
//! bits for the host to compare, every control step timed.
//!
//! The host (`cargo xtask qemu`) writes the run's frames (`SetController`, `SetPlant`,
//! `Start`, encoded with the wire protocol) to a file and names it on QEMU's semihosting
//! command line (`selftest PATH`). The firmware decodes them with the same code it uses
//! on the serial link, runs [`ClosedLoop`] for the requested samples and prints
//!
//! ```text
//! selftest compensator | orc
//! selftest samples N
//! clock SPIN_INSNS TICKS          a 2·10⁶-instruction spin loop, timed (calibration)
//! sample K U_BITS Y_BITS          u[k] and y[k] as f32 bits in hex, one line per sample
//! timing N STEP_TICKS EMPTY_TICKS MAX_STEP_TICKS
//! stack PEAK_BYTES
//! done
//! ```
//!
//! ## Timing
//! Each control step is timed by reading the free-running clock just before and after the
//! call; the same two reads around a call of an empty function (run as often) measure the
//! overhead, which is subtracted. Under `-icount shift=0` the clock (25 MHz) advances one
//! tick per 40 instructions, so a single interval is known to ±1 tick, but the rounding
//! errors of many intervals of varying length average out: the mean over `N` steps is
//! good to a fraction of an instruction (the host reports it), the largest single step
//! only to ±40 instructions.
//!
//! ## Stack
//! cortex-m-rt paints the free RAM between the statics and the stack top at reset; the
//! lowest word no longer holding the paint marks the deepest the stack has been.

use crate::board::{Board, Clock};
use crate::say;
use boucwen_core::Error;
use boucwen_link::device::{ClosedLoop, Controller, OnChipPlant};
use boucwen_link::message::{ControllerParams, Mode, OrcParams, PlantParams};
use boucwen_link::{Decoder, Message};
use core::hint::black_box;

/// Instructions of the calibration spin loop (two per iteration: `subs`, `bne`).
const SPIN_ITERATIONS: u32 = 1_000_000;

/// Runs `n` instructions' worth of a two-instruction loop.
#[inline(never)]
fn spin(iterations: u32) {
    // SAFETY: a register-only countdown loop; touches no memory and no stack.
    unsafe {
        core::arch::asm!("1:", "subs {0}, #1", "bne 1b", inout(reg) iterations => _, options(nomem, nostack));
    }
}

/// A controller wired to the on-chip plant: the compensator ([`ClosedLoop`]) or, built with
/// the `orc` feature, the odd-harmonic repetitive controller (`OrcLoop`).
trait Loop {
    /// One control step: `u[k]`.
    fn control(&mut self) -> Result<f32, Error>;
    /// Applies `u[k]` to the plant: `y[k]`.
    fn actuate(&mut self, u: f32) -> f32;
}

impl Loop for ClosedLoop {
    #[inline]
    fn control(&mut self) -> Result<f32, Error> {
        ClosedLoop::control(self).map(|s| s.out.u)
    }
    #[inline]
    fn actuate(&mut self, u: f32) -> f32 {
        ClosedLoop::actuate(self, u)
    }
}

#[cfg(feature = "orc")]
impl Loop for boucwen_link::device::OrcLoop {
    #[inline]
    fn control(&mut self) -> Result<f32, Error> {
        boucwen_link::device::OrcLoop::control(self).map(|s| s.out.u)
    }
    #[inline]
    fn actuate(&mut self, u: f32) -> f32 {
        boucwen_link::device::OrcLoop::actuate(self, u)
    }
}

#[inline(never)]
fn control<L: Loop>(cl: &mut L) -> Result<f32, Error> {
    cl.control()
}

#[inline(never)]
fn nothing<L>(cl: &mut L) {
    black_box(cl);
}

/// Why the self-test could not run.
pub enum Failure {
    /// The frames file did not hold SetController, SetPlant and Start{Control}.
    Frames(&'static str),
    /// The parameters were rejected.
    Params(Error),
    /// A step failed.
    Step(u32, Error),
}

impl core::fmt::Display for Failure {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Failure::Frames(what) => write!(f, "self-test frames: {what}"),
            Failure::Params(e) => write!(f, "self-test parameters: {e}"),
            Failure::Step(k, e) => write!(f, "self-test step {k}: {e}"),
        }
    }
}

/// The self-test's frames: compensator (and reference), plant, the ORC's gains if the ORC
/// is to run instead of the compensator, and the sample count.
struct Frames {
    controller: ControllerParams,
    plant: PlantParams,
    orc: Option<OrcParams>,
    samples: u32,
}

/// Decodes the self-test's frames.
fn parse(frames: &[u8]) -> Result<Frames, Failure> {
    let (mut ctl, mut plant, mut n, mut orc) = (None, None, None, None);
    let mut dec = Decoder::new();
    for &b in frames {
        match dec.push(b) {
            None => {}
            Some(Err(_)) => return Err(Failure::Frames("a frame failed its checks")),
            Some(Ok(p)) => match p.msg {
                Message::SetController(c) => ctl = Some(c),
                Message::SetPlant(pl) => plant = Some(pl),
                Message::SetOrc(o) => orc = Some(o),
                Message::Start { mode: Mode::Control, samples } => n = Some(samples),
                _ => return Err(Failure::Frames("unexpected message")),
            },
        }
    }
    match (ctl, plant, n) {
        (Some(controller), Some(plant), Some(samples)) => Ok(Frames { controller, plant, orc, samples }),
        _ => Err(Failure::Frames("need SetController, SetPlant and Start{Control}")),
    }
}

/// Peak stack use so far, bytes.
pub fn stack_peak() -> u32 {
    unsafe extern "C" {
        static _stack_end: u32;
        static _stack_start: u32;
    }
    let (lo, hi) = (&raw const _stack_end as usize, &raw const _stack_start as usize);
    let mut at = lo;
    while at < hi {
        // SAFETY: [_stack_end, _stack_start) is the stack region of RAM, word-aligned; the
        // words below the stack pointer belong to no Rust object (they hold the paint).
        let w = unsafe { core::ptr::read_volatile(at as *const u32) };
        if w != cortex_m_rt::STACK_PAINT_VALUE {
            break;
        }
        at += 4;
    }
    (hi - at) as u32
}

/// Runs the self-test on the frames in `frames`.
pub fn run(board: &mut Board, frames: &[u8]) -> Result<(), Failure> {
    let f = parse(frames)?;
    match f.orc {
        None => {
            let controller = Controller::new(&f.controller).map_err(Failure::Params)?;
            let plant = OnChipPlant::new(&f.plant).map_err(Failure::Params)?;
            say!("selftest compensator");
            exercise(board, ClosedLoop::new(controller, plant), f.samples)
        }
        #[cfg(feature = "orc")]
        Some(o) => {
            let l = boucwen_link::device::OrcLoop::new(&f.controller, &o, &f.plant)
                .map_err(Failure::Params)?;
            say!("selftest orc");
            exercise(board, l, f.samples)
        }
        #[cfg(not(feature = "orc"))]
        Some(_) => Err(Failure::Frames("SetOrc: the ORC is not built in (firmware feature `orc`)")),
    }
}

/// Times `n` steps of `cl` and prints every output.
fn exercise<L: Loop>(board: &mut Board, mut cl: L, n: u32) -> Result<(), Failure> {
    let clock: &Clock = &board.clock;
    say!("selftest samples {}", n);

    let t0 = clock.now();
    spin(SPIN_ITERATIONS);
    let t1 = clock.now();
    say!("clock {} {}", 2 * SPIN_ITERATIONS, t1.wrapping_sub(t0));

    let mut empty_ticks = 0u64;
    for _ in 0..n {
        let a = clock.now();
        nothing(&mut cl);
        let b = clock.now();
        empty_ticks += b.wrapping_sub(a) as u64;
    }
    let (mut step_ticks, mut max_ticks) = (0u64, 0u32);
    for k in 0..n {
        let a = clock.now();
        let u = control(&mut cl);
        let b = clock.now();
        let u = u.map_err(|e| Failure::Step(k, e))?;
        let dt = b.wrapping_sub(a);
        step_ticks += dt as u64;
        max_ticks = max_ticks.max(dt);
        let y = cl.actuate(u);
        say!("sample {} {:08x} {:08x}", k, u.to_bits(), y.to_bits());
    }
    say!("timing {} {} {} {}", n, step_ticks, empty_ticks, max_ticks);
    say!("stack {}", stack_peak());
    say!("done");
    Ok(())
}

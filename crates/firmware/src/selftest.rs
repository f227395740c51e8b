//! The self-test: the compensator against the on-chip plant, every output printed as bits
//! for the host to compare, every control step timed.
//!
//! The host (`cargo xtask qemu`) writes the run's frames (`SetController`, `SetPlant`,
//! `Start`, encoded with the wire protocol) to a file and names it on QEMU's semihosting
//! command line (`selftest PATH`). The firmware decodes them with the same code it uses
//! on the serial link, runs [`ClosedLoop`] for the requested samples and prints
//!
//! ```text
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
use boucwen_hal::wire::device::{ClosedLoop, ControlStep, Controller, OnChipPlant};
use boucwen_hal::wire::message::{ControllerParams, Mode, PlantParams};
use boucwen_hal::wire::{Decoder, Message};
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

#[inline(never)]
fn control(cl: &mut ClosedLoop) -> Result<ControlStep, Error> {
    cl.control()
}

#[inline(never)]
fn nothing(cl: &mut ClosedLoop) {
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

/// Decodes the self-test's frames.
fn parse(frames: &[u8]) -> Result<(ControllerParams, PlantParams, u32), Failure> {
    let (mut ctl, mut plant, mut n) = (None, None, None);
    let mut dec = Decoder::new();
    for &b in frames {
        match dec.push(b) {
            None => {}
            Some(Err(_)) => return Err(Failure::Frames("a frame failed its checks")),
            Some(Ok(p)) => match p.msg {
                Message::SetController(c) => ctl = Some(c),
                Message::SetPlant(pl) => plant = Some(pl),
                Message::Start { mode: Mode::Control, samples } => n = Some(samples),
                _ => return Err(Failure::Frames("unexpected message")),
            },
        }
    }
    match (ctl, plant, n) {
        (Some(c), Some(p), Some(n)) => Ok((c, p, n)),
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
    let (cp, pp, n) = parse(frames)?;
    let controller = Controller::new(&cp).map_err(Failure::Params)?;
    let plant = OnChipPlant::new(&pp).map_err(Failure::Params)?;
    let clock: &Clock = &board.clock;
    say!("selftest samples {}", n);

    let t0 = clock.now();
    spin(SPIN_ITERATIONS);
    let t1 = clock.now();
    say!("clock {} {}", 2 * SPIN_ITERATIONS, t1.wrapping_sub(t0));

    let mut cl = ClosedLoop::new(controller, plant);
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
        let step = control(&mut cl);
        let b = clock.now();
        let step = step.map_err(|e| Failure::Step(k, e))?;
        let dt = b.wrapping_sub(a);
        step_ticks += dt as u64;
        max_ticks = max_ticks.max(dt);
        let y = cl.actuate(step.out.u);
        say!("sample {} {:08x} {:08x}", k, step.out.u.to_bits(), y.to_bits());
    }
    say!("timing {} {} {} {}", n, step_ticks, empty_ticks, max_ticks);
    say!("stack {}", stack_peak());
    say!("done");
    Ok(())
}

//! # boucwen-firmware
//!
//! The driver board's firmware: the boucwen compensator (`u_f` and the online odd-harmonic
//! cancellation, `boucwen_core::compensator` in `f32`) run once per sample on a
//! Cortex-M4F, parameters and samples exchanged with the host over the wire protocol of
//! `boucwen_hal::wire`. `no_std`, no allocation; 64 KiB of flash and 16 KiB of RAM at
//! most (`memory.x`: the linker refuses more).
//!
//! | module | what |
//! |---|---|
//! | [`board`] | QEMU `mps2-an386`: UART0, timers, interrupts, semihosting (the only board-specific code) |
//! | [`link`] | the normal mode: protocol on UART0, control step on every timer tick |
//! | [`selftest`] | compensator against the on-chip plant, outputs as bits, steps timed |
//! | [`ring`] | the interrupt-to-main-loop byte queue |
//!
//! The mode comes from QEMU's semihosting command line: `selftest PATH` runs the
//! self-test on the frames in the host file `PATH`; anything else serves the link.
//! `cargo xtask firmware | qemu | hil` build and run it.
#![no_std]
#![no_main]

mod board;
mod console;
mod link;
mod ring;
mod selftest;

use cortex_m_rt::entry;
use cortex_m_semihosting::debug;

/// The UART's nominal rate (QEMU does not pace the UART; a real link needs this much for
/// 1 kHz, see `boucwen_hal::wire`).
const BAUD: u32 = 460_800;

/// Largest self-test frames file.
const FRAMES_MAX: usize = 512;

#[entry]
fn main() -> ! {
    let Some(mut board) = board::Board::take(BAUD) else {
        fail(format_args!("board already taken"));
    };
    let mut cmdline = [0u8; 320];
    let line = board::semihosting::command_line(&mut cmdline).unwrap_or("");
    let mut words = line.split(' ');
    if words.next() == Some("selftest") {
        let path = words.next().unwrap_or("");
        let mut buf = [0u8; FRAMES_MAX];
        let Some(frames) = board::semihosting::read_file(path, &mut buf) else {
            fail(format_args!("selftest: cannot read the frames file '{path}'"));
        };
        match selftest::run(&mut board, frames) {
            Ok(()) => debug::exit(debug::EXIT_SUCCESS),
            Err(e) => fail(format_args!("{e}")),
        }
        loop {
            cortex_m::asm::wfi();
        }
    }
    link::run(&mut board)
}

/// Reports `what` on the host console and ends the QEMU run with a failure status.
fn fail(what: core::fmt::Arguments) -> ! {
    console::line(format_args!("error: {what}"));
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    fail(format_args!("panic: {info}"))
}

//! # boucwen-firmware
//!
//! The driver board's firmware: the boucwen compensator (`u_f` and the online odd-harmonic
//! cancellation, `boucwen_core::compensator` in `f32`) run once per sample on a
//! Cortex-M4F, parameters and samples exchanged with the host over the wire protocol of
//! `boucwen_link`. `no_std`, no allocation; 64 KiB of flash and 16 KiB of RAM at
//! most (`memory.x`: the linker refuses more).
//!
//! | module | what |
//! |---|---|
//! | [`board`] | QEMU `mps2-an386` (default): UART0, timers, interrupts, semihosting; or an STM32F4 (feature `stm32f4`, build-only): USART2, TIM2. The only board-specific code |
//! | [`link`] | the normal mode: protocol on UART0, control step on every timer tick |
//! | [`selftest`] | compensator against the on-chip plant, outputs as bits, steps timed |
//! | [`ring`] | the interrupt-to-main-loop byte queue |
//!
//! On `mps2-an386` the mode comes from QEMU's semihosting command line: `selftest PATH`
//! runs the self-test on the frames in the host file `PATH`; anything else serves the link.
//! The STM32F4 build always serves the link.
//! `cargo xtask firmware | qemu | hil` build and run it.
#![no_std]
#![no_main]

#[cfg(not(feature = "stm32f4"))]
#[path = "board/mps2_an386.rs"]
mod board;
#[cfg(feature = "stm32f4")]
#[path = "board/stm32f4.rs"]
mod board;
#[cfg(not(feature = "stm32f4"))]
mod console;
mod link;
mod ring;
#[cfg(not(feature = "stm32f4"))]
mod selftest;

use cortex_m_rt::entry;

/// The UART's nominal rate (QEMU does not pace the UART; a real link needs this much for
/// 1 kHz, see `boucwen_link`).
const BAUD: u32 = 460_800;

/// Largest self-test frames file.
const FRAMES_MAX: usize = 512;

#[entry]
fn main() -> ! {
    let Some(mut board) = board::Board::take(BAUD) else {
        fail(format_args!("board already taken"));
    };
    let mut cmdline = [0u8; 320];
    let mut buf = [0u8; FRAMES_MAX];
    match board::self_test_frames(&mut cmdline, &mut buf) {
        Ok(None) => link::run(&mut board),
        Err(path) => fail(format_args!("selftest: cannot read the frames file '{path}'")),
        #[cfg(not(feature = "stm32f4"))]
        Ok(Some(frames)) => match selftest::run(&mut board, frames) {
            Ok(()) => board::exit(true),
            Err(e) => fail(format_args!("{e}")),
        },
        #[cfg(feature = "stm32f4")]
        Ok(Some(_)) => fail(format_args!("no self-test on this board")),
    }
}

/// Reports `what` (on the host console where the board has one) and ends with a failure.
fn fail(what: core::fmt::Arguments) -> ! {
    board::report(format_args!("error: {what}"));
    board::exit(false)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    fail(format_args!("panic: {info}"))
}

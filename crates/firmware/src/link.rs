//! The firmware's normal life: the wire protocol on UART0, the control step on the sample
//! timer's tick.
//!
//! The loop sleeps (`wfi`) until an interrupt; then it decodes the bytes the UART interrupt
//! queued, hands each frame to the protocol's [`Device`], and runs one control step per
//! timer tick. Ticks that came while the loop was busy are counted as overruns. Sleeping
//! happens with interrupts masked after checking that nothing is pending, so an interrupt
//! between the check and `wfi` still wakes the core.

use crate::board::{Board, RX, TICKS};
use boucwen_link::Decoder;
use boucwen_link::device::{Device, TimerRequest};
use core::sync::atomic::Ordering;

/// Serves the host forever.
pub fn run(board: &mut Board) -> ! {
    let mut device = Device::new();
    let mut decoder = Decoder::new();
    let mut seen = TICKS.load(Ordering::Acquire);
    loop {
        board.uart.poll();
        while let Some(b) = RX.pop() {
            if let Some(packet) = decoder.push(b) {
                let uart = &mut board.uart;
                let req = device.on_packet(packet, &mut |bytes: &[u8]| uart.write(bytes));
                apply(board, req, &mut seen);
            }
        }
        let dropped = RX.take_dropped();
        if dropped > 0 {
            device.note_rx_overflow(dropped);
        }
        let now = TICKS.load(Ordering::Acquire);
        if now != seen {
            let missed = now.wrapping_sub(seen).wrapping_sub(1);
            seen = now;
            let uart = &mut board.uart;
            let req = device.on_tick(missed, &mut |bytes: &[u8]| uart.write(bytes));
            apply(board, req, &mut seen);
        }
        let mid_frame = decoder.pending() > 0;
        cortex_m::interrupt::free(|_| {
            if !mid_frame && RX.is_empty() && TICKS.load(Ordering::Acquire) == seen {
                cortex_m::asm::wfi();
            }
        });
    }
}

fn apply(board: &mut Board, req: TimerRequest, seen: &mut u32) {
    match req {
        TimerRequest::Keep => {}
        TimerRequest::Start { period_us } => {
            board.timer.start(period_us);
            *seen = TICKS.load(Ordering::Acquire);
        }
        TimerRequest::Stop => board.timer.stop(),
    }
}

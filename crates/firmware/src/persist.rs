//! What survives a reset: the drive and why the firmware went down, in RAM that the
//! start-up code does not touch (`.uninit`), checked by a magic word and a checksum.
//!
//! The sample-timer interrupt stores the drive after every tick; the panic handler adds
//! the reason and resets the chip. At start-up [`take`] returns the drive and the reason
//! (a record with a bad checksum, as after power-on, is no record), so the board can ramp
//! the drive from where it was to 0 V and report why.

use boucwen_link::message::SafeReason;
use core::mem::MaybeUninit;
use core::sync::atomic::{Ordering, compiler_fence};

const MAGIC: u32 = 0xB0C3_5AFE;

#[unsafe(link_section = ".uninit.PERSIST")]
static mut RECORD: MaybeUninit<[u32; 4]> = MaybeUninit::uninit();

fn checksum(w: [u32; 3]) -> u32 {
    (w[0] ^ w[1].rotate_left(7) ^ w[2].rotate_left(13)).wrapping_mul(0x9E37_79B1)
}

fn write(reason: u8, drive_v: f32) {
    let w = [MAGIC, reason as u32, drive_v.to_bits()];
    let rec = [w[0], w[1], w[2], checksum(w)];
    // SAFETY: RECORD is only touched here and in `read`, from code that cannot preempt
    // itself on it (the tick interrupt, the panic handler and `init` before interrupts).
    unsafe { core::ptr::write_volatile(&raw mut RECORD as *mut [u32; 4], rec) };
    compiler_fence(Ordering::SeqCst);
}

fn read() -> Option<(u8, f32)> {
    // SAFETY: any bit pattern is a valid [u32; 4]; an uninitialised one fails the checksum.
    let rec = unsafe { core::ptr::read_volatile(&raw const RECORD as *const [u32; 4]) };
    (rec[0] == MAGIC && rec[3] == checksum([rec[0], rec[1], rec[2]]))
        .then(|| (rec[1] as u8, f32::from_bits(rec[2])))
}

/// Stores the drive now (no reason: a normal tick).
#[inline]
pub fn store_drive(drive_v: f32) {
    write(0, drive_v);
}

/// Stores the drive with the reason the firmware is going down.
pub fn store_reason(reason: SafeReason) {
    let drive = read().map_or(0.0, |(_, v)| v);
    write(reason as u8, drive);
}

/// The record left by the last run of the firmware, cleared: the reason (if it went down
/// for one) and the drive.
pub fn take() -> (Option<SafeReason>, f32) {
    let got = read();
    write(0, 0.0);
    match got {
        Some((r, v)) => (SafeReason::from_u8(r), if v.is_finite() { v } else { 0.0 }),
        None => (None, 0.0),
    }
}

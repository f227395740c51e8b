//! What survives a reset: the drive, the slew of its ramp and why the firmware went down,
//! in RAM that the start-up code does not touch (`.uninit`), checked by a magic word and
//! a checksum.
//!
//! The sample-timer interrupt stores the drive (and the slew in force) after every tick;
//! the panic handler adds the reason and resets the chip. At start-up [`take`] returns
//! them (a record with a bad checksum, as after power-on, is no record), so the board can
//! ramp the drive from where it was to 0 V at the slew the host had set, and report why.

use boucwen_link::message::SafeReason;
use core::mem::MaybeUninit;
use core::sync::atomic::{Ordering, compiler_fence};

const MAGIC: u32 = 0xB0C3_5AFE;

#[unsafe(link_section = ".uninit.PERSIST")]
static mut RECORD: MaybeUninit<[u32; 5]> = MaybeUninit::uninit();

fn checksum(w: [u32; 4]) -> u32 {
    (w[0] ^ w[1].rotate_left(7) ^ w[2].rotate_left(13) ^ w[3].rotate_left(19)).wrapping_mul(0x9E37_79B1)
}

fn write(reason: u8, drive_v: f32, slew_v_per_s: f32) {
    let w = [MAGIC, reason as u32, drive_v.to_bits(), slew_v_per_s.to_bits()];
    let rec = [w[0], w[1], w[2], w[3], checksum(w)];
    // SAFETY: RECORD is only touched here and in `read`, from code that cannot preempt
    // itself on it (the tick interrupt, the panic handler and `init` before interrupts).
    unsafe { core::ptr::write_volatile(&raw mut RECORD as *mut [u32; 5], rec) };
    compiler_fence(Ordering::SeqCst);
}

fn read() -> Option<(u8, f32, f32)> {
    // SAFETY: any bit pattern is a valid [u32; 5]; an uninitialised one fails the checksum.
    let rec = unsafe { core::ptr::read_volatile(&raw const RECORD as *const [u32; 5]) };
    (rec[0] == MAGIC && rec[4] == checksum([rec[0], rec[1], rec[2], rec[3]]))
        .then(|| (rec[1] as u8, f32::from_bits(rec[2]), f32::from_bits(rec[3])))
}

/// Stores the drive and the slew in force now (no reason: a normal tick).
#[inline]
pub fn store_drive(drive_v: f32, slew_v_per_s: f32) {
    write(0, drive_v, slew_v_per_s);
}

/// Stores the reason the firmware is going down, keeping the drive and slew stored last.
pub fn store_reason(reason: SafeReason) {
    let (drive, slew) = read().map_or((0.0, f32::NAN), |(_, v, s)| (v, s));
    write(reason as u8, drive, slew);
}

/// The record left by the last run of the firmware, cleared: the reason (if it went down
/// for one), the drive (0 V if not finite) and the slew (unchecked: the device checks it).
pub fn take() -> (Option<SafeReason>, f32, f32) {
    let got = read();
    write(0, 0.0, f32::NAN);
    match got {
        Some((r, v, s)) => (SafeReason::from_u8(r), if v.is_finite() { v } else { 0.0 }, s),
        None => (None, 0.0, f32::NAN),
    }
}

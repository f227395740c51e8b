//! # boucwen-firmware
//!
//! The driver board's firmware: the boucwen compensator (`u_f` and the online odd-harmonic
//! cancellation, `boucwen_core::compensator` in `f32`) run in the sample timer's interrupt
//! of a Cortex-M4F, parameters and samples exchanged with the host over the wire protocol
//! of `boucwen_link`. `no_std`, no allocation; 64 KiB of flash and 16 KiB of RAM at
//! most (`memory.x`: the linker refuses more).
//!
//! ## Tasks (RTIC 2)
//! | task | priority | what |
//! |---|---|---|
//! | sample timer interrupt | 3 (highest) | reads the sensor, steps the controller, writes the drive, queues the telemetry frame (`Device::on_tick`); times itself; counts missed ticks; stores the drive for after a reset |
//! | UART interrupt | 2 | received bytes into [`RX`]; on a chip also the transmitter, one byte per "transmit empty" interrupt from [`TX`] |
//! | pacing timer interrupt | 2 | `mps2-an386`: one byte of [`TX`] per byte time at [`BAUD`] (QEMU's UART sends at once; a real one does not); the STM32F4's `emulator` build paces from SysTick at the same priority, and a chip's UART paces itself |
//! | idle | 0 | decodes [`RX`], hands frames to `Device::on_packet` (locking the device: the tick waits at most one frame's handling), feeds the watchdog while ticks come, sleeps |
//!
//! RTIC because the design is a few interrupts at fixed priorities sharing one state:
//! RTIC checks the sharing at compile time and locks by raising BASEPRI only to the
//! ceiling (no global interrupt masking, no allocator, no executor), which is what a
//! hard-real-time control interrupt wants; embassy's async executor adds nothing a
//! fixed-rate interrupt needs.
//!
//! Nothing in the control path waits: frames go into [`TX`] whole or are dropped and
//! counted, and the transmitter empties it by interrupt.
//!
//! | module | what |
//! |---|---|
//! | [`board`] | QEMU `mps2-an386` (default): CMSDK UART0 and timers; or, with `stm32f4`, an STM32F405/407 on `stm32f4xx-hal` (USART2, TIM2, ADC1, DAC, IWDG), in QEMU's `netduinoplus2` with `emulator` (TIM5's counter as the clock, SysTick as the timer service) |
//! | [`ring`] | the byte queues between priorities |
//! | [`persist`] | the drive and the reason for a reset, kept across it |
#![no_std]
#![no_main]

#[cfg(not(feature = "stm32f4"))]
#[path = "board/mps2_an386.rs"]
mod board;
#[cfg(feature = "stm32f4")]
#[path = "board/stm32f4.rs"]
mod board;
mod persist;
mod ring;

use core::sync::atomic::{AtomicU32, Ordering};
use ring::ByteRing;

/// The UART's rate: a real link needs this much for 1 kHz (see `boucwen_link`).
pub const BAUD: u32 = 460_800;

/// Bytes received, waiting for `idle`.
pub static RX: ByteRing<512> = ByteRing::new();
/// Frames to send, waiting for the transmitter: 4 KiB, 200 ms of telemetry at 1 kHz (the
/// line drains 46 bytes per ms). In QEMU on a loaded machine this queue overflowed (16 to
/// 208 of 5,000 frames, with 1, 4 or 8 KiB) while the host sent its keepalives on its own
/// clock: the board, slower than the wall, had more of them to answer per second of its
/// own than the line could carry beside the telemetry. The host now paces them by the
/// board's samples too (`boucwen_hal::board::KEEPALIVE_SAMPLES`).
#[cfg(not(feature = "orc"))]
pub static TX: ByteRing<4096> = ByteRing::new();
/// Frames to send: 2 KiB with the ORC, whose 512-sample delay line is on the stack (with
/// 4 KiB the ORC build's static RAM and peak stack filled the 16 KiB, and the stack ran
/// into the statics).
#[cfg(feature = "orc")]
pub static TX: ByteRing<2048> = ByteRing::new();
/// A tick period requested by `idle` (0: none), applied by the tick interrupt.
static PERIOD_REQUEST_US: AtomicU32 = AtomicU32::new(0);
/// Ticks handled (for the watchdog's feeding in `idle`).
static TICKS: AtomicU32 = AtomicU32::new(0);

/// The board's free-running clock (for the intervals between ticks and the cost of the
/// control step; its unit is calibrated against a spin loop at start-up).
#[inline(always)]
pub fn clock() -> u32 {
    board::clock()
}

/// A free-running clock on SysTick (24 bits, counting down at the core clock), read so
/// that differences of two reads wrap correctly in `u32`: one unit is 1/256 of a core
/// clock, and an interval up to 2²⁴ core clocks is measured exactly. What the boards use,
/// unless SysTick has another job ([`start_systick_clock`] starts it).
#[inline(always)]
pub fn systick_clock() -> u32 {
    // SAFETY: reading SysTick's current value register has no side effect.
    let cvr = unsafe { (*cortex_m::peripheral::SYST::PTR).cvr.read() };
    (!cvr) << 8
}

/// Starts SysTick as [`systick_clock`]: the core clock, the full 24-bit range, no interrupt.
pub fn start_systick_clock(syst: &mut cortex_m::peripheral::SYST) {
    syst.set_clock_source(cortex_m::peripheral::syst::SystClkSource::Core);
    syst.set_reload(0x00FF_FFFF);
    syst.clear_current();
    syst.enable_counter();
}

/// Queues one encoded frame for the transmitter (whole, or dropped and counted).
fn send(bytes: &[u8]) {
    TX.push_all(bytes);
    board::kick_tx();
}

/// Instructions of the calibration loop: 2 per iteration (`subs`, `bne`).
const SPIN_ITERATIONS: u32 = 1_000_000;

#[inline(never)]
fn spin(iterations: u32) {
    // SAFETY: a register-only countdown loop; touches no memory and no stack.
    unsafe {
        core::arch::asm!("1:", "subs {0}, #1", "bne 1b", inout(reg) iterations => _, options(nomem, nostack));
    }
}

/// Peak stack use so far, bytes (cortex-m-rt paints the free RAM at reset).
fn stack_peak() -> u32 {
    unsafe extern "C" {
        static _stack_end: u32;
        static _stack_start: u32;
    }
    let (lo, hi) = (&raw const _stack_end as usize, &raw const _stack_start as usize);
    let mut at = lo;
    while at < hi {
        // SAFETY: [_stack_end, _stack_start) is the stack region, word-aligned; the words
        // below the stack pointer belong to no Rust object.
        let w = unsafe { core::ptr::read_volatile(at as *const u32) };
        if w != cortex_m_rt::STACK_PAINT_VALUE {
            break;
        }
        at += 4;
    }
    (hi - at) as u32
}

/// Counts the sample periods missed between two tick interrupts from the clock: the
/// period in clock units is learnt as the median of the intervals between the 8th and the
/// 40th tick after start-up, and again after the start of each run (the timer and the clock
/// need not share a source; a median ignores the odd interval stretched or shortened by a
/// late interrupt), then any interval over 1.5 periods missed `round(interval / period) - 1`
/// ticks. Learnt again at each run: in QEMU's `mps2-an386` (`-icount`, `sleep=off`) the
/// intervals of an idle board after start-up were two thirds of those of a run on one host
/// (every tick of a self-test run then counted missed), not on another; a run's own first
/// ticks are what its later ones are compared with.
pub struct MissedTicks {
    seen: [u32; Self::LEARN as usize],
    last: Option<u32>,
    per_1000us: u32,
    learning: u32,
    period_us: u32,
    running: bool,
}

impl MissedTicks {
    const SKIP: u32 = 8;
    const LEARN: u32 = 32;

    const fn new() -> Self {
        Self {
            seen: [0; Self::LEARN as usize],
            last: None,
            per_1000us: u32::MAX,
            learning: Self::SKIP + Self::LEARN,
            period_us: 1000,
            running: false,
        }
    }

    /// Notes whether a run is on: at a run's start the period is learnt again.
    fn run_state(&mut self, running: bool) {
        if running && !self.running {
            self.learning = Self::SKIP + Self::LEARN;
            self.per_1000us = u32::MAX;
        }
        self.running = running;
    }

    fn period_changed(&mut self, period_us: u32) {
        self.period_us = period_us;
        self.last = None;
        if self.learning > 0 {
            // Learn at the new period from its start.
            self.learning = Self::SKIP + Self::LEARN;
        }
    }

    fn at(&mut self, now: u32) -> u32 {
        let Some(last) = self.last.replace(now) else { return 0 };
        let interval = now.wrapping_sub(last);
        if self.learning > 0 {
            if self.learning <= Self::LEARN {
                self.seen[(self.learning - 1) as usize] = interval;
            }
            self.learning -= 1;
            if self.learning == 0 {
                self.seen.sort_unstable();
                // The median interval at the current period, scaled to 1000 µs.
                let median = self.seen[Self::LEARN as usize / 2] as u64;
                self.per_1000us = (median * 1000 / self.period_us.max(1) as u64).min(u32::MAX as u64) as u32;
            }
            return 0;
        }
        let expected = (self.per_1000us as u64 * self.period_us as u64 / 1000).max(1);
        let i = interval as u64;
        if i * 2 > expected * 3 { ((i + expected / 2) / expected).saturating_sub(1) as u32 } else { 0 }
    }
}

#[rtic::app(device = crate::board::pac, peripherals = false)]
mod app {
    use super::*;
    use boucwen_link::Decoder;
    use boucwen_link::device::{Device, TimerRequest};

    #[shared]
    struct Shared {
        device: Device,
    }

    #[local]
    struct Local {
        tick: board::Tick,
        converters: board::Converters,
        serial: board::SerialPort,
        pacer: board::Pacer,
        watchdog: board::Watchdog,
        decoder: Decoder,
        missed: MissedTicks,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let mut core = cx.core;
        let (saved_reason, saved_drive, saved_slew) = persist::take();
        let watchdog_reset = board::watchdog_reset();
        let resume_v = if saved_reason.is_some() || watchdog_reset { saved_drive } else { 0.0 };
        // The free-running clock starts here too.
        let parts = board::init(BAUD, resume_v, core.SYST, &mut core.SCB);
        let mut device = Device::new();
        if board::HAS_CONVERTERS {
            device = device.with_converters();
        }
        // Calibration: a spin loop of known length, and the cost of reading the clock.
        let t0 = clock();
        spin(SPIN_ITERATIONS);
        let t1 = clock();
        let t2 = clock();
        let d = device.diagnostics_mut();
        d.calib_insns = 2 * SPIN_ITERATIONS;
        d.calib_ticks = t1.wrapping_sub(t0);
        d.clock_overhead_ticks = clock().wrapping_sub(t2);
        let reason = if watchdog_reset { Some(boucwen_link::message::SafeReason::Watchdog) } else { saved_reason };
        if let Some(r) = reason {
            device.begin_safe_state(r, saved_drive, saved_slew);
        }
        board::log_start(reason.map_or(0, |r| r as u8));
        // A lone delimiter first: the host drops whatever half frame the reset cut off.
        send(&[0]);
        let mut tick = parts.tick;
        tick.start(device.period_us());
        (
            Shared { device },
            Local {
                tick,
                converters: parts.converters,
                serial: parts.serial,
                pacer: parts.pacer,
                watchdog: parts.watchdog,
                decoder: Decoder::new(),
                missed: MissedTicks::new(),
            },
        )
    }

    #[idle(shared = [device], local = [decoder, watchdog])]
    fn idle(mut cx: idle::Context) -> ! {
        let mut fed_at = TICKS.load(Ordering::Relaxed);
        loop {
            while let Some(b) = RX.pop() {
                if let Some(packet) = cx.local.decoder.push(b) {
                    let peak = stack_peak();
                    let req = cx.shared.device.lock(|d| {
                        d.diagnostics_mut().stack_peak_bytes = peak;
                        #[cfg(feature = "panic-test")]
                        if d.running() && matches!(&packet, Ok(p) if p.msg == boucwen_link::Message::Stop) {
                            panic!("panic-test: Stop during a run");
                        }
                        d.on_packet(packet, &mut send)
                    });
                    if let TimerRequest::Start { period_us } = req {
                        PERIOD_REQUEST_US.store(period_us, Ordering::Release);
                    }
                }
            }
            let (rx_dropped, tx_dropped) = (RX.take_dropped(), TX.take_dropped());
            if rx_dropped + tx_dropped > 0 {
                cx.shared.device.lock(|d| {
                    d.note_rx_overflow(rx_dropped);
                    for _ in 0..tx_dropped {
                        d.note_tx_dropped();
                    }
                });
            }
            // The watchdog is fed only while the control interrupt runs.
            let ticks = TICKS.load(Ordering::Relaxed);
            if ticks != fed_at {
                fed_at = ticks;
                cx.local.watchdog.feed();
            }
            // Sleep until the next interrupt, also in the middle of a frame: the receive
            // interrupt wakes it. (Checked with interrupts masked, so a byte that arrives
            // after the check still ends the sleep: WFI wakes on a pending interrupt.)
            // In QEMU, spinning here would also starve the emulator's I/O: under -icount
            // the UART gets its next byte only when the CPU idles or a timer expires.
            rtic::export::interrupt::free(|_| {
                if RX.is_empty() {
                    cortex_m::asm::wfi();
                }
            });
        }
    }

    #[task(binds = TICK, priority = 3, shared = [device], local = [tick, converters, missed])]
    fn tick(mut cx: tick::Context) {
        let t0 = clock();
        let local = cx.local;
        local.tick.clear();
        let request = PERIOD_REQUEST_US.swap(0, Ordering::Acquire);
        if request != 0 && request != local.missed.period_us {
            local.tick.start(request);
            local.missed.period_changed(request);
        }
        let converters = &mut *local.converters;
        let missed_ticks = &mut *local.missed;
        cx.shared.device.lock(|device| {
            let in_run = device.running();
            missed_ticks.run_state(in_run);
            let missed = missed_ticks.at(t0);
            device.on_tick(missed, converters, &clock, &mut send);
            persist::store_drive(device.drive_v(), device.safety().slew_v_per_s);
            TICKS.fetch_add(1, Ordering::Relaxed);
            if in_run {
                // Timed over the ticks of a run (the idle ones cost next to nothing).
                let dt = clock().wrapping_sub(t0);
                let d = device.diagnostics_mut();
                d.isr_ticks_max = d.isr_ticks_max.max(dt);
                d.isr_ticks_sum = d.isr_ticks_sum.wrapping_add(dt as u64);
            }
        });
    }

    #[task(binds = UART, priority = 2, local = [serial])]
    fn uart(cx: uart::Context) {
        cx.local.serial.on_interrupt();
    }

    #[task(binds = PACE, priority = 2, local = [pacer])]
    fn pace(cx: pace::Context) {
        cx.local.pacer.on_interrupt();
    }
}

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    // The drive of the last tick is in the record; add why, and start again: the next
    // start ramps the drive from there to 0 V and reports the panic.
    persist::store_reason(boucwen_link::message::SafeReason::Panic);
    cortex_m::peripheral::SCB::sys_reset()
}

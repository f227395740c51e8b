//! The board layer for QEMU's `mps2-an386` (ARM MPS2 FPGA board, AN386 image: a Cortex-M4
//! with FPU). It has no converters: runs drive the on-chip simulated actuator or the host.
//!
//! | peripheral | address | IRQ | the app's name | use |
//! |---|---|---|---|---|
//! | CMSDK APB UART0 | `0x4000_4000` | 0 (RX) | `UART` | the link to the host (`-serial`) |
//! | CMSDK APB timer 0 | `0x4000_0000` | 8 | `TICK` | the sample tick |
//! | CMSDK APB timer 1 | `0x4000_1000` | 9 | `PACE` | one transmitted byte per byte time at the baud rate |
//!
//! The timers and the UART run from the 25 MHz system clock ([`SYSCLK_HZ`]). QEMU's UART
//! sends a byte as soon as it is written, so the transmitter is paced by timer 1 at the
//! configured baud rate (ten bit times per byte), as a real line would be. This board only
//! exists in QEMU, so it has no watchdog to feed and no reset cause to read.
//!
//! Register access is the only `unsafe` code here: volatile reads and writes of the
//! documented registers above.

use crate::{RX, TX};
use boucwen_link::analog::NoFrontEnd;

/// The system clock of the timers and the UART, Hz.
pub const SYSCLK_HZ: u32 = 25_000_000;

/// No converters on this board.
pub const HAS_CONVERTERS: bool = false;

/// The board's converters: none.
pub type Converters = NoFrontEnd;

/// The interrupt lines and the vector table (what a PAC provides for a real chip).
pub mod pac {
    /// Priority bits RTIC assumes (QEMU implements more; the top three are enough).
    pub const NVIC_PRIO_BITS: u8 = 3;

    /// The interrupts the app binds, under the names it binds them by.
    #[derive(Clone, Copy, Debug)]
    #[allow(clippy::upper_case_acronyms)]
    pub enum Interrupt {
        /// UART0 receive.
        UART = 0,
        /// CMSDK timer 0: the sample tick.
        TICK = 8,
        /// CMSDK timer 1: the transmitter's pace.
        PACE = 9,
    }

    /// The name RTIC looks the interrupts up by.
    pub use Interrupt as interrupt;

    // SAFETY: the numbers are the board's IRQ lines (QEMU hw/arm/mps2.c, AN385/AN386 map).
    unsafe impl cortex_m::interrupt::InterruptNumber for Interrupt {
        fn number(self) -> u16 {
            self as u16
        }
    }

    /// One vector: a handler or a reserved slot.
    pub union Vector {
        handler: unsafe extern "C" fn(),
        reserved: usize,
    }

    unsafe extern "C" {
        fn UART();
        fn TICK();
        fn PACE();
    }

    /// The device part of the vector table (cortex-m-rt's `device` feature): the three
    /// lines used, the others unused.
    #[unsafe(link_section = ".vector_table.interrupts")]
    #[unsafe(no_mangle)]
    pub static __INTERRUPTS: [Vector; 32] = {
        let mut v = [const { Vector { reserved: 0 } }; 32];
        v[0] = Vector { handler: UART };
        v[8] = Vector { handler: TICK };
        v[9] = Vector { handler: PACE };
        v
    };
}

/// A memory-mapped 32-bit register of this board.
#[derive(Clone, Copy)]
struct Reg(usize);

impl Reg {
    #[inline(always)]
    fn read(self) -> u32 {
        // SAFETY: `self.0` is one of the aligned peripheral registers listed in the module
        // docs; reading it has no effect beyond the peripheral's documented behaviour.
        unsafe { core::ptr::read_volatile(self.0 as *const u32) }
    }

    #[inline(always)]
    fn write(self, v: u32) {
        // SAFETY: as for `read`; these registers are not memory that Rust code owns.
        unsafe { core::ptr::write_volatile(self.0 as *mut u32, v) }
    }
}

/// CMSDK APB UART registers.
mod uart {
    pub const BASE: usize = 0x4000_4000;
    pub const DATA: usize = 0x00;
    pub const STATE: usize = 0x04;
    pub const CTRL: usize = 0x08;
    pub const INT: usize = 0x0C;
    pub const BAUDDIV: usize = 0x10;
    pub const STATE_TX_FULL: u32 = 1 << 0;
    pub const STATE_RX_FULL: u32 = 1 << 1;
    pub const CTRL_TX_EN: u32 = 1 << 0;
    pub const CTRL_RX_EN: u32 = 1 << 1;
    pub const CTRL_RX_INT_EN: u32 = 1 << 3;
    pub const INT_RX: u32 = 1 << 1;
}

/// CMSDK APB timer registers.
mod timer {
    pub const TIMER0: usize = 0x4000_0000;
    pub const TIMER1: usize = 0x4000_1000;
    pub const CTRL: usize = 0x00;
    pub const VALUE: usize = 0x04;
    pub const RELOAD: usize = 0x08;
    pub const INT: usize = 0x0C;
    pub const CTRL_EN: u32 = 1 << 0;
    pub const CTRL_IRQ_EN: u32 = 1 << 3;
}

/// Starts CMSDK timer `base` interrupting every `ticks` clocks.
fn timer_start(base: usize, ticks: u32) {
    let ticks = ticks.max(2);
    Reg(base + timer::CTRL).write(0);
    Reg(base + timer::INT).write(1);
    // The counter runs RELOAD, …, 1, 0 and interrupts on reaching 0: RELOAD + 1 clocks.
    Reg(base + timer::RELOAD).write(ticks - 1);
    Reg(base + timer::VALUE).write(ticks - 1);
    Reg(base + timer::CTRL).write(timer::CTRL_EN | timer::CTRL_IRQ_EN);
}

/// The sample timer (timer 0).
pub struct Tick {
    _private: (),
}

impl Tick {
    /// Ticks every `period_us` µs.
    pub fn start(&mut self, period_us: u32) {
        let ticks = (period_us as u64 * SYSCLK_HZ as u64 / 1_000_000).clamp(2, u32::MAX as u64) as u32;
        timer_start(timer::TIMER0, ticks);
    }

    /// Acknowledges the interrupt.
    #[inline(always)]
    pub fn clear(&mut self) {
        Reg(timer::TIMER0 + timer::INT).write(1);
    }
}

/// UART0's receiver.
pub struct SerialPort {
    _private: (),
}

impl SerialPort {
    /// Moves every received byte into [`RX`]. Clears the interrupt first, so a byte that
    /// arrives while draining raises it again.
    pub fn on_interrupt(&mut self) {
        Reg(uart::BASE + uart::INT).write(uart::INT_RX);
        while Reg(uart::BASE + uart::STATE).read() & uart::STATE_RX_FULL != 0 {
            RX.push((Reg(uart::BASE + uart::DATA).read() & 0xFF) as u8);
        }
    }
}

/// The transmitter's pace: timer 1 interrupts once per byte time while [`TX`] holds bytes.
pub struct Pacer {
    byte_ticks: u32,
    running: bool,
}

impl Pacer {
    /// Sends one byte of [`TX`] (if the UART can take it); stops when [`TX`] is empty.
    pub fn on_interrupt(&mut self) {
        let fired = Reg(timer::TIMER1 + timer::INT).read() & 1 != 0;
        Reg(timer::TIMER1 + timer::INT).write(1);
        if self.running && !fired {
            // A kick while pacing: the timer sends the next byte on time.
            return;
        }
        if Reg(uart::BASE + uart::STATE).read() & uart::STATE_TX_FULL == 0 {
            match TX.pop() {
                Some(b) => Reg(uart::BASE + uart::DATA).write(b as u32),
                None => {
                    Reg(timer::TIMER1 + timer::CTRL).write(0);
                    self.running = false;
                    return;
                }
            }
        }
        if !self.running {
            timer_start(timer::TIMER1, self.byte_ticks);
            self.running = true;
        }
    }
}

/// Makes the transmitter look at [`TX`]: pends the pacing interrupt, which starts the pace.
pub fn kick_tx() {
    cortex_m::peripheral::NVIC::pend(pac::Interrupt::PACE);
}

/// No watchdog on this board.
pub struct Watchdog;

impl Watchdog {
    /// Nothing to feed.
    pub fn feed(&mut self) {}
}

/// Never: no watchdog.
pub fn watchdog_reset() -> bool {
    false
}

/// No log channel besides the link on this board.
pub fn log_start(_reset_cause: u8) {}

/// The peripherals, set up.
pub struct Parts {
    /// Sample timer (not started).
    pub tick: Tick,
    /// Receiver.
    pub serial: SerialPort,
    /// Transmitter's pace.
    pub pacer: Pacer,
    /// None.
    pub converters: Converters,
    /// None.
    pub watchdog: Watchdog,
}

/// The free-running clock: SysTick.
pub use crate::systick_clock as clock;

/// Sets up the UART (`baud`, receive interrupt), the timers and the free-running clock
/// (SysTick). `_drive_v` (the drive to resume after a reset) has no converter to go to here.
pub fn init(
    baud: u32,
    _drive_v: f32,
    mut syst: cortex_m::peripheral::SYST,
    _scb: &mut cortex_m::peripheral::SCB,
) -> Parts {
    crate::start_systick_clock(&mut syst);
    // The CMSDK UART needs BAUDDIV >= 16; QEMU sends at any rate but checks that.
    Reg(uart::BASE + uart::BAUDDIV).write((SYSCLK_HZ / baud.max(1)).max(16));
    Reg(uart::BASE + uart::CTRL).write(uart::CTRL_TX_EN | uart::CTRL_RX_EN | uart::CTRL_RX_INT_EN);
    Parts {
        tick: Tick { _private: () },
        serial: SerialPort { _private: () },
        pacer: Pacer { byte_ticks: SYSCLK_HZ / (baud.max(1) / 10).max(1), running: false },
        converters: NoFrontEnd,
        watchdog: Watchdog,
    }
}

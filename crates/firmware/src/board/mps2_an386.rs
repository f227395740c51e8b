//! The board layer for QEMU's `mps2-an386` (ARM MPS2 FPGA board, AN386 image: a Cortex-M4
//! with FPU). Everything board-specific is here; the rest of the firmware sees a UART, a
//! sample timer, a free-running clock and the semihosting console.
//!
//! | peripheral | address | IRQ | use |
//! |---|---|---|---|
//! | CMSDK APB UART0 | `0x4000_4000` | 0 (RX) | the link to the host (`-serial`) |
//! | CMSDK APB timer 0 | `0x4000_0000` | 8 | the sample tick |
//! | CMSDK APB timer 1 | `0x4000_1000` | – | free-running 32-bit clock for measurements |
//!
//! Both timers and the UART's baud generator run from the 25 MHz system clock
//! ([`SYSCLK_HZ`]). Under QEMU's `-icount shift=0` one instruction is one nanosecond of
//! virtual time, so one clock tick is 40 instructions; the self-test measures that ratio
//! at start-up (`clock` line of its output) rather than trusting it.
//!
//! Register access is the only `unsafe` code of the firmware: volatile reads and writes of
//! the documented registers above (through [`Reg`]), enabling the two interrupts, and
//! the semihosting calls. Interrupt handlers talk to the main loop through atomics only.

use crate::ring::ByteRing;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::NVIC;
use cortex_m_rt::exception;

/// The system clock of the timers and the UART, Hz.
pub const SYSCLK_HZ: u32 = 25_000_000;

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

/// Interrupt numbers of the peripherals used.
#[derive(Clone, Copy)]
enum Irq {
    Uart0Rx = 0,
    Timer0 = 8,
}

// SAFETY: the numbers are the board's IRQ lines (QEMU hw/arm/mps2.c, AN385/AN386 map).
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

/// Bytes received by the UART interrupt, waiting for the main loop.
pub static RX: ByteRing<512> = ByteRing::new();
/// Sample ticks so far (incremented by the timer interrupt).
pub static TICKS: AtomicU32 = AtomicU32::new(0);

/// UART0: the link to the host.
pub struct Uart {
    _private: (),
}

impl Uart {
    /// Moves every byte the UART holds into [`RX`]. Clears the interrupt first, so a byte
    /// that arrives while draining raises it again.
    fn drain_into_ring() {
        Reg(uart::BASE + uart::INT).write(uart::INT_RX);
        while Reg(uart::BASE + uart::STATE).read() & uart::STATE_RX_FULL != 0 {
            RX.push((Reg(uart::BASE + uart::DATA).read() & 0xFF) as u8);
        }
    }

    /// Sends `bytes`, waiting while the transmit buffer is full.
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            while Reg(uart::BASE + uart::STATE).read() & uart::STATE_TX_FULL != 0 {}
            Reg(uart::BASE + uart::DATA).write(b as u32);
        }
    }

    /// Moves received bytes into [`RX`] now (the interrupt does it too; this catches a byte
    /// that arrived with interrupts masked).
    pub fn poll(&mut self) {
        cortex_m::interrupt::free(|_| Self::drain_into_ring());
    }
}

/// The sample timer (timer 0, interrupt on every period).
pub struct SampleTimer {
    _private: (),
}

impl SampleTimer {
    /// Starts ticking every `period_us` µs; [`TICKS`] counts the ticks.
    pub fn start(&mut self, period_us: u32) {
        let ticks = (period_us as u64 * SYSCLK_HZ as u64 / 1_000_000).clamp(1, u32::MAX as u64) as u32;
        let t = timer::TIMER0;
        Reg(t + timer::CTRL).write(0);
        Reg(t + timer::INT).write(1);
        // The counter runs RELOAD, …, 1, 0 and interrupts on reaching 0: RELOAD + 1 clocks.
        Reg(t + timer::RELOAD).write(ticks - 1);
        Reg(t + timer::VALUE).write(ticks - 1);
        Reg(t + timer::CTRL).write(timer::CTRL_EN | timer::CTRL_IRQ_EN);
    }

    /// Stops ticking.
    pub fn stop(&mut self) {
        Reg(timer::TIMER0 + timer::CTRL).write(0);
        Reg(timer::TIMER0 + timer::INT).write(1);
    }
}

/// A free-running 32-bit clock at [`SYSCLK_HZ`] (timer 1 counting down, read inverted).
pub struct Clock {
    _private: (),
}

impl Clock {
    /// Clock ticks since start, wrapping.
    #[inline(always)]
    pub fn now(&self) -> u32 {
        !Reg(timer::TIMER1 + timer::VALUE).read()
    }
}

/// The board's peripherals, set up.
pub struct Board {
    /// The link.
    pub uart: Uart,
    /// The sample timer.
    pub timer: SampleTimer,
    /// The measurement clock.
    pub clock: Clock,
}

impl Board {
    /// Sets up the clock, the UART (`baud`, receive interrupt) and the timer interrupt.
    /// Returns `None` if called twice.
    pub fn take(baud: u32) -> Option<Self> {
        let _core = cortex_m::Peripherals::take()?;
        let t1 = timer::TIMER1;
        Reg(t1 + timer::CTRL).write(0);
        Reg(t1 + timer::RELOAD).write(u32::MAX);
        Reg(t1 + timer::VALUE).write(u32::MAX);
        Reg(t1 + timer::CTRL).write(timer::CTRL_EN);
        // The CMSDK UART needs BAUDDIV >= 16; QEMU sends at any rate but checks that.
        Reg(uart::BASE + uart::BAUDDIV).write((SYSCLK_HZ / baud.max(1)).max(16));
        Reg(uart::BASE + uart::CTRL).write(uart::CTRL_TX_EN | uart::CTRL_RX_EN | uart::CTRL_RX_INT_EN);
        // SAFETY: the handlers for these lines (in `DefaultHandler`) touch only atomics
        // and the UART's receive registers, so unmasking cannot break a critical section.
        unsafe {
            NVIC::unmask(Irq::Uart0Rx);
            NVIC::unmask(Irq::Timer0);
        }
        Some(Self {
            uart: Uart { _private: () },
            timer: SampleTimer { _private: () },
            clock: Clock { _private: () },
        })
    }
}

/// Every device interrupt lands here with its number (cortex-m-rt's default vector table).
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    match irqn {
        0 => Uart::drain_into_ring(),
        8 => {
            Reg(timer::TIMER0 + timer::INT).write(1);
            TICKS.fetch_add(1, Ordering::Release);
        }
        _ => {}
    }
}

/// Semihosting: the host console, the command line and files, through QEMU.
pub mod semihosting {
    use cortex_m_semihosting::{nr, syscall};

    /// Copies the command line (QEMU's `-semihosting-config arg=…` words, joined by
    /// spaces) into `buf`; returns it, or `None` if the host gave none.
    pub fn command_line(buf: &mut [u8]) -> Option<&str> {
        #[repr(C)]
        struct Block {
            ptr: *mut u8,
            len: usize,
        }
        let mut block = Block { ptr: buf.as_mut_ptr(), len: buf.len() };
        // SAFETY: SYS_GET_CMDLINE writes at most `len` bytes to `ptr` (our buffer) and
        // the length written back into the block.
        let r = unsafe { syscall(nr::GET_CMDLINE, &mut block) };
        if r != 0 {
            return None;
        }
        core::str::from_utf8(buf.get(..block.len)?).ok()
    }

    /// Reads the host file `path` into `buf`; returns the bytes read, `None` on any error
    /// (missing file, longer than `buf`).
    pub fn read_file<'a>(path: &str, buf: &'a mut [u8]) -> Option<&'a [u8]> {
        // SYS_OPEN takes a NUL-terminated name and its length without the NUL.
        let mut name = [0u8; 256];
        name.get_mut(..path.len())?.copy_from_slice(path.as_bytes());
        if path.len() >= name.len() {
            return None;
        }
        let open = [name.as_ptr() as usize, nr::open::R_BINARY, path.len()];
        // SAFETY: the argument block points at our NUL-terminated name.
        let fd = unsafe { syscall(nr::OPEN, &open) };
        if fd == usize::MAX {
            return None;
        }
        let flen = [fd];
        // SAFETY: SYS_FLEN reads the handle only.
        let len = unsafe { syscall(nr::FLEN, &flen) };
        let result = if len <= buf.len() {
            let read = [fd, buf.as_mut_ptr() as usize, len];
            // SAFETY: SYS_READ writes at most `len <= buf.len()` bytes into `buf`; it
            // returns the number of bytes *not* read.
            let left = unsafe { syscall(nr::READ, &read) };
            if left == 0 { buf.get(..len) } else { None }
        } else {
            None
        };
        let close = [fd];
        // SAFETY: closes the handle opened above.
        unsafe { syscall(nr::CLOSE, &close) };
        result
    }
}

/// What the host asked for at start-up: the self-test's frames (`selftest PATH` on the
/// semihosting command line, the file read into `buf`), or `None` to serve the link.
pub fn self_test_frames<'a>(cmdline: &'a mut [u8], buf: &'a mut [u8]) -> Result<Option<&'a [u8]>, &'a str> {
    let line = semihosting::command_line(cmdline).unwrap_or("");
    let mut words = line.split(' ');
    if words.next() != Some("selftest") {
        return Ok(None);
    }
    let path = words.next().unwrap_or("");
    semihosting::read_file(path, buf).map(Some).ok_or(path)
}

/// Ends the run: QEMU exits with success or failure.
pub fn exit(success: bool) -> ! {
    use cortex_m_semihosting::debug;
    debug::exit(if success { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
    loop {
        cortex_m::asm::wfi();
    }
}

/// Reports a line on the host console.
pub fn report(what: core::fmt::Arguments) {
    crate::console::line(what);
}

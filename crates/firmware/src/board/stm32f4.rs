//! The board layer for an STM32F4 (STM32F405/407 class, Cortex-M4F), feature `stm32f4`.
//! Build-only: it is compiled, linked and checked by `cargo xtask flash --build-only` and
//! flashed by `cargo xtask flash`, but no emulator runs it here, so it has not run on a chip.
//!
//! | peripheral | address | IRQ | use |
//! |---|---|---|---|
//! | USART2 (PA2 TX, PA3 RX, AF7) | `0x4000_4400` | 38 | the link to the host |
//! | TIM2 | `0x4000_0000` | 28 | the sample tick |
//!
//! Clocks stay at reset: the 16 MHz internal oscillator drives the core, APB1 and TIM2
//! ([`SYSCLK_HZ`]). The self-test needs QEMU's semihosting and is not built here.
//! Register access is the only `unsafe` code (volatile reads and writes of the registers
//! above, through [`Reg`], and unmasking the two interrupts).

use crate::ring::ByteRing;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::NVIC;
use cortex_m_rt::exception;

/// Core, APB1 and timer clock after reset (HSI), Hz.
pub const SYSCLK_HZ: u32 = 16_000_000;

/// A memory-mapped 32-bit register of this chip.
#[derive(Clone, Copy)]
struct Reg(usize);

impl Reg {
    #[inline(always)]
    fn read(self) -> u32 {
        // SAFETY: `self.0` is one of the aligned peripheral registers of RM0090 used below.
        unsafe { core::ptr::read_volatile(self.0 as *const u32) }
    }

    #[inline(always)]
    fn write(self, v: u32) {
        // SAFETY: as for `read`.
        unsafe { core::ptr::write_volatile(self.0 as *mut u32, v) }
    }

    fn modify(self, f: impl FnOnce(u32) -> u32) {
        self.write(f(self.read()));
    }
}

const RCC_AHB1ENR: Reg = Reg(0x4002_3830);
const RCC_APB1ENR: Reg = Reg(0x4002_3840);
const GPIOA_MODER: Reg = Reg(0x4002_0000);
const GPIOA_AFRL: Reg = Reg(0x4002_0020);
const USART2: usize = 0x4000_4400;
const USART_SR: usize = 0x00;
const USART_DR: usize = 0x04;
const USART_BRR: usize = 0x08;
const USART_CR1: usize = 0x0C;
const SR_RXNE: u32 = 1 << 5;
const SR_TXE: u32 = 1 << 7;
const TIM2: usize = 0x4000_0000;
const TIM_CR1: usize = 0x00;
const TIM_DIER: usize = 0x0C;
const TIM_SR: usize = 0x10;
const TIM_EGR: usize = 0x14;
const TIM_PSC: usize = 0x28;
const TIM_ARR: usize = 0x2C;

#[derive(Clone, Copy)]
enum Irq {
    Tim2 = 28,
    Usart2 = 38,
}

// SAFETY: the numbers are the chip's IRQ lines (RM0090, vector table).
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self as u16
    }
}

/// Bytes received by the UART interrupt, waiting for the main loop.
pub static RX: ByteRing<512> = ByteRing::new();
/// Sample ticks so far.
pub static TICKS: AtomicU32 = AtomicU32::new(0);

/// USART2: the link to the host.
pub struct Uart {
    _private: (),
}

impl Uart {
    fn drain_into_ring() {
        // Reading SR then DR clears RXNE and an overrun.
        while Reg(USART2 + USART_SR).read() & SR_RXNE != 0 {
            RX.push((Reg(USART2 + USART_DR).read() & 0xFF) as u8);
        }
    }

    /// Sends `bytes`, waiting for the transmit register to empty.
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            while Reg(USART2 + USART_SR).read() & SR_TXE == 0 {}
            Reg(USART2 + USART_DR).write(b as u32);
        }
    }

    /// Moves received bytes into [`RX`] now.
    pub fn poll(&mut self) {
        cortex_m::interrupt::free(|_| Self::drain_into_ring());
    }
}

/// The sample timer (TIM2, update interrupt every period).
pub struct SampleTimer {
    _private: (),
}

impl SampleTimer {
    /// Starts ticking every `period_us` µs (1 MHz timer clock after the prescaler).
    pub fn start(&mut self, period_us: u32) {
        Reg(TIM2 + TIM_CR1).write(0);
        Reg(TIM2 + TIM_PSC).write(SYSCLK_HZ / 1_000_000 - 1);
        Reg(TIM2 + TIM_ARR).write(period_us.max(1) - 1);
        Reg(TIM2 + TIM_EGR).write(1);
        Reg(TIM2 + TIM_SR).write(0);
        Reg(TIM2 + TIM_DIER).write(1);
        Reg(TIM2 + TIM_CR1).write(1);
    }

    /// Stops ticking.
    pub fn stop(&mut self) {
        Reg(TIM2 + TIM_CR1).write(0);
        Reg(TIM2 + TIM_SR).write(0);
    }
}

/// The board's peripherals, set up.
pub struct Board {
    /// The link.
    pub uart: Uart,
    /// The sample timer.
    pub timer: SampleTimer,
}

impl Board {
    /// Clocks on, PA2/PA3 to USART2, the UART at `baud` with its receive interrupt, the
    /// timer interrupt unmasked. `None` if called twice.
    pub fn take(baud: u32) -> Option<Self> {
        let _core = cortex_m::Peripherals::take()?;
        RCC_AHB1ENR.modify(|v| v | 1); // GPIOA
        RCC_APB1ENR.modify(|v| v | 1 | (1 << 17)); // TIM2, USART2
        GPIOA_MODER.modify(|v| (v & !(0b1111 << 4)) | (0b1010 << 4));
        GPIOA_AFRL.modify(|v| (v & !(0xFF << 8)) | (0x77 << 8));
        // Oversampling by 16: BRR = f_APB1 / baud (mantissa and fraction in one number).
        Reg(USART2 + USART_BRR).write((SYSCLK_HZ + baud.max(1) / 2) / baud.max(1));
        Reg(USART2 + USART_CR1).write((1 << 13) | (1 << 5) | (1 << 3) | (1 << 2));
        // SAFETY: the handlers touch only atomics and their peripheral's registers.
        unsafe {
            NVIC::unmask(Irq::Usart2);
            NVIC::unmask(Irq::Tim2);
        }
        Some(Self { uart: Uart { _private: () }, timer: SampleTimer { _private: () } })
    }
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    match irqn {
        38 => Uart::drain_into_ring(),
        28 => {
            Reg(TIM2 + TIM_SR).write(0);
            TICKS.fetch_add(1, Ordering::Release);
        }
        _ => {}
    }
}

/// No self-test on this board: always serve the link.
pub fn self_test_frames<'a>(_cmdline: &'a mut [u8], _buf: &'a mut [u8]) -> Result<Option<&'a [u8]>, &'a str> {
    Ok(None)
}

/// Ends the run: with no host to report to, wait for a reset.
pub fn exit(_success: bool) -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

/// No console on this board.
pub fn report(_what: core::fmt::Arguments) {}

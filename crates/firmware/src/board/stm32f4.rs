//! The board layer for an STM32F405/407 (Cortex-M4F) on `stm32f4xx-hal`, feature
//! `stm32f4`; with `emulator` as well, the same build for QEMU's `netduinoplus2`.
//!
//! | peripheral | pins | the app's interrupt | use |
//! |---|---|---|---|
//! | USART2, 8N1 at the baud rate | PA2 TX, PA3 RX (AF7) | `UART` (USART2) | the link to the host |
//! | TIM2, update at the sample rate | – | `TICK` (TIM2) | the sample tick; its compare channel 2, 5 µs before the update, triggers ADC1 |
//! | ADC1, channel 1, 12 bits, 15-cycle sampling | PA1 | – | the sensor ([`boucwen_link::analog::SENSOR`]) |
//! | DAC channel 1, 12 bits | PA4 | – | the drive ([`boucwen_link::analog::DRIVE`]) |
//! | IWDG, 50 ms | – | – | fed by `idle` while ticks come |
//! | SysTick | – | – | the free-running clock ([`crate::systick_clock`]) |
//!
//! The app's `PACE` task is bound to TIM3's line, which nothing raises on this board: a
//! chip's UART paces its own transmitter (one byte per "transmit empty" interrupt).
//!
//! Clocks: 168 MHz from the 8 MHz crystal through the PLL (APB1 42 MHz, its timers
//! 84 MHz). The sensor's conversion is started by the timer, 5 µs before each tick, so at
//! the tick the result is in the ADC's data register: the interrupt reads it without
//! waiting.
//!
//! ## `emulator` (QEMU 7.2's netduinoplus2)
//! What QEMU does not model, or models wrongly, is replaced; nothing else differs.
//! * No RCC (the ready bits the crystal and PLL set-up waits for never come): the clocks
//!   stay on the 16 MHz internal oscillator.
//! * No DAC: the DAC is a register stand-in in RAM (same codes).
//! * The UART sends each byte at once: the transmitter is paced at the baud rate.
//! * The timers (TIM2–TIM5, `hw/timer/stm32f2xx_timer.c`) count at a fixed 1 GHz whatever
//!   the prescaler's input, and schedule each update from the absolute virtual time plus
//!   the time of the last configuration, so the period is not the programmed one and grows
//!   with the time since start (a 1 ms tick set up seconds after start comes seconds apart:
//!   the first runs went silent after 48 samples). Their counter, read, is right. So the
//!   free-running clock is TIM5's counter (1 GHz: one unit per virtual nanosecond, one
//!   instruction under `-icount shift=0`), and the core's SysTick (modelled at the board's
//!   168 MHz) is a one-shot timer service ([`emulator`]) that raises the sample tick's
//!   line (TIM2's, the app's `TICK`) once per period on that clock and sends one byte of
//!   [`TX`] per byte time.

use crate::{RX, TX};
use boucwen_link::analog::{AdcCode, DRIVE, DacCode, FrontEnd, SENSOR};
use stm32f4xx_hal::pac as chip;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::serial::{Event as SerialEvent, Serial};
use stm32f4xx_hal::{rcc::Config as RccConfig, watchdog::IndependentWatchdog};

/// The board has an ADC and a DAC.
pub const HAS_CONVERTERS: bool = true;

/// The interrupts the app binds, under the names it binds them by (`board-stm32f4.x`
/// points the chip's TIM2, USART2 and TIM3 vectors at them).
pub mod pac {
    pub use stm32f4xx_hal::pac::NVIC_PRIO_BITS;

    /// The app's interrupts with the chip's numbers (RM0090, vector table).
    #[derive(Clone, Copy, Debug)]
    #[allow(clippy::upper_case_acronyms)]
    pub enum Interrupt {
        /// TIM2: the sample tick.
        TICK = 28,
        /// TIM3: the app's `PACE` line, never raised on this board.
        PACE = 29,
        /// USART2.
        UART = 38,
    }

    /// The name RTIC looks the interrupts up by.
    pub use Interrupt as interrupt;

    // SAFETY: the numbers are TIM2's, TIM3's and USART2's lines of the STM32F405/407.
    unsafe impl cortex_m::interrupt::InterruptNumber for Interrupt {
        fn number(self) -> u16 {
            self as u16
        }
    }
}

/// How long before the tick the sensor is converted, µs.
const ADC_LEAD_US: u32 = 5;

/// The sample timer (TIM2) and the ADC trigger on its channel 2.
pub struct Tick {
    tim: chip::TIM2,
    timer_clk_hz: u32,
}

impl Tick {
    /// Ticks every `period_us` µs (1 MHz counter); the ADC is triggered `ADC_LEAD_US`
    /// before each update. (`emulator`: the timer is programmed all the same, but the
    /// tick comes from [`emulator`]'s service.)
    pub fn start(&mut self, period_us: u32) {
        #[cfg(feature = "emulator")]
        emulator::set_period(period_us);
        let t = &self.tim;
        t.cr1().modify(|_, w| w.cen().clear_bit());
        t.psc().write(|w| w.psc().set((self.timer_clk_hz / 1_000_000 - 1) as u16));
        let arr = period_us.max(2 * ADC_LEAD_US) - 1;
        t.arr().write(|w| w.arr().set(arr));
        // Channel 2 in PWM mode 1: its rising edge at CCR2 triggers ADC1 (EXTSEL TIM2_CC2).
        t.ccmr1_output().modify(|_, w| w.oc2m().pwm_mode1());
        t.ccr(1).write(|w| w.ccr().set(arr + 1 - ADC_LEAD_US));
        t.ccer().modify(|_, w| w.cc2e().set_bit());
        t.egr().write(|w| w.ug().set_bit());
        t.sr().write(|w| w.uif().clear_bit());
        #[cfg(not(feature = "emulator"))]
        t.dier().modify(|_, w| w.uie().set_bit());
        t.cr1().modify(|_, w| w.cen().set_bit());
    }

    /// Acknowledges the interrupt.
    #[inline(always)]
    pub fn clear(&mut self) {
        self.tim.sr().write(|w| w.uif().clear_bit());
    }
}

/// The DAC's data register: the chip's, or the emulator's stand-in.
struct DacReg;

#[cfg(feature = "emulator")]
static DAC_STANDIN: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

impl DacReg {
    #[inline(always)]
    fn write(code: DacCode) {
        #[cfg(not(feature = "emulator"))]
        {
            // SAFETY: DHR12R1 of the DAC, enabled in `init`; only the tick interrupt writes it.
            unsafe { (*chip::DAC::ptr()).dhr12r1().write(|w| w.daccdhr().set(code.0)) };
        }
        #[cfg(feature = "emulator")]
        DAC_STANDIN.store(code.0 as u32, core::sync::atomic::Ordering::Relaxed);
    }
}

/// The ADC and DAC behind the front-end seam.
pub struct Converters {
    adc: chip::ADC1,
}

impl FrontEnd for Converters {
    fn sense(&mut self) -> Option<f32> {
        let sr = self.adc.sr().read();
        if sr.eoc().bit_is_clear() {
            return None;
        }
        // Reading DR clears EOC.
        let code = AdcCode(self.adc.dr().read().data().bits());
        SENSOR.um(code)
    }

    fn drive(&mut self, u: f32) -> f32 {
        let (code, _) = DRIVE.code(u);
        DacReg::write(code);
        DRIVE.volts(code)
    }
}

/// USART2.
pub struct SerialPort {
    serial: Serial<chip::USART2>,
    paced: bool,
}

impl SerialPort {
    /// Received bytes into [`RX`]; on a chip, the next byte of [`TX`] out (transmit-empty
    /// interrupt on while bytes wait).
    pub fn on_interrupt(&mut self) {
        use embedded_hal_nb::serial::{Read, Write};
        while let Ok(b) = self.serial.read() {
            RX.push(b);
        }
        if self.paced {
            return;
        }
        if self.serial.is_tx_empty() {
            match TX.pop() {
                Some(b) => {
                    let _ = self.serial.write(b);
                    self.serial.listen(SerialEvent::TxEmpty);
                }
                None => self.serial.unlisten(SerialEvent::TxEmpty),
            }
        } else {
            self.serial.listen(SerialEvent::TxEmpty);
        }
    }
}

/// The app's `PACE` task on this board: never raised (a chip's UART paces itself; the
/// emulator's service paces the transmitter from SysTick).
pub struct Pacer;

impl Pacer {
    /// Nothing to do.
    pub fn on_interrupt(&mut self) {}
}

/// Makes the transmitter look at [`TX`] (`emulator`: nothing to do, the service's next
/// byte time sends what waits).
pub fn kick_tx() {
    #[cfg(not(feature = "emulator"))]
    cortex_m::peripheral::NVIC::pend(pac::Interrupt::UART);
}

/// The free-running clock: SysTick on a chip.
#[cfg(not(feature = "emulator"))]
pub use crate::systick_clock as clock;
/// The free-running clock: TIM5's counter in QEMU.
#[cfg(feature = "emulator")]
pub use emulator::clock;

#[cfg(feature = "emulator")]
pub mod emulator {
    //! The timer service of the `emulator` build (see the module docs above for why): the
    //! core's SysTick interrupts once per byte time of the link (ten bit times at the baud
    //! rate) and at each interrupt
    //! * sends one byte of [`TX`] into USART2's data register, as a UART sends one byte per
    //!   byte time;
    //! * pends TIM2's line (the app's `TICK`, priority 3) when a sample period has passed
    //!   since the last tick on the clock (TIM5's counter): the tick comes at most one byte
    //!   time (21.7 µs at 460,800 baud) after its time, and a service that fell more than a
    //!   period behind starts again from now (the tick interrupt counts what was missed).
    //!
    //! SysTick runs at the link's priority (the app's 2), so it never delays the tick
    //! interrupt and is held off, like a chip's UART interrupt, while `idle` holds the
    //! device. It shares only atomics and the transmit queue (whose one consumer it is).
    //! (SysTick set as a one-shot timer, re-armed for each next event, lost an expiry now
    //! and then in QEMU 7.2: a periodic reload is what its model keeps.)

    use super::chip;
    use crate::TX;
    use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
    use cortex_m::peripheral::{NVIC, SCB, SYST, scb::SystemHandler, syst::SystClkSource};

    /// QEMU's STM32 timers' clock (the SoC's fixed `clock-frequency`), Hz.
    const TIMER_HZ: u64 = 1_000_000_000;
    /// QEMU's SysTick clock: netduinoplus2's core clock, Hz (QEMU has no RCC to change it).
    const SYSTICK_HZ: u64 = 168_000_000;

    static PERIOD: AtomicU32 = AtomicU32::new(0);
    static RESTART: AtomicBool = AtomicBool::new(false);
    static NEXT_TICK: AtomicU32 = AtomicU32::new(0);

    /// Virtual nanoseconds on TIM5's counter (never configured, so QEMU computes it right).
    #[inline(always)]
    pub fn clock() -> u32 {
        // SAFETY: reading TIM5's counter register has no side effect.
        unsafe { (*chip::TIM5::ptr()).cnt().read().bits() }
    }

    /// Starts the service for a link at `baud` (no tick until [`set_period`]).
    pub fn start(mut syst: SYST, scb: &mut SCB, baud: u32) {
        let byte_cycles = (10 * SYSTICK_HZ / baud.max(1) as u64).clamp(2, 0x00FF_FFFF) as u32;
        let prio_bits = super::pac::NVIC_PRIO_BITS;
        let link_prio = ((1u8 << prio_bits) - 2) << (8 - prio_bits);
        // SAFETY: SysTick's priority is set before it is enabled; nothing else uses it.
        unsafe { scb.set_priority(SystemHandler::SysTick, link_prio) };
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(byte_cycles - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
    }

    /// Ticks every `period_us` µs from the next byte time on.
    pub fn set_period(period_us: u32) {
        let ns = (period_us as u64 * TIMER_HZ / 1_000_000).min(i32::MAX as u64) as u32;
        PERIOD.store(ns, Ordering::Relaxed);
        RESTART.store(true, Ordering::Release);
    }

    #[cortex_m_rt::exception]
    fn SysTick() {
        if let Some(b) = TX.pop() {
            // SAFETY: USART2's data register; in this build only this handler writes it
            // (the UART interrupt only reads received bytes). QEMU's USART takes a byte at
            // once, so the previous one is gone a byte time later.
            unsafe { (*chip::USART2::ptr()).dr().write(|w| w.dr().set(b as u16)) };
        }
        let period = PERIOD.load(Ordering::Relaxed);
        if period == 0 {
            return;
        }
        let now = clock();
        let due = |t: u32| (now.wrapping_sub(t) as i32) >= 0;
        let mut next = NEXT_TICK.load(Ordering::Relaxed);
        if RESTART.swap(false, Ordering::Acquire) {
            next = now;
        }
        if due(next) {
            NVIC::pend(super::pac::Interrupt::TICK);
            next = next.wrapping_add(period);
            if due(next) {
                next = now.wrapping_add(period);
            }
        }
        NEXT_TICK.store(next, Ordering::Relaxed);
    }
}

/// The independent watchdog.
pub struct Watchdog {
    iwdg: IndependentWatchdog,
}

impl Watchdog {
    /// Reloads it.
    pub fn feed(&mut self) {
        self.iwdg.feed();
    }
}

/// Whether the last reset came from the independent watchdog (the flag is then cleared).
pub fn watchdog_reset() -> bool {
    // SAFETY: RCC_CSR is read and its flags cleared once, in `init`, before anything else
    // uses the RCC.
    let rcc = unsafe { &*chip::RCC::ptr() };
    let wd = rcc.csr().read().wdgrstf().bit_is_set();
    rcc.csr().modify(|_, w| w.rmvf().set_bit());
    wd
}

/// Logs the start on defmt (RTT).
pub fn log_start(reset_cause: u8) {
    defmt::info!("boucwen firmware: started, reset cause {=u8} (0 power-on, 3 panic, 4 watchdog)", reset_cause);
}

use defmt_rtt as _;

/// The peripherals, set up.
pub struct Parts {
    /// Sample timer (not started).
    pub tick: Tick,
    /// The UART.
    pub serial: SerialPort,
    /// The transmitter's pace.
    pub pacer: Pacer,
    /// ADC and DAC.
    pub converters: Converters,
    /// Started.
    pub watchdog: Watchdog,
}

/// Clocks, pins, USART2 at `baud`, the converters (the DAC starting at `drive_v`, the
/// drive to resume after a reset), the free-running clock and the watchdog (`emulator`:
/// the timer service too).
pub fn init(baud: u32, drive_v: f32, syst: cortex_m::peripheral::SYST, scb: &mut cortex_m::peripheral::SCB) -> Parts {
    // SAFETY: called once, from `init`, before any other use of the peripherals.
    let dp = unsafe { chip::Peripherals::steal() };
    #[cfg(not(feature = "emulator"))]
    let clocks = RccConfig::hse(8.MHz()).sysclk(168.MHz()).pclk1(42.MHz()).pclk2(84.MHz());
    #[cfg(feature = "emulator")]
    let clocks = RccConfig::hsi();
    let mut rcc = dp.RCC.freeze(clocks);
    let timer_clk_hz = rcc.clocks.timclk1().raw();
    {
        use stm32f4xx_hal::rcc::{Enable, Reset};
        chip::TIM2::enable(&mut rcc);
        chip::TIM2::reset(&mut rcc);
    }
    #[cfg(not(feature = "emulator"))]
    {
        let mut syst = syst;
        let _ = scb;
        crate::start_systick_clock(&mut syst);
    }
    #[cfg(feature = "emulator")]
    {
        use stm32f4xx_hal::rcc::Enable;
        chip::TIM5::enable(&mut rcc);
        emulator::start(syst, scb, baud);
    }
    let gpioa = dp.GPIOA.split(&mut rcc);

    // The drive first: the DAC's output is enabled holding the code to resume from.
    let mut pa4 = gpioa.pa4.into_analog();
    let _ = &mut pa4;
    {
        use stm32f4xx_hal::dac::{DacExt, DacOut, DacPin};
        let mut dac = dp.DAC.constrain(pa4, &mut rcc);
        let (code, _) = DRIVE.code(drive_v);
        dac.set_value(code.0);
        DacReg::write(code);
        dac.enable();
    }

    // The sensor: ADC1 channel 1 (PA1), one conversion per TIM2 CC2 rising edge. Set up
    // on the PAC's typed registers: the HAL's constructor calibrates against Vref by a
    // software conversion and waits for it, which QEMU's ADC model never finishes.
    let _pa1 = gpioa.pa1.into_analog();
    {
        use stm32f4xx_hal::rcc::{Enable, Reset};
        chip::ADC1::enable(&mut rcc);
        chip::ADC1::reset(&mut rcc);
    }
    let adc_regs = dp.ADC1;
    adc_regs.smpr2().modify(|_, w| w.smp1().cycles15());
    adc_regs.sqr1().modify(|_, w| w.l().set(0));
    adc_regs.sqr3().modify(|_, w| unsafe { w.sq1().bits(1) });
    adc_regs.cr2().modify(|_, w| {
        w.extsel().tim2cc2();
        w.exten().rising_edge();
        w.adon().set_bit()
    });

    let mut serial: Serial<chip::USART2> =
        Serial::new(dp.USART2, (gpioa.pa2, gpioa.pa3), baud.bps(), &mut rcc).unwrap_or_else(|_| {
            panic!("USART2 cannot run at the configured baud rate")
        });
    serial.listen(SerialEvent::RxNotEmpty);

    let mut iwdg = IndependentWatchdog::new(dp.IWDG);
    iwdg.start(50.millis());

    Parts {
        tick: Tick { tim: dp.TIM2, timer_clk_hz },
        serial: SerialPort { serial, paced: cfg!(feature = "emulator") },
        pacer: Pacer,
        converters: Converters { adc: adc_regs },
        watchdog: Watchdog { iwdg },
    }
}

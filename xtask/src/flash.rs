//! `cargo xtask flash`: the firmware for an STM32F4 board (feature `stm32f4`), built,
//! checked against the budget and flashed with probe-rs.
//!
//! This is the chip's build (crystal and PLL, the DAC, TIM2's tick and ADC trigger, the
//! UART's own pacing), which no emulator here runs: QEMU's netduinoplus2 runs the build with
//! the `emulator` feature instead (`cargo xtask qemu --board stm32f4`). No probe is
//! attached on the project's machines. With `--build-only` (what CI runs) the task stops
//! after the build and the budget check; otherwise it needs `probe-rs` on PATH
//! (`cargo install probe-rs-tools`) and a probe on the board's SWD pins, and runs
//! `probe-rs download --chip CHIP ELF` and `probe-rs reset --chip CHIP`.

use crate::qemu::{FLASH_BUDGET, RAM_BUDGET};
use crate::{elf, tools};
use std::process::Command;

/// Options of the task.
pub struct Options {
    /// probe-rs' name of the chip.
    pub chip: String,
    /// Stop after the build.
    pub build_only: bool,
}

/// Runs the task; returns every failure.
pub fn run(opts: &Options) -> Vec<String> {
    let elf = match tools::build_firmware(&["stm32f4"]) {
        Ok(e) => e,
        Err(e) => return e,
    };
    let usage = match elf::usage(&elf) {
        Ok(u) => u,
        Err(e) => return vec![e],
    };
    println!(
        "{}: flash {} B of {FLASH_BUDGET}, static RAM {} B of {RAM_BUDGET} (STM32F4: USART2 at 460800 baud, TIM2 at 1 kHz)",
        elf.display(),
        usage.flash_bytes,
        usage.static_ram_bytes
    );
    let mut failures = vec![];
    if usage.flash_bytes > FLASH_BUDGET {
        failures.push(format!("flash {} B exceeds {FLASH_BUDGET} B", usage.flash_bytes));
    }
    if usage.static_ram_bytes > RAM_BUDGET {
        failures.push(format!("static RAM {} B exceeds {RAM_BUDGET} B", usage.static_ram_bytes));
    }
    if opts.build_only || !failures.is_empty() {
        if opts.build_only {
            println!("built only; to flash: probe-rs download --chip {} {}", opts.chip, elf.display());
        }
        return failures;
    }
    let elf_s = elf.to_string_lossy().into_owned();
    for args in [vec!["download", "--chip", &opts.chip, &elf_s], vec!["reset", "--chip", &opts.chip]] {
        match Command::new("probe-rs").args(&args).status() {
            Ok(s) if s.success() => {}
            Ok(s) => return vec![format!("probe-rs {} failed ({s})", args[0])],
            Err(e) => {
                return vec![format!(
                    "cannot run probe-rs ({e}): install it with `cargo install probe-rs-tools`, or use --build-only"
                )];
            }
        }
    }
    println!("flashed {} to the {} and reset it", elf.display(), opts.chip);
    vec![]
}

//! `cargo xtask`: the firmware's build, its self-test in QEMU and hardware in the loop.
//!
//! ```text
//! cargo xtask firmware                  build the firmware, print its flash and RAM use
//! cargo xtask qemu [--json]             self-test in QEMU, bit-exact against the host
//! cargo xtask hil [--inject-faults R]   the board in QEMU on a pseudo-terminal, the host
//!                 [--json]              driving the virtual bimorph over the serial link
//! cargo xtask qemu --orc                the same with the ORC built in and run too
//! cargo xtask timing [--json]           the control interrupt's cost and missed ticks under
//!                                       a burst of damaged frames, the link paced
//! cargo xtask panic [--json]            a panic during a run, the ramp to 0 V after the reset
//!     (each of qemu, hil, timing, panic takes --board mps2|stm32f4: QEMU's mps2-an386 or
//!      netduinoplus2, the STM32F4 build with its `emulator` feature)
//! cargo xtask flash [--build-only]      an STM32F4 board: build, budget, probe-rs
//! ```
//! Every task checks the tools it needs first and names the Debian package of each missing
//! one; all failures are listed before the task exits non-zero.

mod elf;
mod flash;
mod hil;
mod panic;
mod qemu;
mod session;
mod timing;
mod tools;

/// The link's rate (the firmware's `BAUD`).
pub const BAUD: u32 = 460_800;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "cargo xtask", about = "Firmware builds, QEMU runs and hardware in the loop for boucwen")]
struct Cli {
    #[command(subcommand)]
    task: Task,
}

#[derive(Subcommand)]
enum Task {
    /// Build the firmware for thumbv7em-none-eabihf and report its flash and RAM use.
    Firmware,
    /// Run the firmware's self-test in QEMU (mps2-an386) and compare it with the host bit for bit.
    Qemu {
        /// The board (its QEMU machine).
        #[arg(long, value_enum, default_value = "mps2")]
        board: tools::Board,
        /// Samples of the self-test (at least 1000).
        #[arg(long, default_value_t = 2000)]
        samples: u32,
        /// End with one JSON line of the figures (the report goes to stderr).
        #[arg(long)]
        json: bool,
        /// Build with the `orc` feature and also run Li et al.'s odd-harmonic repetitive
        /// controller on the chip.
        #[arg(long)]
        orc: bool,
    },
    /// Hardware in the loop: the firmware in QEMU on a pseudo-terminal, `boucwen hil` driving
    /// the virtual bimorph against it over the serial link.
    Hil {
        /// The board (its QEMU machine).
        #[arg(long, value_enum, default_value = "mps2")]
        board: tools::Board,
        /// Damage this fraction of the bytes in each direction (dropped or one bit flipped).
        #[arg(long, value_name = "RATE")]
        inject_faults: Option<f64>,
        /// Samples to run.
        #[arg(long, default_value_t = 5000)]
        samples: u32,
        /// A free-running control run (a measurement that misses the board's next tick is
        /// missing) instead of lockstep (the tick waits for it, boundedly).
        #[arg(long)]
        free_running: bool,
        /// End with one JSON line of the figures.
        #[arg(long)]
        json: bool,
    },
    /// The control interrupt's timing with the link paced like the real UART while the host
    /// sends a burst of damaged frames: instructions per interrupt and missed ticks.
    Timing {
        /// The board (its QEMU machine).
        #[arg(long, value_enum, default_value = "mps2")]
        board: tools::Board,
        /// Damaged frames in the burst.
        #[arg(long, default_value_t = 2000)]
        frames: u32,
        /// End with one JSON line: ticks, missed_ticks, isr_insns_max, isr_insns_mean, bad_frames.
        #[arg(long)]
        json: bool,
    },
    /// A panic during a run (the firmware's `panic-test` hook), and the ramp of the drive to
    /// 0 V after the reset that follows.
    Panic {
        /// The board (its QEMU machine).
        #[arg(long, value_enum, default_value = "mps2")]
        board: tools::Board,
        /// End with one JSON line: ramp_from_v, ramp_steps, ramp_ms, safe_reason, reset_cause.
        #[arg(long)]
        json: bool,
    },
    /// Build the firmware for an STM32F4 board (feature `stm32f4`), check the budget and
    /// flash it with probe-rs.
    Flash {
        /// probe-rs' chip name.
        #[arg(long, default_value = "STM32F407VGTx")]
        chip: String,
        /// Build and check only (no probe needed).
        #[arg(long)]
        build_only: bool,
    },
}

fn finish(failures: Vec<String>) -> ExitCode {
    if failures.is_empty() {
        return ExitCode::SUCCESS;
    }
    for f in &failures {
        eprintln!("xtask: {f}");
    }
    eprintln!("xtask: {} failure(s)", failures.len());
    ExitCode::FAILURE
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.task {
        Task::Firmware => match tools::build_firmware(&[]) {
            Ok(elf) => match qemu::describe(&elf) {
                Ok(s) => {
                    println!("{s}");
                    finish(vec![])
                }
                Err(e) => finish(vec![e]),
            },
            Err(e) => finish(e),
        },
        Task::Qemu { board, samples, json, orc } => {
            let (summary, failures) = qemu::run(board, samples, json, orc);
            if let (true, Some(s)) = (json, &summary) {
                println!("{}", qemu::json_line(s));
            }
            finish(failures)
        }
        Task::Hil { board, inject_faults, samples, free_running, json } => {
            finish(hil::run(&hil::Options { board, inject_faults, json, samples, free_running }))
        }
        Task::Timing { board, frames, json } => finish(timing::run(board, frames, json)),
        Task::Panic { board, json } => finish(panic::run(board, json)),
        Task::Flash { chip, build_only } => finish(flash::run(&flash::Options { chip, build_only })),
    }
}

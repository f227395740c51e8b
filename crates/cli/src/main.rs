//! `boucwen`: sweep, simulate, identify, compare, diagnose, and drive a board over a serial link (hil, board).
//!
//! Every failure prints one line naming what went wrong and where, and exits non-zero.

use clap::{Parser, Subcommand};
use std::process::ExitCode;

mod cmd_board;
mod cmd_compare;
mod cmd_diagnose;
mod cmd_hil;
mod cmd_identify;
mod cmd_mimo;
mod cmd_simulate;
mod cmd_sweep;
mod record_args;

#[derive(Parser)]
#[command(
    name = "boucwen",
    version,
    about = "Model, identify and compensate the hysteresis of piezoelectric bimorphs"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Repeat the paper's identification and compensation experiments over a frequency range
    /// on the virtual bimorph (Figs. 10 and 16).
    Sweep(cmd_sweep::SweepArgs),
    /// Run the virtual bimorph on a drive (a sine, or a column of a CSV file) and write the
    /// record (t, u, y).
    Simulate(cmd_simulate::SimulateArgs),
    /// Fit a model to a record (t, u, y) and report its parameters and its free-run error on
    /// the part held out.
    Identify(cmd_identify::IdentifyArgs),
    /// Run a model file (`identify --save`) in free simulation on another record's drive and
    /// report its RMS error, fit and NRMSE.
    Compare(cmd_compare::CompareArgs),
    /// Show what the extended model gets wrong on a record, name the cause, extend the model
    /// and measure the gain.
    Diagnose(cmd_diagnose::DiagnoseArgs),
    /// Hardware in the loop: drive the board on a serial device with the virtual bimorph as
    /// its actuator; the board runs the compensator.
    Hil(cmd_hil::HilArgs),
    /// The board on a bench: excite and record, design from records, load and verify, run
    /// with the telemetry streamed into a record.
    Board(cmd_board::BoardArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Sweep(a) => cmd_sweep::run(a),
        Command::Simulate(a) => cmd_simulate::run(a),
        Command::Identify(a) => cmd_identify::run(a).map_err(anyhow::Error::msg),
        Command::Compare(a) => cmd_compare::run(a).map_err(anyhow::Error::msg),
        Command::Diagnose(a) => cmd_diagnose::run(a).map_err(anyhow::Error::msg),
        Command::Hil(a) => cmd_hil::run(a),
        Command::Board(a) => cmd_board::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // The libraries' errors name their cause in their own message; one line.
            eprintln!("boucwen: {e}");
            ExitCode::FAILURE
        }
    }
}

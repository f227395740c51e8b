//! `boucwen hil --port PATH`: hardware in the loop over a serial device.
//!
//! The board on `PATH` (the firmware, on a real board or in QEMU on a pseudo-terminal)
//! runs the compensator; the host is its actuator: the virtual bimorph
//! (`--scenario`, the paper's actuator by default). Before the run the host designs the
//! compensator on the virtual bimorph itself (`boucwen_lab::design::design_on_plant`):
//! 1. a record of the drive `sin(2π f t)` (`--amplitude` V, 6 s) is fitted by the
//!    extended model with its input delay `τ` (output error, an invertible loop); the
//!    board's compensator previews the reference by `τ` (its inverse works on `d(k + τ)`);
//! 2. the reference amplitude α is eq. (25) on that record;
//! 3. `u_f` alone is run in-process on the model's controller; the odd harmonic that stands
//!    out in its tracking error is the one the board cancels, with the identified model's
//!    response at `n·f` (none if no harmonic stands out).
//!
//! Then the board runs `--samples` samples ([`boucwen_hal::hil`]), in lockstep unless
//! `--free-running`; the host prints what was exchanged, lost and corrupted, the tracking
//! RMSE beside the one the same controller reaches in-process without a link, and, after
//! it falls silent, how the board took its drive to 0 V. Exits non-zero when a sample is not
//! accounted for or a command differs from the host's shadow controller.

use anyhow::{anyhow, bail};
use boucwen_core::compensator::Saturation;
use boucwen_hal::hil::{self, HilOptions};
use boucwen_lab::design::{PlantDesign, design_on_plant};
use boucwen_sim::{Bimorph, Scenario};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct HilArgs {
    /// The board's serial device (e.g. /dev/ttyUSB0, or QEMU's /dev/pts/N).
    #[arg(long)]
    port: String,
    /// Line speed (ignored by pseudo-terminals).
    #[arg(long, default_value_t = 460_800)]
    baud: u32,
    /// Samples to run.
    #[arg(long, default_value_t = 5000)]
    samples: u32,
    /// Damage this fraction of the bytes in each direction (dropped or one bit flipped).
    #[arg(long, value_name = "RATE")]
    inject_faults: Option<f64>,
    /// Seed of the fault injection.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Drive frequency f (Hz).
    #[arg(long, default_value_t = 23.0)]
    freq: f64,
    /// Drive amplitude of the identification record (V).
    #[arg(long, default_value_t = 1.0)]
    amplitude: f64,
    /// Scenario file of the virtual bimorph (TOML); the paper's actuator if omitted.
    #[arg(long)]
    scenario: Option<PathBuf>,
    /// A free-running control run: a measurement that misses the board's next tick is
    /// missing (by default the run is in lockstep: the board's tick waits for it, boundedly).
    #[arg(long)]
    free_running: bool,
    /// End with one JSON line: samples, samples_accounted, corrupted_frames, lost_frames,
    /// rmse_um, safe_state_ms, lockstep.
    #[arg(long)]
    json: bool,
}

/// Seconds of the identification record.
const IDENT_SECONDS: f64 = 6.0;

pub fn run(a: HilArgs) -> anyhow::Result<()> {
    if a.samples < 1000 {
        bail!("--samples {}: at least 1000", a.samples);
    }
    let rate = a.inject_faults.unwrap_or(0.0);
    if !(rate.is_finite() && (0.0..0.5).contains(&rate)) {
        bail!("--inject-faults {rate}: a fraction of bytes from 0 to below 0.5");
    }
    let scenario = match &a.scenario {
        Some(p) => Scenario::from_path(p)?,
        None => Scenario::default(),
    };
    let ts = scenario.sampling.ts_s;
    if !(a.freq.is_finite() && a.freq > 0.0 && 2.0 * a.freq < 0.5 / ts) {
        bail!("--freq {}: above 0 and below a quarter of the sample rate", a.freq);
    }
    if !(a.amplitude.is_finite() && a.amplitude > 0.0 && a.amplitude <= 100.0) {
        bail!("--amplitude {}: above 0 and at most 100 V", a.amplitude);
    }
    let spec = PlantDesign {
        freq_hz: a.freq,
        amplitude_v: a.amplitude,
        seconds: IDENT_SECONDS,
        saturation: Saturation::symmetric(10.0),
    };
    let design = design_on_plant(&mut Bimorph::new(&scenario)?, &spec)
        .map_err(|e| anyhow!("designing on the virtual bimorph at {} Hz: {e}", a.freq))?;
    eprintln!("{design}");
    let params = design.params;
    let opts = HilOptions {
        fault_rate: rate,
        seed: a.seed,
        lockstep: !a.free_running,
        ..HilOptions::new(a.samples)
    };
    let ideal = hil::without_link(&mut Bimorph::new(&scenario)?, &params, a.samples, opts.settle_samples)?;
    let report = hil::run_on_port(&a.port, a.baud, &mut Bimorph::new(&scenario)?, &params, &opts)
        .map_err(|e| anyhow!("{}: {e}", a.port))?;
    println!("{}", report.summary());
    println!("tracking RMSE of the same controller in-process, without the link: {ideal:.4} µm");
    if a.json {
        println!("{}", serde_json::to_string(&report.json_summary())?);
    }
    report.verdict().map_err(|e| anyhow!("{}: {e}", a.port))
}

//! External tools: finding them (with the package that provides each), building the
//! firmware, running a child process with a time limit.

use std::path::{Path, PathBuf};
use std::process::Command;

/// A tool the tasks need, and how to get it on Debian.
pub struct Tool {
    /// What it is called in messages.
    pub name: &'static str,
    /// Where it must be (Debian's paths: the rustup toolchain on PATH has no
    /// standard-library source for the Cortex-M target).
    pub path: &'static str,
    /// The Debian package.
    pub package: &'static str,
}

/// Debian's rustc, which comes with the standard library's source.
pub const RUSTC: Tool = Tool { name: "rustc (Debian)", path: "/usr/bin/rustc", package: "rustc-web" };
/// Debian's cargo.
pub const CARGO: Tool = Tool { name: "cargo (Debian)", path: "/usr/bin/cargo", package: "cargo-web" };
/// The standard library's source, for `-Z build-std=core`.
pub const RUST_SRC: Tool = Tool {
    name: "Rust library source",
    path: "/usr/lib/rustlib/src/rust/library/core",
    package: "rust-web-src",
};
/// The linker.
pub const LLD: Tool = Tool { name: "ld.lld", path: "/usr/bin/ld.lld", package: "lld" };
/// The emulator.
pub const QEMU: Tool =
    Tool { name: "qemu-system-arm", path: "/usr/bin/qemu-system-arm", package: "qemu-system-arm" };

/// Checks that every tool is there; names each missing one with its package.
pub fn check(tools: &[&Tool]) -> Result<(), Vec<String>> {
    let missing: Vec<String> = tools
        .iter()
        .filter(|t| !Path::new(t.path).exists())
        .map(|t| format!("{} not found at {}: apt-get install {}", t.name, t.path, t.package))
        .collect();
    if missing.is_empty() { Ok(()) } else { Err(missing) }
}

/// The workspace root (xtask lives in `<root>/xtask`).
pub fn root() -> PathBuf {
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    here.parent().map_or(here.clone(), Path::to_path_buf)
}

/// The board a firmware task is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Board {
    /// QEMU's mps2-an386 (Cortex-M4F, CMSDK UART and timers).
    Mps2,
    /// An STM32F405/407; in QEMU, netduinoplus2 (built with the `emulator` feature).
    Stm32f4,
}

impl Board {
    /// The firmware features of this board's QEMU build (plus `extra`). The STM32F4 build
    /// with the ORC is built without the preview of the reference (`no-preview`): with it,
    /// it overflowed its 64 KiB of flash by about 300 B.
    pub fn qemu_features(self, extra: &[&'static str]) -> Vec<&'static str> {
        let mut f = match self {
            Board::Mps2 => vec![],
            Board::Stm32f4 => vec!["stm32f4", "emulator"],
        };
        f.extend_from_slice(extra);
        if self == Board::Stm32f4 && extra.contains(&"orc") {
            f.push("no-preview");
        }
        f
    }

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Board::Mps2 => "mps2-an386",
            Board::Stm32f4 => "stm32f4 (QEMU netduinoplus2)",
        }
    }
}

/// Where the firmware is built: `$CARGO_TARGET_DIR/firmware`, else `<root>/target/firmware`
/// (`firmware-F1-F2` for a build with features, so builds do not overwrite each other).
pub fn firmware_target_dir(features: &[&str]) -> PathBuf {
    let base = std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root().join("target"), PathBuf::from);
    if features.is_empty() {
        base.join("firmware")
    } else {
        base.join(format!("firmware-{}", features.join("-")))
    }
}

/// The firmware crate's directory.
pub fn firmware_dir() -> PathBuf {
    root().join("crates").join("firmware")
}

/// Builds the firmware (release, with the cargo `features`: `orc`, `stm32f4`,
/// `emulator`) and returns the ELF's path.
pub fn build_firmware(features: &[&str]) -> Result<PathBuf, Vec<String>> {
    check(&[&RUSTC, &CARGO, &RUST_SRC, &LLD])?;
    let target_dir = firmware_target_dir(features);
    eprintln!(
        "building the firmware (thumbv7em-none-eabihf{}) in {}",
        if features.is_empty() { String::new() } else { format!(", features {}", features.join(",")) },
        target_dir.display()
    );
    let mut cmd = Command::new(CARGO.path);
    cmd.args(["build", "--release"]);
    if !features.is_empty() {
        cmd.args(["--features", &features.join(",")]);
    }
    let status = cmd
        .current_dir(firmware_dir())
        // The outer (rustup) cargo's variables would point the inner one at the wrong
        // toolchain or make it share the host build's jobserver and lock.
        .env_remove("CARGO")
        .env_remove("RUSTUP_TOOLCHAIN")
        .env_remove("CARGO_MAKEFLAGS")
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .env("RUSTC", RUSTC.path)
        .env("RUSTC_BOOTSTRAP", "1")
        .env("CARGO_TARGET_DIR", &target_dir)
        .status()
        .map_err(|e| vec![format!("cannot run {}: {e}", CARGO.path)])?;
    if !status.success() {
        return Err(vec![format!("firmware build failed ({status})")]);
    }
    let elf = target_dir.join("thumbv7em-none-eabihf").join("release").join("boucwen-firmware");
    if !elf.exists() {
        return Err(vec![format!("firmware build produced no {}", elf.display())]);
    }
    Ok(elf)
}

/// The QEMU command for the firmware on `board`, its link on a pseudo-terminal: no
/// display, one instruction per virtual nanosecond. On mps2-an386 the board's UART0 is
/// QEMU's first serial port; on netduinoplus2 USART2 is the second (`-serial null -serial
/// pty`). With `virtual_only` the virtual clock never follows the wall clock
/// (`sleep=off`: an idle board skips to its next timer event), so a loaded host cannot
/// make the board miss ticks; runs where the host must answer within a tick (hardware in
/// the loop) keep the default, where an idle board's time passes with the wall clock.
pub fn qemu_command(board: Board, elf: &Path, virtual_only: bool) -> Command {
    let mut c = Command::new(QEMU.path);
    match board {
        Board::Mps2 => c.args(["-machine", "mps2-an386", "-cpu", "cortex-m4"]).args(["-serial", "pty"]),
        Board::Stm32f4 => c.args(["-machine", "netduinoplus2"]).args(["-serial", "null", "-serial", "pty"]),
    };
    c.args(["-nographic", "-monitor", "none"])
        .args(["-icount", if virtual_only { "shift=0,sleep=off" } else { "shift=0" }])
        .arg("-kernel")
        .arg(elf);
    c
}

//! External tools: finding them (with the package that provides each), building the
//! firmware, running a child process with a time limit.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

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

/// Where the firmware is built: `$CARGO_TARGET_DIR/firmware`, else `<root>/target/firmware`
/// (`firmware-FEATURE` for a build with a feature, so builds do not overwrite each other).
pub fn firmware_target_dir(feature: Option<&str>) -> PathBuf {
    let base = std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root().join("target"), PathBuf::from);
    base.join(feature.map_or_else(|| "firmware".to_string(), |f| format!("firmware-{f}")))
}

/// The firmware crate's directory.
pub fn firmware_dir() -> PathBuf {
    root().join("crates").join("firmware")
}

/// Builds the firmware (release, with the cargo `feature` if given: `orc`, `stm32f4`) and
/// returns the ELF's path.
pub fn build_firmware(feature: Option<&str>) -> Result<PathBuf, Vec<String>> {
    check(&[&RUSTC, &CARGO, &RUST_SRC, &LLD])?;
    let target_dir = firmware_target_dir(feature);
    eprintln!(
        "building the firmware (thumbv7em-none-eabihf{}) in {}",
        feature.map_or(String::new(), |f| format!(", feature {f}")),
        target_dir.display()
    );
    let mut cmd = Command::new(CARGO.path);
    cmd.args(["build", "--release"]);
    if let Some(f) = feature {
        cmd.args(["--features", f]);
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

/// The QEMU command for the firmware: `mps2-an386`, no display, semihosting on (with
/// `semihosting_args` as its command line), one instruction per virtual nanosecond.
pub fn qemu_command(elf: &Path, semihosting_args: &[&str], serial: &str) -> Command {
    let mut sh = String::from("enable=on,target=native");
    for a in semihosting_args {
        sh.push_str(",arg=");
        sh.push_str(a);
    }
    let mut c = Command::new(QEMU.path);
    c.args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-nographic", "-monitor", "none"])
        .args(["-serial", serial])
        .args(["-semihosting-config", &sh])
        .args(["-icount", "shift=0"])
        .arg("-kernel")
        .arg(elf);
    c
}

/// What a child printed and how it ended.
pub struct Finished {
    /// Exit status (`None`: killed at the time limit).
    pub status: Option<ExitStatus>,
    /// Standard output.
    pub stdout: String,
    /// Standard error.
    pub stderr: String,
}

/// Runs `cmd` to completion or until `limit`, collecting its output.
pub fn run_with_limit(mut cmd: Command, limit: Duration) -> Result<Finished, String> {
    let mut child: Child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot start {:?}: {e}", cmd.get_program()))?;
    let mut out = child.stdout.take().ok_or("no stdout pipe")?;
    let mut err = child.stderr.take().ok_or("no stderr pipe")?;
    let out_thread = std::thread::spawn(move || {
        let mut s = Vec::new();
        let _ = out.read_to_end(&mut s);
        s
    });
    let err_thread = std::thread::spawn(move || {
        let mut s = Vec::new();
        let _ = err.read_to_end(&mut s);
        s
    });
    let start = Instant::now();
    let status = loop {
        match child.try_wait().map_err(|e| e.to_string())? {
            Some(s) => break Some(s),
            None if start.elapsed() > limit => {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            None => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    let stdout = String::from_utf8_lossy(&out_thread.join().unwrap_or_default()).into_owned();
    let stderr = String::from_utf8_lossy(&err_thread.join().unwrap_or_default()).into_owned();
    Ok(Finished { status, stdout, stderr })
}

//! Puts the board's memory layout where cortex-m-rt's `link.x` looks for it (`memory.x`):
//! `memory-stm32f4.x` with the `stm32f4` feature, else `memory.x` (QEMU's mps2-an386).
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let layout = if env::var_os("CARGO_FEATURE_STM32F4").is_some() { "memory-stm32f4.x" } else { "memory.x" };
    fs::copy(layout, out.join("memory.x")).expect("copy the memory layout to OUT_DIR");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory-stm32f4.x");
    println!("cargo:rerun-if-changed=build.rs");
}

//! Puts the board's memory layout where cortex-m-rt's `link.x` looks for it (`memory.x`):
//! `memory-stm32f4.x` with the `stm32f4` feature, else `memory-mps2.x` (QEMU's mps2-an386; neither is called `memory.x` in this folder, where the linker would find it first), and
//! the interrupt names: on mps2-an386 the vector table names the app's interrupts itself
//! (an empty `device.x`); on the STM32F4 the PAC's `device.x` names the vectors and
//! `board-stm32f4.x` points the three the app uses at its handlers.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let stm32 = env::var_os("CARGO_FEATURE_STM32F4").is_some();
    let layout = if stm32 { "memory-stm32f4.x" } else { "memory-mps2.x" };
    fs::copy(layout, out.join("memory.x")).expect("copy the memory layout to OUT_DIR");
    if stm32 {
        fs::copy("board-stm32f4.x", out.join("board.x")).expect("copy board-stm32f4.x");
        println!("cargo:rustc-link-arg=-Tboard.x");
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    } else {
        fs::write(out.join("device.x"), "/* mps2-an386: __INTERRUPTS names the handlers */\n")
            .expect("write device.x");
    }
    println!("cargo:rustc-link-search={}", out.display());
    for f in ["memory-mps2.x", "memory-stm32f4.x", "board-stm32f4.x", "build.rs"] {
        println!("cargo:rerun-if-changed={f}");
    }
}

//! Linker set-up for the two boards: writes the chosen board's memory map to
//! OUT_DIR/nanocal-memory.x, which `memory.x` (at the crate root) includes.
use std::env;
use std::fs;
use std::path::PathBuf;

/// STM32L475VG: the last 64 KiB of flash (bank 2) hold the store (see src/bin/stm32.rs).
const STM32_MEMORY: &str = "MEMORY\n{\n  FLASH : ORIGIN = 0x08000000, LENGTH = 1024K - 64K\n  RAM   : ORIGIN = 0x20000000, LENGTH = 96K\n}\n";

/// mps2-an386: 4 MiB ZBT SSRAM1 at 0 (code, the vector table at reset), 4 MiB SSRAM2/3 at
/// 0x2000_0000 (data).
const QEMU_MEMORY: &str = "MEMORY\n{\n  FLASH : ORIGIN = 0x00000000, LENGTH = 4M\n  RAM   : ORIGIN = 0x20000000, LENGTH = 4M\n}\n";

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let qemu = env::var_os("CARGO_FEATURE_QEMU").is_some();
    let memory = if qemu { QEMU_MEMORY } else { STM32_MEMORY };
    fs::write(out.join("nanocal-memory.x"), memory).expect("write OUT_DIR/nanocal-memory.x");
    // memory.x is found in the crate root (the linker's working directory); also put a copy in
    // OUT_DIR for builds started from elsewhere.
    fs::copy("memory.x", out.join("memory.x")).expect("copy memory.x to OUT_DIR");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    if env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}

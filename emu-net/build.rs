//! Build script of the mps2-an386 binary: puts the AN386 memory layout (`an386.x`) where
//! cortex-m-rt's `link.x` finds it.
//!
//! `link.x` does `INCLUDE memory.x`. The linker runs in the workspace root, whose own `memory.x`
//! (the STM32 firmware's) is found first and does `INCLUDE board.x`; so the layout is written here
//! both as `memory.x` and as `board.x` in `OUT_DIR`, on the linker's search path: whichever
//! `memory.x` the linker reads, it ends with the AN386 layout. (The root package's build script
//! writes its own `board.x` only into its own `OUT_DIR`, never on this binary's search path.)

use std::{env, error::Error, fs, path::PathBuf};

fn main() -> Result<(), Box<dyn Error>> {
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("cargo did not set OUT_DIR")?);
    fs::copy("an386.x", out.join("memory.x"))?;
    fs::copy("an386.x", out.join("board.x"))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=an386.x");
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}

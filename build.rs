//! Build script of the firmware: puts the board's memory layout (`memory/l475vg.x`,
//! `memory/f103c8.x` or `memory/f429zi.x`) where the linker finds it as `board.x`, and adds
//! defmt's linker script to the `hw` build only.
//!
//! cortex-m-rt's `link.x` does `INCLUDE memory.x`; the linker finds our top-level `memory.x` in
//! its working directory (the package root), and that file does `INCLUDE board.x`, which the
//! linker finds here in `OUT_DIR` (on its search path). The board file must not be called
//! `memory.x`: the linker would read the top-level one first.
//!
//! `-Tlink.x` lives in `.cargo/config.toml` (every build needs it); `-Tdefmt.x` is here because
//! only the `hw` feature links defmt, and the linker fails on a script that no crate provides.

use std::{env, error::Error, fs, path::PathBuf};

fn main() -> Result<(), Box<dyn Error>> {
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("cargo did not set OUT_DIR")?);
    // One memory layout per board, chosen by the board feature.
    let board = if env::var_os("CARGO_FEATURE_BOARD_F103").is_some() {
        "memory/f103c8.x"
    } else if env::var_os("CARGO_FEATURE_BOARD_F429").is_some() {
        "memory/f429zi.x"
    } else {
        "memory/l475vg.x"
    };
    fs::copy(board, out.join("board.x"))?;
    // Also where the linker looks when its working directory is not the package root.
    fs::copy("memory.x", out.join("memory.x"))?;
    println!("cargo:rustc-link-search={}", out.display());
    if env::var_os("CARGO_FEATURE_HW").is_some() {
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory");
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}

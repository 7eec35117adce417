//! Puts the board's bootloader memory layout (`memory-l475.x` or `memory-f429.x`) where
//! cortex-m-rt's `link.x` finds it as `memory.x`. The linker runs in the workspace's root, whose
//! `memory.x` (the application's) it reads first; that file only does `INCLUDE board.x`, so the
//! layout goes into `OUT_DIR` (on the search path) under that name too.

use std::{env, error::Error, fs, path::PathBuf};

fn main() -> Result<(), Box<dyn Error>> {
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("cargo did not set OUT_DIR")?);
    let l475 = env::var_os("CARGO_FEATURE_BOARD_L475").is_some();
    let f429 = env::var_os("CARGO_FEATURE_BOARD_F429").is_some();
    let layout = match (l475, f429) {
        (true, false) => "memory-l475.x",
        (false, true) => "memory-f429.x",
        _ => {
            return Err("exactly one board feature: board-l475 (the default) or board-f429".into())
        }
    };
    fs::copy(layout, out.join("board.x"))?;
    fs::copy(layout, out.join("memory.x"))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory-l475.x");
    println!("cargo:rerun-if-changed=memory-f429.x");
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}

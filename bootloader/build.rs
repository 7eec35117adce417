//! Puts the bootloader's memory layout (`memory.x`: its 32 KiB) where cortex-m-rt's `link.x`
//! finds it. The linker runs in the workspace's root, whose `memory.x` (the application's) it
//! reads first; that file only does `INCLUDE board.x`, so the layout goes into `OUT_DIR` (on the
//! search path) under that name too.

use std::{env, error::Error, fs, path::PathBuf};

fn main() -> Result<(), Box<dyn Error>> {
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("cargo did not set OUT_DIR")?);
    fs::copy("memory.x", out.join("board.x"))?;
    fs::copy("memory.x", out.join("memory.x"))?;
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}

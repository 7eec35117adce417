//! Build script of the firmware: puts `memory.x` where the linker finds it, and adds defmt's
//! linker script to the `hw` build only.
//!
//! cortex-m-rt's `link.x` does `INCLUDE memory.x`, which the linker resolves through its search
//! path. Copying the file into `OUT_DIR` and adding that directory to the search path works no
//! matter which directory cargo runs the linker from, and relinks when `memory.x` changes.
//! `-Tlink.x` lives in `.cargo/config.toml` (every build needs it); `-Tdefmt.x` is here because
//! only the `hw` feature links defmt, and the linker fails on a script that no crate provides.

use std::{env, error::Error, fs, path::PathBuf};

fn main() -> Result<(), Box<dyn Error>> {
    let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("cargo did not set OUT_DIR")?);
    fs::copy("memory.x", out.join("memory.x"))?;
    println!("cargo:rustc-link-search={}", out.display());
    if env::var_os("CARGO_FEATURE_HW").is_some() {
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}

//! Build script of the firmware: puts the board's memory layout (`memory/l475vg.x`,
//! `memory/f103c8.x` or `memory/f429zi.x`) where the linker finds it as `board.x`, and adds
//! defmt's linker script to the `hw` build only.
//!
//! cortex-m-rt's `link.x` does `INCLUDE memory.x`; the linker finds our top-level `memory.x` in
//! its working directory (the package root), and that file does `INCLUDE board.x`, which the
//! linker finds here in `OUT_DIR` (on its search path). The board file must not be called
//! `memory.x`: the linker would read the top-level one first.
//!
//! With `update` on the board (`hw`), it also writes the public key images are verified with
//! (`update_key.rs`, for src/dfu/): the file `RC_GATEWAY_UPDATE_KEY` names (its 32 bytes, or
//! 64 hexadecimal digits: `rcgw key new` writes NAME.pub), or no key at all, which refuses every
//! image. Never the TEST key: only the emulator build takes that one.
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
    update_key(&out)?;
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory");
    println!("cargo:rerun-if-changed=build.rs");
    Ok(())
}

/// `update_key.rs`: `Some([..])` from `RC_GATEWAY_UPDATE_KEY`'s file, else `None`.
fn update_key(out: &std::path::Path) -> Result<(), Box<dyn Error>> {
    println!("cargo:rerun-if-env-changed=RC_GATEWAY_UPDATE_KEY");
    let key = match env::var_os("RC_GATEWAY_UPDATE_KEY") {
        Some(path) if env::var_os("CARGO_FEATURE_HW").is_some() => {
            println!("cargo:rerun-if-changed={}", PathBuf::from(&path).display());
            let bytes = fs::read(&path)
                .map_err(|e| format!("RC_GATEWAY_UPDATE_KEY {}: {e}", path.display()))?;
            let key = public_key(&bytes).ok_or_else(|| {
                format!(
                    "RC_GATEWAY_UPDATE_KEY {}: not a public key (32 bytes, or 64 hex digits)",
                    path.display()
                )
            })?;
            let list: Vec<String> = key.iter().map(|b| format!("{b:#04x}")).collect();
            format!("Some([{}])", list.join(", "))
        }
        _ => "None".to_string(),
    };
    fs::write(out.join("update_key.rs"), key)?;
    Ok(())
}

/// A public key file's 32 bytes: raw, or as hex text.
fn public_key(bytes: &[u8]) -> Option<[u8; 32]> {
    if let Ok(raw) = <[u8; 32]>::try_from(bytes) {
        return Some(raw);
    }
    let text = std::str::from_utf8(bytes).ok()?;
    let digits: Vec<u8> = text.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    let mut key = [0u8; 32];
    if digits.len() != 64 {
        return None;
    }
    for (byte, pair) in key.iter_mut().zip(digits.chunks(2)) {
        *byte = u8::from_str_radix(std::str::from_utf8(pair).ok()?, 16).ok()?;
    }
    Some(key)
}

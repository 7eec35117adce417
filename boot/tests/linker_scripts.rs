//! The linker scripts say what `layout::L475` and `layout::F429` say: the bootloader's
//! (bootloader/memory-*.x) and the application's (memory/l475vg.x, memory/f429zi.x) FLASH regions
//! are BOOTLOADER and ACTIVE. The scripts cannot read the constants, so this holds them equal.

use rc_boot::layout::{Region, F429, L475};

/// The FLASH region's origin and length in a linker script's MEMORY block.
fn flash_region(path: &str) -> Region {
    let text = std::fs::read_to_string(format!("{}/../{path}", env!("CARGO_MANIFEST_DIR")))
        .unwrap_or_else(|e| panic!("{path}: {e}"));
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("FLASH"))
        .unwrap_or_else(|| panic!("{path}: no FLASH region"));
    let field = |name: &str| {
        let at = line
            .find(name)
            .unwrap_or_else(|| panic!("{path}: no {name}"))
            + name.len();
        let value = line[at..]
            .trim_start_matches([' ', '='])
            .split([',', ' '])
            .next()
            .unwrap_or_default();
        if let Some(hex) = value.strip_prefix("0x") {
            u32::from_str_radix(hex, 16).unwrap()
        } else if let Some(k) = value.strip_suffix('K') {
            k.parse::<u32>().unwrap() * 1024
        } else {
            value.parse().unwrap()
        }
    };
    let start = field("ORIGIN");
    Region {
        start,
        end: start + field("LENGTH"),
    }
}

#[test]
fn the_bootloader_is_linked_where_the_layout_puts_it() {
    assert_eq!(flash_region("bootloader/memory-l475.x"), L475.bootloader);
    assert_eq!(flash_region("bootloader/memory-f429.x"), F429.bootloader);
}

#[test]
fn the_application_is_linked_into_active() {
    assert_eq!(flash_region("memory/l475vg.x"), L475.active);
    assert_eq!(flash_region("memory/f429zi.x"), F429.active);
}

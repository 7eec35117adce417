//! Where the bootloader, the application and embassy-boot's partitions sit in the flash.
//!
//! # The STM32L475VG (1 MiB, two banks of 512 KiB, 2 KiB pages, 8-byte writes)
//!
//! | Region | From | To (excl.) | Size | Bank | Written by |
//! |---|---|---|---|---|---|
//! | BOOTLOADER | `0x0800_0000` | `0x0800_8000` | 32 KiB (16 pages) | 1 | the programmer (SWD) only |
//! | ACTIVE | `0x0800_8000` | `0x0808_0000` | 480 KiB (240 pages) | 1 | the bootloader (swap, revert) |
//! | DFU | `0x0808_0000` | `0x080F_8800` | 482 KiB (241 pages) | 2 | the application (image transfer); the bootloader (swap) |
//! | (spare) | `0x080F_8800` | `0x080F_C000` | 14 KiB (7 pages) | 2 | nobody |
//! | STATE | `0x080F_C000` | `0x080F_E000` | 8 KiB (4 pages) | 2 | the application (marks); the bootloader (progress, revert mark) |
//! | SETTINGS | `0x080F_E000` | `0x0810_0000` | 8 KiB (4 pages) | 2 | the application's settings store; never embassy-boot |
//!
//! Why this way:
//!
//! * **BOOTLOADER, 32 KiB.** The bootloader runs `BootLoader::prepare_boot` (copying pages, no
//!   signature check: the application verifies the image before it marks it) and jumps. An
//!   embassy-boot bootloader for an STM32 with no logging is of the order of 10 KiB at
//!   `opt-level = "z"` (the HAL's flash driver, the RCC set-up, embassy-boot's copy loop); 32 KiB
//!   leaves room for a watchdog, a panic path that still jumps to a known application and a
//!   later logging build, and keeps ACTIVE a round 480 KiB, 7.5 times the 64 KiB application of
//!   today. `0x0800_8000` is aligned far beyond what the Cortex-M4's vector table offset needs.
//! * **ACTIVE fills the rest of bank 1.** The application runs from bank 1 and never writes it.
//! * **DFU and STATE in bank 2.** The application erases and writes both while it runs from
//!   bank 1; the L4 can read one bank while it programs the other (read-while-write), so the
//!   CPU is not stalled for an erase. A page of bank 1 erased under the running program would
//!   stall it for the page's 25 ms.
//! * **DFU is ACTIVE plus one page**, the least embassy-boot allows: its swap moves ACTIVE's pages
//!   up by one page in DFU, so the old application ends up in DFU's pages `1..=240` and can be
//!   copied back (the revert).
//! * **STATE, 4 pages**, right below the settings: embassy-boot keeps a magic word, a
//!   "revert done" word and one progress word per page copy (two copies a page for the swap, two
//!   for the revert): `(2 + 4 × 240) × 8 = 7,696` bytes with the L4's 8-byte writes, which
//!   needs four 2 KiB pages. It stays where it is if ACTIVE and DFU are ever resized (even a
//!   16 KiB bootloader, ACTIVE 248 pages, needs only `(2 + 992) × 8 = 7,952` bytes).
//! * **SETTINGS, untouched**: `0x080F_E000..0x0810_0000`, the settings store's four pages, as
//!   before.
//!
//! # The STM32F429ZI (2 MiB, two banks of 1 MiB, sectors of 16, 64 and 128 KiB, 4-byte writes)
//!
//! | Region | From | To (excl.) | Size | Sectors | Written by |
//! |---|---|---|---|---|---|
//! | BOOTLOADER | `0x0800_0000` | `0x0802_0000` | 128 KiB (the bootloader takes 32 KiB of it) | 0-4 | the programmer (SWD) only |
//! | ACTIVE | `0x0802_0000` | `0x080E_0000` | 768 KiB | 5-10 | the bootloader |
//! | (spare) | `0x080E_0000` | `0x0810_0000` | 128 KiB | 11 | nobody |
//! | SETTINGS | `0x0810_0000` | `0x0810_8000` | 32 KiB | 12, 13 | the application's settings store |
//! | STATE | `0x0810_8000` | `0x0810_C000` | 16 KiB | 14 | the application (marks); the bootloader |
//! | (spare) | `0x0810_C000` | `0x0812_0000` | 80 KiB | 15, 16 | nobody |
//! | DFU | `0x0812_0000` | `0x0820_0000` | 896 KiB | 17-23 | the application; the bootloader (swap) |
//!
//! embassy-boot copies ACTIVE and DFU in pages of one erase unit, so its page here is a 128 KiB
//! sector: ACTIVE must start on one (sector 5, so the bootloader's region is the first 128 KiB)
//! and DFU, which must be ACTIVE and one page, takes all seven of bank 2 (so ACTIVE has six, and
//! sector 11 stays spare). STATE needs only `(2 + 4 × 6) × 4 = 104` bytes: one 16 KiB sector of
//! bank 2, erased in 0.25 s (0.5 s at most) where a 128 KiB one takes 1 s (2 s at most). The
//! settings keep their two sectors. The application runs from bank 1 and writes only bank 2
//! (read-while-write between the banks). It erases DFU's 128 KiB sectors without waiting
//! (src/board/f429.rs): one outlasts its 1 s watchdog.
//!
//! Every rule is checked at compile time ([`Layout::check`] on [`L475`] and [`F429`]), and the same
//! check serves the scaled-down layouts of the tests.

/// One of the L475's erase units: a 2 KiB page.
pub const PAGE: u32 = 2048;
/// The L475's write unit: a 64-bit double word (the flash's ECC covers each one).
pub const WORD: u32 = 8;
/// The value of an erased byte.
pub const ERASED: u8 = 0xFF;

/// A range of flash addresses, `start..end`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Region {
    /// The first address.
    pub start: u32,
    /// One past the last address.
    pub end: u32,
}

impl Region {
    /// The region's size in bytes (0 if `end` is below `start`: [`Layout::check`] refuses that).
    pub const fn len(&self) -> u32 {
        self.end.saturating_sub(self.start)
    }

    /// Whether the region is empty.
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The region's start as an offset from `base` (the flash's first address), as
    /// `embassy_embedded_hal`'s partitions and a flash driver count.
    pub const fn offset_from(&self, base: u32) -> u32 {
        self.start.saturating_sub(base)
    }

    /// Whether the two regions share a byte.
    pub const fn overlaps(&self, other: &Region) -> bool {
        self.start < other.end && other.start < self.end
    }

    /// Whether `other` lies wholly inside this region.
    pub const fn contains(&self, other: &Region) -> bool {
        other.start >= self.start && other.end <= self.end
    }
}

/// A flash layout for embassy-boot: the whole flash, its banks and the regions in it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// The whole flash.
    pub flash: Region,
    /// The first address of the second bank (the flash can read one bank while it programs
    /// the other).
    pub bank2: u32,
    /// The erase unit of ACTIVE and DFU (a page, or a sector), in bytes: embassy-boot's page,
    /// which its swap copies whole.
    pub page: u32,
    /// The erase unit of STATE and the settings, in bytes (the L475: a page, as everywhere; the
    /// F429: a 16 KiB sector, where ACTIVE's and DFU's are 128 KiB).
    pub small_page: u32,
    /// The write unit, in bytes.
    pub word: u32,
    /// The bootloader's own code.
    pub bootloader: Region,
    /// The application that runs.
    pub active: Region,
    /// Where a new image is written, and the old one kept during a trial boot.
    pub dfu: Region,
    /// embassy-boot's state: the mark and the swap's progress.
    pub state: Region,
    /// The application's settings pages: no embassy-boot partition may touch them.
    pub settings: Region,
}

/// Why a [`Layout`] is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayoutError {
    /// A region is empty, outside the flash, or not made of whole pages.
    NotPages,
    /// Two regions overlap.
    Overlap,
    /// The bootloader does not start the flash, or ACTIVE does not follow it.
    Order,
    /// DFU is smaller than ACTIVE plus one page (embassy-boot's swap needs the page).
    DfuTooSmall,
    /// STATE cannot hold the magic, the revert word and four progress words per ACTIVE page.
    StateTooSmall,
    /// ACTIVE is not in the first bank, or DFU or STATE is not in the second: the application,
    /// running from ACTIVE, writes DFU and STATE.
    Banks,
    /// The small page is not a multiple of the write unit, or the page of the small page.
    Units,
}

impl Layout {
    /// The bytes embassy-boot's STATE partition needs for this ACTIVE: a magic word, the
    /// "revert done" word and `4 × pages` progress words (a swap and a revert each copy every
    /// page twice), each one write unit.
    pub const fn state_needed(&self) -> u32 {
        (2 + 4 * (self.active.len() / self.page)) * self.word
    }

    /// The largest image file (application and trailer) this layout takes: ACTIVE's size, as
    /// the swap moves ACTIVE's size of DFU into ACTIVE.
    pub const fn max_image(&self) -> u32 {
        self.active.len()
    }

    const fn pages(&self, r: &Region, unit: u32) -> bool {
        r.start < r.end
            && self.flash.contains(r)
            && r.start.is_multiple_of(unit)
            && r.end.is_multiple_of(unit)
    }

    /// Checks embassy-boot's rules and ours; `Ok` if the layout is usable.
    pub const fn check(&self) -> Result<(), LayoutError> {
        if self.word == 0
            || self.small_page == 0
            || !self.small_page.is_multiple_of(self.word)
            || !self.page.is_multiple_of(self.small_page)
        {
            return Err(LayoutError::Units);
        }
        // The bootloader's region is never erased by embassy-boot, but ACTIVE follows it on a
        // page; STATE and the settings are erased in small pages.
        let regions = [
            (self.bootloader, self.page),
            (self.active, self.page),
            (self.dfu, self.page),
            (self.state, self.small_page),
            (self.settings, self.small_page),
        ];
        let mut rest: &[(Region, u32)] = &regions;
        while let [(r, unit), others @ ..] = rest {
            if !self.pages(r, *unit) {
                return Err(LayoutError::NotPages);
            }
            let mut after = others;
            while let [(o, _), more @ ..] = after {
                if r.overlaps(o) {
                    return Err(LayoutError::Overlap);
                }
                after = more;
            }
            rest = others;
        }
        if self.bootloader.start != self.flash.start || self.active.start != self.bootloader.end {
            return Err(LayoutError::Order);
        }
        if self.active.end > self.bank2
            || self.dfu.start < self.bank2
            || self.state.start < self.bank2
        {
            return Err(LayoutError::Banks);
        }
        if self.dfu.len() < self.active.len() + self.page {
            return Err(LayoutError::DfuTooSmall);
        }
        if self.state.len() < self.state_needed() {
            return Err(LayoutError::StateTooSmall);
        }
        Ok(())
    }
}

/// The L475's flash starts here.
pub const FLASH_BASE: u32 = 0x0800_0000;
/// 1 MiB.
pub const FLASH_SIZE: u32 = 1024 * 1024;
/// The second bank: the flash's second half.
pub const BANK2: u32 = FLASH_BASE + FLASH_SIZE / 2;
/// The bootloader's size (see the module's table).
pub const BOOTLOADER_SIZE: u32 = 32 * 1024;
/// The settings store's pages at the flash's end (unchanged by the bootloader).
pub const SETTINGS_SIZE: u32 = 4 * PAGE;
/// STATE's size: four pages (see the module's table).
pub const STATE_SIZE: u32 = 4 * PAGE;

const ACTIVE_START: u32 = FLASH_BASE + BOOTLOADER_SIZE;
const SETTINGS_START: u32 = FLASH_BASE + FLASH_SIZE - SETTINGS_SIZE;
const STATE_START: u32 = SETTINGS_START - STATE_SIZE;

/// The STM32L475VG's layout.
pub const L475: Layout = Layout {
    flash: Region {
        start: FLASH_BASE,
        end: FLASH_BASE + FLASH_SIZE,
    },
    bank2: BANK2,
    page: PAGE,
    small_page: PAGE,
    word: WORD,
    bootloader: Region {
        start: FLASH_BASE,
        end: ACTIVE_START,
    },
    active: Region {
        start: ACTIVE_START,
        end: BANK2,
    },
    dfu: Region {
        start: BANK2,
        // The least embassy-boot takes: ACTIVE and one page.
        end: BANK2 + (BANK2 - ACTIVE_START) + PAGE,
    },
    state: Region {
        start: STATE_START,
        end: SETTINGS_START,
    },
    settings: Region {
        start: SETTINGS_START,
        end: FLASH_BASE + FLASH_SIZE,
    },
};

const _: () = assert!(
    matches!(L475.check(), Ok(())),
    "the L475's layout breaks a rule"
);
// The figures in the module's table.
const _: () = assert!(L475.active.start == 0x0800_8000 && L475.active.end == 0x0808_0000);
const _: () = assert!(L475.dfu.start == 0x0808_0000 && L475.dfu.end == 0x080F_8800);
const _: () = assert!(L475.state.start == 0x080F_C000 && L475.state.end == 0x080F_E000);
const _: () = assert!(L475.settings.start == 0x080F_E000 && L475.settings.end == 0x0810_0000);
const _: () = assert!(L475.state_needed() == 7_696);

/// The F429's sectors: bank 1's (and bank 2's) first four are 16 KiB, the fifth 64 KiB, the other
/// seven 128 KiB (RM0090, "Flash module organization", 2 MiB dual-bank).
pub const F429_SMALL_SECTOR: u32 = 16 * 1024;
/// The F429's 128 KiB sectors: ACTIVE's and DFU's erase unit.
pub const F429_SECTOR: u32 = 128 * 1024;
/// The F429's write unit, as embassy-stm32 writes it (a 32-bit word at x32 parallelism).
pub const F429_WORD: u32 = 4;
/// The F429's second bank (its flash is 2 MiB in two banks of 1 MiB).
pub const F429_BANK2: u32 = FLASH_BASE + 0x10_0000;

/// The F429 sector that holds `addr`: its start and size (RM0090, "Flash module organization":
/// in each bank four of 16 KiB, one of 64 KiB, seven of 128 KiB). `None` outside the flash.
pub const fn f429_sector(addr: u32) -> Option<(u32, u32)> {
    if addr < FLASH_BASE || addr >= FLASH_BASE + 0x20_0000 {
        return None;
    }
    let bank = if addr >= F429_BANK2 {
        F429_BANK2
    } else {
        FLASH_BASE
    };
    let offset = addr - bank;
    Some(if offset < 4 * F429_SMALL_SECTOR {
        (
            bank + offset / F429_SMALL_SECTOR * F429_SMALL_SECTOR,
            F429_SMALL_SECTOR,
        )
    } else if offset < 0x2_0000 {
        (bank + 4 * F429_SMALL_SECTOR, 0x1_0000)
    } else {
        (
            bank + 0x2_0000 + (offset - 0x2_0000) / F429_SECTOR * F429_SECTOR,
            F429_SECTOR,
        )
    })
}

/// Whether `region` is made of whole F429 sectors of `unit` bytes each: what the chip erases
/// when a partition of that erase unit asks (a 16 KiB-aligned STATE in the 64 KiB sector 16
/// could never be erased).
pub const fn f429_sectors_of(region: Region, unit: u32) -> bool {
    let mut at = region.start;
    while at < region.end {
        match f429_sector(at) {
            Some((start, size)) if start == at && size == unit => at += size,
            _ => return false,
        }
    }
    at == region.end && region.start < region.end
}

/// The STM32F429ZI's layout (NUCLEO-F429ZI; see the module's second table).
pub const F429: Layout = Layout {
    flash: Region {
        start: FLASH_BASE,
        end: FLASH_BASE + 0x20_0000,
    },
    bank2: F429_BANK2,
    page: F429_SECTOR,
    small_page: F429_SMALL_SECTOR,
    word: F429_WORD,
    // Sectors 0-4 (4 × 16 + 64 KiB): ACTIVE must start on a 128 KiB sector.
    bootloader: Region {
        start: FLASH_BASE,
        end: FLASH_BASE + F429_SECTOR,
    },
    // Sectors 5-10. (Sector 11 is spare: DFU must be ACTIVE and one sector, and bank 2 has
    // seven 128 KiB sectors.)
    active: Region {
        start: FLASH_BASE + F429_SECTOR,
        end: FLASH_BASE + 7 * F429_SECTOR,
    },
    // Sectors 17-23.
    dfu: Region {
        start: F429_BANK2 + F429_SECTOR,
        end: F429_BANK2 + 8 * F429_SECTOR,
    },
    // Sector 14.
    state: Region {
        start: F429_BANK2 + 2 * F429_SMALL_SECTOR,
        end: F429_BANK2 + 3 * F429_SMALL_SECTOR,
    },
    // Sectors 12 and 13, as before the bootloader (src/board/f429.rs).
    settings: Region {
        start: F429_BANK2,
        end: F429_BANK2 + 2 * F429_SMALL_SECTOR,
    },
};

const _: () = assert!(
    matches!(F429.check(), Ok(())),
    "the F429's layout breaks a rule"
);
// The figures in the module's table.
const _: () = assert!(F429.active.start == 0x0802_0000 && F429.active.end == 0x080E_0000);
const _: () = assert!(F429.dfu.start == 0x0812_0000 && F429.dfu.end == 0x0820_0000);
const _: () = assert!(F429.state.start == 0x0810_8000 && F429.state.end == 0x0810_C000);
const _: () = assert!(F429.settings.start == 0x0810_0000 && F429.settings.end == 0x0810_8000);
const _: () = assert!(F429.state_needed() == 104);
// Layout::check knows one unit per region; the chip's sectors say which it is.
const _: () = assert!(
    f429_sectors_of(F429.active, F429.page)
        && f429_sectors_of(F429.dfu, F429.page)
        && f429_sectors_of(F429.state, F429.small_page)
        && f429_sectors_of(F429.settings, F429.small_page),
    "an F429 region is not made of the chip's sectors of its erase unit"
);

#[cfg(test)]
mod tests {
    use super::*;

    fn with(f: impl FnOnce(&mut Layout)) -> Result<(), LayoutError> {
        let mut l = L475;
        f(&mut l);
        l.check()
    }

    #[test]
    fn l475_and_f429_pass() {
        assert_eq!(L475.check(), Ok(()));
        assert_eq!(F429.check(), Ok(()));
    }

    #[test]
    fn f429_rules_can_fail() {
        let with = |f: &dyn Fn(&mut Layout)| {
            let mut l = F429;
            f(&mut l);
            l.check()
        };
        // DFU must be ACTIVE and one 128 KiB sector: sectors 18-23 are not.
        assert_eq!(
            with(&|l| l.dfu.start += F429_SECTOR),
            Err(LayoutError::DfuTooSmall)
        );
        // ACTIVE on a 16 KiB sector (right after a 32 KiB bootloader) is not a whole page.
        assert_eq!(
            with(&|l| {
                l.bootloader.end = FLASH_BASE + 2 * F429_SMALL_SECTOR;
                l.active.start = l.bootloader.end;
            }),
            Err(LayoutError::NotPages)
        );
        // STATE in 16 KiB sectors is fine, but not across half of one.
        assert_eq!(
            with(&|l| l.state.end -= F429_SMALL_SECTOR / 2),
            Err(LayoutError::NotPages)
        );
        assert_eq!(with(&|l| l.small_page = 48 * 1024), Err(LayoutError::Units));
    }

    #[test]
    fn f429_sectors_are_the_chips() {
        assert_eq!(f429_sector(0x0800_0000), Some((0x0800_0000, 0x4000)));
        assert_eq!(f429_sector(0x0801_3FFF), Some((0x0801_0000, 0x1_0000)));
        assert_eq!(f429_sector(0x080F_FFFF), Some((0x080E_0000, 0x2_0000)));
        assert_eq!(f429_sector(0x0810_C000), Some((0x0810_C000, 0x4000)));
        assert_eq!(f429_sector(0x0812_0000), Some((0x0812_0000, 0x2_0000)));
        assert_eq!(f429_sector(0x0820_0000), None);
        // STATE on a 16 KiB boundary inside the 64 KiB sector 16: Layout::check takes it, the
        // chip does not.
        let state = Region {
            start: 0x0811_0000,
            end: 0x0811_4000,
        };
        let mut moved = F429;
        moved.state = state;
        assert_eq!(moved.check(), Ok(()));
        assert!(!f429_sectors_of(state, F429_SMALL_SECTOR));
        // ACTIVE from sector 4 (64 KiB) is not 128 KiB sectors.
        assert!(!f429_sectors_of(
            Region {
                start: 0x0801_0000,
                end: 0x0808_0000
            },
            F429_SECTOR
        ));
    }

    #[test]
    fn each_rule_can_fail() {
        assert_eq!(with(|l| l.dfu.end -= PAGE), Err(LayoutError::DfuTooSmall));
        assert_eq!(
            with(|l| l.state.start += PAGE),
            Err(LayoutError::StateTooSmall)
        );
        assert_eq!(with(|l| l.dfu.end += 8), Err(LayoutError::NotPages));
        assert_eq!(
            with(|l| l.state.end = l.settings.start + PAGE),
            Err(LayoutError::Overlap)
        );
        assert_eq!(
            with(|l| {
                l.state = Region {
                    start: l.dfu.end - PAGE,
                    end: l.dfu.end - PAGE + STATE_SIZE,
                }
            }),
            Err(LayoutError::Overlap)
        );
        assert_eq!(with(|l| l.active.start += PAGE), Err(LayoutError::Order));
        assert_eq!(
            with(|l| {
                // STATE in bank 1, below ACTIVE's end: ACTIVE shrinks to make room.
                l.active.end -= STATE_SIZE;
                l.state = Region {
                    start: l.active.end,
                    end: l.active.end + STATE_SIZE,
                };
            }),
            Err(LayoutError::Banks)
        );
        assert_eq!(with(|l| l.word = 3), Err(LayoutError::Units));
        assert_eq!(with(|l| l.settings.end += PAGE), Err(LayoutError::NotPages));
    }

    #[test]
    fn state_rule_matches_embassy_boot() {
        // embassy-boot asserts `2 + 4 * pages <= state_len / write_size`.
        let pages = L475.active.len() / PAGE;
        assert!(2 + 4 * pages <= L475.state.len() / WORD);
        assert!(2 + 4 * pages > (L475.state.len() - PAGE) / WORD);
    }
}

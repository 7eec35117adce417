//! Where DFU and STATE are ([`Parts`]): on the board, windows on the settings store's flash
//! driver; in the emulator, RAM (QEMU's flash cannot be written). Each is a
//! [`NorFlash`](embedded_storage::nor_flash::NorFlash) that never reaches outside its partition.

#[cfg(feature = "emulator")]
use super::{PAGE, WORD};
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// This board's flash layout (the emulator's is the L475's: the same firmware).
#[cfg(feature = "board-l475")]
pub(super) const LAYOUT: rc_boot::layout::Layout = rc_boot::layout::L475;
/// This board's flash layout.
#[cfg(feature = "board-f429")]
pub(super) const LAYOUT: rc_boot::layout::Layout = rc_boot::layout::F429;

/// This board's id.
#[cfg(feature = "board-l475")]
pub(super) const BOARD_ID: u16 = rc_boot::BOARD_L475;
/// This board's id.
#[cfg(feature = "board-f429")]
pub(super) const BOARD_ID: u16 = rc_boot::BOARD_F429;

/// The public key images are verified with. A static, so that its 32 bytes are in the image as
/// they are (`rcgw sign` refuses an application that does not hold the signing key's public half).
#[cfg(feature = "hw")]
pub(super) static UPDATE_KEY: Option<[u8; 32]> =
    include!(concat!(env!("OUT_DIR"), "/update_key.rs"));
#[cfg(feature = "emulator")]
pub(super) static UPDATE_KEY: Option<[u8; 32]> = Some(rc_boot::TEST_PUBLIC_KEY);

/// The emulator's DFU partition, in RAM: 32 KiB of the 96 KiB the build links into (the other
/// statics and the deepest stack, the node in it, take about 16 KiB: `scripts/size-report.sh`).
#[cfg(feature = "emulator")]
pub const EMU_PARTITION: usize = 32 * 1024;

#[cfg(feature = "emulator")]
static EMU_RAM: static_cell::ConstStaticCell<[u8; EMU_PARTITION]> =
    static_cell::ConstStaticCell::new([0; EMU_PARTITION]);

/// The emulator's STATE pages, in RAM: as large as the board's.
#[cfg(feature = "emulator")]
static EMU_STATE: static_cell::ConstStaticCell<[u8; rc_boot::layout::STATE_SIZE as usize]> =
    static_cell::ConstStaticCell::new([0xFF; rc_boot::layout::STATE_SIZE as usize]);

/// Where the partitions are kept: on the board, nothing (the settings store lends its flash
/// driver for each job); in the emulator, the RAM of both (taken once: the gateway task's).
pub(super) struct Home {
    #[cfg(feature = "emulator")]
    dfu: &'static mut [u8],
    #[cfg(feature = "emulator")]
    state: &'static mut [u8],
}

impl Home {
    /// The largest image: DFU's size, but no larger than ACTIVE, where the bootloader swaps it.
    #[cfg(feature = "hw")]
    pub(super) const LARGEST_IMAGE: u32 = LAYOUT.max_image();
    /// The largest image: the emulator's RAM partition.
    #[cfg(feature = "emulator")]
    pub(super) const LARGEST_IMAGE: u32 = EMU_PARTITION as u32;

    pub(super) fn new() -> Home {
        Home {
            #[cfg(feature = "emulator")]
            dfu: EMU_RAM.take().as_mut_slice(),
            #[cfg(feature = "emulator")]
            state: EMU_STATE.take().as_mut_slice(),
        }
    }

    /// DFU and STATE, on the board's flash.
    #[cfg(feature = "hw")]
    pub(super) fn parts<'a>(
        &'a mut self,
        settings: &'a mut crate::settings::SavedSettings,
    ) -> Parts<'a> {
        Parts {
            flash: settings.flash(),
        }
    }

    /// DFU and STATE, in the emulator's RAM.
    #[cfg(feature = "emulator")]
    pub(super) fn parts<'a>(
        &'a mut self,
        _settings: &'a mut crate::settings::SavedSettings,
    ) -> Parts<'a> {
        Parts {
            dfu: &mut *self.dfu,
            state: &mut *self.state,
        }
    }
}

/// Where DFU and STATE are: windows on the board's flash.
#[cfg(feature = "hw")]
pub(super) struct Parts<'a> {
    flash: Option<&'a mut crate::board::SettingsFlash>,
}

#[cfg(feature = "hw")]
impl Parts<'_> {
    fn window(&mut self, range: core::ops::Range<u32>) -> Result<impl NorFlash + '_, ()> {
        let flash = self.flash.as_deref_mut().ok_or(())?;
        Ok(Window {
            flash,
            base: range.start,
            len: range.end - range.start,
        })
    }

    pub(super) fn dfu(&mut self) -> Result<impl NorFlash + '_, ()> {
        self.window(crate::board::DFU_RANGE)
    }

    pub(super) fn state(&mut self) -> Result<impl NorFlash + '_, ()> {
        self.window(crate::board::STATE_RANGE)
    }

    /// One step of the erase of DFU's erase unit at `offset`: the L475's 2 KiB page erased at
    /// once (25 ms at most).
    #[cfg(feature = "board-l475")]
    pub(super) fn erase_step(&mut self, offset: u32) -> nb::Result<(), ()> {
        let page = super::PAGE;
        let mut dfu = self.dfu().map_err(nb::Error::Other)?;
        if offset.saturating_add(page) as usize > dfu.capacity() {
            return Err(nb::Error::Other(()));
        }
        dfu.erase(offset, offset + page).map_err(|_| {
            warn!("update: erase at {:#x} failed", offset);
            nb::Error::Other(())
        })
    }

    /// One step of the erase of DFU's erase unit at `offset`: the F429's 128 KiB sector started,
    /// or looked at (`WouldBlock` while the flash works: up to 2 s).
    #[cfg(feature = "board-f429")]
    pub(super) fn erase_step(&mut self, offset: u32) -> nb::Result<(), ()> {
        let flash = self.flash.as_deref_mut().ok_or(nb::Error::Other(()))?;
        let range = crate::board::DFU_RANGE;
        if offset >= range.end - range.start {
            return Err(nb::Error::Other(()));
        }
        flash.erase_step(range.start + offset).map_err(|e| {
            if let nb::Error::Other(e) = e {
                warn!(
                    "update: erase at {:#x} failed: {}",
                    offset,
                    defmt::Debug2Format(&e)
                );
            }
            e.map(|_| ())
        })
    }
}

/// Where DFU and STATE are: the emulator's RAM.
#[cfg(feature = "emulator")]
pub(super) struct Parts<'a> {
    dfu: &'a mut [u8],
    state: &'a mut [u8],
}

#[cfg(feature = "emulator")]
impl Parts<'_> {
    pub(super) fn dfu(&mut self) -> Result<impl NorFlash + '_, ()> {
        Ok(Ram(&mut *self.dfu))
    }

    pub(super) fn state(&mut self) -> Result<impl NorFlash + '_, ()> {
        Ok(Ram(&mut *self.state))
    }

    /// One step of the erase of DFU's page at `offset`: in RAM, at once.
    pub(super) fn erase_step(&mut self, offset: u32) -> nb::Result<(), ()> {
        let page = super::PAGE;
        Ram(&mut *self.dfu)
            .erase(offset, offset.saturating_add(page))
            .map_err(|_| nb::Error::Other(()))
    }
}

/// A partition of the flash: offsets from its start, none past its end.
#[cfg(feature = "hw")]
struct Window<'a, F> {
    flash: &'a mut F,
    base: u32,
    len: u32,
}

/// A partition's error: the flash's, or an offset outside the partition.
#[derive(Debug)]
enum PartError<E> {
    Outside,
    #[cfg_attr(feature = "emulator", allow(dead_code))]
    Flash(E),
}

impl<E: NorFlashError> NorFlashError for PartError<E> {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            PartError::Outside => NorFlashErrorKind::OutOfBounds,
            PartError::Flash(e) => e.kind(),
        }
    }
}

#[cfg(feature = "hw")]
impl<F: ErrorType> ErrorType for Window<'_, F> {
    type Error = PartError<F::Error>;
}

#[cfg(feature = "hw")]
impl<F: ReadNorFlash> Window<'_, F> {
    /// The flash's offset of `offset..offset + len` in the window, if it is inside.
    fn at(&self, offset: u32, len: usize) -> Result<u32, PartError<F::Error>> {
        let end = (offset as usize)
            .checked_add(len)
            .ok_or(PartError::Outside)?;
        if end > self.len as usize {
            return Err(PartError::Outside);
        }
        Ok(self.base + offset)
    }
}

#[cfg(feature = "hw")]
impl<F: ReadNorFlash> ReadNorFlash for Window<'_, F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let at = self.at(offset, bytes.len())?;
        self.flash.read(at, bytes).map_err(PartError::Flash)
    }

    fn capacity(&self) -> usize {
        self.len as usize
    }
}

#[cfg(feature = "hw")]
impl<F: NorFlash> NorFlash for Window<'_, F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let at = self.at(offset, bytes.len())?;
        self.flash.write(at, bytes).map_err(PartError::Flash)
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let at = self.at(from, to.saturating_sub(from) as usize)?;
        self.flash
            .erase(at, at + (to - from))
            .map_err(PartError::Flash)
    }
}

/// A partition in the emulator's RAM, as NOR flash of the L475's units.
#[cfg(feature = "emulator")]
struct Ram<'a>(&'a mut [u8]);

#[cfg(feature = "emulator")]
impl ErrorType for Ram<'_> {
    type Error = PartError<NorFlashErrorKind>;
}

#[cfg(feature = "emulator")]
impl ReadNorFlash for Ram<'_> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let from = offset as usize;
        let to = from.checked_add(bytes.len()).ok_or(PartError::Outside)?;
        bytes.copy_from_slice(self.0.get(from..to).ok_or(PartError::Outside)?);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.0.len()
    }
}

#[cfg(feature = "emulator")]
impl NorFlash for Ram<'_> {
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = PAGE as usize;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let from = offset as usize;
        let to = from.checked_add(bytes.len()).ok_or(PartError::Outside)?;
        self.0
            .get_mut(from..to)
            .ok_or(PartError::Outside)?
            .copy_from_slice(bytes);
        Ok(())
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0
            .get_mut(from as usize..to as usize)
            .ok_or(PartError::Outside)?
            .fill(0xFF);
        Ok(())
    }
}

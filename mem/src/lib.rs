//! `memcpy` and `memset` for the firmware, about 150 bytes instead of compiler-builtins' 1.9 KB.
//!
//! LLVM lowers every struct move and zeroing it does not inline to these calls (on Arm, to the
//! EABI's `__aeabi_memcpy4`, `__aeabi_memclr8` and so on). compiler-builtins provides them tuned
//! for speed: an unrolled `memcpy` that realigns misaligned copies with shifts (744 B), and a
//! separate body for each EABI variant (another 1.2 KB). The STM32F103 has 56 KiB of flash for
//! the whole firmware, and its copies are small (frames of 16 bytes, engine and register state
//! of a few hundred): a word loop when both ends are word-aligned, a byte loop otherwise, is
//! enough. `scripts/cpu-load.sh` measures what this costs per bus transaction.
//!
//! compiler-builtins defines its versions as weak symbols, so these strong ones replace them at
//! link time. They are exported under the C names only on the MCU (`target_os = "none"`): on
//! the host, the tests call them as Rust functions next to the C library's.
//!
//! The loops read and write through `read_volatile`/`write_volatile`: LLVM would otherwise
//! recognise a plain copy loop as a `memcpy` and compile it to a call to itself.

#![no_std]
#![deny(missing_docs)]

use core::ptr::{read_volatile, write_volatile};

/// Copies `n` bytes from `src` to `dst` (which do not overlap): words while both are
/// word-aligned, then bytes.
///
/// # Safety
/// As C's `memcpy`: both ranges valid for `n` bytes and not overlapping.
#[inline(never)]
pub unsafe fn copy(dst: *mut u8, src: *const u8, n: usize) {
    let mut i = 0;
    if (dst as usize | src as usize) & 3 == 0 {
        while n - i >= 4 {
            write_volatile(
                dst.add(i).cast::<u32>(),
                read_volatile(src.add(i).cast::<u32>()),
            );
            i += 4;
        }
    }
    while i < n {
        write_volatile(dst.add(i), read_volatile(src.add(i)));
        i += 1;
    }
}

/// Sets `n` bytes at `dst` to `byte`: words while `dst` is word-aligned, then bytes.
///
/// # Safety
/// As C's `memset`: the range valid for `n` bytes.
#[inline(never)]
pub unsafe fn fill(dst: *mut u8, byte: u8, n: usize) {
    let mut i = 0;
    if dst as usize & 3 == 0 {
        let word = u32::from_ne_bytes([byte; 4]);
        while n - i >= 4 {
            write_volatile(dst.add(i).cast::<u32>(), word);
            i += 4;
        }
    }
    while i < n {
        write_volatile(dst.add(i), byte);
        i += 1;
    }
}

/// The C and Arm EABI entry points (Arm's run-time ABI, §4.3.4). Only on the MCU.
#[cfg(target_os = "none")]
mod symbols {
    use super::{copy, fill};

    /// C `memcpy`.
    #[no_mangle]
    pub unsafe extern "C" fn memcpy(dst: *mut u8, src: *const u8, n: usize) -> *mut u8 {
        copy(dst, src, n);
        dst
    }

    /// C `memset`; `c` is converted to a byte, as C says.
    #[no_mangle]
    pub unsafe extern "C" fn memset(dst: *mut u8, c: i32, n: usize) -> *mut u8 {
        fill(dst, c as u8, n);
        dst
    }

    /// EABI copy, any alignment.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memcpy(dst: *mut u8, src: *const u8, n: usize) {
        copy(dst, src, n)
    }

    /// EABI copy, both ends 4-byte aligned.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memcpy4(dst: *mut u8, src: *const u8, n: usize) {
        copy(dst, src, n)
    }

    /// EABI copy, both ends 8-byte aligned.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memcpy8(dst: *mut u8, src: *const u8, n: usize) {
        copy(dst, src, n)
    }

    /// EABI fill; note the argument order (length before value), unlike C's.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memset(dst: *mut u8, n: usize, c: i32) {
        fill(dst, c as u8, n)
    }

    /// EABI fill, 4-byte aligned.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memset4(dst: *mut u8, n: usize, c: i32) {
        fill(dst, c as u8, n)
    }

    /// EABI fill, 8-byte aligned.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memset8(dst: *mut u8, n: usize, c: i32) {
        fill(dst, c as u8, n)
    }

    /// EABI zeroing.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memclr(dst: *mut u8, n: usize) {
        fill(dst, 0, n)
    }

    /// EABI zeroing, 4-byte aligned.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memclr4(dst: *mut u8, n: usize) {
        fill(dst, 0, n)
    }

    /// EABI zeroing, 8-byte aligned.
    #[no_mangle]
    pub unsafe extern "C" fn __aeabi_memclr8(dst: *mut u8, n: usize) {
        fill(dst, 0, n)
    }
}

#[cfg(test)]
mod tests {
    use super::{copy, fill};

    /// Every source and destination offset (word-aligned and not) and every length up to a few
    /// words, against slice copies, in a buffer with guard bytes around the target range.
    #[test]
    fn copy_moves_exactly_the_bytes_asked_for() {
        let src: [u8; 80] = core::array::from_fn(|i| (i as u8).wrapping_mul(37).wrapping_add(11));
        for s in 0..8 {
            for d in 0..8 {
                for n in 0..=64 {
                    let mut dst = [0xA5u8; 80];
                    // SAFETY: both ranges lie inside their 80-byte arrays (8 + 64 < 80).
                    unsafe { copy(dst.as_mut_ptr().add(d), src.as_ptr().add(s), n) };
                    let mut want = [0xA5u8; 80];
                    want[d..d + n].copy_from_slice(&src[s..s + n]);
                    assert_eq!(dst, want, "src +{s}, dst +{d}, {n} bytes");
                }
            }
        }
    }

    #[test]
    fn fill_sets_exactly_the_bytes_asked_for() {
        for byte in [0u8, 0x5A, 0xFF] {
            for d in 0..8 {
                for n in 0..=64 {
                    let mut dst = [0xA5u8; 80];
                    // SAFETY: the range lies inside the array (8 + 64 < 80).
                    unsafe { fill(dst.as_mut_ptr().add(d), byte, n) };
                    let mut want = [0xA5u8; 80];
                    want[d..d + n].fill(byte);
                    assert_eq!(dst, want, "value {byte:#x}, dst +{d}, {n} bytes");
                }
            }
        }
    }
}

//! The NUCLEO-F429ZI's Ethernet, which [`super::board`] brings up: the LAN8742A PHY through its
//! management interface (SMI), the check that its reference clock reaches the MAC, the MAC's
//! address and the DMA's frames. The RMII pins are in the board's table (`super`).

use core::future::Future;
use core::task::Context;

use embassy_stm32::eth::{self, PacketQueue, Phy, Sma, StationManagement};
use embassy_stm32::peripherals::{ETH, ETH_SMA};
use static_cell::ConstStaticCell;

/// The LAN8742A's address on the SMI: its PHYAD0 strap, low on the NUCLEO-F429ZI (UM1974).
pub(super) const PHY_ADDRESS: u8 = 0;

/// Ethernet frames the DMA holds, each way: 4 of 1.5 KiB each (12 KiB of RAM). Modbus TCP moves
/// small segments; four let a burst from several clients in while the stack is busy.
const PACKETS: usize = 4;

/// The Ethernet DMA's descriptors and frame buffers, in `.bss` (SRAM, which the DMA reaches:
/// `memory/f429zi.x`), built in place (`ConstStaticCell`: no 12 KiB temporary on the stack).
pub(super) static PACKET_QUEUE: ConstStaticCell<PacketQueue<PACKETS, PACKETS>> =
    ConstStaticCell::new(PacketQueue::new());

/// The Ethernet driver as the network stack takes it ([`crate::net`]).
pub type EthernetDevice = eth::Ethernet<'static, ETH, Lan8742a<Sma<'static, ETH_SMA>>>;

/// The Ethernet, brought up by [`super::board`], and what the network stack needs besides it.
pub struct Ethernet {
    /// The MAC and PHY.
    pub device: EthernetDevice,
    /// A random seed from the RNG: embassy-net takes its TCP initial sequence numbers and
    /// ephemeral ports from it, which must not be guessable (a guessed sequence number lets
    /// a third party inject into a connection).
    pub seed: u64,
}

/// The MAC address: locally administered (first octet 0x02: the "local" bit set, the multicast
/// bit clear), the other five octets a hash of the chip's 96-bit unique ID, so that each board
/// keeps its own address across starts and two boards on one network differ (but for a hash
/// collision, one in 2⁴⁰ per pair) without an OUI of our own.
pub(super) fn mac_address() -> [u8; 6] {
    // FNV-1a, 64 bits: small and good enough to spread the ID's lot, wafer and X/Y fields.
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for byte in embassy_stm32::uid::uid() {
        hash ^= u64::from(byte);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    let [a, b, c, d, e, ..] = hash.to_le_bytes();
    [0x02, a, b, c, d, e]
}

/// The LAN8742A's identifier, PHY ID 1 (register 2): Microchip's OUI bits 3-18 (LAN8742A data
/// sheet, 4.2.3); ID 2 (register 3) holds the model, 0xC13x.
const PHY_ID1: u16 = 0x0007;

/// Whether the PHY answers at [`PHY_ADDRESS`] with its identifier within
/// [`PHY_RESET_WAIT_MS`] (it leaves its own power-on reset with the board's; no PHY reads
/// 0xFFFF: MDIO floats high with its pull-up).
pub(super) fn phy_answers(sma: &mut impl StationManagement) -> bool {
    for _ in 0..PHY_RESET_WAIT_MS {
        let (id1, id2) = (sma.smi_read(PHY_ADDRESS, 2), sma.smi_read(PHY_ADDRESS, 3));
        if id1 == PHY_ID1 && id2 & 0xFFF0 == 0xC130 {
            return true;
        }
        embassy_time::block_for(embassy_time::Duration::from_millis(1));
    }
    false
}

/// The LAN8742A through its SMI: reset, auto-negotiation advertising 10 and 100 Mbit/s, half and
/// full duplex, and the MAC set to the speed and duplex the link came up at.
///
/// Why not embassy's `GenericPhy`: its automatic address search panics when no PHY answers
/// (a damaged PHY would then stop the RS485 gateway, which needs no network), and waits for a
/// reset without bound at a fixed address. And embassy-stm32 0.6.0's MAC (eth v1) is set to
/// 100 Mbit/s full duplex once and never follows the link: a link at 10 Mbit/s or half duplex
/// would be up and pass nothing (or collide), so [`Phy::poll_link`] here sets the MAC's speed
/// (MACCR.FES) and duplex (MACCR.DM) to what the PHY resolved, whenever that changes.
///
/// **A partner that does not negotiate** (a switch port with its speed and duplex fixed): the PHY
/// finds the speed by parallel detection, which can only report half duplex (IEEE 802.3 clause
/// 28); the port itself is then almost always fixed at full duplex, so the MAC runs full duplex:
/// a port forced to 100 Mbit/s full duplex works (it never linked before: only 100 Mbit/s full
/// duplex was advertised and accepted). A port forced to *half* duplex would run mismatched
/// (late collisions, lost frames): README says to let such a port negotiate.
pub struct Lan8742a<S> {
    sma: S,
    address: u8,
    /// The speed (100 Mbit/s?) and duplex (full?) the MAC was last set to while the link was up.
    mode: Option<(bool, bool)>,
}

/// IEEE 802.3 clause 22 registers and the LAN8742A's own.
mod reg {
    /// Basic Control.
    pub const BCR: u8 = 0;
    pub const BCR_RESET: u16 = 1 << 15;
    pub const BCR_AUTONEG: u16 = 1 << 12;
    pub const BCR_RESTART_AUTONEG: u16 = 1 << 9;
    /// Basic Status.
    pub const BSR: u8 = 1;
    pub const BSR_LINK: u16 = 1 << 2;
    pub const BSR_AUTONEG_DONE: u16 = 1 << 5;
    /// Auto-negotiation advertisement: selector 802.3, 10BASE-T and 100BASE-TX, half and full
    /// duplex.
    pub const ANAR: u8 = 4;
    pub const ANAR_ALL: u16 = 1 << 8 | 1 << 7 | 1 << 6 | 1 << 5 | 0x0001;
    /// Auto-negotiation expansion: bit 0, the link partner negotiates.
    pub const ANER: u8 = 6;
    pub const ANER_PARTNER_NEGOTIATES: u16 = 1 << 0;
    /// LAN8742A PHY Special Control/Status: bits 4:2 the speed and duplex resolved (001 10 Mbit/s
    /// half, 101 10 full, 010 100 half, 110 100 full).
    pub const PSCSR: u8 = 31;
    pub const PSCSR_100: u16 = 1 << 3;
    pub const PSCSR_FULL: u16 = 1 << 4;
}

impl<S: StationManagement> Lan8742a<S> {
    /// The PHY at `address` on `sma`.
    pub fn new(sma: S, address: u8) -> Lan8742a<S> {
        Lan8742a {
            sma,
            address,
            mode: None,
        }
    }

    fn read(&mut self, register: u8) -> u16 {
        self.sma.smi_read(self.address, register)
    }

    fn write(&mut self, register: u8, value: u16) {
        self.sma.smi_write(self.address, register, value)
    }
}

/// Sets the MAC's speed and duplex (MACCR.FES, MACCR.DM), which embassy-stm32 0.6.0 sets to
/// 100 Mbit/s full duplex once. Called as the link comes up, before frames flow.
fn set_mac_mode(fast: bool, full: bool) {
    use embassy_stm32::pac::eth::vals::{Dm, Fes};
    embassy_stm32::pac::ETH.ethernet_mac().maccr().modify(|w| {
        w.set_fes(if fast { Fes::FES100 } else { Fes::FES10 });
        w.set_dm(if full {
            Dm::FULL_DUPLEX
        } else {
            Dm::HALF_DUPLEX
        });
    });
}

/// How long the PHY may take to leave its reset (the LAN8742A takes well under a millisecond;
/// an absent PHY reads all ones, the reset bit included, and is waited for this long only).
const PHY_RESET_WAIT_MS: u32 = 100;

/// How often the link is read while the stack waits for it.
const LINK_POLL: embassy_time::Duration = embassy_time::Duration::from_millis(500);

impl<S: StationManagement> Phy for Lan8742a<S> {
    fn phy_reset(&mut self) {
        self.write(reg::BCR, reg::BCR_RESET);
        for _ in 0..PHY_RESET_WAIT_MS {
            if self.read(reg::BCR) & reg::BCR_RESET == 0 {
                return;
            }
            embassy_time::block_for(embassy_time::Duration::from_millis(1));
        }
        warn!("Ethernet: the PHY did not answer");
    }

    fn phy_init(&mut self) {
        self.write(reg::ANAR, reg::ANAR_ALL);
        self.write(reg::BCR, reg::BCR_AUTONEG | reg::BCR_RESTART_AUTONEG);
    }

    fn poll_link(&mut self, cx: &mut Context) -> bool {
        // Read again after LINK_POLL: the stack polls the link only when woken.
        let _ = core::pin::pin!(embassy_time::Timer::after(LINK_POLL)).poll(cx);
        let bsr = self.read(reg::BSR);
        // All ones: no PHY answers (MDIO idles high).
        let up = reg::BSR_LINK | reg::BSR_AUTONEG_DONE;
        if bsr == u16::MAX || bsr & up != up {
            self.mode = None;
            return false;
        }
        let resolved = self.read(reg::PSCSR);
        let fast = resolved & reg::PSCSR_100 != 0;
        // Parallel detection (a partner that does not negotiate) says half duplex: see above.
        let full = resolved & reg::PSCSR_FULL != 0
            || self.read(reg::ANER) & reg::ANER_PARTNER_NEGOTIATES == 0;
        if self.mode != Some((fast, full)) {
            set_mac_mode(fast, full);
            self.mode = Some((fast, full));
            info!(
                "net: link up, {} Mbit/s, {} duplex",
                if fast { 100 } else { 10 },
                if full { "full" } else { "half" }
            );
        }
        true
    }
}

/// How long the MAC's DMA may take to leave its software reset once the PHY's reference clock
/// runs (a few of its cycles; [`mac_clock_runs`]).
const REF_CLK_WAIT_MS: u32 = 10;

/// Whether the PHY's 50 MHz reference clock (RMII REF_CLK, PA1) reaches the MAC. The MAC's DMA
/// leaves its software reset (ETH_DMABMR.SR) only once every clock of its interface runs, and
/// embassy-stm32 0.6.0 waits for that without bound in `Ethernet::new_with_phy`: a PHY that
/// answers on the management interface (clocked by the MCU) but sends no reference clock (its
/// crystal or its REF_CLK strap faulty) would hang the start there. So the same reset first,
/// bounded ([`REF_CLK_WAIT_MS`]); embassy's then passes at once. Also done in the order the
/// reference manual asks (RM0090, SYSCFG_PMC.MII_RMII_SEL: set while the MAC is held in reset,
/// before its clocks), which embassy's is not. Without the clock: the MAC's clocks off again,
/// `false`.
pub(super) fn mac_clock_runs() -> bool {
    use embassy_stm32::pac::gpio::vals::Moder;
    use embassy_stm32::pac::{ETH, GPIOA, RCC, SYSCFG};
    const REF_CLK_PIN: usize = 1;
    const AF_ETH: u8 = 11;
    critical_section::with(|_| {
        RCC.ahb1rstr().modify(|w| w.set_ethrst(true));
        SYSCFG.pmc().modify(|w| w.set_mii_rmii_sel(true));
        RCC.ahb1rstr().modify(|w| w.set_ethrst(false));
        RCC.ahb1enr().modify(|w| {
            w.set_ethen(true);
            w.set_ethtxen(true);
            w.set_ethrxen(true);
        });
        GPIOA.afr(0).modify(|w| w.set_afr(REF_CLK_PIN, AF_ETH));
        GPIOA
            .moder()
            .modify(|w| w.set_moder(REF_CLK_PIN, Moder::ALTERNATE));
    });
    let dma = ETH.ethernet_dma();
    dma.dmabmr().modify(|w| w.set_sr(true));
    for _ in 0..REF_CLK_WAIT_MS {
        if !dma.dmabmr().read().sr() {
            return true;
        }
        embassy_time::block_for(embassy_time::Duration::from_millis(1));
    }
    RCC.ahb1enr().modify(|w| {
        w.set_ethen(false);
        w.set_ethtxen(false);
        w.set_ethrxen(false);
    });
    false
}

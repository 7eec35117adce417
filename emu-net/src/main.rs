//! The gateway's network side on QEMU's `mps2-an386` machine: a Cortex-M4 with an SMSC LAN9118
//! Ethernet controller (QEMU has no STM32 with Ethernet). It proves the network task (embassy-net,
//! its sockets and buffers, the per-socket serving loop) in the emulator, not the STM32's MAC.
//!
//! - IPv4 10.0.2.15/24, gateway 10.0.2.2, static: the addresses of QEMU's user-mode network
//!   (`-nic user,hostfwd=tcp:127.0.0.1:PORT-:502`).
//! - TCP port 502, [`SOCKETS`] sockets, each served by its own task ([`serve`]): up to five
//!   connections at once. For now each connection is echoed; the echo is where the gateway's
//!   node will be called.
//! - The log goes over semihosting (`-semihosting-config enable=on,target=native`).
//!
//! Run it with `scripts/emu-net.sh`.

#![no_std]
#![no_main]

/// One line to the semihosting console.
#[macro_export]
macro_rules! log {
    ($($arg:tt)*) => {
        cortex_m_semihosting::hprintln!($($arg)*)
    };
}

mod rt;
mod time;

use embassy_executor::Spawner;
use embassy_net::tcp::TcpSocket;
use embassy_net::{Config, Ipv4Address, Ipv4Cidr, Stack, StackResources, StaticConfigV4};
use embassy_time::Duration;
use static_cell::StaticCell;

/// The LAN9118's register window on the AN386 (hw/arm/mps2.c: `ethernet_base`).
const ETH_BASE: usize = 0x4020_0000;
/// A locally administered MAC address (bit 1 of the first byte set).
const MAC: [u8; 6] = [0x02, 0x00, 0x00, 0x47, 0x57, 0x01];
/// The Modbus/TCP port.
const PORT: u16 = 502;
/// Connections served at once: one socket, one task each.
pub const SOCKETS: usize = 5;
/// Bytes of each socket's receive and transmit buffer.
const SOCKET_BUF: usize = 1024;
/// A connection idle this long is dropped (the socket is then free for the next client).
const IDLE_TIMEOUT: Duration = Duration::from_secs(60);

/// Shared by the driver and the LAN9118's interrupt handler (`rt::DefaultHandler`).
pub static ETH_STATE: lan9118::State = lan9118::State::new();

/// One socket's buffers.
struct SocketBuffers {
    rx: [u8; SOCKET_BUF],
    tx: [u8; SOCKET_BUF],
}

/// Every socket's buffers, in a static: socket `i` takes entry `i` once.
static BUFFERS: [StaticCell<SocketBuffers>; SOCKETS] = [const { StaticCell::new() }; SOCKETS];
static RESOURCES: StaticCell<StackResources<SOCKETS>> = StaticCell::new();

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(mut core) = cortex_m::Peripherals::take() else {
        log!("core peripherals taken twice");
        loop {
            cortex_m::asm::wfi();
        }
    };
    time::init(core.SYST);
    rt::run(|spawner| start(spawner, &mut core.NVIC))
}

/// Brings the Ethernet controller and the stack up and spawns the tasks.
fn start(spawner: Spawner, nvic: &mut cortex_m::peripheral::NVIC) {
    // SAFETY: 0x4020_0000 is the AN386's LAN9118 (hw/arm/mps2.c), device memory for good, and
    // only the driver (and its interrupt handler, through `ETH_STATE`) touches it.
    let regs = unsafe { lan9118::Regs::new(ETH_BASE) };
    let mut eth = match lan9118::Lan9118::new(regs, &ETH_STATE, MAC) {
        Ok(eth) => eth,
        Err(e) => {
            log!("lan9118: {:?}", e);
            return;
        }
    };
    log!(
        "lan9118: ID_REV {:#010x}, MAC {:02x?}",
        eth.id_rev(),
        eth.read_mac().unwrap_or_default()
    );
    // The driver has set the line active high: only now may the NVIC see it.
    // SAFETY: no mask-based critical section of this program relies on IRQ 13 being masked.
    unsafe { cortex_m::peripheral::NVIC::unmask(rt::ETH_IRQ) };
    let _ = nvic;

    let config = Config::ipv4_static(StaticConfigV4 {
        address: Ipv4Cidr::new(Ipv4Address::new(10, 0, 2, 15), 24),
        gateway: Some(Ipv4Address::new(10, 0, 2, 2)),
        dns_servers: Default::default(),
    });
    // The seed of TCP's initial sequence numbers and ephemeral ports: the time since reset
    // (which varies a little under QEMU) over a constant. Not secret, as nothing here is.
    let seed = 0x5EED_0502_u64 ^ embassy_time::Instant::now().as_ticks();
    let (stack, runner) =
        embassy_net::new(eth, config, RESOURCES.init(StackResources::new()), seed);
    match net_task(runner) {
        Ok(token) => spawner.spawn(token),
        Err(_) => log!("net task not started"),
    }
    for index in 0..SOCKETS {
        match socket_task(stack, index) {
            Ok(token) => spawner.spawn(token),
            Err(_) => log!("socket task {} not started", index),
        }
    }
    log!(
        "emu-net: listening on 10.0.2.15:{} with {} sockets",
        PORT,
        SOCKETS
    );
}

/// The stack's own task: moves frames between the driver and the sockets.
#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, lan9118::Lan9118>) -> ! {
    runner.run().await
}

/// One task per socket index.
#[embassy_executor::task(pool_size = SOCKETS)]
async fn socket_task(stack: Stack<'static>, index: usize) {
    serve(stack, index).await
}

/// Socket `index`: accepts a connection on [`PORT`], serves it until the client closes it (or it
/// fails or idles out), and accepts the next one, forever. Its buffers are the static entry
/// `index` of [`BUFFERS`].
///
/// The echo below is the stand-in for the gateway: there, each request read is handed to the
/// shared node and its answer written back, on the same loop.
pub async fn serve(stack: Stack<'static>, index: usize) {
    let Some(cell) = BUFFERS.get(index) else {
        log!("socket {}: no buffers", index);
        return;
    };
    let Some(buffers) = cell.try_init(SocketBuffers {
        rx: [0; SOCKET_BUF],
        tx: [0; SOCKET_BUF],
    }) else {
        log!("socket {}: buffers taken twice", index);
        return;
    };
    let SocketBuffers { rx, tx } = buffers;
    let mut data = [0u8; 512];
    loop {
        let mut socket = TcpSocket::new(stack, rx, tx);
        socket.set_timeout(Some(IDLE_TIMEOUT));
        // Answers go out at once, not after Nagle's wait for an ACK.
        socket.set_nagle_enabled(false);
        if let Err(e) = socket.accept(PORT).await {
            log!("socket {}: accept: {:?}", index, e);
            continue;
        }
        log!(
            "socket {}: connected from {:?}",
            index,
            socket.remote_endpoint()
        );
        loop {
            let n = match socket.read(&mut data).await {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) => {
                    log!("socket {}: read: {:?}", index, e);
                    break;
                }
            };
            let Some(request) = data.get(..n) else { break };
            if let Err(e) = write_all(&mut socket, request).await {
                log!("socket {}: write: {:?}", index, e);
                break;
            }
        }
        socket.close();
        // Wait for the FIN to be sent and acknowledged before the socket is dropped (dropping it
        // frees its slot in the stack at once, and would cut the close short).
        let _ = socket.flush().await;
        log!("socket {}: closed", index);
    }
}

/// Writes all of `bytes`.
async fn write_all(
    socket: &mut TcpSocket<'_>,
    mut bytes: &[u8],
) -> Result<(), embassy_net::tcp::Error> {
    while !bytes.is_empty() {
        let n = socket.write(bytes).await?;
        bytes = bytes.get(n..).unwrap_or_default();
    }
    Ok(())
}

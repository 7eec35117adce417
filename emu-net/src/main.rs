//! The gateway's network side on QEMU's `mps2-an386` machine: a Cortex-M4 with an SMSC LAN9118
//! Ethernet controller (QEMU has no STM32 with Ethernet). It runs the protocol [`Node`] with its
//! Modbus TCP side behind the network task the Ethernet board runs ([`rc_net`]: the same socket
//! tasks, pipes and buffers), so what the emulator suite proves over TCP is the board's code;
//! not the STM32's Ethernet MAC, its PHY or its driver (embassy-stm32's `eth`).
//!
//! - IPv4 from the node's settings
//!   ([`GatewaySettings::net`](protocol::plc::GatewaySettings::net)); this build sets
//!   10.0.2.15/24, router 10.0.2.2, the addresses of QEMU's user-mode network
//!   (`-nic user,hostfwd=tcp:127.0.0.1:PORT-:502`).
//! - TCP port 502, [`rc_net::SOCKETS`] sockets, each served by its own task ([`rc_net::serve`]);
//!   the gateway task owns the node and answers them.
//! - No RS485 bus and no PIO here: the bus frames the node sends go nowhere, so its axes stay
//!   offline (the bus is proven on the L475 emulator build). No flash: SAVE is counted, not
//!   stored.
//! - The log goes over semihosting (`-semihosting-config enable=on,target=native`); the line
//!   `ready` says the sockets listen.
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

use embassy_executor::Spawner;
use embassy_futures::select::select;
use embassy_net::{Config, Ipv4Address, Ipv4Cidr, Stack, StackResources, StaticConfigV4};
use embassy_time::Timer;
use protocol::net::Ipv4;
use protocol::node::{Action, Node};
use protocol::plc::{Boot, GatewayConfig, SettingsRequest, IDENTITY};
use protocol::time::Instant;
use protocol::AxisSet;
use rc_net::{Port, SocketHandle, SOCKETS};
use static_cell::StaticCell;

/// The LAN9118's register window on the AN386 (hw/arm/mps2.c: `ethernet_base`).
const ETH_BASE: usize = 0x4020_0000;
/// A locally administered MAC address (bit 1 of the first byte set).
const MAC: [u8; 6] = [0x02, 0x00, 0x00, 0x47, 0x57, 0x01];
/// Bytes of each socket's TCP receive and transmit buffer (as on the Ethernet board).
const SOCKET_BUF: usize = 1024;

/// Shared by the driver and the LAN9118's interrupt handler (`rt::DefaultHandler`).
pub static ETH_STATE: lan9118::State = lan9118::State::new();

/// Where the socket tasks and the gateway task meet; each event is logged as the node gets it.
static PORT: Port = Port::with_trace(trace);

/// One socket's buffers.
struct SocketBuffers {
    rx: [u8; SOCKET_BUF],
    tx: [u8; SOCKET_BUF],
}

/// Every socket's buffers, in a static: socket `i` takes entry `i` once.
static BUFFERS: [StaticCell<SocketBuffers>; SOCKETS] = [const { StaticCell::new() }; SOCKETS];
static RESOURCES: StaticCell<StackResources<SOCKETS>> = StaticCell::new();
static NODE: StaticCell<Node> = StaticCell::new();

/// The node's configuration here: two axes (on no bus), the emulator's network.
fn config() -> GatewayConfig {
    let mut config = GatewayConfig::new(AxisSet::first(2));
    config.bus.establish = false;
    config.settings.net.ip = Ipv4([10, 0, 2, 15]);
    config.settings.net.prefix = 24;
    config.settings.net.router = Ipv4([10, 0, 2, 2]);
    config
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(core) = cortex_m::Peripherals::take() else {
        log!("core peripherals taken twice");
        loop {
            cortex_m::asm::wfi();
        }
    };
    rt::start_time(core.SYST);
    rt::run(start)
}

/// The network settings as embassy-net takes them.
fn ip_config(config: &GatewayConfig) -> Config {
    let net = config.settings.net;
    let [a, b, c, d] = net.ip.0;
    let router = (net.router != Ipv4::UNSPECIFIED).then(|| {
        let [a, b, c, d] = net.router.0;
        Ipv4Address::new(a, b, c, d)
    });
    Config::ipv4_static(StaticConfigV4 {
        address: Ipv4Cidr::new(Ipv4Address::new(a, b, c, d), net.prefix),
        gateway: router,
        dns_servers: Default::default(),
    })
}

/// Brings the Ethernet controller, the stack and the node up and spawns the tasks.
fn start(spawner: Spawner) {
    // SAFETY: 0x4020_0000 is the AN386's LAN9118 (hw/arm/mps2.c), device memory for good, and
    // only the driver (and its interrupt handler, through `ETH_STATE`) touches it.
    let regs = unsafe { lan9118::Regs::new(ETH_BASE) };
    let eth = match lan9118::Lan9118::new(regs, &ETH_STATE, MAC) {
        Ok(eth) => eth,
        Err(e) => {
            log!("lan9118: {:?}", e);
            return;
        }
    };
    // The driver has set the line active high: only now may the NVIC see it.
    // SAFETY: no mask-based critical section of this program relies on IRQ 13 being masked.
    unsafe { cortex_m::peripheral::NVIC::unmask(rt::ETH_IRQ) };

    let config = config();
    // The seed of TCP's initial sequence numbers and ephemeral ports: the time since reset
    // (which varies a little under QEMU) over a constant. Not secret, as nothing here is.
    let seed = 0x5EED_0502_u64 ^ embassy_time::Instant::now().as_ticks();
    let (stack, runner) = embassy_net::new(
        eth,
        ip_config(&config),
        RESOURCES.init(StackResources::new()),
        seed,
    );
    let node = NODE.init(Node::new(config, &IDENTITY, Boot::DEFAULT));
    match net_task(runner) {
        Ok(token) => spawner.spawn(token),
        Err(_) => log!("net task not started"),
    }
    for index in SocketHandle::all() {
        match socket_task(stack, index) {
            Ok(token) => spawner.spawn(token),
            Err(_) => log!("socket task {} not started", index),
        }
    }
    match gateway_task(node) {
        Ok(token) => spawner.spawn(token),
        Err(_) => log!("gateway task not started"),
    }
    log!("ready");
}

/// The stack's own task: moves frames between the driver and the sockets.
#[embassy_executor::task]
async fn net_task(mut runner: embassy_net::Runner<'static, lan9118::Lan9118>) -> ! {
    runner.run().await
}

/// One task per socket, with the socket's buffers.
#[embassy_executor::task(pool_size = SOCKETS)]
async fn socket_task(stack: Stack<'static>, index: SocketHandle) {
    let Some(buffers) = BUFFERS.get(index.index()).and_then(|cell| {
        cell.try_init(SocketBuffers {
            rx: [0; SOCKET_BUF],
            tx: [0; SOCKET_BUF],
        })
    }) else {
        log!("socket {}: no buffers", index);
        return;
    };
    let SocketBuffers { rx, tx } = buffers;
    rc_net::serve(stack, &PORT, index, rx, tx).await
}

/// Now, as the protocol counts time (µs since boot).
fn now() -> Instant {
    Instant(embassy_time::Instant::now().as_micros())
}

/// The node's owner: network events in, the node's actions out, until its next deadline.
#[embassy_executor::task]
async fn gateway_task(node: &'static mut Node) -> ! {
    let mut saves = 0;
    loop {
        let deadline = async {
            match node.poll_at() {
                Some(Instant(us)) => Timer::at(embassy_time::Instant::from_micros(us)).await,
                None => core::future::pending().await,
            }
        };
        // An event or the deadline: either way the node gets what is queued, then acts.
        select(PORT.ready(), deadline).await;
        let clock = now();
        PORT.pump(node, clock);
        loop {
            while let Some(action) = node.poll(clock) {
                match action {
                    Action::Tcp(tcp) => PORT.act(tcp, node, clock),
                    Action::Settings(SettingsRequest::Save) => {
                        saves += 1;
                        node.stored(Ok(saves));
                    }
                    // No bus, no serial PLC line, no flash, no restart here.
                    Action::Bus(_)
                    | Action::Line(_)
                    | Action::Reply(_)
                    | Action::PlcLine(_)
                    | Action::Settings(_) => {}
                }
            }
            // What came meanwhile, and what a request that got no reply left waiting in a pipe.
            if !PORT.pump(node, clock) {
                break;
            }
        }
    }
}

/// The log's line for a connection's start or end.
fn trace(event: &rc_net::Event) {
    match event {
        rc_net::Event::Opened { socket, peer } => log!("socket {}: {} connected", socket, peer),
        rc_net::Event::Closed(socket) => log!("socket {}: ended", socket),
        rc_net::Event::Data(_) | rc_net::Event::Sent(_) | rc_net::Event::Eof(_) => {}
    }
}

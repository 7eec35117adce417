//! Modbus TCP over the board's Ethernet (feature `net`): embassy-net's stack on the board's MAC,
//! with the address from the stored settings, and `rc_net`'s socket tasks around the node. The
//! gateway task stays the node's only owner: it meets the socket tasks in [`PORT`]
//! (`gateway`), as the mps2-an386 emulator build does with the same `rc_net`.

use embassy_executor::Spawner;
use embassy_net::{Config, Ipv4Address, Ipv4Cidr, Runner, Stack, StackResources, StaticConfigV4};
use protocol::net::{prefix_ok, NetConfig};
use rc_net::{Port, SocketHandle, SOCKETS};
use static_cell::ConstStaticCell;

use crate::board::{Ethernet, EthernetDevice};

/// Where the socket tasks and the gateway task meet.
pub static PORT: Port = Port::new();

/// Each socket's own TCP receive and send buffers: 1 KiB each way (a Modbus TCP frame is 260
/// bytes at most), 10 KiB for the five.
const SOCKET_BUFFER: usize = 1024;

/// The TCP buffers: a receive and a send buffer per socket, in `.bss`.
static BUFFERS: ConstStaticCell<[[u8; SOCKET_BUFFER]; 2 * SOCKETS]> =
    ConstStaticCell::new([[0; SOCKET_BUFFER]; 2 * SOCKETS]);

/// The stack's sockets: one per socket task, no DHCP or DNS (the address is static).
static RESOURCES: ConstStaticCell<StackResources<SOCKETS>> =
    ConstStaticCell::new(StackResources::new());

/// The address the board takes: the stored one (`net`, loaded with the settings) if it is a
/// host address with a valid prefix, else [`NetConfig::DEFAULT`]'s (a first start, a record
/// from a board without Ethernet, a PLC that wrote nonsense), so that the board is always
/// reachable somewhere documented. The router 0.0.0.0 (or any non-host address) is none.
pub fn stack_config(net: &NetConfig) -> Config {
    let net = if net.ip.is_host() && prefix_ok(net.prefix.into()) {
        net
    } else {
        warn!("net: the stored address is not a host address: the default applies");
        &NetConfig::DEFAULT
    };
    info!(
        "net: address {}/{}, router {}",
        net.ip, net.prefix, net.router
    );
    Config::ipv4_static(StaticConfigV4 {
        address: Ipv4Cidr::new(Ipv4Address::from(net.ip.0), net.prefix),
        gateway: net
            .router
            .is_host()
            .then(|| Ipv4Address::from(net.router.0)),
        dns_servers: Default::default(),
    })
}

/// Starts the network stack on `ethernet` at the address of `net` and spawns its task and the
/// [`SOCKETS`] socket tasks. A task that cannot be spawned is logged and left out (the RS485
/// side runs without it).
pub fn spawn(spawner: Spawner, ethernet: Ethernet, net: &NetConfig) {
    let Ethernet { device, seed } = ethernet;
    let (stack, runner) = embassy_net::new(device, stack_config(net), RESOURCES.take(), seed);
    match run_stack(runner) {
        Ok(token) => spawner.spawn(token),
        Err(_) => error!("net: stack task not started"),
    }
    let mut buffers = BUFFERS.take().iter_mut();
    for index in SocketHandle::all() {
        let (Some(rx), Some(tx)) = (buffers.next(), buffers.next()) else {
            break;
        };
        match socket(stack, index, rx, tx) {
            Ok(token) => spawner.spawn(token),
            Err(_) => error!("net: socket task not started"),
        }
    }
}

/// embassy-net's stack: moves frames between the MAC and the sockets, forever.
#[embassy_executor::task]
async fn run_stack(mut runner: Runner<'static, EthernetDevice>) -> ! {
    runner.run().await
}

/// Socket `index`: one client at a time on port 502 ([`rc_net::serve`]).
#[embassy_executor::task(pool_size = SOCKETS)]
async fn socket(
    stack: Stack<'static>,
    index: SocketHandle,
    rx: &'static mut [u8; SOCKET_BUFFER],
    tx: &'static mut [u8; SOCKET_BUFFER],
) -> ! {
    rc_net::serve(stack, &PORT, index, rx, tx).await
}

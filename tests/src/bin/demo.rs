//! The gateway's job without hardware: four simulated Robo Cylinders on the RS485 side, and a
//! scripted PLC on the other, sending Modbus RTU frames to the firmware's own `Node`. Virtual
//! time: the figures are exact and the run takes a moment.
//!
//! `cargo run -p rc-host --bin demo`
//!
//! Lengths are written in 0.01 mm (`75_50` is 75.50 mm), as the registers carry them.
#![allow(clippy::inconsistent_digit_grouping)]

use protocol::line::Baud;
use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::{AxisConfig, GatewayConfig};
use protocol::units::{Lead, Length, Scale};
use protocol::{Axis, AxisMap, AxisSet, PositionNo};
use rc_host::node_harness::NodeHarness;
use rc_tools::sim::{Bus, BusConfig, ControllerConfig};

const MS: u64 = 1000;
const AXES: u8 = 4;

type Rig = NodeHarness;

fn write(h: &mut Rig, unit: u8, address: u16, values: &[u16]) -> Result<(), Exception> {
    h.write(unit, address, values)
}

fn read(h: &mut Rig, unit: u8, address: u16, n: u16) -> Vec<u16> {
    match h.read(unit, address, n) {
        Ok(out) => out,
        Err(e) => {
            println!("    (exception {:02X} reading 0x{address:04X})", e.code());
            vec![0; usize::from(n)]
        }
    }
}

/// Poll DSS1 like a PLC every 20 ms until `bit` is set.
fn wait_for(h: &mut Rig, unit: u8, bit: u16, what: &str) {
    let start = h.now;
    while read(h, unit, DSS1, 1)[0] & bit == 0 {
        h.run_until(h.now + 20 * MS);
        if h.now - start > 20_000 * MS {
            println!("    {what}: not reached after 20 s");
            return;
        }
    }
    println!("    {what} after {:.0} ms", (h.now - start) as f64 / 1000.0);
}

fn status(h: &mut Rig, unit: u8) {
    let r = read(h, unit, PNOW, 8);
    let pnow = (u32::from(r[0]) << 16 | u32::from(r[1])) as i32;
    let cmst = read(h, unit, CMST, 2);
    println!(
        "    unit {unit}: PNOW {:>7.2} mm  DSS1 {:016b}  DOPM {:016b}  CMST {} CMER {:04X}",
        f64::from(pnow) / 100.0,
        r[5],
        r[4],
        cmst[0],
        cmst[1]
    );
}

fn main() {
    let axes: Vec<Axis> = (0..AXES).filter_map(Axis::new).collect();
    // The simulator's actuator: 8 mm lead, 100 mm stroke; the gateway's default conventions.
    let Some(lead) = Lead::from_hundredths(800) else {
        return;
    };
    let scale = Scale {
        lead,
        ..AxisConfig::default().scale
    };
    let mut bus = Bus::new(BusConfig::default());
    let mut row = [0u32; 10];
    row[0] = scale
        .position_to_wire(Length(40_00))
        .map_or(0, |p| p.to_wire());
    for &a in &axes {
        let mut c = ControllerConfig::default();
        if let Some(p) = PositionNo::new(3) {
            c.points = vec![(p, row)];
        }
        bus.add_controller(a, c);
    }
    let mut config = GatewayConfig::new(AxisSet::first(AXES));
    config.settings.axes = AxisMap::new(AxisConfig {
        scale,
        stroke: Length(100_00),
    });
    let mut h = NodeHarness::new(config, bus);

    println!(
        "== {AXES} simulated controllers power up at 9.6 kbit/s, RTIM 255 ms (their defaults)"
    );
    h.run_until(3_000 * MS);
    let baud = h.node.gateway().engine().line_baud();
    let link: Vec<u16> = axes
        .iter()
        .map(|a| read(&mut h, a.get() + 1, LINK, 1)[0])
        .collect();
    println!(
        "   after the §6-1 establishment: bus at {} bit/s, LINK per axis {link:?} (1 = online)",
        baud.bits_per_second()
    );
    assert_eq!(baud, Baud::B115200);

    println!("\n== PLC: servo on and home axis 0 (unit 1): DRG1 = SON, then SON|HOME");
    let _ = write(&mut h, 1, DRG1, &[DRG1_SON]);
    let _ = write(&mut h, 1, DRG1, &[DRG1_SON | DRG1_HOME]);
    wait_for(&mut h, 1, 1 << 4, "HEND");
    status(&mut h, 1);

    println!("\n== PLC: POSR = 3, CSTR: move to point 3 (40 mm)");
    let _ = write(&mut h, 1, DRG1, &[DRG1_SON]);
    let _ = write(&mut h, 1, POSR, &[3]);
    let _ = write(&mut h, 1, DRG1, &[DRG1_SON | DRG1_CSTR]);
    h.run_until(h.now + 50 * MS);
    wait_for(&mut h, 1, 1 << 3, "PEND");
    status(&mut h, 1);

    println!("\n== PLC: direct numeric move (FC10 at 0x9900): 75.50 mm at 120 mm/s, 0.3 G");
    let _ = write(&mut h, 1, DIRECT, &[0, 75_50, 0, 10, 0, 120_00, 30]);
    h.run_until(h.now + 50 * MS);
    wait_for(&mut h, 1, 1 << 3, "PEND");
    status(&mut h, 1);

    println!("\n== PLC: out-of-range requests get exceptions; nothing reaches the bus");
    for (address, values, what) in [
        (POSR, vec![16], "POSR = 16"),
        (
            DIRECT,
            vec![0, 150_00, 0, 10, 0, 120_00, 30],
            "direct move to 150 mm (stroke 100 mm)",
        ),
        (0x1234, vec![1], "unknown register 0x1234"),
    ] {
        let answer = write(&mut h, 1, address, &values);
        println!(
            "    {what}: {:?}",
            answer.err().map(|e| format!("exception {:02X}", e.code()))
        );
    }

    println!("\n== The PLC goes silent for 1.5 s while axis 0 moves slowly: the watchdog stops it");
    let _ = write(&mut h, 1, DIRECT, &[0, 5_00, 0, 10, 0, 10_00, 30]);
    h.run_until(h.now + 1_500 * MS);
    let fs = read(&mut h, 63, G_FAILSAFE, 2);
    println!(
        "    FAILSAFE {:#06X} (bit 0: PLC watchdog), trips {}",
        fs[0], fs[1]
    );
    status(&mut h, 1);

    println!(
        "\n== Diagnostics (gateway unit 63, 0x0400 + 16 x axis): frames sent / replies / time-outs"
    );
    for a in 0..AXES {
        let d = read(&mut h, 63, G_DIAG + 16 * u16::from(a), 6);
        let w = |i: usize| u32::from(d[i]) << 16 | u32::from(d[i + 1]);
        println!("    axis {a}: {} / {} / {}", w(0), w(2), w(4));
    }
    println!("\nVirtual time elapsed: {:.1} s", h.now as f64 / 1e6);
}

//! SON held in DRG1: the servo an alarm reset turned off comes back on by itself.

use protocol::plc::map::*;
use protocol::plc::CommandState;

use crate::{axis, gateway, home, read, settle, unit, write, MS, S};

/// SON held: the servo an alarm reset turned off comes back on, without a command in CMST.
#[test]
fn held_son_turns_the_servo_back_on_without_touching_cmst() {
    let mut h = gateway(1);
    home(&mut h, 0);
    h.bus
        .inject_alarm(axis(0), protocol::alarm::AlarmCode(0xC0))
        .unwrap();
    h.run_until(h.now + 100 * MS);
    write(&mut h, unit(0), DRG1, &[DRG1_SON | DRG1_ALRS]).unwrap();
    assert_eq!(settle(&mut h, 0, 2 * S), (CommandState::Done, 0));
    let status = read(&mut h, unit(0), CMST, 4).unwrap();
    for _ in 0..60 {
        h.run_until(h.now + 50 * MS);
        let _ = read(&mut h, unit(0), CMST, 1);
    }
    assert!(h.bus.controller(axis(0)).unwrap().servo(), "servo back on");
    assert_eq!(
        read(&mut h, unit(0), CMST, 4).unwrap(),
        status,
        "CMST/CMCT untouched"
    );
}

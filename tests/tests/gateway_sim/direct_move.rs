//! The direct numeric move (0x9900): a relative move is checked from where the axis is.

use protocol::modbus::Exception;
use protocol::plc::map::*;
use protocol::plc::CommandState;

use crate::{gateway_with, home, pnow_mm100, settle, unit, write, S};

/// A relative direct move is checked from where the axis is: only from rest with nothing
/// queued (else it would run from the end of the queued move, past the stroke).
#[test]
fn a_relative_move_behind_another_is_refused() {
    let mut h = gateway_with(1, 60_00, None, &[]);
    home(&mut h, 0);
    write(&mut h, unit(0), DIRECT, &[0, 55_00, 0, 10, 0, 50_00, 30]).unwrap();
    let relative = [0, 40_00, 0, 10, 0, 50_00, 30, 0, 1 << 3];
    assert_eq!(
        write(&mut h, unit(0), DIRECT, &relative),
        Err(Exception::ServerDeviceFailure)
    );
    assert_eq!(settle(&mut h, 0, 10 * S), (CommandState::Done, 0));
    assert_eq!(
        write(&mut h, unit(0), DIRECT, &relative),
        Err(Exception::IllegalDataValue),
        "55 + 40 > 60 mm"
    );
    assert!(pnow_mm100(&mut h, 0) <= 60_00);
}

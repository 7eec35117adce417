//! Print docs/plc.md's Modbus register table from the code (`protocol::plc::map::MAP`).
fn main() {
    print!("{}", rc_host::regmap::markdown());
}

//! README's register table is the one the code generates: change `plc::map::MAP`, then run
//! `cargo run -p rc-host --bin regmap` and paste its output between the markers.

#[test]
fn readme_register_map_matches_the_code() {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../README.md")).unwrap();
    let generated = rc_host::regmap::markdown();
    assert!(
        readme.contains(&generated),
        "README.md's register map differs from plc::map::MAP; regenerate it with \
         `cargo run -p rc-host --bin regmap`"
    );
}

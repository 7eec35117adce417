//! The register table in docs/plc.md is the one the code generates: change `plc::map::MAP`, then run
//! `cargo run -p rc-host --bin regmap` and paste its output between the markers.

#[test]
fn the_documented_register_map_matches_the_code() {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/plc.md")).unwrap();
    let generated = rc_host::regmap::markdown();
    assert!(
        readme.contains(&generated),
        "docs/plc.md's register map differs from plc::map::MAP; regenerate it with \
         `cargo run -p rc-host --bin regmap`"
    );
}

/// README is the entry point (what the gateway is, the two commands, the boards, first start,
/// troubleshooting, links); each topic's detail has one home in docs/ or CONTRIBUTING.md. It grew
/// to 1,268 lines, explaining topics in several places, before it was split (issue 38).
#[test]
fn readme_stays_an_entry_point() {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../README.md")).unwrap();
    let lines = readme.lines().count();
    assert!(
        lines < 600,
        "README.md has {lines} lines: move the detail to its home in docs/ and link it"
    );
}

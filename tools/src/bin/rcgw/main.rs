//! `rcgw`: configure, watch, back up and restore a gateway and every controller's point table
//! from a PC, through the gateway's PLC port (Modbus RTU on a serial port or a pseudo-terminal,
//! or Modbus TCP).
//!
//! ```text
//! $ rcgw --rtu /dev/ttyUSB0 status --watch
//! $ rcgw --tcp 192.168.1.100:502 config show > gateway.toml
//! $ rcgw --tcp 192.168.1.100:502 config apply gateway.toml --save
//! $ rcgw --rtu /dev/ttyUSB0 backup line3.toml
//! $ rcgw --rtu /dev/ttyUSB0 restore line3.toml --dry-run
//! ```
//!
//! Exit status 0 on success, 1 on a line or device error, 2 on bad input; every message names
//! the port, the unit and the register.

/// Text on standard output ([`emit`]).
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::emit(&format!($($arg)*))
    };
}

/// A line on standard output ([`emit`]).
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::emit(&format!("{}\n", format_args!($($arg)*)))
    };
}

mod backup;
mod config;
mod control;
mod diag;
mod link;
mod points;
mod restore;
mod settings;
mod sign;
mod status;
mod update;

use std::io::IsTerminal;
use std::process::ExitCode;

use clap::{ArgGroup, Parser, Subcommand};
use protocol::plc::map::G_AXIS_BASE;

use crate::link::{Fail, Gw, Link};
use crate::settings::Settings;

/// Configure, watch, back up and restore an IAI Robo Cylinder gateway over Modbus RTU or TCP.
#[derive(Parser, Debug)]
#[command(name = "rcgw", version)]
#[command(group(ArgGroup::new("line").args(["rtu", "tcp"])))]
pub(crate) struct Cli {
    /// Modbus RTU on this serial device (or pseudo-terminal).
    #[arg(long, global = true, value_name = "PATH")]
    rtu: Option<String>,
    /// --rtu: the PLC line's rate, bit/s.
    #[arg(long, global = true, default_value_t = 115_200)]
    baud: u32,
    /// --rtu: the PLC line's parity.
    #[arg(long, global = true, default_value = "none", value_parser = ["none", "odd", "even"])]
    parity: String,
    /// Modbus TCP to this HOST:PORT.
    #[arg(long, global = true, value_name = "HOST:PORT")]
    tcp: Option<String>,
    /// The gateway's unit id (UNITID; on TCP 255 reaches it too).
    #[arg(long, global = true, default_value_t = 63, value_parser = clap::value_parser!(u8).range(1..=255))]
    unit: u8,
    /// JSON on standard output, for scripts.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Every enabled axis as the PLC sees it, FAILSAFE and the LEDs.
    Status {
        /// Redraw until interrupted.
        #[arg(long)]
        watch: bool,
        /// --watch: seconds between redraws.
        #[arg(long, default_value_t = 0.5)]
        interval: f64,
        /// --watch: stop after this many redraws.
        #[arg(long)]
        count: Option<u64>,
    },
    /// The gateway's settings as TOML: show, compare with a file, apply a file.
    Config {
        #[command(subcommand)]
        action: ConfigCmd,
    },
    /// Settings, version, identity and the point table of every online axis, to one TOML file.
    Backup { file: String },
    /// Settings and point tables from a backup: only what differs is written, then verified.
    Restore {
        file: String,
        /// Show what would change; write nothing.
        #[arg(long)]
        dry_run: bool,
        /// SAVE the settings after restoring them.
        #[arg(long)]
        save: bool,
    },
    /// Write APPLY and wait for the establishment: the pending settings (bus rate, RTIM, PLC
    /// line, UNITID, AXISBASE, axes enabled) take effect, e.g. after a config apply that failed.
    Apply,
    /// Counters: per axis, bus, PLC line, FC08; reset cause and config source.
    Diag,
    /// Acknowledge FAILSAFE.
    Ack,
    /// Store the settings in flash (SAVE).
    Save,
    /// Restart the gateway (the saved settings take effect, a marked firmware image starts on
    /// trial), wait until it answers again and say what it runs.
    Restart {
        /// Only write RESTART: do not wait for the gateway to come back.
        #[arg(long)]
        no_wait: bool,
        /// How long to wait for the gateway to answer again, seconds (a swap of a whole image
        /// takes tens of seconds on the board).
        #[arg(long, default_value_t = 60.0, value_name = "S")]
        wait: f64,
    },
    /// Erase the stored settings and restart with the defaults.
    FactoryReset {
        /// Yes, erase them.
        #[arg(long)]
        yes: bool,
    },
    /// Send a signed firmware image into the gateway's DFU partition (resumes a cut transfer),
    /// where the gateway checks its signature and marks it for the next start; or show what the
    /// gateway has and runs (--status).
    Update {
        /// The signed image (`rcgw sign`).
        #[arg(required_unless_present = "status", conflicts_with = "status")]
        file: Option<String>,
        /// A cross-check: refuse the image unless its trailer names this board (decimal, or hex
        /// with 0x). Not needed: the image names its board and the gateway tells its own.
        #[arg(long, value_parser = parse_board)]
        board: Option<u16>,
        /// The running version, what the bootloader did at this start, the image marked for the
        /// next start, and the transfer's state.
        #[arg(long)]
        status: bool,
    },
    /// Signing keys: `key new --out NAME` writes NAME (the secret seed) and NAME.pub.
    Key {
        #[command(subcommand)]
        action: KeyCmd,
    },
    /// Sign an application binary into a firmware image, or check an image's signature
    /// (--check IMAGE --pub NAME.pub). No gateway needed.
    Sign {
        /// The application's binary (raw, as objcopy -O binary writes it).
        #[arg(required_unless_present = "check", conflicts_with = "check")]
        app: Option<String>,
        /// The secret key file (`rcgw key new`).
        #[arg(long, value_name = "NAME", conflicts_with_all = ["test_key", "check"])]
        key: Option<String>,
        /// Sign (or check) with the public TEST key: for tests and the emulator only, never a
        /// release.
        #[arg(long)]
        test_key: bool,
        /// The board the image is for: l475 (0x0475) or f429 (0x0429), or an id (decimal, or
        /// hex with 0x).
        #[arg(long, value_parser = parse_board, default_value = "l475")]
        board: u16,
        /// The firmware's version, MAJOR.MINOR.PATCH.
        #[arg(long, value_parser = sign::parse_version, required_unless_present = "check")]
        version: Option<rc_boot::image::Version>,
        /// Where the image goes.
        #[arg(long, value_name = "IMAGE", required_unless_present = "check")]
        out: Option<String>,
        /// Check this image's signature instead (exit 0 if it verifies, 1 if not).
        #[arg(long, value_name = "IMAGE")]
        check: Option<String>,
        /// --check: the public key file (NAME.pub).
        #[arg(long = "pub", value_name = "NAME.pub", requires = "check")]
        public: Option<String>,
        /// Sign even if the application does not hold the key's public half (a test image; a
        /// firmware without it would refuse every image after it).
        #[arg(long, conflicts_with = "check")]
        unchecked: bool,
    },
}

#[derive(Subcommand, Debug)]
enum KeyCmd {
    /// A new Ed25519 key pair: NAME (32 raw bytes, the secret seed, mode 0600) and NAME.pub (32
    /// raw bytes, printed in hex too). Refuses to overwrite.
    New {
        #[arg(long, value_name = "NAME")]
        out: String,
    },
}

fn parse_board(text: &str) -> Result<u16, String> {
    match text.to_ascii_lowercase().as_str() {
        "l475" => return Ok(rc_boot::BOARD_L475),
        "f429" => return Ok(rc_boot::BOARD_F429),
        _ => {}
    }
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => text.parse(),
    };
    parsed
        .map_err(|_| format!("{text:?}: a board is l475, f429 or an id 0-65535 (or 0x0000-0xFFFF)"))
}

#[derive(Subcommand, Debug)]
enum ConfigCmd {
    /// Every setting, as TOML (or JSON).
    Show,
    /// What applying FILE would change.
    Diff { file: String },
    /// Check every value of FILE, write what differs, APPLY when needed.
    Apply {
        file: String,
        /// SAVE afterwards.
        #[arg(long)]
        save: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = run(&cli);
    if result.is_err() && std::io::stderr().is_terminal() {
        // The progress line, cleared before the message.
        eprint!("\r\x1b[K");
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Fail::Device(m)) => {
            eprintln!("rcgw: {m}");
            ExitCode::from(1)
        }
        Err(Fail::Input(m)) => {
            eprintln!("rcgw: {m}");
            ExitCode::from(2)
        }
    }
}

/// Text written to standard output. A closed pipe (`rcgw status --watch | head -2`) ends the
/// run cleanly, exit 0: the reader has what it wanted.
fn emit(text: &str) {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    if let Err(e) = stdout
        .write_all(text.as_bytes())
        .and_then(|()| stdout.flush())
    {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("rcgw: standard output: {e}");
        std::process::exit(1);
    }
}

/// The line, opened: no request made.
pub(crate) fn open_link(cli: &Cli) -> Result<Link, Fail> {
    Ok(match (&cli.rtu, &cli.tcp) {
        (Some(path), _) => Link::rtu(
            path,
            cli.baud,
            link::parity_of(&cli.parity).unwrap_or(serialport::Parity::None),
        )?,
        (None, Some(addr)) => Link::tcp(addr)?,
        (None, None) => return Err(Fail::Input("--rtu PATH or --tcp HOST:PORT".into())),
    })
}

fn connect(cli: &Cli) -> Result<Gw, Fail> {
    let link = open_link(cli)?;
    let mut gw = Gw {
        link,
        unit: cli.unit,
        base: 1,
    };
    gw.base = gw.get(G_AXIS_BASE)? as u8;
    Ok(gw)
}

/// A firmware image: bad input (exit 2) if it cannot be read or is empty.
fn read_image(path: &str) -> Result<Vec<u8>, Fail> {
    let image = std::fs::read(path).map_err(|e| Fail::Input(format!("{path}: {e}")))?;
    if image.is_empty() {
        return Err(Fail::Input(format!("{path}: empty")));
    }
    Ok(image)
}

/// A file read and parsed as TOML: bad input (exit 2) if not.
fn read_toml(path: &str) -> Result<toml::Table, Fail> {
    let text = std::fs::read_to_string(path).map_err(|e| Fail::Input(format!("{path}: {e}")))?;
    text.parse::<toml::Table>()
        .map_err(|e| Fail::Input(format!("{path}: not valid TOML: {e}")))
}

fn bad_file(path: &str, errors: Vec<String>) -> Fail {
    Fail::Input(format!(
        "{path}: {} error(s), nothing written:\n  {}",
        errors.len(),
        errors.join("\n  ")
    ))
}

/// `value` as pretty JSON, keys in the order its struct or `json!` has them.
fn print_json(value: &impl serde::Serialize) {
    outln!(
        "{}",
        serde_json::to_string_pretty(value).unwrap_or_default()
    );
}

fn run(cli: &Cli) -> Result<(), Fail> {
    // Commands without a gateway.
    match &cli.command {
        Cmd::Key {
            action: KeyCmd::New { out },
        } => return sign::key_new(out, cli.json),
        Cmd::Sign {
            check: Some(image),
            public,
            test_key,
            ..
        } => {
            let key = match (public, test_key) {
                (Some(path), false) => sign::KeySource::File(path),
                (None, true) => sign::KeySource::Test,
                _ => {
                    return Err(Fail::Input(
                        "--check IMAGE: --pub NAME.pub or --test-key".into(),
                    ))
                }
            };
            return sign::check(image, key, cli.json);
        }
        Cmd::Sign {
            app: Some(app),
            key,
            test_key,
            board,
            version: Some(version),
            out: Some(out),
            unchecked,
            ..
        } => {
            let key = match (key, test_key) {
                (Some(path), false) => sign::KeySource::File(path),
                (None, true) => sign::KeySource::Test,
                _ => return Err(Fail::Input("sign: --key NAME or --test-key".into())),
            };
            return sign::sign(app, key, *board, *version, out, *unchecked, cli.json);
        }
        Cmd::Sign { .. } => {
            return Err(Fail::Input(
                "sign APP --key NAME --version V --out IMAGE, or sign --check IMAGE --pub NAME.pub"
                    .into(),
            ))
        }
        _ => {}
    }
    // Files are checked before the line is opened: a bad file writes nothing.
    let mut image = None;
    match &cli.command {
        Cmd::Config {
            action: ConfigCmd::Diff { file } | ConfigCmd::Apply { file, .. },
        } => {
            let doc = read_toml(file)?;
            Settings::from_toml(&doc, &[], false).map_err(|e| bad_file(file, e))?;
        }
        Cmd::Restore { file, .. } => {
            backup::load(file)?;
        }
        Cmd::Update {
            file: Some(file),
            board,
            ..
        } => {
            let bytes = read_image(file)?;
            let trailer = sign::read_trailer(&bytes).map_err(|why| {
                Fail::Input(format!(
                    "{file}: not a signed image ({why}): sign it with `rcgw sign`"
                ))
            })?;
            if let Some(board) = board.filter(|&b| b != trailer.board) {
                return Err(Fail::Input(format!(
                    "{file}: the image is for board {:#06x}, not {board:#06x} (--board)",
                    trailer.board
                )));
            }
            image = Some((bytes, trailer));
        }
        Cmd::FactoryReset { yes: false } => {
            return Err(Fail::Input(
                "factory-reset erases every stored setting: add --yes".into(),
            ))
        }
        _ => {}
    }
    // RESTART is the first request: a gateway whose new firmware is on trial and has not had
    // a request yet restarts unconfirmed (and rolls back), as after a power cut.
    if let Cmd::Restart { no_wait, wait } = &cli.command {
        let mut gw = Gw {
            link: open_link(cli)?,
            unit: cli.unit,
            base: 1,
        };
        return control::restart(
            &mut gw,
            cli,
            cli.json,
            (!no_wait).then(|| std::time::Duration::from_secs_f64(wait.max(0.0))),
        );
    }
    let mut gw = connect(cli)?;
    match &cli.command {
        Cmd::Status {
            watch,
            interval,
            count,
        } => status::status(&mut gw, cli.json, *watch, *interval, *count),
        Cmd::Config { action } => config::config(&mut gw, cli.json, action),
        Cmd::Backup { file } => backup::backup(&mut gw, cli.json, file),
        Cmd::Restore {
            file,
            dry_run,
            save,
        } => restore::restore(&mut gw, cli.json, file, *dry_run, *save),
        Cmd::Apply => control::apply(&mut gw, cli.json),
        Cmd::Diag => diag::diag(&mut gw, cli.json),
        Cmd::Ack => control::ack(&mut gw, cli.json),
        Cmd::Save => control::save(&mut gw, cli.json),
        Cmd::Restart { .. } => Ok(()),
        Cmd::FactoryReset { .. } => control::factory_reset(&mut gw, cli.json),
        Cmd::Update { status: true, .. } => update::status(&mut gw, cli.json),
        Cmd::Update { .. } => match &image {
            Some((bytes, trailer)) => update::update(&mut gw, cli.json, bytes, trailer),
            None => Err(Fail::Input("update FILE or update --status".into())),
        },
        Cmd::Key { .. } | Cmd::Sign { .. } => Ok(()),
    }
}

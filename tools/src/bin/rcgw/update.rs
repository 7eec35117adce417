//! `rcgw update FILE`: a firmware image into the gateway's DFU partition over the PLC link
//! (unit 63's UPDCTL, UPDSTAT and UPDCHUNK: `protocol::plc::update`), resumed where a cut
//! transfer stopped; `rcgw update --status`: what the gateway has.
//!
//! The image is a signed one (`rcgw sign`): its trailer is read before anything is sent, and
//! an image for another board or larger than the gateway takes is refused here (exit 2). The
//! gateway checks the signature at FINISH and marks the image for its next start; `rcgw
//! restart` starts it, on trial.

use std::time::{Duration, Instant};

use protocol::modbus::Exception;
use protocol::plc::map::{G_UPDATE, G_UPDATE_CHUNK, G_UPDATE_STATUS, G_UPDATE_STATUS_LEN};
use protocol::plc::update::{
    begin_registers, chunk_registers, crc32, UpdateError, UpdateState, UpdateStatus, CHUNK_ALIGN,
    FINISH, MAX_CHUNK,
};
use rc_boot::image::Trailer;
use serde_json::json;

use crate::backup::progress;
use crate::control::{boot_text, marked_text, running};
use crate::link::{Fail, Gw};
use crate::print_json;
use crate::sign::version_text;

/// How long a refusal that says "not now" (an axis moves, a SAVE, the flash busy) is waited
/// out, and a state that is the gateway's to leave (erasing, finishing).
const PATIENCE: Duration = Duration::from_secs(60);

/// UPDSTAT's state by name.
fn state_name(state: u16) -> &'static str {
    UpdateState::from_code(state).map_or("unknown", UpdateState::name)
}

/// UPDSTAT's last error, in words.
fn error_text(error: u16) -> String {
    UpdateError::from_code(error).map_or_else(|| format!("error {error}"), |e| e.text().into())
}

fn read_status(gw: &mut Gw) -> Result<UpdateStatus, Fail> {
    let unit = gw.unit;
    let registers = gw.read(unit, G_UPDATE_STATUS, G_UPDATE_STATUS_LEN)?;
    UpdateStatus::parse(&registers).ok_or_else(|| {
        Fail::Device(format!(
            "{}: not 16 registers",
            gw.at(unit, G_UPDATE_STATUS)
        ))
    })
}

/// The gateway's status as JSON.
fn status_json(s: &UpdateStatus) -> serde_json::Value {
    json!({
        "state": state_name(s.state),
        "error": error_text(s.error),
        "received": s.received,
        "next": s.next,
        "size": s.size,
        "crc32": format!("{:08x}", s.crc32),
        "board": s.board,
        "partition": s.partition,
        "refusals": s.refusals,
        "max_chunk": s.max_chunk,
    })
}

/// `rcgw update --status`.
pub fn status(gw: &mut Gw, json: bool) -> Result<(), Fail> {
    let s = read_status(gw)?;
    let run = running(gw)?;
    if json {
        let mut value = status_json(&s);
        value["running"] = json!(run.version);
        value["boot"] = json!(run.boot.name());
        value["marked"] = json!(marked_text(run.marked));
        print_json(&value);
        return Ok(());
    }
    outln!("running    {}, {}", run.version, boot_text(run.boot));
    outln!(
        "marked     {}",
        marked_text(run.marked).map_or_else(
            || "nothing for the next start".to_string(),
            |v| format!("{v}, starts at the next restart (`rcgw restart`)")
        )
    );
    if s.partition == 0 {
        outln!("no DFU partition: this gateway takes no firmware image over the PLC link");
        return Ok(());
    }
    outln!("state      {}", state_name(s.state));
    outln!(
        "image      {} of {} bytes written, CRC-32 {:08x}",
        s.next,
        s.size,
        s.crc32
    );
    outln!(
        "partition  {} bytes, board id {:#06x}, chunks of up to {} bytes",
        s.partition,
        s.board,
        s.max_chunk
    );
    outln!(
        "last error {} ({} refusals)",
        error_text(s.error),
        s.refusals
    );
    Ok(())
}

/// Read failures in a row that [`wait_out`] rides out: the gateway may not answer while one step
/// of its own work runs (the L475 checks the signature in one step: tens of ms on the board, but
/// over a second in an emulator on a busy PC), and UPDSTAT's read can simply be asked again.
const SILENT_READS: u32 = 3;

/// Waits while the gateway is in `state` (erasing, finishing): its status after.
fn wait_out(gw: &mut Gw, state: UpdateState) -> Result<UpdateStatus, Fail> {
    let deadline = Instant::now() + PATIENCE;
    let mut silent = 0;
    loop {
        let s = match read_status(gw) {
            Ok(s) => s,
            Err(Fail::Device(_)) if silent < SILENT_READS && Instant::now() < deadline => {
                silent += 1;
                continue;
            }
            Err(e) => return Err(e),
        };
        silent = 0;
        if s.state != state as u16 {
            return Ok(s);
        }
        if Instant::now() > deadline {
            return Err(Fail::Device(format!(
                "{}: still {} after {} s",
                gw.at(gw.unit, G_UPDATE_STATUS),
                state_name(s.state),
                PATIENCE.as_secs()
            )));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Writes `values` at `address` of the gateway unit, waiting out "not now" (04) for at most
/// [`PATIENCE`]: `Ok(Err(status))` when the gateway refused it for good (03, 02).
fn write_patiently(
    gw: &mut Gw,
    address: u16,
    values: &[u16],
    show: bool,
) -> Result<Result<(), UpdateStatus>, Fail> {
    let deadline = Instant::now() + PATIENCE;
    let unit = gw.unit;
    loop {
        match gw.try_write(unit, address, values)? {
            Ok(()) => return Ok(Ok(())),
            Err(Exception::ServerDeviceFailure) if Instant::now() < deadline => {
                // The flash still busy with the last chunk is the common case, and short.
                let s = read_status(gw)?;
                if s.error == UpdateError::Busy as u16 {
                    std::thread::sleep(Duration::from_millis(1));
                } else {
                    progress(show, &format!("waiting: {}", error_text(s.error)));
                    std::thread::sleep(Duration::from_millis(20));
                }
            }
            Err(_) => return Ok(Err(read_status(gw)?)),
        }
    }
}

fn refused(gw: &Gw, address: u16, s: &UpdateStatus) -> Fail {
    Fail::Device(format!(
        "{}: refused: {} (state {})",
        gw.at(gw.unit, address),
        error_text(s.error),
        state_name(s.state)
    ))
}

/// The largest image a gateway of `board` with a DFU partition of `partition` bytes takes: the
/// partition, and for a board with a bootloader its ACTIVE partition (smaller than DFU), which
/// the bootloader's swap fills.
fn largest_image(board: u16, partition: u32) -> u32 {
    match rc_boot::layout_of(board) {
        Some(layout) => partition.min(layout.max_image()),
        None => partition,
    }
}

/// `rcgw update FILE`: the signed image sent, from the next offset the gateway shows when it
/// already has part of this image, then checked (the signature) and marked by the gateway.
pub fn update(gw: &mut Gw, json: bool, image: &[u8], trailer: &Trailer) -> Result<(), Fail> {
    let board = trailer.board;
    let version = version_text(trailer.version);
    let show = !json && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let size = u32::try_from(image.len()).unwrap_or(u32::MAX);
    let crc = crc32(image);
    let s = read_status(gw)?;
    if s.partition == 0 {
        return Err(Fail::Device(format!(
            "{}: this gateway has no DFU partition",
            gw.link.name
        )));
    }
    if board != s.board {
        return Err(Fail::Input(format!(
            "the image is for board {board:#06x}, this gateway is board {:#06x}: nothing sent",
            s.board
        )));
    }
    let largest = largest_image(s.board, s.partition);
    if size > largest {
        return Err(Fail::Input(format!(
            "the image is {size} bytes, the gateway takes at most {largest} (DFU partition {}): nothing sent",
            s.partition
        )));
    }
    let same = s.size == size && s.crc32 == crc;
    // The file's CRC-32 does not depend on the trailer (the trailer ends with its own CRC-32,
    // which cancels it out): the same application signed again with another version has the
    // same size and CRC-32. So "already there" also needs BOOTSTAT's marked version.
    let marked_now = if s.state == UpdateState::Ready as u16 && same {
        running(gw)?.marked
    } else {
        0
    };
    if s.state == UpdateState::Ready as u16 && same && marked_now == trailer.version.to_u32() {
        if json {
            let mut value = status_json(&s);
            value["already"] = json!(true);
            print_json(&value);
        } else {
            outln!(
                "image {version} of {size} bytes (CRC-32 {crc:08x}) already in the DFU partition, checked and marked: nothing sent; restart the gateway to run it (`rcgw restart`)"
            );
        }
        return Ok(());
    }
    // The gateway's largest chunk, if smaller than ours (another firmware's), kept aligned.
    let most =
        MAX_CHUNK.min(usize::from(s.max_chunk)) / CHUNK_ALIGN as usize * CHUNK_ALIGN as usize;
    if most == 0 {
        return Err(Fail::Device(format!(
            "{}: the gateway takes chunks of {} bytes",
            gw.at(gw.unit, G_UPDATE_STATUS),
            s.max_chunk
        )));
    }
    let resumed = s.state == UpdateState::Receiving as u16 && same;
    let mut next = if resumed {
        s.next
    } else {
        if let Err(s) = write_patiently(gw, G_UPDATE, &begin_registers(size, crc, board), show)? {
            return Err(refused(gw, G_UPDATE, &s));
        }
        progress(show, "erasing");
        let s = wait_out(gw, UpdateState::Erasing)?;
        if s.state != UpdateState::Receiving as u16 {
            return Err(refused(gw, G_UPDATE, &s));
        }
        0
    };
    let from = next;
    let started = Instant::now();
    while next < size {
        let start = next as usize;
        let end = (start + most).min(image.len());
        let chunk = image.get(start..end).unwrap_or_default();
        match write_patiently(gw, G_UPDATE_CHUNK, &chunk_registers(next, chunk), show)? {
            Ok(()) => next = end as u32,
            // Out of step (a reply lost before this run): go on from where the gateway is.
            // Only while the transfer is still this image's: another master's BEGIN replaced it.
            Err(s)
                if s.error == UpdateError::OutOfOrder as u16
                    && s.state == UpdateState::Receiving as u16
                    && (s.size, s.crc32) == (size, crc)
                    && s.next > next
                    && s.next <= size =>
            {
                next = s.next
            }
            Err(s) => return Err(refused(gw, G_UPDATE_CHUNK, &s)),
        }
        let done = f64::from(next - from);
        let rate = done / started.elapsed().as_secs_f64().max(1e-3);
        let left = f64::from(size - next) / rate.max(1.0);
        progress(
            show,
            &format!(
                "sent {next} of {size} bytes ({:.0} %), {:.1} KB/s, {left:.0} s left",
                f64::from(next) * 100.0 / f64::from(size),
                rate / 1000.0
            ),
        );
    }
    if let Err(s) = write_patiently(gw, G_UPDATE, &[FINISH], show)? {
        return Err(refused(gw, G_UPDATE, &s));
    }
    progress(show, "checking");
    let s = wait_out(gw, UpdateState::Finishing)?;
    progress(show, "");
    if s.state != UpdateState::Ready as u16 {
        return Err(Fail::Device(format!(
            "{}: the gateway did not take the image {version}: {} (state {})",
            gw.at(gw.unit, G_UPDATE),
            error_text(s.error),
            state_name(s.state)
        )));
    }
    let marked = marked_text(running(gw)?.marked);
    let seconds = started.elapsed().as_secs_f64();
    if json {
        let mut value = status_json(&s);
        value["resumed_at"] = json!(resumed.then_some(from));
        value["seconds"] = json!(seconds);
        value["marked"] = json!(marked);
        print_json(&value);
    } else {
        let resumed = if resumed {
            format!(", resumed at {from}")
        } else {
            String::new()
        };
        outln!(
            "image {version} of {size} bytes (CRC-32 {crc:08x}) sent in {seconds:.1} s{resumed}; the gateway checked its signature and marked {} for the next start: restart the gateway to run it (`rcgw restart`)",
            marked.as_deref().unwrap_or("it")
        );
    }
    Ok(())
}

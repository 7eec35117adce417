//! `rcgw key new` and `rcgw sign`: the signing key and the signed firmware image
//! (`rc_boot::image`), with rc-boot's own code, so what `rcgw sign` writes is exactly what the
//! gateway's check takes.
//!
//! **Key files are raw bytes**: the secret key file is the 32-byte Ed25519 seed
//! (`rc_boot::image::SecretKey`), the public key file the 32-byte public key the firmware build
//! embeds. Raw, not hex text: that is the form both ends use (no parsing, no line ends, no
//! encoding to get wrong), the length alone (exactly 32) tells a truncated or wrong file, and a
//! secret key in hex is one `cat` away from a terminal's scroll-back or a chat window. The
//! public key is printed in hex for the firmware's source.

use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;

use rc_boot::image::{self, SecretKey, Trailer, Version, TRAILER_LEN};
use rc_boot::update::Verifier;
use serde_json::json;

use crate::link::Fail;
use crate::print_json;

/// A key's length in bytes (secret seed and public key alike).
const KEY_LEN: usize = 32;

/// What the TEST key prints, each time it is used.
const TEST_KEY_WARNING: &str =
    "rcgw: WARNING: signing with the public TEST key (rc_boot::TEST_KEY_SEED): \
anyone can sign with it; only a test or emulator build accepts it. NOT A RELEASE.";

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// `PATH.pub`.
fn pub_path(path: &str) -> String {
    format!("{path}.pub")
}

/// Creates `path` with `mode`, refusing an existing file.
fn create_new(path: &str, mode: u32, bytes: &[u8]) -> Result<(), Fail> {
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .open(path)
        .map_err(|e| {
            if e.kind() == std::io::ErrorKind::AlreadyExists {
                Fail::Input(format!("{path}: exists already: not overwritten"))
            } else {
                Fail::Input(format!("{path}: {e}"))
            }
        })?;
    file.write_all(bytes)
        .and_then(|()| file.sync_all())
        .map_err(|e| Fail::Device(format!("{path}: {e}")))
}

/// `rcgw key new --out NAME`: NAME (the secret seed, mode 0600) and NAME.pub.
pub fn key_new(out: &str, json: bool) -> Result<(), Fail> {
    let public_path = pub_path(out);
    for path in [out, public_path.as_str()] {
        if std::path::Path::new(path).exists() {
            return Err(Fail::Input(format!(
                "{path}: exists already: not overwritten"
            )));
        }
    }
    let key = SecretKey::generate()
        .map_err(|e| Fail::Device(format!("no random numbers from the system: {e}")))?;
    let public = key.public_key();
    create_new(out, 0o600, &key.0)?;
    create_new(&public_path, 0o644, &public)?;
    if json {
        print_json(&json!({"secret": out, "public": public_path, "public_hex": hex(&public)}));
    } else {
        outln!("secret key {out} (keep it offline; mode 0600), public key {public_path}:");
        outln!("{}", hex(&public));
    }
    Ok(())
}

/// A 32-byte key file.
fn read_key(path: &str) -> Result<[u8; KEY_LEN], Fail> {
    let bytes = std::fs::read(path).map_err(|e| Fail::Input(format!("{path}: {e}")))?;
    bytes.as_slice().try_into().map_err(|_| {
        Fail::Input(format!(
            "{path}: {} bytes: a key file is exactly {KEY_LEN} raw bytes (`rcgw key new`)",
            bytes.len()
        ))
    })
}

/// "1.2.3" as a version: major and minor 0-255, patch 0-65535.
pub fn parse_version(text: &str) -> Result<Version, String> {
    let bad = || format!("{text:?}: a version is MAJOR.MINOR.PATCH (0-255.0-255.0-65535)");
    let mut parts = text.split('.');
    let (Some(major), Some(minor), Some(patch), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(bad());
    };
    Ok(Version {
        major: major.parse().map_err(|_| bad())?,
        minor: minor.parse().map_err(|_| bad())?,
        patch: patch.parse().map_err(|_| bad())?,
    })
}

/// A version as "1.2.3".
pub fn version_text(v: Version) -> String {
    format!("{}.{}.{}", v.major, v.minor, v.patch)
}

/// Where the signing key comes from.
pub enum KeySource<'a> {
    File(&'a str),
    Test,
}

/// `rcgw sign APP --key NAME --board ID --version V --out IMAGE`.
pub fn sign(
    app_path: &str,
    key: KeySource<'_>,
    board: u16,
    version: Version,
    out: &str,
    unchecked: bool,
    json: bool,
) -> Result<(), Fail> {
    let app = std::fs::read(app_path).map_err(|e| Fail::Input(format!("{app_path}: {e}")))?;
    if app.is_empty() {
        return Err(Fail::Input(format!("{app_path}: empty")));
    }
    if app.len() >= TRAILER_LEN && Trailer::parse(&app[app.len() - TRAILER_LEN..]).is_ok() {
        return Err(Fail::Input(format!(
            "{app_path}: already a signed image (it ends with a trailer): sign the application's binary"
        )));
    }
    let secret = match key {
        KeySource::File(path) => SecretKey(read_key(path)?),
        KeySource::Test => {
            eprintln!("{TEST_KEY_WARNING}");
            SecretKey(rc_boot::TEST_KEY_SEED)
        }
    };
    // The firmware verifies the next image with the key built into it: an application without
    // this key's public half (built without RC_GATEWAY_UPDATE_KEY, with another key, or with the
    // secret file by mistake) would be accepted now and refuse every image after it.
    if let KeySource::File(path) = key {
        let public = secret.public_key();
        if !unchecked && !app.windows(public.len()).any(|w| w == public) {
            return Err(Fail::Input(format!(
                "{app_path}: the application does not hold {path}'s public key: a firmware built \
                 with RC_GATEWAY_UPDATE_KEY={path}.pub verifies images with it; this one would \
                 refuse every image after it (--unchecked signs anyway, for a test image)"
            )));
        }
    }
    let signed = image::sign(&app, board, version, &secret)
        .map_err(|e| Fail::Input(format!("{app_path}: cannot be signed: {e:?}")))?;
    std::fs::write(out, &signed).map_err(|e| Fail::Input(format!("{out}: {e}")))?;
    if json {
        print_json(&json!({
            "image": out,
            "board": board,
            "version": version_text(version),
            "app_len": app.len(),
            "image_len": signed.len(),
            "public_hex": hex(&secret.public_key()),
        }));
    } else {
        outln!(
            "{out}: {} bytes, version {} for board {board:#06x}, signed by {}",
            signed.len(),
            version_text(version),
            hex(&secret.public_key())
        );
    }
    Ok(())
}

/// The trailer of a whole image file, its application and padding checked (not the
/// signature): a sentence on why not.
pub fn read_trailer(image: &[u8]) -> Result<Trailer, String> {
    let at = image
        .len()
        .checked_sub(TRAILER_LEN)
        .ok_or_else(|| format!("{} bytes, shorter than a trailer", image.len()))?;
    let trailer = Trailer::parse(image.get(at..).unwrap_or_default())
        .map_err(|e| format!("no valid trailer at its end ({e:?})"))?;
    image::split(image, trailer.board, u32::MAX).map_err(|e| format!("{e:?}"))?;
    Ok(trailer)
}

/// Whether the image's signature verifies with `public`.
pub fn signature_ok(image: &[u8], trailer: &Trailer, public: &[u8; KEY_LEN]) -> bool {
    let Ok(mut verifier) = Verifier::new(trailer) else {
        return false;
    };
    verifier.update(image);
    verifier.finish(public).is_ok()
}

/// `rcgw sign --check IMAGE --pub NAME.pub`: exit 0 if the signature verifies, 1 if not.
pub fn check(path: &str, key: KeySource<'_>, json: bool) -> Result<(), Fail> {
    let image = std::fs::read(path).map_err(|e| Fail::Input(format!("{path}: {e}")))?;
    let (public, key_name) = match key {
        KeySource::File(p) => (read_key(p)?, p.to_string()),
        KeySource::Test => (rc_boot::TEST_PUBLIC_KEY, "the TEST key".to_string()),
    };
    let trailer = read_trailer(&image)
        .map_err(|why| Fail::Device(format!("{path}: not a signed image: {why}")))?;
    let good = signature_ok(&image, &trailer, &public);
    if json {
        print_json(&json!({
            "image": path,
            "board": trailer.board,
            "version": version_text(trailer.version),
            "app_len": trailer.app_len,
            "signature": if good { "ok" } else { "bad" },
        }));
    }
    if !good {
        return Err(Fail::Device(format!(
            "{path}: the signature does NOT verify with {key_name}: signed with another key, or altered after signing"
        )));
    }
    if !json {
        outln!(
            "{path}: version {} for board {:#06x}, {} bytes of application: the signature verifies with {key_name}",
            version_text(trailer.version),
            trailer.board,
            trailer.app_len
        );
    }
    Ok(())
}

//! The signer agrees with standard Ed25519 (RFC 8032) and with embassy-boot's verifier.

use rc_boot::image::{digest, sign, split, SecretKey, Trailer, Version, TRAILER_LEN};
use rc_boot::BOARD_L475;

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

#[test]
fn rfc8032_test_1() {
    // RFC 8032 §7.1, TEST 1 (the empty message).
    let seed: [u8; 32] = hex("9d61b19deffd5a60ba844af492ec2cc44449c5697b326919703bac031cae7f60")
        .try_into()
        .unwrap();
    let key = SecretKey(seed);
    assert_eq!(
        key.public_key().to_vec(),
        hex("d75a980182b10ab7d54bfed3c964073a0ee172f3daa62325af021a68f707511a")
    );
    assert_eq!(
        key.sign_raw(b"").to_vec(),
        hex(concat!(
            "e5564300c360ac729086e2cc806e828a84877f1eb8e5d974d873e06522490155",
            "5fb8821590a33bacc61e39701cf9b46bd25bf5f0595bbe24655141438e7a100b"
        ))
    );
}

#[test]
fn signature_is_over_the_sha512_of_the_signed_part() {
    let key = SecretKey::generate().unwrap();
    assert_ne!(key.0, SecretKey::generate().unwrap().0);
    let app = b"not much of an application";
    let v = Version {
        major: 2,
        minor: 1,
        patch: 0,
    };
    let image = sign(app, BOARD_L475, v, &key).unwrap();
    let (a, t) = split(&image, BOARD_L475, 1 << 20).unwrap();
    assert_eq!(a, app);
    assert_eq!(t.version, v);
    assert_eq!(image.len(), 32 + TRAILER_LEN);
    let signed = &image[..t.signed_len().unwrap() as usize];
    // Ed25519 of the digest, the way embassy-boot verifies (salty, the digest as message).
    let pk = salty::PublicKey::try_from(&key.public_key()).unwrap();
    let sig = salty::Signature::from(&t.signature);
    assert!(pk.verify(&digest(signed), &sig).is_ok());
    // Not of the bytes themselves, nor of a digest of the application alone.
    assert!(pk.verify(signed, &sig).is_err());
    assert!(pk.verify(&digest(&image[..32]), &sig).is_err());
    // The padding is the erased value.
    assert!(image[26..32].iter().all(|&b| b == 0xFF));
    assert_eq!(Trailer::parse(&image[32..]).unwrap().signature, t.signature);
}

#[test]
fn test_key_constants_agree() {
    let k = SecretKey(rc_boot::TEST_KEY_SEED);
    assert_eq!(k.public_key(), rc_boot::TEST_PUBLIC_KEY);
}

/// `boot/test-key.pub` is the TEST key's public half as text (what scripts/size-report.sh builds
/// the board firmware with: any key links the same code, none links no verification at all).
#[test]
fn the_test_key_file_is_the_test_public_key() {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/test-key.pub"))
        .expect("boot/test-key.pub");
    let hex: String = rc_boot::TEST_PUBLIC_KEY
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    assert_eq!(text.trim(), hex);
}

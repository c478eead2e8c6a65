//! What the golden-vector tests share: the manuals' byte strings, and an encoder's output.
#![allow(dead_code)]

use conductor_protocols::dynamixel1::EncodeError;

/// Bytes written as a manual writes them: hexadecimal pairs separated by spaces.
pub fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// The bytes a Dynamixel encoder (either protocol's) writes into a buffer large enough for any
/// of the tests' packets.
pub fn enc(f: impl FnOnce(&mut [u8]) -> Result<usize, EncodeError>) -> Vec<u8> {
    let mut buf = [0u8; 256];
    let n = f(&mut buf).unwrap();
    buf[..n].to_vec()
}

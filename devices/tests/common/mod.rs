//! Helpers shared by the integration tests.
// Each test binary uses some of them.
#![allow(dead_code)]

use std::io::Read;

/// Reads from `port` until `n` CR- or BEL-terminated lines (SLCAN answers) have arrived.
pub fn read_lines(port: &mut impl Read, n: usize) -> String {
    let mut got = Vec::new();
    let mut buf = [0u8; 256];
    while got.iter().filter(|&&b| b == b'\r' || b == 7).count() < n {
        let k = port.read(&mut buf).unwrap();
        got.extend_from_slice(&buf[..k]);
    }
    String::from_utf8(got).unwrap()
}

/// The value of `"key": value` in a flat JSON line (numbers and number lists only), as the
/// simulators and the Python clients print it.
pub fn field(json: &str, key: &str) -> String {
    let start = json
        .find(&format!("\"{key}\": "))
        .unwrap_or_else(|| panic!("{key} in {json}"))
        + key.len()
        + 4;
    let rest = &json[start..];
    let end = if rest.starts_with('[') {
        rest.find(']').unwrap() + 1
    } else {
        rest.find([',', '}']).unwrap()
    };
    rest[..end].to_string()
}

//! Helpers shared by the integration tests.

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

//! Where the firmware and its harness live. Tests and benchmarks find them here; environment
//! variables override the defaults (CI builds the firmware once and points at it).

use std::path::{Path, PathBuf};

/// Environment variable: path of the firmware ELF.
pub const ENV_ELF: &str = "SCORE_FIRMWARE_ELF";
/// Environment variable: the harness directory (with `node_modules` installed by `npm ci`).
pub const ENV_HARNESS: &str = "SCORE_EMULATOR_DIR";

/// `score/firmware` in this checkout.
pub fn firmware_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("score/firmware/tools has a parent")
        .to_path_buf()
}

/// The release ELF the firmware build produces.
pub fn default_elf() -> PathBuf {
    firmware_dir().join("target/thumbv6m-none-eabi/release/score-firmware")
}

/// The firmware ELF: `$SCORE_FIRMWARE_ELF`, else [`default_elf`]. An error that says how to
/// build it when it is missing.
pub fn firmware_elf() -> Result<PathBuf, String> {
    let p = std::env::var_os(ENV_ELF)
        .map(PathBuf::from)
        .unwrap_or_else(default_elf);
    if p.is_file() {
        Ok(p)
    } else {
        Err(format!(
            "the Score firmware ELF {} is missing: build it with \
             `cargo run -p score-firmware-tools --bin score-fw -- build` \
             (or `cd score/firmware && cargo build --release --locked`), or set {ENV_ELF}",
            p.display()
        ))
    }
}

/// The harness directory: `$SCORE_EMULATOR_DIR`, else `score/firmware/emulator`; an error if
/// its npm packages are not installed.
pub fn harness_dir() -> Result<PathBuf, String> {
    let d = std::env::var_os(ENV_HARNESS)
        .map(PathBuf::from)
        .unwrap_or_else(|| firmware_dir().join("emulator"));
    if d.join("node_modules/rp2040js/package.json").is_file() {
        Ok(d)
    } else {
        Err(format!(
            "the emulator harness in {} has no node_modules/rp2040js: run `npm ci` there \
             (Node >= 18), or set {ENV_HARNESS}",
            d.display()
        ))
    }
}

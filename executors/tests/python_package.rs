//! The Python package (`python/`) against the real executor: its pytest suite starts
//! `conductor-executor` on the simulated mini-Hubo leg in domains of its own and checks
//! discovery, states and their history, verdicts, ticks, stats and the watchdog contract, and
//! its ctypes types against bus/ABI.md.
//!
//! The venv's interpreter comes from `cargo xtask setup` (which installs the package with pytest
//! and numpy); `PYTHONPATH` points at this checkout's `python/src`, so the code under test is
//! the checkout's even when the venv holds another install.

use std::process::Command;

use conductor_testkit::{python, workspace};

#[test]
fn the_python_package_passes_its_tests_against_a_live_executor() {
    let root = workspace();
    let out = Command::new(python())
        .args([
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "python/tests",
        ])
        .current_dir(&root)
        .env(
            "CONDUCTOR_EXECUTOR",
            env!("CARGO_BIN_EXE_conductor-executor"),
        )
        .env("PYTHONPATH", root.join("python/src"))
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .env_remove("CONDUCTOR_DOMAIN")
        .output()
        .expect("start pytest");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "pytest failed ({}):\n{stdout}\n{stderr}",
        out.status
    );
    // The suite ran (pytest exits 5 when it collects nothing, but be explicit).
    let summary = stdout.lines().last().unwrap_or_default();
    assert!(
        summary.contains(" passed") && !summary.contains("failed"),
        "{stdout}"
    );
}

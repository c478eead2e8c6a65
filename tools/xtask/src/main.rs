//! `cargo xtask <task>`: the project's automation, with no dependencies beyond std so it builds
//! in seconds on a fresh machine.
//!
//! * `setup` — installs what the test suite needs and the machine may lack: the Python venv with
//!   the interop packages (`tools/python-requirements.txt`), the `thumbv6m-none-eabi` target,
//!   socat (Debian) and the emulator harness's npm packages (`npm ci`).
//! * `test`  — `setup`, then the Score firmware build, every test of the workspace (the firmware
//!   tests boot that image in the rp2040js emulator; tools/cli's `bench` test runs
//!   `conductor bench --quick`), the f32 build of Score, and the no_std crates built for the
//!   RP2040's Cortex-M0+.
//! * `fuzz`  — every fuzz target for a set number of executions and a table of the results
//!   (see [`fuzz`]; `cargo xtask fuzz --help`).

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::Instant;

mod fuzz;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let task = args.first().map(String::as_str).unwrap_or("help");
    let result = match task {
        "setup" => setup().map(|_| ()),
        "test" => test(),
        "fuzz" => fuzz::fuzz(&args[1..]),
        _ => {
            eprintln!("usage: cargo xtask <setup|test|fuzz>");
            eprintln!("  setup  install the Python venv and other test prerequisites");
            eprintln!("  test   setup, then run the whole test suite");
            eprintln!("  fuzz   run every fuzz target N times and tabulate (--help)");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask {task}: {e}");
            ExitCode::FAILURE
        }
    }
}

type Result<T = ()> = std::result::Result<T, String>;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .nth(2)
        .expect("tools/xtask sits two levels below the workspace root")
        .to_path_buf()
}

fn run(cmd: &mut Command) -> Result {
    eprintln!("xtask: running {cmd:?}");
    let status = cmd
        .status()
        .map_err(|e| format!("cannot start {cmd:?}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{cmd:?} failed with {status}"))
    }
}

/// What the test suite needs, installed if missing. Returns the environment the tests need.
fn setup() -> Result<Vec<(String, String)>> {
    let t = Instant::now();
    let python = python_venv()?;
    rust_target(THUMB)?;
    debian_tools(&[("socat", "socat"), ("cyclictest", "rt-tests")])?;
    npm_ci(&root().join("score/firmware/emulator"))?;
    eprintln!("xtask: setup done in {:.1} s", t.elapsed().as_secs_f64());
    Ok(vec![(
        "CONDUCTOR_PYTHON".into(),
        python.display().to_string(),
    )])
}

/// Installs Debian packages whose command is missing (the emulator harness bridges USB CDC to
/// pseudo-terminals with socat; `conductor bench` runs cyclictest).
fn debian_tools(tools: &[(&str, &str)]) -> Result {
    let missing: Vec<&str> = tools
        .iter()
        .filter(|(cmd, _)| {
            !Command::new("sh")
                .args(["-c", &format!("command -v {cmd}")])
                .output()
                .is_ok_and(|o| o.status.success())
        })
        .map(|(_, pkg)| *pkg)
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    let sudo: &[&str] = if is_root() { &[] } else { &["sudo"] };
    let apt = |args: &[&str]| {
        let mut all: Vec<&str> = sudo.to_vec();
        all.push("apt-get");
        all.extend_from_slice(args);
        let mut c = Command::new(all[0]);
        c.args(&all[1..]).env("DEBIAN_FRONTEND", "noninteractive");
        run(&mut c)
    };
    if apt(&[&["install", "-y", "-q"][..], &missing].concat()).is_err() {
        // A fresh machine may have no package lists yet.
        apt(&["update", "-q"])?;
        apt(&[&["install", "-y", "-q"][..], &missing].concat())?;
    }
    Ok(())
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

/// `npm ci` in `dir` (the emulator harness pins rp2040js), unless node_modules matches the lock.
fn npm_ci(dir: &Path) -> Result {
    let lock = dir.join("package-lock.json");
    let stamp = dir.join("node_modules/.package-lock.json");
    let fresh = match (std::fs::metadata(&lock), std::fs::metadata(&stamp)) {
        (Ok(l), Ok(s)) => s.modified().ok() >= l.modified().ok(),
        _ => false,
    };
    if fresh {
        return Ok(());
    }
    run(Command::new("npm")
        .current_dir(dir)
        .args(["ci", "--no-audit", "--no-fund"]))
}

/// The RP2040's target: Cortex-M0+, no FPU.
const THUMB: &str = "thumbv6m-none-eabi";

fn rust_target(target: &str) -> Result {
    let installed = Command::new("rustup")
        .args(["target", "list", "--installed"])
        .output()
        .map_err(|e| format!("rustup: {e}"))?;
    if String::from_utf8_lossy(&installed.stdout)
        .lines()
        .any(|l| l.trim() == target)
    {
        return Ok(());
    }
    run(Command::new("rustup").args(["target", "add", target]))
}

/// `.venv` with the pinned interop packages; reinstalled only when the requirements change.
fn python_venv() -> Result<PathBuf> {
    let root = root();
    let venv = root.join(".venv");
    let python = venv.join("bin/python");
    let reqs = root.join("tools/python-requirements.txt");
    let wanted = std::fs::read_to_string(&reqs).map_err(|e| format!("{}: {e}", reqs.display()))?;
    let stamp = venv.join("conductor-requirements.txt");
    if std::fs::read_to_string(&stamp).ok().as_deref() == Some(wanted.as_str()) && python.exists() {
        return Ok(python);
    }
    if !python.exists() {
        run(Command::new("python3").args(["-m", "venv"]).arg(&venv))?;
    }
    run(Command::new(&python)
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--disable-pip-version-check",
            "-r",
        ])
        .arg(&reqs))?;
    std::fs::write(&stamp, wanted).map_err(|e| e.to_string())?;
    Ok(python)
}

fn cargo(root: &Path, env: &[(String, String)], args: &[&str]) -> Result {
    let t = Instant::now();
    run(Command::new(env!("CARGO"))
        .current_dir(root)
        .args(args)
        .envs(env.iter().map(|(k, v)| (k, v))))?;
    eprintln!(
        "xtask: `cargo {}` passed in {:.1} s",
        args.join(" "),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

fn test() -> Result {
    let env = setup()?;
    let root = root();
    // The no_std crates must build for the firmware's target: proves no_std and no heap.
    for features in [&[][..], &["--features", "score-core/f32"][..]] {
        let mut args = vec!["build", "--locked", "--target", THUMB, "-p", "score-core"];
        args.extend_from_slice(features);
        cargo(&root, &env, &args)?;
    }
    cargo(
        &root,
        &env,
        &[
            "build",
            "--locked",
            "--target",
            THUMB,
            "-p",
            "conductor-protocols",
        ],
    )?;
    // The Score firmware image (ELF + UF2) that the emulator tests boot.
    cargo(
        &root,
        &env,
        &[
            "run",
            "--locked",
            "-p",
            "score-firmware-tools",
            "--bin",
            "score-fw",
            "--",
            "build",
        ],
    )?;
    cargo(&root, &env, &["test", "--workspace", "--locked"])?;
    // Score's algorithm tests again with its f32 number type.
    cargo(
        &root,
        &env,
        &[
            "test",
            "--locked",
            "-p",
            "score-core",
            "-p",
            "score-host",
            "--features",
            "score-host/f32",
        ],
    )?;
    Ok(())
}

//! `cargo xtask <task>`: the project's automation, with no dependencies beyond std so it builds
//! in seconds on a fresh machine.
//!
//! * `setup` — installs what the test suite needs and the machine may lack: the Python venv with
//!   the interop packages (`tools/python-requirements.txt`) and the `conductor` Python package
//!   (`python/`, editable), the `thumbv6m-none-eabi` target, socat (Debian) and the emulator
//!   harness's npm packages (`npm ci`); for the CAN tests in a VM, QEMU, can-utils and
//!   busybox-static (Debian), and Debian's kernel image with the modules the VM loads, extracted
//!   into `target/can-vm/` (the package is downloaded, not installed).
//! * `test`  — the habits (`cargo fmt --check`, clippy and `cargo doc`, warnings denied: see
//!   [`habits`]), `setup`, then the Score firmware build, every test of the workspace (the firmware
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
    rustup_add("target", &[THUMB])?;
    // `ip` makes the network namespaces and veth pair of the bridge test (tools/cli/tests/bridge.rs).
    debian_tools(&[
        ("socat", "socat"),
        ("cyclictest", "rt-tests"),
        ("ip", "iproute2"),
        ("qemu-system-x86_64", "qemu-system-x86"),
        ("candump", "can-utils"),
        ("slcand", "can-utils"),
        ("busybox", "busybox-static"),
    ])?;
    let can_vm = can_vm_kernel()?;
    npm_ci(&root().join("score/firmware/emulator"))?;
    eprintln!("xtask: setup done in {:.1} s", t.elapsed().as_secs_f64());
    Ok(vec![
        ("CONDUCTOR_PYTHON".into(), python.display().to_string()),
        ("CONDUCTOR_CAN_VM".into(), can_vm.display().to_string()),
    ])
}

/// The kernel modules the CAN VM loads (conductor-testkit's `can_vm::MODULES`), by their path
/// under `lib/modules/<release>/kernel/`.
const CAN_VM_MODULES: &[&str] = &[
    "drivers/virtio/virtio_ring.ko",
    "drivers/virtio/virtio.ko",
    "drivers/virtio/virtio_pci_legacy_dev.ko",
    "drivers/virtio/virtio_pci_modern_dev.ko",
    "drivers/virtio/virtio_pci.ko",
    "net/9p/9pnet.ko",
    "net/9p/9pnet_virtio.ko",
    "fs/netfs/netfs.ko",
    "fs/fscache/fscache.ko",
    "fs/9p/9p.ko",
    "fs/overlayfs/overlay.ko",
    "net/can/can.ko",
    "net/can/can-raw.ko",
    "drivers/net/can/dev/can-dev.ko",
    "net/can/can-gw.ko",
    "drivers/net/can/vcan.ko",
    "drivers/net/can/slcan/slcan.ko",
];

/// Debian's stock kernel for the CAN tests' VM, in `target/can-vm/<release>/`: the image
/// uncompressed (`vmlinux`: boots ~4 s faster under emulation) and the modules of
/// [`CAN_VM_MODULES`]. The package is downloaded with `apt-get download` and only those files
/// are taken from it (a full install would build an initramfs nobody needs). `release` names
/// the ready one; kept until the package's release changes.
fn can_vm_kernel() -> Result<PathBuf> {
    let dir = root().join("target/can-vm");
    let stamp = dir.join("release");
    // linux-image-amd64 depends on the current linux-image-<release>.
    let deps = Command::new("apt-cache")
        .args(["depends", "linux-image-amd64"])
        .output()
        .map_err(|e| format!("apt-cache: {e}"))?;
    let deps = String::from_utf8_lossy(&deps.stdout).to_string();
    let release = deps
        .lines()
        .find_map(|l| l.trim().strip_prefix("Depends: linux-image-"))
        .map(str::to_string)
        .or_else(|| {
            // Without package lists, keep what was prepared.
            std::fs::read_to_string(&stamp)
                .ok()
                .map(|s| s.trim().to_string())
        })
        .ok_or("cannot tell the kernel release: `apt-cache depends linux-image-amd64` names none (apt-get update?)")?;
    let here = dir.join(&release);
    let ready = std::fs::read_to_string(&stamp)
        .ok()
        .as_deref()
        .map(str::trim)
        == Some(release.as_str())
        && here.join("vmlinux").exists();
    if ready {
        return Ok(dir);
    }
    let t = Instant::now();
    let _ = std::fs::remove_dir_all(&here);
    std::fs::create_dir_all(here.join("modules")).map_err(|e| e.to_string())?;
    let package = format!("linux-image-{release}");
    run(Command::new("apt-get")
        .current_dir(&here)
        .args(["download", "-q", &package]))
    .or_else(|_| {
        run(Command::new("apt-get").args(["update", "-q"]))?;
        run(Command::new("apt-get")
            .current_dir(&here)
            .args(["download", "-q", &package]))
    })?;
    let deb = std::fs::read_dir(&here)
        .map_err(|e| e.to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|x| x == "deb"))
        .ok_or("apt-get download left no .deb")?;
    let mut wanted = vec![format!("./boot/vmlinuz-{release}")];
    wanted.extend(
        CAN_VM_MODULES
            .iter()
            .map(|m| format!("./lib/modules/{release}/kernel/{m}")),
    );
    let tar = format!(
        "dpkg-deb --fsys-tarfile '{}' | tar -x -C '{}' {}",
        deb.display(),
        here.display(),
        wanted
            .iter()
            .map(|w| format!("'{w}'"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    run(Command::new("sh").args(["-c", &tar]))?;
    let _ = std::fs::remove_file(&deb);
    for m in CAN_VM_MODULES {
        let from = here.join(format!("lib/modules/{release}/kernel/{m}"));
        let name = Path::new(m).file_name().ok_or("module name")?;
        std::fs::rename(&from, here.join("modules").join(name))
            .map_err(|e| format!("{}: {e}", from.display()))?;
    }
    let _ = std::fs::remove_dir_all(here.join("lib"));
    // The bzImage's payload is an xz stream: decompress it from its magic on.
    let vmlinuz = here.join(format!("boot/vmlinuz-{release}"));
    let image = std::fs::read(&vmlinuz).map_err(|e| format!("{}: {e}", vmlinuz.display()))?;
    let magic = [0xFD, b'7', b'z', b'X', b'Z', 0x00];
    let at = image
        .windows(magic.len())
        .position(|w| w == magic)
        .ok_or("the kernel image holds no xz stream")?;
    let xz = here.join("payload.xz");
    std::fs::write(&xz, &image[at..]).map_err(|e| e.to_string())?;
    let vmlinux = std::fs::File::create(here.join("vmlinux")).map_err(|e| e.to_string())?;
    let status = Command::new("xz")
        .args(["-dc", "--single-stream"])
        .arg(&xz)
        .stdout(vmlinux)
        .status()
        .map_err(|e| format!("xz: {e}"))?;
    if !status.success() {
        return Err(format!("xz could not decompress {}", vmlinuz.display()));
    }
    let _ = std::fs::remove_file(&xz);
    let _ = std::fs::remove_dir_all(here.join("boot"));
    std::fs::write(&stamp, &release).map_err(|e| e.to_string())?;
    // Older releases go.
    for e in std::fs::read_dir(&dir)
        .map_err(|e| e.to_string())?
        .flatten()
    {
        if e.path().is_dir() && e.file_name() != release.as_str() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
    eprintln!(
        "xtask: kernel {release} for the CAN VM ready in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    Ok(dir)
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
    if apt(&[
        &["install", "-y", "-q", "--no-install-recommends"][..],
        &missing,
    ]
    .concat())
    .is_err()
    {
        // A fresh machine may have no package lists yet.
        apt(&["update", "-q"])?;
        apt(&[
            &["install", "-y", "-q", "--no-install-recommends"][..],
            &missing,
        ]
        .concat())?;
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

/// Adds what `rustup <kind> list --installed` lacks of `wanted` (`kind`: `target` or
/// `component`; components are listed with their host's triple, `clippy-x86_64-…`).
fn rustup_add(kind: &str, wanted: &[&str]) -> Result {
    let installed = Command::new("rustup")
        .args([kind, "list", "--installed"])
        .output()
        .map_err(|e| format!("rustup: {e}"))?;
    let installed = String::from_utf8_lossy(&installed.stdout);
    let missing: Vec<&str> = wanted
        .iter()
        .copied()
        .filter(|w| {
            !installed
                .lines()
                .map(str::trim)
                .any(|l| l == *w || l.strip_prefix(*w).is_some_and(|rest| rest.starts_with('-')))
        })
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    run(Command::new("rustup").args([kind, "add"]).args(&missing))
}

/// `.venv` with the pinned interop packages and the `conductor` package of `python/` (editable,
/// so the venv runs this checkout's code); reinstalled only when the requirements, the package's
/// `pyproject.toml` or the checkout it points at change.
fn python_venv() -> Result<PathBuf> {
    let root = root();
    let venv = root.join(".venv");
    let python = venv.join("bin/python");
    let reqs = root.join("tools/python-requirements.txt");
    let package = root.join("python");
    let pyproject = package.join("pyproject.toml");
    let wanted = [&reqs, &pyproject]
        .iter()
        .map(|p| std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display())))
        .collect::<Result<Vec<_>>>()?
        .join("")
        + &package.display().to_string();
    let stamp = venv.join("conductor-requirements.txt");
    if std::fs::read_to_string(&stamp).ok().as_deref() == Some(wanted.as_str()) && python.exists() {
        return Ok(python);
    }
    if !python.exists() {
        run(Command::new("python3").args(["-m", "venv"]).arg(&venv))?;
    }
    let pip_install = |how: &str, what: &Path| {
        run(Command::new(&python)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
            ])
            .arg(how)
            .arg(what))
    };
    pip_install("-r", &reqs)?;
    pip_install("-e", &package)?;
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

/// Formatting, lints and docs, all with warnings denied: `cargo fmt --check`, clippy on every
/// target of the workspace (the workspace lints of `Cargo.toml` included) and `cargo doc` of
/// the workspace's own crates. Clippy and rustdoc read the dependencies' metadata from one
/// `check` build they share, so the pair costs about one check of the workspace.
fn habits(root: &Path) -> Result {
    rustup_add("component", &["rustfmt", "clippy"])?;
    cargo(root, &[], &["fmt", "--all", "--check"])?;
    cargo(
        root,
        &[],
        &[
            "clippy",
            "--workspace",
            "--all-targets",
            "--locked",
            "--",
            "-D",
            "warnings",
        ],
    )?;
    cargo(
        root,
        &[("RUSTDOCFLAGS".into(), "-D warnings".into())],
        &["doc", "--workspace", "--no-deps", "--locked"],
    )
}

fn test() -> Result {
    let root = root();
    // The habits first: they need nothing installed and fail in seconds to minutes, before
    // the setup and the long test run.
    habits(&root)?;
    let env = setup()?;
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
    cargo(
        &root,
        &env,
        &["test", "--workspace", "--locked", "--no-fail-fast"],
    )?;
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

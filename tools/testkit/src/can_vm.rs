//! A real Linux CAN stack for tests: Debian's stock kernel booted in QEMU, with the host's root
//! file system shared read-only, so that binaries built on the host (test binaries, the
//! executor) run inside it unchanged.
//!
//! The build machines' own kernel has no CAN; Debian's has vcan, can-raw, can-gw and slcan as
//! modules. `cargo xtask setup` installs QEMU, can-utils and busybox-static and extracts the
//! kernel image and the modules this needs into `target/can-vm/` ([`CACHE_ENV`] overrides
//! it). The guest:
//!
//! 1. boots that kernel directly (`-kernel`, TCG unless the CPU really has VMX/SVM) with a tiny
//!    initramfs written here: the static busybox and the virtio, 9p, overlay and CAN modules,
//!    loaded with `insmod` in dependency order;
//! 2. mounts the host's `/` (9p, read-only), puts a tmpfs overlay on it and `switch_root`s into
//!    it, with fresh `/proc`, `/sys`, `/dev` (ptys), `/dev/shm`, `/tmp` and `/run`;
//! 3. runs a shell script given by the caller as root, with its stdout and stderr and exit
//!    status written to a second, writable 9p share (a folder on the host), then powers off.
//!
//! Nothing on the host changes but that folder; the guest's writes go to its tmpfs.

use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Environment variable naming the kernel cache folder (default `<workspace>/target/can-vm`).
pub const CACHE_ENV: &str = "CONDUCTOR_CAN_VM";

/// The QEMU binary.
pub const QEMU: &str = "qemu-system-x86_64";

/// Modules loaded in the initramfs, in dependency order (file names without `.ko`).
pub const MODULES: &[&str] = &[
    "virtio_ring",
    "virtio",
    "virtio_pci_legacy_dev",
    "virtio_pci_modern_dev",
    "virtio_pci",
    "9pnet",
    "9pnet_virtio",
    "netfs",
    "fscache",
    "9p",
    "overlay",
    "can",
    "can-raw",
    "can-dev",
    "can-gw",
    "vcan",
    "slcan",
];

/// Where the guest mounts the writable share (the run's folder on the host).
pub const GUEST_OUT: &str = "/canvm/out";

/// The prepared kernel: an uncompressed image and the modules of [`MODULES`].
#[derive(Debug, Clone)]
pub struct CanVm {
    /// `vmlinux` (an ELF the QEMU loader boots through its PVH entry).
    pub kernel: PathBuf,
    /// Folder holding `<module>.ko` for every module of [`MODULES`].
    pub modules: PathBuf,
    /// The kernel release (`6.1.0-48-amd64`).
    pub release: String,
}

/// Why no VM can be started.
#[derive(Debug)]
pub enum Unavailable {
    /// QEMU cannot run on this machine at all (not installed, not an x86-64 host): callers skip
    /// with this message.
    NoQemu(String),
    /// QEMU is there but the kernel has not been prepared: callers fail with this message.
    NotPrepared(String),
}

/// What a guest run produced.
#[derive(Debug)]
pub struct VmRun {
    /// The script's standard output.
    pub stdout: String,
    /// The script's standard error.
    pub stderr: String,
    /// The script's exit status; `None` if the guest never reported one (crash, timeout).
    pub status: Option<i32>,
    /// The serial console (kernel messages, QEMU's own errors).
    pub console: String,
    /// From QEMU's start to its exit.
    pub elapsed: Duration,
    /// The run's folder on the host (the guest sees it at [`GUEST_OUT`]).
    pub out: PathBuf,
}

impl CanVm {
    /// The cache folder: `$CONDUCTOR_CAN_VM`, else `<workspace>/target/can-vm`.
    pub fn cache_dir() -> PathBuf {
        std::env::var_os(CACHE_ENV)
            .map(PathBuf::from)
            .unwrap_or_else(|| crate::workspace().join("target/can-vm"))
    }

    /// Finds QEMU and the prepared kernel.
    pub fn find() -> Result<CanVm, Unavailable> {
        if std::env::consts::ARCH != "x86_64" {
            return Err(Unavailable::NoQemu(format!(
                "the CAN VM boots Debian's amd64 kernel; this is a {} host",
                std::env::consts::ARCH
            )));
        }
        match Command::new(QEMU).arg("-version").output() {
            Ok(o) if o.status.success() => {}
            Ok(o) => {
                return Err(Unavailable::NoQemu(format!(
                    "{QEMU} -version failed: {}",
                    String::from_utf8_lossy(&o.stderr).trim()
                )))
            }
            Err(e) => {
                return Err(Unavailable::NoQemu(format!(
                    "{QEMU} not found ({e}); `cargo xtask setup` installs it (qemu-system-x86)"
                )))
            }
        }
        let dir = Self::cache_dir();
        let not_prepared = |what: String| {
            Unavailable::NotPrepared(format!(
                "{what}: run `cargo xtask setup`, which extracts Debian's kernel into {}",
                dir.display()
            ))
        };
        let release = std::fs::read_to_string(dir.join("release"))
            .map_err(|e| not_prepared(format!("{}/release: {e}", dir.display())))?
            .trim()
            .to_string();
        let kernel = dir.join(&release).join("vmlinux");
        let modules = dir.join(&release).join("modules");
        if !kernel.exists() {
            return Err(not_prepared(format!("no {}", kernel.display())));
        }
        for m in MODULES {
            let ko = modules.join(format!("{m}.ko"));
            if !ko.exists() {
                return Err(not_prepared(format!("no {}", ko.display())));
            }
        }
        if !Path::new(BUSYBOX).exists() {
            return Err(not_prepared(format!(
                "no {BUSYBOX} (Debian's busybox-static)"
            )));
        }
        Ok(CanVm {
            kernel,
            modules,
            release,
        })
    }

    /// Boots the guest and runs `script` (POSIX sh, as root) in it; QEMU is killed after
    /// `timeout`. `out` is the run's folder on the host, created empty (its path must not
    /// contain spaces).
    pub fn run(&self, script: &str, out: &Path, timeout: Duration) -> io::Result<VmRun> {
        let _ = std::fs::remove_dir_all(out);
        std::fs::create_dir_all(out)?;
        std::fs::write(out.join("run.sh"), script)?;
        let initrd = out.join("initrd.cpio");
        self.write_initramfs(&initrd)?;
        let console = out.join("console.log");
        let kvm = has_hw_virt() && Path::new("/dev/kvm").exists();
        let accel: &[&str] = if kvm {
            &["-accel", "kvm", "-cpu", "host"]
        } else {
            &["-accel", "tcg", "-cpu", "max"]
        };
        let t = Instant::now();
        let mut child = Command::new("timeout")
            .args(["-s", "KILL", &format!("{}", timeout.as_secs().max(1))])
            .arg(QEMU)
            .args(accel)
            .args([
                "-m",
                "512",
                "-smp",
                "2",
                "-nographic",
                "-no-reboot",
                "-nic",
                "none",
            ])
            .arg("-kernel")
            .arg(&self.kernel)
            .arg("-initrd")
            .arg(&initrd)
            .args(["-append", "console=ttyS0 quiet panic=-1"])
            .arg("-virtfs")
            .arg("local,path=/,mount_tag=hostroot,security_model=none,readonly=on,multidevs=remap")
            .arg("-virtfs")
            .arg(format!(
                "local,path={},mount_tag=out,security_model=none",
                out.display()
            ))
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&console)?)
            .stderr(Stdio::from(std::fs::File::create(out.join("qemu.err"))?))
            .spawn()?;
        child.wait()?;
        let elapsed = t.elapsed();
        let read = |n: &str| std::fs::read_to_string(out.join(n)).unwrap_or_default();
        Ok(VmRun {
            stdout: read("stdout"),
            stderr: read("stderr"),
            status: read("rc").trim().parse().ok(),
            console: read("console.log") + &read("qemu.err"),
            elapsed,
            out: out.to_path_buf(),
        })
    }

    /// The initramfs: busybox, the modules, `/init` (stage 1) and `/stage2`.
    fn write_initramfs(&self, path: &Path) -> io::Result<()> {
        let mut cpio = Newc::default();
        cpio.dir("bin");
        cpio.dir("mod");
        cpio.file("bin/busybox", 0o755, &std::fs::read(BUSYBOX)?);
        for m in MODULES {
            cpio.file(
                &format!("mod/{m}.ko"),
                0o644,
                &std::fs::read(self.modules.join(format!("{m}.ko")))?,
            );
        }
        let modules = MODULES.join(" ");
        cpio.file(
            "init",
            0o755,
            STAGE1.replace("@MODULES@", &modules).as_bytes(),
        );
        cpio.file(
            "stage2",
            0o755,
            STAGE2.replace("@OUT@", GUEST_OUT).as_bytes(),
        );
        let mut f = std::fs::File::create(path)?;
        f.write_all(&cpio.finish())
    }
}

/// Debian's static busybox (package busybox-static).
const BUSYBOX: &str = "/bin/busybox";

/// Stage 1, in the initramfs: modules, the host's root under a tmpfs overlay, switch_root.
const STAGE1: &str = r#"#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin
mkdir -p /proc /sys /dev /host /rw /root
mount -t proc proc /proc
mount -t devtmpfs dev /dev
for m in @MODULES@; do insmod /mod/$m.ko || echo "canvm: insmod $m failed"; done
mount -t 9p -o trans=virtio,version=9p2000.L,msize=524288,cache=loose,ro hostroot /host || echo "canvm: no host root"
mount -t tmpfs tmpfs /rw
mkdir -p /rw/upper /rw/work
mount -t overlay overlay -o lowerdir=/host,upperdir=/rw/upper,workdir=/rw/work /root || echo "canvm: no overlay"
mkdir -p /root/canvm/out
mount -t 9p -o trans=virtio,version=9p2000.L,msize=524288 out /root/canvm/out || echo "canvm: no out share"
cp /stage2 /root/canvm/stage2
umount /proc
exec switch_root /root /bin/sh /canvm/stage2
"#;

/// Stage 2, in the host's root: fresh kernel file systems, the script, power off.
const STAGE2: &str = r#"export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
export HOME=/root
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev 2>/dev/null
mkdir -p /dev/pts /dev/shm
mount -t devpts -o ptmxmode=0666 devpts /dev/pts
ln -sf /dev/pts/ptmx /dev/ptmx
mount -t tmpfs tmpfs /dev/shm
mount -t tmpfs tmpfs /tmp
mount -t tmpfs tmpfs /run
ip link set lo up
cd @OUT@
/bin/sh @OUT@/run.sh > @OUT@/stdout 2> @OUT@/stderr
echo $? > @OUT@/rc
sync
echo o > /proc/sysrq-trigger
sleep 30
"#;

/// Whether the CPU has hardware virtualisation (a `/dev/kvm` without it is a paravirtual
/// backend that boots far slower than emulation).
pub fn has_hw_virt() -> bool {
    std::fs::read_to_string("/proc/cpuinfo").is_ok_and(|c| {
        c.lines()
            .filter(|l| l.starts_with("flags"))
            .any(|l| l.split_whitespace().any(|f| f == "vmx" || f == "svm"))
    })
}

/// A `newc` cpio archive (what the kernel unpacks as an initramfs).
#[derive(Default)]
struct Newc {
    buf: Vec<u8>,
    ino: u32,
}

impl Newc {
    fn entry(&mut self, name: &str, mode: u32, data: &[u8]) {
        self.ino += 1;
        let header = format!(
            "070701{:08X}{:08X}{:08X}{:08X}{:08X}{:08X}{:08X}{:08X}{:08X}{:08X}{:08X}{:08X}{:08X}",
            self.ino,
            mode,
            0,
            0,
            1,
            0,
            data.len(),
            0,
            0,
            0,
            0,
            name.len() + 1,
            0
        );
        self.buf.extend_from_slice(header.as_bytes());
        self.buf.extend_from_slice(name.as_bytes());
        self.buf.push(0);
        self.pad();
        self.buf.extend_from_slice(data);
        self.pad();
    }

    fn pad(&mut self) {
        while !self.buf.len().is_multiple_of(4) {
            self.buf.push(0);
        }
    }

    fn dir(&mut self, name: &str) {
        self.entry(name, 0o040_755, &[]);
    }

    fn file(&mut self, name: &str, perm: u32, data: &[u8]) {
        self.entry(name, 0o100_000 | perm, data);
    }

    fn finish(mut self) -> Vec<u8> {
        self.entry("TRAILER!!!", 0, &[]);
        self.buf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newc_entries_are_aligned_and_end_with_the_trailer() {
        let mut c = Newc::default();
        c.dir("bin");
        c.file("init", 0o755, b"#!/bin/sh\n");
        let b = c.finish();
        assert_eq!(&b[..6], b"070701");
        assert_eq!(b.len() % 4, 0);
        let text = String::from_utf8_lossy(&b);
        assert!(text.contains("init\0"));
        assert!(text.contains("TRAILER!!!\0"));
        // The init entry's file size field (7th field) is 10 bytes.
        let at = text.find("init\0").unwrap();
        let header = &text[at - 110..at];
        assert_eq!(&header[54..62], "0000000A", "{header}");
    }
}

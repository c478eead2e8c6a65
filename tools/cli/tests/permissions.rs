//! Who may command a state (docs/permissions.md), checked with real users: the test creates a
//! service user and a second user (`useradd`; root or passwordless `sudo` needed, as for the
//! test suite's other system set-up), launches the two-subsystem manifest as the service user
//! (`setpriv`), and tries the domain as the service user, the other user and root. The users are
//! deleted at the end. Also: the UDP gateway answers on loopback only unless told otherwise.

mod support;

use std::net::UdpSocket;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use conductor_bus::Domain;
use support::*;

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

/// `program` run as root: directly when the test is root, else through `sudo -n`.
fn as_root(program: &str) -> Command {
    if is_root() {
        Command::new(program)
    } else {
        let mut c = Command::new("sudo");
        c.args(["-n", program]);
        c
    }
}

fn run_ok(mut c: Command) -> String {
    let out = conductor_testkit::run_ok(&mut c);
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// System users created for the test, deleted (with their groups) on drop, with the
/// directory they run the staged program from.
struct Users(Vec<String>, Stage);

impl Users {
    fn create(tags: &[&str]) -> Self {
        let mut users = Users(Vec::new(), Stage::new(&tags.concat()));
        for tag in tags {
            let name = format!("cdt{}{tag}", std::process::id());
            let mut c = as_root("useradd");
            c.args([
                "--system",
                "--no-create-home",
                "--user-group",
                "--shell",
                "/usr/sbin/nologin",
                &name,
            ]);
            run_ok(c);
            users.0.push(name);
        }
        users
    }

    fn uid(&self, i: usize) -> u32 {
        let mut c = Command::new("id");
        c.args(["-u", &self.0[i]]);
        run_ok(c).trim().parse().unwrap()
    }

    /// `program args...` as user i (uid, gid and groups of that user only).
    fn cmd(&self, i: usize, program: &str) -> Command {
        let mut c = as_root("setpriv");
        let u = &self.0[i];
        c.args(["--reuid", u, "--regid", u, "--init-groups", program]);
        c
    }

    fn conductor(&self, i: usize, d: &Domain) -> Command {
        let mut c = self.cmd(i, self.1.path("conductor").to_str().unwrap());
        c.arg("--domain").arg(d.name());
        c
    }
}

impl Drop for Users {
    fn drop(&mut self) {
        for u in &self.0 {
            // userdel refuses while a process of the user is still exiting: retry a while.
            let end = Instant::now() + Duration::from_secs(10);
            loop {
                let mut c = as_root("userdel");
                c.arg(u);
                let deleted = c.output().is_ok_and(|o| o.status.success());
                if deleted || Instant::now() > end {
                    break;
                }
                std::thread::sleep(Duration::from_millis(200));
            }
        }
    }
}

/// The `conductor` program and the test manifest where every user can reach them: the checkout
/// may sit under a directory only root may enter (`/root`), which the test users could not.
/// Linked (or copied across file systems) into `/tmp/conductor-perm-<pid><tag>/`, removed on
/// drop: a copy left behind would pin a whole debug binary in /tmp after every run.
struct Stage(PathBuf);

impl Stage {
    fn new(tag: &str) -> Self {
        let dir = PathBuf::from(format!("/tmp/conductor-perm-{}{tag}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let stage = Stage(dir);
        std::fs::set_permissions(&stage.0, std::fs::Permissions::from_mode(0o755)).unwrap();
        let exe = stage.path("conductor");
        let _ = std::fs::remove_file(&exe);
        if std::fs::hard_link(env!("CARGO_BIN_EXE_conductor"), &exe).is_err() {
            std::fs::copy(env!("CARGO_BIN_EXE_conductor"), &exe).unwrap();
        }
        std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).unwrap();
        let manifest = stage.path("two-subsystems.toml");
        std::fs::copy(
            workspace().join("executors/tests/manifests/two-subsystems.toml"),
            &manifest,
        )
        .unwrap();
        std::fs::set_permissions(&manifest, std::fs::Permissions::from_mode(0o644)).unwrap();
        stage
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Stage {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Removes what a domain left on disk (files of users that are about to be deleted).
fn remove_domain_files(d: &Domain) {
    let mut rm = as_root("rm");
    rm.args(["-rf", d.root_path().trim_end_matches('/')]);
    for e in std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(Result::ok)
    {
        if e.file_name().to_string_lossy().starts_with(&d.prefix()) {
            rm.arg(e.path());
        }
    }
    let _ = rm.status();
}

fn stderr_of(mut c: Command) -> String {
    let out = c.output().expect("run");
    assert!(!out.status.success(), "{c:?} should have failed");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The domain's shm files: (name, owner uid, mode).
fn shm_files(d: &Domain) -> Vec<(String, u32, u32)> {
    std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with(&d.prefix()))
        .filter_map(|e| {
            let m = e.metadata().ok()?;
            Some((
                e.file_name().to_string_lossy().into_owned(),
                m.uid(),
                m.mode() & 0o7777,
            ))
        })
        .collect()
}

#[test]
fn only_the_executors_user_can_read_or_command_its_domain() {
    let users = Users::create(&["s", "o"]);
    let (svc, other) = (0, 1);
    let svc_uid = users.uid(svc);
    let d = Domain::unique("perm").unwrap();
    let manifest = users.1.path("two-subsystems.toml");
    // The binaries must be reachable by the service user (the workspace is world-readable).
    let mut launch = users.conductor(svc, &d);
    launch
        .arg("launch")
        .arg(&manifest)
        .args(["--no-rt", "--quiet"]);
    let launcher = Bg::spawn(&mut launch);

    // The service user sees and commands its states.
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        let mut c = users.conductor(svc, &d);
        c.arg("list");
        let out = c.output().unwrap();
        if String::from_utf8_lossy(&out.stdout).lines().count() == 10 {
            break;
        }
        assert!(Instant::now() < end, "the states never appeared: {out:?}");
        std::thread::sleep(Duration::from_millis(200));
    }
    let mut set = users.conductor(svc, &d);
    set.args(["set", "arm/j3", "1.25"]);
    run_ok(set);
    let get = |who: usize| {
        let mut c = users.conductor(who, &d);
        c.args(["get", "arm/j3", "--raw"]);
        c
    };
    assert_eq!(run_ok(get(svc)).trim(), "1.25");

    // What is on disk: every segment is the service user's, readable and writable by it only,
    // except iceoryx2's 16-byte node counter, which every user may write.
    let files = shm_files(&d);
    assert!(files.len() > 10, "{files:?}");
    for (name, uid, mode) in &files {
        assert_eq!(*uid, svc_uid, "{name}");
        let want = if name.ends_with(".global_mgmt") {
            0o666
        } else {
            0o600
        };
        assert_eq!(*mode, want, "{name}: {mode:o}");
    }
    let dir = std::fs::metadata(d.root_path()).unwrap();
    assert_eq!((dir.uid(), dir.mode() & 0o777), (svc_uid, 0o750));
    let base = std::fs::metadata(conductor_bus::domain::ROOT_BASE).unwrap();
    assert_eq!(
        base.permissions().mode() & 0o7777,
        0o1777,
        "shared like /tmp"
    );

    // Another user can neither read nor command: the tools say why, and the kernel agrees.
    for args in [&["list"][..], &["get", "arm/j3"], &["set", "arm/j3", "-1"]] {
        let mut c = users.conductor(other, &d);
        c.args(args);
        let err = stderr_of(c);
        assert!(
            err.contains(&format!("belongs to uid {svc_uid}, not to this process")),
            "{args:?}: {err}"
        );
    }
    let (segment, _, _) = files
        .iter()
        .find(|(n, _, _)| n.ends_with(".data"))
        .expect("a data segment");
    let mut cat = users.cmd(other, "cat");
    cat.arg(format!("/dev/shm/{segment}"));
    assert!(stderr_of(cat).contains("Permission denied"));
    assert_eq!(run_ok(get(svc)).trim(), "1.25", "nothing changed");

    // Root is refused too (its segments would be root's, which the executor cannot open).
    let mut c = as_root(env!("CARGO_BIN_EXE_conductor"));
    c.arg("--domain")
        .arg(d.name())
        .args(["set", "arm/j3", "-1"]);
    assert!(stderr_of(c).contains(&format!("sudo -u '#{svc_uid}'")));
    assert_eq!(run_ok(get(svc)).trim(), "1.25");
    let (stopped, stderr) = launcher.interrupt();
    assert!(stopped, "{stderr}");
    remove_domain_files(&d);
}

#[test]
fn a_domain_claimed_by_another_user_is_refused_not_used() {
    let users = Users::create(&["a", "b"]);
    let (svc, squatter) = (0, 1);
    let d = Domain::unique("squat").unwrap();
    // Any bus join makes the shared base directory exist (mode 1777).
    let probe = Domain::unique("squatbase").unwrap();
    let mut c = users.conductor(squatter, &probe);
    c.arg("list");
    run_ok(c);
    // The squatter creates the robot's domain directory first, open to everyone.
    let path = d.root_path();
    let mut mk = users.cmd(squatter, "mkdir");
    mk.args(["-m", "0777", &path]);
    run_ok(mk);
    let mut launch = users.conductor(svc, &d);
    launch
        .arg("launch")
        .arg(users.1.path("two-subsystems.toml"));
    launch.args(["--no-rt", "--quiet"]);
    let err = stderr_of(launch);
    assert!(
        err.contains(&format!(
            "belongs to uid {}, not to this process",
            users.uid(squatter)
        )),
        "{err}"
    );
    // Its own directory, made writable by others, is refused as well.
    let mut chown = as_root("chown");
    chown.args([&users.0[svc], path.trim_end_matches('/')]);
    run_ok(chown);
    let mut list = users.conductor(svc, &d);
    list.arg("list");
    assert!(stderr_of(list).contains("mode 0777 lets other users change the domain's records"));
    remove_domain_files(&d);
    remove_domain_files(&probe);
}

/// The UDP gateway binds 127.0.0.1 by default: a datagram to another address of the machine
/// gets no answer. `--bind` opens it, with a warning.
#[test]
fn the_udp_gateway_answers_on_loopback_only_unless_bound_elsewhere() {
    // A non-loopback address of this machine (the test needs one: any networked host has it).
    let probe = UdpSocket::bind("0.0.0.0:0").unwrap();
    probe.connect("192.0.2.255:9").ok();
    let ip = match probe.local_addr().unwrap().ip() {
        ip if !ip.is_loopback() && !ip.is_unspecified() => ip,
        _ => {
            let out = Command::new("hostname").arg("-I").output().unwrap();
            String::from_utf8_lossy(&out.stdout)
                .split_whitespace()
                .find_map(|a| a.parse().ok())
                .expect("a non-loopback IPv4 address")
        }
    };
    let (d, _leg) = domain_with_leg("udpbind", 200.0, leg);
    let ask = |to: std::net::SocketAddr| -> Option<String> {
        let s = UdpSocket::bind((to.ip(), 0)).unwrap();
        s.set_read_timeout(Some(Duration::from_millis(500)))
            .unwrap();
        s.send_to(b"GET", to).unwrap();
        let mut buf = [0u8; 100];
        s.recv(&mut buf)
            .ok()
            .map(|n| String::from_utf8_lossy(&buf[..n]).into_owned())
    };
    for bind in [None, Some(ip)] {
        let base = free_udp_ports(3);
        let mut cmd = conductor(&d);
        cmd.args(["udp-gateway", "leg/*", "--base-port", &base.to_string()]);
        if let Some(ip) = bind {
            cmd.args(["--bind", &ip.to_string()]);
        }
        let mut gw = Bg::spawn(&mut cmd);
        let head = gw.until(Duration::from_secs(10), |l| l == "READY");
        let on = bind.map_or("127.0.0.1".to_string(), |ip| ip.to_string());
        assert!(
            head[0].starts_with(&format!("udp-gateway on {on} ")),
            "{head:?}"
        );
        let local = ask((std::net::Ipv4Addr::LOCALHOST, base).into());
        let remote = ask((ip, base).into());
        let (_, stderr) = gw.interrupt();
        match bind {
            None => {
                assert_eq!(local.as_deref(), Some("0"));
                assert_eq!(remote, None, "answered on {ip}");
                assert!(!stderr.contains("warning"), "{stderr}");
            }
            Some(_) => {
                assert_eq!(local, None, "bound to {ip} only");
                assert_eq!(remote.as_deref(), Some("0"));
                assert!(
                    stderr.contains("anyone who reaches this address can command the robot"),
                    "{stderr}"
                );
            }
        }
    }
}

//! Starting a supervised process: its command line (the executor's, a gateway's from the
//! manifest's typed options, the view's), what it inherits, and the threads that forward its
//! output and watch for its ready line.

use std::ffi::OsString;
use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Instant;

use conductor_manifest::{GatewayDef, GatewayKind, ScoreGatewayArgs, ViewDef};
use nix::sys::signal::Signal;

use super::readiness::{executor_ready, gateway_ready, Event, EventKind};
use super::{Phase, Role, Supervisor, TAIL_LINES};
use crate::launcher::{LaunchError, LaunchOptions};

/// The arguments of the view process (after [`LaunchOptions::view_args`]).
pub(super) fn view_args(v: &ViewDef, domain: &str) -> Vec<OsString> {
    let mut a: Vec<OsString> = vec![
        "--domain".into(),
        domain.into(),
        "--listen".into(),
        v.listen.to_string().into(),
    ];
    if v.clamp {
        a.push("--clamp".into());
    }
    a
}

/// The arguments of a gateway process (after [`LaunchOptions::gateway_args`]).
pub(super) fn gateway_args(g: &GatewayDef, domain: &str) -> Vec<OsString> {
    match g.kind {
        GatewayKind::Score => ScoreGatewayArgs::for_gateway(g, domain).to_args(),
        GatewayKind::Bridge => vec![
            "--manifest".into(),
            g.port.clone().into(),
            "--domain".into(),
            domain.into(),
        ],
    }
}

/// The program (and its leading arguments) that runs gateway `g`.
fn gateway_program<'a>(opts: &'a LaunchOptions, g: &GatewayDef) -> (&'a PathBuf, &'a [OsString]) {
    match g.kind {
        GatewayKind::Score => (&opts.gateway, &opts.gateway_args),
        GatewayKind::Bridge => (&opts.bridge, &opts.bridge_args),
    }
}

/// In a forked child before `exec`: marks every descriptor above stderr close-on-exec, so the
/// program inherits only stdin, stdout and stderr. The launcher's process holds descriptors that
/// were opened without `O_CLOEXEC` (iceoryx2's node and port files of the launcher's own bus, and
/// in a program that launches in-process, whatever that program has open); without this, each
/// executor started after them would carry them for its whole life. Marked rather than closed:
/// std reports a failed `exec` through a close-on-exec pipe of its own.
///
/// Only async-signal-safe system calls (close_range(2), else fcntl(2) on each descriptor).
fn inherit_only_stdio() {
    // SAFETY: close_range(2) takes three integers and touches no memory of this process.
    let marked = unsafe {
        libc::syscall(
            libc::SYS_close_range,
            3 as libc::c_uint,
            libc::c_uint::MAX,
            libc::CLOSE_RANGE_CLOEXEC,
        )
    } == 0;
    if marked {
        return;
    }
    // Kernels before 5.11 lack CLOSE_RANGE_CLOEXEC: every possible descriptor, one by one.
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit(2) writes the struct it is given, which lives on this stack.
    let max = if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } == 0 {
        limit.rlim_cur.min(1 << 20) as libc::c_int
    } else {
        1024
    };
    for fd in 3..max {
        // SAFETY: fcntl(2) on a descriptor number; one that is not open fails with EBADF.
        let flags = unsafe { libc::fcntl(fd, libc::F_GETFD) };
        if flags >= 0 && flags & libc::FD_CLOEXEC == 0 {
            // SAFETY: as above, on a descriptor that is open.
            unsafe { libc::fcntl(fd, libc::F_SETFD, flags | libc::FD_CLOEXEC) };
        }
    }
}

impl Supervisor {
    pub(super) fn spawn(&mut self, i: usize) -> Result<(), LaunchError> {
        let c = &mut self.children[i];
        c.generation += 1;
        let mut cmd = match &c.role {
            Role::Executor => {
                let mut cmd = Command::new(&self.opts.executor);
                cmd.args(&self.opts.executor_args)
                    .arg("--manifest")
                    .arg(&self.manifest)
                    .arg("--subsystem")
                    .arg(&c.subsystem)
                    .arg("--domain")
                    .arg(self.domain.name());
                if self.opts.no_rt {
                    cmd.arg("--no-rt");
                }
                cmd
            }
            Role::Gateway(g) => {
                let (program, args) = gateway_program(&self.opts, g);
                let mut cmd = Command::new(program);
                if self.opts.no_rt {
                    // No real-time set-up for any process of the launch.
                    let mut g = g.clone();
                    g.options.priority = None;
                    cmd.args(args).args(gateway_args(&g, self.domain.name()));
                } else {
                    cmd.args(args).args(gateway_args(g, self.domain.name()));
                }
                cmd
            }
            Role::View(v) => {
                let mut cmd = Command::new(&self.opts.view);
                cmd.args(&self.opts.view_args)
                    .args(view_args(v, self.domain.name()));
                cmd
            }
        };
        cmd.stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            // Its own process group: a terminal's Ctrl-C reaches only the launcher, which
            // forwards it once.
            .process_group(0);
        let gateway = c.role.auxiliary();
        // SAFETY: the closure runs in the forked child before exec and only makes the
        // async-signal-safe sigprocmask(2), close_range(2)/fcntl(2) and prctl(2) system calls.
        unsafe {
            cmd.pre_exec(move || {
                if gateway {
                    // A launcher that takes SIGINT/SIGTERM with sigwait has them blocked, and the
                    // mask survives exec. An executor takes them the same way (so one arriving
                    // while it starts waits for it); a gateway has ordinary handlers, which a
                    // blocked signal would never reach.
                    nix::sys::signal::pthread_sigmask(
                        nix::sys::signal::SigmaskHow::SIG_SETMASK,
                        Some(&nix::sys::signal::SigSet::empty()),
                        None,
                    )
                    .map_err(std::io::Error::from)?;
                }
                inherit_only_stdio();
                // The child stops (orderly) if the launcher dies.
                nix::sys::prctl::set_pdeathsig(Signal::SIGTERM).map_err(std::io::Error::from)
            });
        }
        let mut child = cmd.spawn().map_err(|source| match &c.role {
            Role::Executor => LaunchError::Spawn {
                subsystem: c.subsystem.clone(),
                program: self.opts.executor.clone(),
                source,
            },
            Role::Gateway(g) => LaunchError::SpawnGateway {
                gateway: c.subsystem.clone(),
                program: gateway_program(&self.opts, g).0.clone(),
                source,
            },
            Role::View(_) => LaunchError::SpawnView {
                program: self.opts.view.clone(),
                source,
            },
        })?;
        let stdout = child.stdout.take().expect("piped");
        let stderr = child.stderr.take().expect("piped");
        let (tx, generation) = (self.events.0.clone(), c.generation);
        let ready_line = match c.role {
            Role::Executor => executor_ready,
            // `ready view ws://…`, like a gateway's `ready <name> …`.
            Role::Gateway(_) | Role::View(_) => gateway_ready,
        };
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if let Some(what) = ready_line(&line) {
                    let _ = tx.send(Event {
                        child: i,
                        generation,
                        kind: EventKind::Ready(what),
                    });
                }
            }
        });
        let tail = c.tail.clone();
        if let Ok(mut t) = c.tail.lock() {
            t.clear();
        }
        c.output = Some(std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                note!("{line}");
                if let Ok(mut t) = tail.lock() {
                    if t.len() == TAIL_LINES {
                        t.pop_front();
                    }
                    t.push_back(line);
                }
            }
        }));
        let pid = child.id();
        c.proc = Some(child);
        c.phase = Phase::Starting {
            since: Instant::now(),
        };
        match &c.role {
            Role::Gateway(g) if g.kind == GatewayKind::Bridge => {
                note!(
                    "conductor: bridge started (pid {pid}) for {}",
                    g.port.display()
                )
            }
            Role::Gateway(g) => note!(
                "conductor: gateway {} started (pid {pid}), waiting for its board on {}",
                c.subsystem,
                g.port.display()
            ),
            Role::Executor | Role::View(_) => {}
        }
        self.set_info(i, Some(pid), false);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use conductor_manifest::GatewayOptions;

    fn def() -> GatewayDef {
        GatewayDef {
            name: "board".into(),
            kind: GatewayKind::Score,
            port: "/dev/score-link".into(),
            options: GatewayOptions::default(),
        }
    }

    fn strings(a: Vec<OsString>) -> Vec<String> {
        a.into_iter().map(|s| s.into_string().unwrap()).collect()
    }

    #[test]
    fn gateway_arguments_carry_only_what_the_manifest_sets() {
        assert_eq!(
            strings(gateway_args(&def(), "d1")),
            [
                "--port",
                "/dev/score-link",
                "--subsystem",
                "board",
                "--domain",
                "d1"
            ]
        );
        let g = GatewayDef {
            options: GatewayOptions {
                max_rate_hz: Some(500.0),
                lazy_rate_hz: Some(2.5),
                restore: false,
                retry_ms: Some(50),
                watchdog_ms: Some(250),
                priority: Some(70),
            },
            ..def()
        };
        assert_eq!(
            strings(gateway_args(&g, "d1"))[6..],
            [
                "--max-rate",
                "500",
                "--lazy-rate",
                "2.5",
                "--no-restore",
                "--retry-ms",
                "50",
                "--watchdog-ms",
                "250",
                "--priority",
                "70"
            ]
        );
    }

    #[test]
    fn view_arguments() {
        let v = ViewDef::default();
        assert_eq!(
            strings(view_args(&v, "d1")),
            ["--domain", "d1", "--listen", "127.0.0.1:8765"]
        );
        let v = ViewDef {
            listen: "0.0.0.0:9000".parse().unwrap(),
            clamp: true,
        };
        assert_eq!(
            strings(view_args(&v, "d1"))[3..],
            ["0.0.0.0:9000", "--clamp"]
        );
        assert_eq!(
            gateway_ready("ready view ws://127.0.0.1:8765").as_deref(),
            Some("ws://127.0.0.1:8765")
        );
    }
}

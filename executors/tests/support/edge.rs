//! The hardware-edge tests' rig: a shipped manifest pointed at a simulator's pseudo-terminal, an
//! executor process whose stderr is collected, and helpers to read states and send frames.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use conductor_bus::{Bus, Controller, Domain, StateSample, StateSubscriber};

use super::EXECUTOR;

/// The workspace root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("executors/ sits in the workspace")
        .to_path_buf()
}

/// A shipped manifest from deploy/, with `replace` applied (each `from` must occur), written to
/// a temporary file.
pub fn shipped(name: &str, replace: &[(&str, &str)]) -> PathBuf {
    let mut text = std::fs::read_to_string(root().join("deploy").join(name)).unwrap();
    for (from, to) in replace {
        assert!(text.contains(from), "{name} has no {from:?}");
        text = text.replace(from, to);
    }
    super::temp_manifest(name.trim_end_matches(".toml"), &text)
}

/// An executor process; SIGTERM and wait when dropped.
pub struct Exec {
    child: Child,
    lines: Arc<Mutex<Vec<String>>>,
    /// The stderr reader: it ends at the executor's exit (end of file).
    reader: Option<std::thread::JoinHandle<()>>,
    status: Option<ExitStatus>,
}

impl Exec {
    /// Starts `conductor-executor` for `subsystem` of `manifest` in `domain` (normal
    /// scheduling: these tests are about behaviour) and waits for READY, or for its exit.
    pub fn start(
        manifest: &Path,
        subsystem: &str,
        domain: &Domain,
    ) -> Result<Exec, (ExitStatus, Vec<String>)> {
        let mut child = Command::new(EXECUTOR)
            .arg("--manifest")
            .arg(manifest)
            .args([
                "--subsystem",
                subsystem,
                "--domain",
                domain.name(),
                "--no-rt",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let lines = Arc::new(Mutex::new(Vec::new()));
        let err = BufReader::new(child.stderr.take().unwrap());
        let l2 = lines.clone();
        let reader = std::thread::spawn(move || {
            for line in err.lines().map_while(Result::ok) {
                eprintln!("{line}");
                l2.lock().unwrap().push(line);
            }
        });
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        loop {
            line.clear();
            if out.read_line(&mut line).unwrap_or(0) == 0 {
                let status = child.wait().unwrap();
                let _ = reader.join();
                let log = lines.lock().unwrap().clone();
                return Err((status, log));
            }
            if line.contains("READY") {
                break;
            }
        }
        Ok(Exec {
            child,
            lines,
            reader: Some(reader),
            status: None,
        })
    }

    /// Its process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// SIGTERM, then the exit status.
    pub fn stop(&mut self) -> ExitStatus {
        if let Some(s) = self.status {
            return s;
        }
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.child.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        let s = self.child.wait().unwrap();
        // Every line it wrote: the reader ends at end of file.
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
        self.status = Some(s);
        s
    }

    /// SIGTERM; it must exit with success (every safe action confirmed). Returns its log.
    pub fn stop_ok(&mut self) -> Vec<String> {
        let status = self.stop();
        let log = self.log();
        assert!(status.success(), "{status}: {log:#?}");
        log
    }

    /// SIGTERM; it must exit with success, saying that `n` devices were confirmed in their
    /// safe state on the wire.
    pub fn stop_confirmed(&mut self, n: usize) {
        let log = self.stop_ok();
        let want = format!("devices in their safe state ({n} confirmed on the wire)");
        assert!(
            log.iter().any(|l| l.contains(&want)),
            "no {want:?}: {log:#?}"
        );
    }

    /// Every stderr line so far.
    pub fn log(&self) -> Vec<String> {
        self.lines.lock().unwrap().clone()
    }

    /// Waits until a stderr line contains `text`.
    pub fn wait_log(&self, secs: u64, text: &str) -> String {
        let end = Instant::now() + Duration::from_secs(secs);
        loop {
            if let Some(l) = self.log().into_iter().find(|l| l.contains(text)) {
                return l;
            }
            assert!(
                Instant::now() < end,
                "no log line with {text:?} within {secs} s: {:#?}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Exec {
    fn drop(&mut self) {
        self.stop();
    }
}

/// A state's subscriber with its newest sample.
pub struct Watch {
    pub sub: StateSubscriber,
    pub last: Option<StateSample>,
    pub all: Vec<StateSample>,
}

impl Watch {
    /// The samples recorded from index `from` on that are not STALE.
    pub fn fresh_from(&self, from: usize) -> Vec<StateSample> {
        self.all[from..]
            .iter()
            .filter(|s| s.status & conductor_bus::status::STALE == 0)
            .copied()
            .collect()
    }

    pub fn new(bus: &Bus, name: &str) -> Watch {
        Watch {
            sub: StateSubscriber::with_buffer(bus, name, 1024).unwrap(),
            last: None,
            all: Vec::new(),
        }
    }

    /// Takes what arrived; returns the newest.
    pub fn poll(&mut self) -> Option<StateSample> {
        while let Some(s) = self.sub.receive().unwrap() {
            self.all.push(s);
            self.last = Some(s);
        }
        self.last
    }

    /// Waits (up to `secs`) for a sample accepted by `pred`, polling every 2 ms.
    pub fn until(
        &mut self,
        secs: f64,
        what: &str,
        pred: impl Fn(&StateSample) -> bool,
    ) -> StateSample {
        let end = Instant::now() + Duration::from_secs_f64(secs);
        loop {
            while let Some(s) = self.sub.receive().unwrap() {
                self.all.push(s);
                self.last = Some(s);
                if pred(&s) {
                    return s;
                }
            }
            assert!(
                Instant::now() < end,
                "{what}: not within {secs} s; last {:?}",
                self.last
            );
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// Sends one frame of `(state, value)` setpoints.
pub fn send(ctl: &mut Controller, setpoints: &[(&str, f64)]) {
    for (n, v) in setpoints {
        ctl.add_ctrl(n, *v).unwrap();
    }
    ctl.send_ctrl().unwrap();
}

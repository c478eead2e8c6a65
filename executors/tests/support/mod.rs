//! Helpers for the process tests: launch options pointing at this build's executor, temporary
//! manifests, a background recorder of state samples, and the domain's leftovers on disk.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use conductor_bus::{monotonic_ns, Bus, Domain, StateSample, StateSubscriber};
use conductor_executor::launcher::LaunchOptions;

pub mod edge;

pub const EXECUTOR: &str = env!("CARGO_BIN_EXE_conductor-executor");
pub const LAUNCHER: &str = env!("CARGO_BIN_EXE_conductor-launch");

/// Options for an in-process launch in `domain`: this build's executor, no signal handling
/// (the test harness owns the process), no summary.
pub fn options(domain: &Domain) -> LaunchOptions {
    LaunchOptions {
        executor: EXECUTOR.into(),
        domain: Some(domain.name().into()),
        quiet: true,
        handle_signals: false,
        ..LaunchOptions::default()
    }
}

pub fn test_manifest(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/manifests")
        .join(name)
}

/// Writes `text` to a fresh file in the temporary directory.
pub fn temp_manifest(tag: &str, text: &str) -> PathBuf {
    static N: AtomicU32 = AtomicU32::new(0);
    let path = std::env::temp_dir().join(format!(
        "conductor-test-{tag}-{}-{}.toml",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    std::fs::write(&path, text).unwrap();
    path
}

/// Polls `f` until it returns Some, or panics after `secs`.
pub fn eventually<T>(secs: u64, what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let end = Instant::now() + Duration::from_secs(secs);
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(Instant::now() < end, "{what}: not within {secs} s");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Everything a subscriber saw of one state.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    pub samples: Vec<StateSample>,
    pub missed: u64,
    pub restarts: u64,
}

/// Subscribes to states on its own thread (bus handles are per thread) and records every sample
/// until stopped.
pub struct Recorder {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Vec<Recording>>>,
}

impl Recorder {
    pub fn start(domain: &Domain, states: &[&str]) -> Recorder {
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = mpsc::channel();
        let names: Vec<String> = states.iter().map(|s| s.to_string()).collect();
        let (d, s) = (domain.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            let bus = Bus::open(&d, "test-recorder").unwrap();
            let mut subs: Vec<StateSubscriber> = names
                .iter()
                .map(|n| StateSubscriber::with_buffer(&bus, n, 256).unwrap())
                .collect();
            let mut recs = vec![Recording::default(); subs.len()];
            ready_tx.send(()).unwrap();
            loop {
                let last = s.load(Ordering::Relaxed);
                for (sub, rec) in subs.iter_mut().zip(&mut recs) {
                    while let Some(x) = sub.receive().unwrap() {
                        rec.samples.push(x);
                    }
                    rec.missed = sub.missed();
                    rec.restarts = sub.restarts();
                }
                if last {
                    return recs;
                }
                std::thread::sleep(Duration::from_millis(1));
            }
        });
        ready_rx.recv().unwrap();
        Recorder {
            stop,
            thread: Some(thread),
        }
    }

    pub fn finish(mut self) -> Vec<Recording> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().unwrap().join().unwrap()
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// What of the domain is left on disk: shared-memory files and node records.
pub fn leftovers(domain: &Domain) -> (Vec<String>, Vec<String>) {
    let prefix = domain.prefix();
    let shm: Vec<String> = std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(&prefix))
                .collect()
        })
        .unwrap_or_default();
    let mut records = Vec::new();
    let root = PathBuf::from(domain.root_path());
    let mut stack = vec![root];
    while let Some(dir) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&dir) else {
            continue;
        };
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                records.push(p.display().to_string());
            }
        }
    }
    (shm, records)
}

/// Whether a process exists.
pub fn alive(pid: u32) -> bool {
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid as i32), None).is_ok()
}

pub fn now_ns() -> u64 {
    monotonic_ns()
}

/// Removes a private test domain's last files when dropped (after everything in it stopped):
/// iceoryx2's per-domain node counter in /dev/shm and the empty record directories.
pub struct DomainGuard(pub Domain);

impl Drop for DomainGuard {
    fn drop(&mut self) {
        let Ok(scan) = conductor_executor::cleanup::scan_and_clean(&self.0) else {
            return;
        };
        if !scan.alive.is_empty() {
            return;
        }
        // SAFETY: the domain is private to this test (`Domain::unique`) and no process of it is
        // alive, which is the precondition of removing its node counter.
        let _ = unsafe {
            iceoryx2::testing::remove_global_mgmt_segment::<conductor_bus::RtIpc>(
                self.0.iceoryx2_config(),
            )
        };
        let _ = std::fs::remove_dir_all(self.0.root_path());
    }
}

/// A fresh private domain, cleaned up when the guard drops.
pub fn private_domain(tag: &str) -> (Domain, DomainGuard) {
    let d = Domain::unique(tag).unwrap();
    (d.clone(), DomainGuard(d))
}

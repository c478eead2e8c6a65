//! Which CPUs the bridge runs on.
//!
//! An executor sleeps on its own CPU between ticks and wakes the exporting bridge when it
//! publishes. Left free to run anywhere, the bridge is often woken onto the executor's CPU and
//! waits there until the executor sleeps again (measured in benches/README.md, "The bridge
//! off the executor's CPU"). So the bridge keeps off the CPUs the manifest pins executors to,
//! or runs where `cpus` says.

use nix::sched::{sched_setaffinity, CpuSet};
use nix::unistd::Pid;

use crate::config::BridgeConfig;
use crate::error::{BridgeError, Result};

/// Moves every thread of this process (and so every thread it starts later, Zenoh's included)
/// to the CPUs `cfg` asks for. Returns what was done, for the log; `None` when nothing was
/// asked (no `cpus`, and no executor CPU to keep off, or none left to run on without them).
pub fn place(cfg: &BridgeConfig) -> Result<Option<String>> {
    let fail = |what: String| BridgeError::Config(what);
    let usable = conductor_bus::rt::usable_cpus();
    let (chosen, why) = match &cfg.cpus {
        Some(cpus) => {
            if let Some(bad) = cpus.iter().find(|c| !usable.contains(c)) {
                return Err(fail(format!(
                    "cpus: CPU {bad} is not available to this process (it may use {})",
                    list(&usable)
                )));
            }
            (cpus.clone(), "as configured".to_string())
        }
        None => {
            let rest: Vec<usize> = usable
                .iter()
                .copied()
                .filter(|c| !cfg.executor_cpus.contains(c))
                .collect();
            if rest.is_empty() || rest.len() == usable.len() {
                return Ok(None);
            }
            let kept: Vec<usize> = usable
                .iter()
                .copied()
                .filter(|c| cfg.executor_cpus.contains(c))
                .collect();
            (rest, format!("off the executors' CPU(s) {}", list(&kept)))
        }
    };
    let mut set = CpuSet::new();
    for &c in &chosen {
        set.set(c)
            .map_err(|e| fail(format!("cpus: CPU {c}: {e}")))?;
    }
    // Each thread has its own mask: set it on every thread already running (the caller's, and
    // any a library started); threads started later inherit it.
    let tasks = std::fs::read_dir("/proc/self/task")
        .map_err(|e| fail(format!("cannot list this process's threads: {e}")))?;
    for t in tasks.flatten() {
        let Some(tid) = t.file_name().to_str().and_then(|s| s.parse::<i32>().ok()) else {
            continue;
        };
        match sched_setaffinity(Pid::from_raw(tid), &set) {
            // A thread that ended since the listing is no longer in the way.
            Ok(()) | Err(nix::errno::Errno::ESRCH) => {}
            Err(e) => {
                return Err(fail(format!(
                    "cannot move the bridge to CPU(s) {}: {e}",
                    list(&chosen)
                )))
            }
        }
    }
    Ok(Some(format!("running on CPU(s) {} ({why})", list(&chosen))))
}

fn list(cpus: &[usize]) -> String {
    cpus.iter()
        .map(|c| c.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

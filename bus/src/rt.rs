//! Real-time set-up of a thread (an executor's tick loop, a gateway's link loop): CPU
//! affinity, locked memory, pre-faulted stack, SCHED_FIFO priority. Each step that is not
//! permitted yields a [`RtProblem`] that says how to grant it; the caller warns and carries on,
//! or refuses to run when real time is required.

use std::fmt;

use nix::sys::mman::{mlockall, MlockAllFlags};
use nix::sys::resource::{getrlimit, Resource, RLIM_INFINITY};

/// What real-time set-up to attempt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RtRequest {
    /// SCHED_FIFO priority (1–99); `None` leaves normal scheduling.
    pub priority: Option<i32>,
    /// CPU to pin to.
    pub cpu: Option<usize>,
    /// Lock all current and future memory.
    pub lock_memory: bool,
}

/// One step that could not be done, with the fix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RtProblem {
    /// What failed.
    pub what: String,
    /// How to make it work.
    pub fix: String,
}

impl fmt::Display for RtProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}; {}", self.what, self.fix)
    }
}

/// What the set-up achieved.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RtStatus {
    /// The thread runs SCHED_FIFO.
    pub fifo: bool,
    /// The priority in effect (when `fifo`).
    pub priority: i32,
    /// The CPU the thread is pinned to.
    pub cpu: Option<usize>,
    /// Memory is locked.
    pub memory_locked: bool,
    /// The CPUs are asked to stay out of deep idle states (`/dev/cpu_dma_latency` held at 0).
    pub wakeup_latency_held: bool,
    /// Steps that failed.
    pub problems: Vec<RtProblem>,
}

impl RtStatus {
    /// One line for the log: `SCHED_FIFO 80 on CPU 1, memory locked`.
    pub fn summary(&self) -> String {
        let sched = if self.fifo {
            format!("SCHED_FIFO {}", self.priority)
        } else {
            "normal scheduling".into()
        };
        let cpu = self
            .cpu
            .map_or_else(|| "any CPU".to_string(), |c| format!("CPU {c}"));
        let mem = if self.memory_locked {
            "memory locked"
        } else {
            "memory not locked"
        };
        let idle = if self.wakeup_latency_held {
            ", deep idle states off"
        } else {
            ""
        };
        format!("{sched} on {cpu}, {mem}{idle}")
    }
}

/// The open `/dev/cpu_dma_latency`: the kernel honours the request only while it stays open,
/// so it lives as long as the process.
static WAKEUP_LATENCY: std::sync::OnceLock<std::fs::File> = std::sync::OnceLock::new();

/// Asks the kernel's PM QoS to keep every CPU out of idle states whose exit latency exceeds
/// `max_us` (0: no deep C-states), as cyclictest does: leaving a deep C-state can add tens to
/// hundreds of µs to a wake-up. Held until the process exits.
pub fn hold_wakeup_latency(max_us: i32) -> Result<(), RtProblem> {
    use std::io::Write;
    if WAKEUP_LATENCY.get().is_some() {
        return Ok(());
    }
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/cpu_dma_latency")
        .map_err(|e| RtProblem {
            what: format!("cannot open /dev/cpu_dma_latency ({e})"),
            fix: "run as root or grant write access to /dev/cpu_dma_latency (udev rule), or \
                  disable deep C-states on the kernel command line (processor.max_cstate=1)"
                .into(),
        })?;
    f.write_all(&max_us.to_ne_bytes()).map_err(|e| RtProblem {
        what: format!("writing /dev/cpu_dma_latency failed ({e})"),
        fix: "check the kernel's PM QoS support".into(),
    })?;
    let _ = WAKEUP_LATENCY.set(f);
    Ok(())
}

/// The CPUs the calling thread may run on, in order.
pub fn usable_cpus() -> Vec<usize> {
    let mut ids: Vec<usize> = core_affinity::get_core_ids()
        .unwrap_or_default()
        .iter()
        .map(|c| c.id)
        .collect();
    ids.sort_unstable();
    ids
}

/// Pins the calling thread to `cpu`.
pub fn pin_to_cpu(cpu: usize) -> Result<(), RtProblem> {
    let ids = core_affinity::get_core_ids().unwrap_or_default();
    let Some(id) = ids.iter().find(|c| c.id == cpu) else {
        let avail: Vec<String> = ids.iter().map(|c| c.id.to_string()).collect();
        return Err(RtProblem {
            what: format!("cannot pin to CPU {cpu}: it is not available to this process"),
            fix: format!(
                "choose one of the CPUs this process may use ({}) in the manifest's `cpu`",
                avail.join(", ")
            ),
        });
    };
    if core_affinity::set_for_current(*id) {
        Ok(())
    } else {
        Err(RtProblem {
            what: format!("cannot pin to CPU {cpu}: sched_setaffinity failed"),
            fix: "check the process's CPU set (taskset, cgroup cpuset)".into(),
        })
    }
}

/// Keeps the calling thread, and the threads it starts, off `cpu`: what the rest of a robot
/// computer does when its real-time CPU is isolated (the stress test's logger and probe).
/// Nothing changes when `cpu` is the only CPU the thread may use.
pub fn avoid_cpu(cpu: usize) -> Result<(), RtProblem> {
    use nix::sched::{sched_getaffinity, sched_setaffinity, CpuSet};
    use nix::unistd::Pid;
    let fail = |e: nix::Error| RtProblem {
        what: format!("cannot keep off CPU {cpu}: sched_setaffinity failed ({e})"),
        fix: "check the process's CPU set (taskset, cgroup cpuset)".into(),
    };
    let mut set = sched_getaffinity(Pid::from_raw(0)).map_err(fail)?;
    let others = (0..CpuSet::count())
        .filter(|&c| c != cpu && set.is_set(c).unwrap_or(false))
        .count();
    if others == 0 {
        return Ok(());
    }
    set.unset(cpu).map_err(fail)?;
    sched_setaffinity(Pid::from_raw(0), &set).map_err(fail)
}

/// Locks all current and future pages in RAM (so the loop never takes a page fault), when the
/// memory-lock limit allows it.
pub fn lock_memory() -> Result<(), RtProblem> {
    // With MCL_FUTURE, every later allocation counts against RLIMIT_MEMLOCK: under a finite
    // limit and without CAP_IPC_LOCK, a later allocation could fail. Only lock when unlimited.
    let (soft, _) = getrlimit(Resource::RLIMIT_MEMLOCK).unwrap_or((0, 0));
    let root = nix::unistd::geteuid().is_root();
    if soft != RLIM_INFINITY && !root {
        return Err(RtProblem {
            what: format!("memory not locked: RLIMIT_MEMLOCK is {soft} bytes"),
            fix: "raise it (`ulimit -l unlimited`, LimitMEMLOCK=infinity in a systemd unit, or \
                  `@realtime - memlock unlimited` in /etc/security/limits.conf) or grant \
                  CAP_IPC_LOCK"
                .into(),
        });
    }
    mlockall(MlockAllFlags::MCL_CURRENT | MlockAllFlags::MCL_FUTURE).map_err(|e| RtProblem {
        what: format!("mlockall failed: {e}"),
        fix: "grant CAP_IPC_LOCK or raise RLIMIT_MEMLOCK (`ulimit -l unlimited`)".into(),
    })
}

/// Touches `bytes` of stack below the caller so the loop never faults a stack page in.
#[inline(never)]
pub fn prefault_stack(bytes: usize) {
    const CHUNK: usize = 64 * 1024;
    fn touch(depth: usize) {
        let mut buf = [0u8; CHUNK];
        // Volatile writes: the pages are really touched, not optimised away.
        for i in (0..CHUNK).step_by(4096) {
            // SAFETY: `i < CHUNK`, so the pointer is inside `buf`.
            unsafe { core::ptr::write_volatile(buf.as_mut_ptr().add(i), 1) };
        }
        if depth > 1 {
            touch(depth - 1);
        }
        std::hint::black_box(&buf);
    }
    touch(bytes.div_ceil(CHUNK).max(1));
}

/// Switches the calling thread to SCHED_FIFO at `priority`.
pub fn set_fifo(priority: i32) -> Result<(), RtProblem> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pthread_self() is the calling thread; `param` is a valid sched_param for the call.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        return Ok(());
    }
    let (rtprio, _) = getrlimit(Resource::RLIMIT_RTPRIO).unwrap_or((0, 0));
    Err(RtProblem {
        what: format!(
            "cannot use SCHED_FIFO priority {priority}: {} (RLIMIT_RTPRIO is {})",
            nix::errno::Errno::from_raw(rc).desc(),
            if rtprio == RLIM_INFINITY {
                "unlimited".to_string()
            } else {
                rtprio.to_string()
            }
        ),
        fix: "grant it: run as root, `sudo setcap cap_sys_nice,cap_ipc_lock+ep \
              $(which conductor-executor)`, or raise the real-time priority limit (`ulimit -r 99`, \
              LimitRTPRIO=99 in a systemd unit, `@realtime - rtprio 99` in \
              /etc/security/limits.conf); see deploy/ for the RT tuning guide"
            .into(),
    })
}

/// Runs the requested set-up steps in order (affinity, memory lock, stack, priority) and reports
/// what took effect. Call it on the real-time thread, after building everything it will use.
pub fn setup(req: RtRequest) -> RtStatus {
    let mut st = RtStatus::default();
    if let Some(cpu) = req.cpu {
        match pin_to_cpu(cpu) {
            Ok(()) => st.cpu = Some(cpu),
            Err(p) => st.problems.push(p),
        }
    }
    if req.lock_memory {
        match lock_memory() {
            Ok(()) => st.memory_locked = true,
            Err(p) => st.problems.push(p),
        }
    }
    prefault_stack(256 * 1024);
    if let Some(prio) = req.priority {
        match set_fifo(prio) {
            Ok(()) => {
                st.fifo = true;
                st.priority = prio;
            }
            Err(p) => st.problems.push(p),
        }
        // Only worth holding for a real-time executor; not being allowed to is not fatal.
        st.wakeup_latency_held = hold_wakeup_latency(0).is_ok();
    }
    st
}

#[cfg(test)]
mod tests {

    #[test]
    fn avoid_cpu_leaves_the_cpu_out_of_the_threads_set() {
        use nix::sched::sched_getaffinity;
        use nix::unistd::Pid;
        let cpus = |set: nix::sched::CpuSet| -> Vec<usize> {
            (0..nix::sched::CpuSet::count())
                .filter(|&c| set.is_set(c).unwrap())
                .collect()
        };
        // In a thread of its own: affinity is per thread.
        std::thread::spawn(move || {
            let before = cpus(sched_getaffinity(Pid::from_raw(0)).unwrap());
            let first = before[0];
            avoid_cpu(first).unwrap();
            let after = cpus(sched_getaffinity(Pid::from_raw(0)).unwrap());
            if before.len() > 1 {
                let want: Vec<usize> = before.iter().copied().filter(|&c| c != first).collect();
                assert_eq!(after, want);
            } else {
                assert_eq!(after, before, "the only CPU stays");
            }
        })
        .join()
        .unwrap();
    }

    use super::*;

    #[test]
    fn pinning_to_a_missing_cpu_says_which_exist() {
        let e = pin_to_cpu(100_000).unwrap_err();
        assert!(e.what.contains("CPU 100000"), "{e}");
        assert!(e.fix.contains("choose one of"), "{e}");
    }

    #[test]
    fn an_invalid_priority_is_refused_with_the_fix() {
        // 0 is never a valid SCHED_FIFO priority, privileged or not.
        let e = set_fifo(0).unwrap_err();
        assert!(e.what.contains("SCHED_FIFO priority 0"), "{e}");
        assert!(e.fix.contains("rtprio"), "{e}");
    }

    #[test]
    fn wakeup_latency_is_held_or_refused_with_the_fix() {
        match hold_wakeup_latency(0) {
            Ok(()) => {
                // While our fd is open the kernel's effective request is ours: 0 µs.
                let v = std::fs::read("/dev/cpu_dma_latency").unwrap();
                assert_eq!(i32::from_ne_bytes(v[..4].try_into().unwrap()), 0);
            }
            Err(e) => assert!(e.what.contains("/dev/cpu_dma_latency"), "{e}"),
        }
    }

    #[test]
    fn summary_reads_well() {
        let s = RtStatus {
            fifo: true,
            priority: 80,
            cpu: Some(1),
            memory_locked: true,
            wakeup_latency_held: true,
            problems: vec![],
        };
        assert_eq!(
            s.summary(),
            "SCHED_FIFO 80 on CPU 1, memory locked, deep idle states off"
        );
        assert_eq!(
            RtStatus::default().summary(),
            "normal scheduling on any CPU, memory not locked"
        );
    }
}

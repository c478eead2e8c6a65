//! What the figures depend on: the kernel, its preemption model, the CPUs and the load, read
//! from /proc and /sys at the time of the run.

use serde::Serialize;

/// Facts about the machine a run was made on.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Machine {
    /// `uname -r`.
    pub kernel: String,
    /// `uname -v` (holds `PREEMPT_RT` / `PREEMPT_DYNAMIC`).
    pub kernel_version: String,
    /// `/sys/kernel/realtime` reads 1 (a PREEMPT_RT kernel).
    pub preempt_rt: bool,
    /// CPUs online.
    pub cpus: usize,
    /// The kernel command line (isolcpus, nohz_full, ...).
    pub cmdline: String,
    /// 1-minute load average when the run started.
    pub load_start: f64,
    /// 1-minute load average when it ended.
    pub load_end: f64,
}

fn read(path: &str) -> String {
    std::fs::read_to_string(path)
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

/// The 1-minute load average (0 when unreadable).
pub fn load_average() -> f64 {
    read("/proc/loadavg")
        .split_whitespace()
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.0)
}

impl Machine {
    /// One line for a report: kernel, CPUs, PREEMPT_RT or not, and the load average at the
    /// start and the end of the run (no final period).
    pub fn summary(&self) -> String {
        format!(
            "Linux {} ({}), {} CPUs, {}; load average {:.2} at the start, {:.2} at the end",
            self.kernel,
            self.kernel_version,
            self.cpus,
            if self.preempt_rt {
                "PREEMPT_RT"
            } else {
                "not PREEMPT_RT"
            },
            self.load_start,
            self.load_end
        )
    }

    /// Reads the facts now (`load_end` is set by the caller at the end).
    pub fn now() -> Self {
        let version = read("/proc/sys/kernel/version");
        Self {
            kernel: read("/proc/sys/kernel/osrelease"),
            preempt_rt: read("/sys/kernel/realtime") == "1" || version.contains("PREEMPT_RT"),
            kernel_version: version,
            cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
            cmdline: read("/proc/cmdline"),
            load_start: load_average(),
            load_end: 0.0,
        }
    }
}

/// `YYYY-MM-DD HH:MM:SS UTC` of the system clock.
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    utc(secs)
}

/// Formats seconds since the Unix epoch as `YYYY-MM-DD HH:MM:SS UTC`.
pub fn utc(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let tod = secs % 86_400;
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm, proleptic Gregorian).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02} UTC",
        tod / 3600,
        tod % 3600 / 60,
        tod % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_dates() {
        assert_eq!(utc(0), "1970-01-01 00:00:00 UTC");
        // 2000-02-29 (a leap day of a century leap year) 12:34:56.
        assert_eq!(utc(951_827_696), "2000-02-29 12:34:56 UTC");
        assert_eq!(utc(4_102_444_799), "2099-12-31 23:59:59 UTC");
    }

    #[test]
    fn machine_facts_are_read() {
        let m = Machine::now();
        assert!(m.cpus >= 1);
        assert!(!m.kernel.is_empty(), "{m:?}");
    }
}

//! What a process holds, from /proc, and what a domain left in shared memory.

use std::path::Path;

/// Resident set size (KiB) and open file descriptors of `pid`, if it exists.
pub fn usage(pid: u32) -> Option<(u64, u64)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let rss = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())?;
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count() as u64;
    Some((rss, fds))
}

/// Entries of the domain: its files in /dev/shm (iceoryx2's segments, prefixed `cdr_<domain>_`)
/// and under its root directory (`/tmp/conductor/<domain>/`, node and service records).
pub fn shm_entries(prefix: &str, root: &str) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with(prefix))
                .map(|n| format!("/dev/shm/{n}"))
                .collect()
        })
        .unwrap_or_default();
    files(Path::new(root), &mut names);
    names.sort();
    names
}

fn files(dir: &Path, out: &mut Vec<String>) {
    let Ok(d) = std::fs::read_dir(dir) else {
        return;
    };
    for e in d.filter_map(Result::ok) {
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            files(&e.path(), out);
        } else {
            out.push(e.path().display().to_string());
        }
    }
}

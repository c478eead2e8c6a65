//! `deploy/rt-check` runs on this machine, reports every check, and changes nothing.

use std::path::PathBuf;
use std::process::Command;

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../deploy/rt-check")
}

/// Every setting rt-check could change with --apply, read before and after.
fn snapshot() -> Vec<(String, String)> {
    let mut files: Vec<String> = vec![
        "/sys/kernel/mm/transparent_hugepage/enabled".into(),
        "/proc/sys/kernel/sched_rt_runtime_us".into(),
        "/proc/irq/default_smp_affinity".into(),
    ];
    if let Ok(dir) = std::fs::read_dir("/sys/devices/system/cpu") {
        for e in dir.flatten() {
            let gov = e.path().join("cpufreq/scaling_governor");
            if gov.exists() {
                files.push(gov.display().to_string());
            }
        }
    }
    files
        .into_iter()
        .map(|f| {
            let v = std::fs::read_to_string(&f).unwrap_or_default();
            (f, v)
        })
        .collect()
}

#[test]
fn reports_every_check_and_changes_nothing() {
    let before = snapshot();
    let out = Command::new("bash").arg(script()).output().unwrap();
    let after = snapshot();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "rt-check failed: {text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for check in [
        "preemption",
        "isolcpus",
        "nohz_full",
        "irqbalance",
        "irq-affinity",
        "rt_runtime",
        "governor",
        "thp",
        "memlock",
        "rtprio",
        "dev-shm",
        "swap",
    ] {
        let line = text
            .lines()
            .find(|l| l.split_whitespace().nth(1) == Some(check))
            .unwrap_or_else(|| panic!("no {check} line in:\n{text}"));
        let level = line.split_whitespace().next().unwrap();
        assert!(["OK", "WARN", "INFO"].contains(&level), "{line}");
    }
    assert_eq!(before, after, "rt-check changed a setting without --apply");
    let warns = text.lines().filter(|l| l.starts_with("WARN")).count();
    if warns > 0 {
        assert!(text.contains(&format!("{warns} warning(s). Nothing was changed.")));
    } else {
        assert!(text.contains("Ready for real time."));
    }

    // --strict turns warnings into a failing exit code, for provisioning scripts.
    let strict = Command::new("bash")
        .arg(script())
        .arg("--strict")
        .status()
        .unwrap();
    assert_eq!(strict.success(), warns == 0);
}

#[test]
fn rejects_unknown_options() {
    let out = Command::new("bash")
        .arg(script())
        .arg("--frobnicate")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown option --frobnicate"));
}

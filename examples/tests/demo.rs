//! The demo end to end: the simulated mini-Hubo leg launched as a real executor process, the
//! PID controller in the demo process, tracking errors against the linear theory.

use std::process::Command;

use conductor_bus::{Domain, RtIpc};
use conductor_examples::minihubo::{error_ratio, gait_rms, GAINS};
use iceoryx2::testing::remove_global_mgmt_segment;

#[test]
fn the_leg_tracks_the_gait_and_the_pid_beats_the_open_loop_as_predicted() {
    let d = Domain::unique("demo").unwrap();
    // 6 s of tracking: 3 s per phase, of which the last 2 s (one whole gait cycle, so the RMS
    // of each joint's sinusoidal error is exact) are measured.
    let out = conductor_testkit::run_ok(Command::new(env!("CARGO_BIN_EXE_conductor-demo")).args([
        "--seconds",
        "6",
        "--domain",
        d.name(),
    ]));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let summary = stdout
        .lines()
        .find(|l| l.starts_with("summary:"))
        .unwrap_or_else(|| panic!("no summary in {stdout}"));
    let kv: std::collections::HashMap<&str, &str> = summary
        .split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .collect();
    let get = |k: &str| kv[k].parse::<f64>().unwrap();
    let (open, pid) = (get("open_loop_rms"), get("pid_rms"));
    // Linear theory for the servo lag (τ = 50 ms) behind a pure delay d: the error can only grow
    // with d. The loop's delay (read-back on the next bus cycle, the state's 4 ms period, the
    // controller's wake-up, the frame applied on the next 2 ms tick) is a few ms; 25 ms bounds
    // it with room for a loaded machine. 3 % below the delay-free figure allows for sampling.
    let tau = 0.05;
    for (name, measured, pid_gains) in [("open loop", open, None), ("PID", pid, Some(GAINS))] {
        let lo = 0.97 * gait_rms(error_ratio(tau, pid_gains, 0.0));
        let hi = gait_rms(error_ratio(tau, pid_gains, 0.025));
        assert!(
            (lo..=hi).contains(&measured),
            "{name}: rms error {measured} outside [{lo}, {hi}]\n{stdout}"
        );
    }
    assert!(open / pid > 4.0, "{summary}");
    // The demo and its executor have exited: only the domain's node counter is left.
    // SAFETY: the domain is private to this test and no process of it is alive, which is the
    // precondition of removing its node counter.
    let _ = unsafe { remove_global_mgmt_segment::<RtIpc>(d.iceoryx2_config()) };
    let _ = std::fs::remove_dir_all(d.root_path());
}

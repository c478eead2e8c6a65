//! `conductor set` tells the truth about setpoints the executor refuses: a real executor process
//! (`conductor launch`) drives an MIT-mode motor on the in-process simulated CAN bus, with a
//! 100 ms command watchdog. After the watchdog trips the motor, `set` of its position fails and
//! names the state that enables it; once that state is set to 1, the position is taken again.
//! Switching the motor off through its enable state makes `set` fail as "disabled". `top` counts
//! the trip and the refusals.

mod support;

use std::process::Output;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bus::{Bus, Controller, Domain};
use support::*;

/// The flags `conductor get` prints for `state`, or `None` while it cannot read it.
fn flags(d: &Domain, state: &str) -> Option<String> {
    let out = conductor(d).args(["get", state]).output().ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    let (_, f) = text.split_once("flags ")?;
    Some(f.trim_end().trim_end_matches(')').to_string())
}

/// Polls `get` until the state's flags satisfy `pred`; panics (with the last flags) after 30 s.
fn wait_flags(d: &Domain, state: &str, what: &str, pred: impl Fn(&str) -> bool) -> String {
    let end = Instant::now() + Duration::from_secs(30);
    let mut last = None;
    loop {
        if let Some(f) = flags(d, state) {
            if pred(&f) {
                return f;
            }
            last = Some(f);
        }
        assert!(
            Instant::now() < end,
            "{state} never {what}; last flags {last:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn driving(f: &str) -> bool {
    !f.contains("disabled") && !f.contains("tripped")
}

fn run(d: &Domain, args: &[&str]) -> Output {
    conductor(d).args(args).output().expect("run conductor")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn set_fails_when_the_executor_refuses_and_says_how_to_enable() {
    let dir = tempdir("refusals");
    let manifest = dir.join("leg.toml");
    std::fs::write(&manifest, TRIPPING_LEG).unwrap();
    let d = Domain::unique("refusals").unwrap();
    let launcher = Bg::spawn(
        conductor(&d)
            .arg("launch")
            .arg(&manifest)
            .args(["--no-rt", "--quiet"]),
    );

    // Brought up and enabled from where it is (startup = "enable").
    wait_flags(&d, "leg/knee", "enabled", driving);
    // Taken: exit 0, and the sample after the frame has no REJECTED. The frame arms the watchdog.
    let out = ok(conductor(&d).args(["set", "leg/knee", "0.1"]));
    assert!(
        out.starts_with("sent leg/knee <- 0.1\nnow  leg/knee = "),
        "{out}"
    );
    assert!(!out.contains("rejected"), "{out}");

    // No frame for 0.1 s: the watchdog takes the motor out of motor mode.
    wait_flags(&d, "leg/knee", "tripped", |f| f.contains("tripped"));
    let o = run(&d, &["set", "leg/knee", "0.2"]);
    let (out, err) = (text(&o.stdout), text(&o.stderr));
    assert!(
        !o.status.success(),
        "a refused setpoint must fail: {out}{err}"
    );
    // What was sent and the sample that refused it, then the reason and the way out.
    assert!(
        out.starts_with("sent leg/knee <- 0.2\nnow  leg/knee = "),
        "{out}"
    );
    assert!(out.contains("rejected") && out.contains("tripped"), "{out}");
    assert!(
        err.starts_with(
            "conductor: the executor refused leg/knee <- 0.2: device knee is tripped (the \
             command watchdog fired"
        ),
        "{err}"
    );
    assert!(
        err.contains("conductor set leg/knee_enable 1 enables it from where it is"),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "{err}");
    // Its kp is refused the same way (the hint finds the enable state by device, not by name).
    let err = fails(conductor(&d).args(["set", "leg/knee_kp", "20"]));
    assert!(err.contains("conductor set leg/knee_enable 1"), "{err}");

    // --wait 0 cannot know: exit 0, and it says so.
    let o = run(&d, &["set", "leg/knee", "0.2", "--wait", "0"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("note: not checked"), "{o:?}");

    // top: the tripped motor, none enabled, the refusals counted.
    let out = ok(conductor(&d).args(["top", "--once", "--wide"]));
    let header: Vec<&str> = out.lines().nth(1).unwrap().split_whitespace().collect();
    let leg: Vec<&str> = out
        .lines()
        .find(|l| l.starts_with("leg "))
        .unwrap_or_else(|| panic!("no leg row: {out}"))
        .split_whitespace()
        .collect();
    let col = |name: &str| leg[header.iter().position(|h| *h == name).unwrap()];
    assert_eq!((col("ENABLED"), col("TRIPPED")), ("0/1", "1"), "{out}");
    assert!(col("REFUSED").parse::<u64>().unwrap() >= 3, "{out}");
    assert!(col("WATCHDOG").parse::<u64>().unwrap() >= 1, "{out}");
    let out = ok(conductor(&d).args(["top", "--once"]));
    assert!(out.contains("TRIP") && out.contains("REFUSED"), "{out}");

    // From here a controller streams frames (its own gain, every 20 ms), as one does while
    // driving: the watchdog stays quiet while the motor is enabled and commanded from the CLI.
    let stop = Arc::new(AtomicBool::new(false));
    let keeper = {
        let (stop, d) = (stop.clone(), d.clone());
        std::thread::spawn(move || {
            let bus = Bus::open(&d, "test/keeper").unwrap();
            let mut ctl = Controller::new(&bus);
            while !stop.load(Ordering::Relaxed) {
                ctl.add_ctrl("leg/knee_kp", 20.0).unwrap();
                ctl.send_ctrl().unwrap();
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };

    // Enabled again through its enable state: taken, and the position is taken again.
    let out = ok(conductor(&d).args(["set", "leg/knee_enable", "1"]));
    assert!(!out.contains("rejected"), "{out}");
    wait_flags(&d, "leg/knee", "enabled again", driving);
    let out = ok(conductor(&d).args(["set", "leg/knee", "0.2"]));
    assert!(
        out.contains("now  leg/knee = ") && !out.contains("rejected"),
        "{out}"
    );

    // Switched off through its enable state: disabled, not tripped; refused as such.
    ok(conductor(&d).args(["set", "leg/knee_enable", "0"]));
    wait_flags(&d, "leg/knee", "disabled", |f| f.contains("disabled"));
    let err = fails(conductor(&d).args(["set", "leg/knee", "0.3"]));
    assert!(
        err.contains("refused leg/knee <- 0.3: device knee is disabled"),
        "{err}"
    );
    assert!(
        err.contains("enable it: conductor set leg/knee_enable 1"),
        "{err}"
    );
    ok(conductor(&d).args(["set", "leg/knee_enable", "1"]));
    wait_flags(&d, "leg/knee", "enabled again", driving);
    ok(conductor(&d).args(["set", "leg/knee", "0.3"]));

    stop.store(true, Ordering::Relaxed);
    keeper.join().unwrap();
    let (ok_exit, stderr) = launcher.interrupt();
    assert!(ok_exit, "launcher failed: {stderr}");
    let _ = std::fs::remove_dir_all(dir);
}

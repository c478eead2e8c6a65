//! The hardware edge on a Dynamixel bus, end to end: `conductor-executor` against the bus
//! simulator on a pseudo-terminal, whose X-series servos behave as the e-Manual says (torque
//! off at power-on, EEPROM refused with torque on, hardware errors latched until a reboot).
//!
//! Bring-up errors name the bus, the id, the expected and the found model; a configuration the
//! servo refuses is an error; EEPROM is written with torque off; a hardware error becomes fault
//! flags and a trip; a tripped servo refuses setpoints until enabled again, from where it is; a
//! vanished port is reopened and the servos resume without a restart.

mod support;

use std::time::{Duration, Instant};

use conductor_bus::{status, Bus, Controller, Domain, StatsSubscriber};
use conductor_devices::sim::dxl::{DxlBusSim, DxlSimConfig};
use conductor_devices::sim::fault::FaultConfig;
use conductor_devices::sim::runner::{run_dxl, run_dxl_faultless, Endpoint, Pty, Running};
use support::edge::{send, Exec, Watch};
use support::{eventually, temp_manifest};

const PULSE: f64 = 2.0 * std::f64::consts::PI / 4096.0;

/// A bus of servos `ids` on a pty (with a symlink, so it can be unplugged and plugged back).
fn bus(tag: &str, cfg: DxlSimConfig) -> (Running<DxlBusSim>, String) {
    let link = std::env::temp_dir().join(format!("conductor-edge-{tag}-{}", std::process::id()));
    let sim = run_dxl_faultless(Endpoint::Pty(Pty::open(Some(&link)).unwrap()), cfg);
    sim.sim().start_log();
    (sim, link.display().to_string())
}

fn ids(n: u8) -> DxlSimConfig {
    DxlSimConfig {
        ids: (1..=n).collect(),
        ..DxlSimConfig::default()
    }
}

/// A manifest: servos 1..=`n` (`extra` added to each device table), a position and an enable
/// state per servo, at 200 Hz.
fn manifest(port: &str, n: u8, top: &str, extra: &str) -> String {
    let mut s = format!(
        "system = \"edge\"\n[subsystems.arm]\nrate_hz = 200\n{top}\n\
         [subsystems.arm.hardware.uart]\nkind = \"serial\"\nport = \"{port}\"\n\
         [subsystems.arm.protocols.robotis]\nkind = \"dynamixel2\"\nhardware = \"uart\"\n\
         timeout_us = 10000\n"
    );
    for i in 1..=n {
        s += &format!(
            "[subsystems.arm.devices.j{i}]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = {i}\n{extra}\n\
             [subsystems.arm.states.p{i}]\ndevice = \"j{i}\"\nchannel = \"position\"\nwritable = true\nmin = -1\nmax = 1\n\
             [subsystems.arm.states.e{i}]\ndevice = \"j{i}\"\nchannel = \"enable\"\nwritable = true\nmin = 0\nmax = 1\n"
        );
    }
    s
}

fn start(
    tag: &str,
    text: &str,
) -> (
    Result<Exec, (std::process::ExitStatus, Vec<String>)>,
    Domain,
) {
    let d = Domain::unique(tag).unwrap();
    let path = temp_manifest(tag, text);
    (Exec::start(&path, "arm", &d), d)
}

/// [`start`], for a test in which the executor must run.
fn running(tag: &str, text: &str) -> (Exec, Domain) {
    let (r, d) = start(tag, text);
    (r.unwrap_or_else(|(s, log)| panic!("{s}: {log:#?}")), d)
}

#[test]
fn a_wrong_model_stops_the_executor_naming_bus_id_expected_and_found() {
    let (sim, port) = bus("model", ids(3));
    sim.sim().servo_mut(3).unwrap().set_model(1130);
    let (r, _d) = start("model", &manifest(&port, 3, "", ""));
    let (status, log) = r.err().expect("the executor must not run");
    assert_eq!(status.code(), Some(2), "{log:#?}");
    let line = log
        .iter()
        .find(|l| l.contains("error:") && l.contains("\"j3\""))
        .unwrap_or_else(|| panic!("{log:#?}"));
    for part in [
        "id 3 on bus \"uart\"",
        "answered as model 1130 (xm540-w150)",
        "expects xm430-w350 (1020)",
    ] {
        assert!(line.contains(part), "{part:?} in {line}");
    }
    // The servos that did come up were put back in their safe state before it exited.
    assert!(log.iter().any(|l| l.contains("not running")), "{log:#?}");
}

#[test]
fn a_missing_servo_is_an_error_unless_optional() {
    let (sim, port) = bus("missing", ids(2));
    let (r, _d) = start("missing", &manifest(&port, 3, "", ""));
    let (status, log) = r.err().expect("servo 3 is not on the bus");
    assert_eq!(status.code(), Some(2));
    assert!(
        log.iter()
            .any(|l| l.contains("\"j3\"") && l.contains("id 3") && l.contains("does not answer")),
        "{log:#?}"
    );
    // Optional: a warning, the others run, its states stay STALE (never a value).
    let text = manifest(&port, 2, "", "")
        + "[subsystems.arm.devices.j3]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = 3\noptional = true\n\
           [subsystems.arm.states.p3]\ndevice = \"j3\"\nchannel = \"position\"\n\
           [subsystems.arm.states.e3]\ndevice = \"j3\"\nchannel = \"enable\"\nwritable = true\n";
    let (mut exec, d) = running("optional", &text);
    let w = exec.wait_log(2, "warning: optional");
    assert!(w.contains("\"j3\"") && w.contains("STALE"), "{w}");
    let bus = Bus::open(&d, "t").unwrap();
    let mut p1 = Watch::new(&bus, "arm/p1");
    let mut p3 = Watch::new(&bus, "arm/p3");
    p1.until(2.0, "p1 published", |s| s.status & status::STALE == 0);
    std::thread::sleep(Duration::from_millis(200));
    assert!(
        p3.poll().is_none(),
        "no value is ever invented for an absent servo"
    );
    exec.stop_ok();
    drop(sim);
}

/// A stop asked for while the devices are still being brought up (a servo that does not
/// answer yet) is a stop: exit status 0, not "cannot run" (which a launcher would take for a
/// robot that is not as its manifest says).
#[test]
fn a_stop_during_bring_up_is_a_stop_not_a_failure() {
    let (_sim, port) = bus("stop-bring-up", ids(1));
    let d = Domain::unique("stop-bring-up").unwrap();
    let path = support::temp_manifest("stop-bring-up", &manifest(&port, 2, "", ""));
    let child = std::process::Command::new(support::EXECUTOR)
        .arg("--manifest")
        .arg(&path)
        .args(["--subsystem", "arm", "--domain", d.name(), "--no-rt"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Servo 2 is not on the bus: the bring-up probes it for seconds.
    std::thread::sleep(Duration::from_millis(500));
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    let out = child.wait_with_output().unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_configuration_the_servo_refuses_is_an_error() {
    // Operating Mode 2 does not exist on an XM430: the servo answers Data Range Error and
    // keeps 3; the read-back says so.
    let (_sim, port) = bus("config", ids(1));
    let (r, _d) = start("config", &manifest(&port, 1, "", "operating_mode = 2"));
    let (status, log) = r.err().expect("refused configuration");
    assert_eq!(status.code(), Some(2));
    assert!(
        log.iter().any(|l| l.contains("\"j1\"")
            && l.contains("refused its configuration: register 11 reads 3 after writing 2")),
        "{log:#?}"
    );
}

#[test]
fn eeprom_is_written_with_torque_off_and_read_back_then_enabled_where_it_is() {
    // Servos still powered from a previous run: torque on, Return Delay Time 250 (500 µs),
    // resting off centre. The manifest wants return delay 0.
    let cfg = DxlSimConfig {
        torque_on: true,
        return_delay_us: 500,
        initial_position: 2300,
        ..ids(2)
    };
    let (sim, port) = bus("eeprom", cfg);
    let (mut exec, _d) = running("eeprom", &manifest(&port, 2, "", "return_delay_us = 0"));
    {
        let s = sim.sim();
        let log = s.instruction_log();
        for id in 1..=2u8 {
            let mine: Vec<_> = log.iter().filter(|r| r.1 == id).collect();
            let at = |addr: u16, data: &[u8]| mine.iter().position(|r| r.3 == addr && r.4 == data);
            let off = at(64, &[0]).unwrap_or_else(|| panic!("torque off: {mine:?}"));
            let delay = at(9, &[0]).unwrap_or_else(|| panic!("return delay: {mine:?}"));
            let goal = at(116, &2300i32.to_le_bytes()).unwrap_or_else(|| panic!("goal: {mine:?}"));
            let on = mine
                .iter()
                .rposition(|r| r.3 == 64 && r.4 == [1])
                .unwrap_or_else(|| panic!("torque on: {mine:?}"));
            assert!(
                off < delay && delay < goal && goal < on,
                "servo {id}: {mine:?}"
            );
            let servo = s.servo(id).unwrap();
            assert_eq!(servo.table[9], 0, "written and kept");
            assert!(servo.torque_on());
            assert_eq!(servo.present_position(), 2300, "enabled where it was");
        }
    }
    exec.stop_ok();
}

#[test]
fn a_hardware_error_trips_the_servo_and_enable_reboots_it() {
    let (sim, port) = bus("fault", ids(2));
    let (mut exec, d) = running("fault", &manifest(&port, 2, "", ""));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p2 = Watch::new(&bus, "arm/p2");
    let mut e2 = Watch::new(&bus, "arm/e2");
    send(&mut ctl, &[("arm/p2", 0.3)]);
    p2.until(2.0, "p2 moved", |s| (s.value - 0.3).abs() < 4.0 * PULSE);

    // Overload: the servo cuts its torque and raises the alert bit in every status packet.
    sim.sim().servo_mut(2).unwrap().inject_hardware_error(0x20);
    // Tripped, flagged, and shown limp: the servo cut its own torque (the hold found it off).
    p2.until(2.0, "fault flags", |s| {
        let all = status::DEVICE_FAULT | status::TRIPPED | status::DISABLED;
        s.status & all == all
    });
    exec.wait_log(2, "reports a fault: 0x20");
    exec.wait_log(2, "tripped by its fault");
    // Refused, loudly: REJECTED on the state, counted.
    send(&mut ctl, &[("arm/p2", -0.3)]);
    p2.until(1.0, "refused", |s| s.status & status::REJECTED != 0);
    let mut stats = StatsSubscriber::new(&bus, "arm").unwrap();
    let st = eventually(2, "stats", || {
        stats
            .latest()
            .unwrap()
            .filter(|s| s.setpoints_refused > 0 && s.device_faults > 0)
    });
    assert_eq!((st.devices_tripped, st.devices_faulted), (1, 1), "{st:?}");
    assert_eq!(
        exec.log()
            .iter()
            .filter(|l| l.contains("reports a fault"))
            .count(),
        1,
        "one line per transition, not per packet"
    );
    let goal = sim.sim().servo(2).unwrap().goal_position();
    assert!(
        (goal - (2048 + 196)).abs() <= 6,
        "the refused setpoint never reached it: {goal}"
    );

    // Enable: only a REBOOT clears a latched hardware error; then it is brought up again and
    // enabled where it is.
    send(&mut ctl, &[("arm/e2", 1.0)]);
    e2.until(3.0, "enabled again", |s| s.value == 1.0);
    let s = p2.until(1.0, "flags clear", |s| {
        s.status & (status::DEVICE_FAULT | status::TRIPPED | status::DISABLED) == 0
    });
    assert_eq!(sim.sim().stats().reboot, 1);
    let servo = sim.sim().servo(2).unwrap().clone();
    assert_eq!(servo.hardware_error(), 0);
    assert!(servo.torque_on());
    assert_eq!(
        servo.goal_position(),
        servo.present_position(),
        "enabled where it is"
    );
    assert!(
        (s.value - 0.3).abs() < 4.0 * PULSE,
        "it stayed where it was: {s:?}"
    );
    send(&mut ctl, &[("arm/p2", -0.3)]);
    p2.until(2.0, "commands again", |s| {
        (s.value + 0.3).abs() < 4.0 * PULSE
    });
    exec.stop_ok();
}

#[test]
fn reboot_on_fault_recovers_by_itself() {
    let (sim, port) = bus("reboot", ids(1));
    let (mut exec, d) = running("reboot", &manifest(&port, 1, "", "reboot_on_fault = true"));
    let bus = Bus::open(&d, "t").unwrap();
    let mut p1 = Watch::new(&bus, "arm/p1");
    p1.until(2.0, "up", |s| s.status & status::DISABLED == 0);
    sim.sim().servo_mut(1).unwrap().inject_hardware_error(0x04);
    p1.until(2.0, "tripped", |s| s.status & status::TRIPPED != 0);
    // The first reboot waits 1 s.
    let t = Instant::now();
    p1.until(4.0, "recovered", |s| {
        s.status & (status::TRIPPED | status::DISABLED | status::DEVICE_FAULT) == 0
    });
    assert!(
        t.elapsed() >= Duration::from_millis(800),
        "{:?}",
        t.elapsed()
    );
    assert_eq!(sim.sim().stats().reboot, 1);
    exec.stop_ok();
}

#[test]
fn the_watchdog_trips_setpoints_are_refused_until_enable_from_where_it_is() {
    let (sim, port) = bus("watchdog", ids(1));
    let (mut exec, d) = running("watchdog", &manifest(&port, 1, "watchdog_ms = 150", ""));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p1 = Watch::new(&bus, "arm/p1");
    // Frames faster than the watchdog while it moves.
    let t = Instant::now();
    while p1
        .poll()
        .is_none_or(|s| (s.value - 0.5).abs() >= 4.0 * PULSE)
    {
        assert!(t.elapsed() < Duration::from_secs(2), "{:?}", p1.last);
        send(&mut ctl, &[("arm/p1", 0.5)]);
        std::thread::sleep(Duration::from_millis(50));
    }
    // Silence: the watchdog holds it where it is and trips it.
    let s = p1.until(2.0, "tripped", |s| {
        s.status & (status::WATCHDOG | status::TRIPPED) == status::WATCHDOG | status::TRIPPED
    });
    assert_eq!(s.status & status::DISABLED, 0, "hold keeps torque on");
    exec.wait_log(2, "tripped by the command watchdog");
    // A frame does not clear the trip: its setpoint is refused, and says why.
    send(&mut ctl, &[("arm/p1", -0.5)]);
    p1.until(1.0, "refused", |s| s.status & status::REJECTED != 0);
    exec.wait_log(
        2,
        "setpoint for \"p1\" refused: its device is holding, tripped",
    );
    std::thread::sleep(Duration::from_millis(100));
    let goal = sim.sim().servo(1).unwrap().goal_position();
    assert!(
        (goal - (2048 + 326)).abs() <= 2,
        "still where it held: {goal}"
    );
    // enable = 1: enabled again, from where it is.
    send(&mut ctl, &[("arm/e1", 1.0)]);
    p1.until(2.0, "enabled", |s| {
        s.status & (status::TRIPPED | status::WATCHDOG) == 0
    });
    // Frames faster than the watchdog again.
    let t = Instant::now();
    while p1
        .poll()
        .is_none_or(|s| (s.value + 0.5).abs() >= 4.0 * PULSE)
    {
        assert!(
            t.elapsed() < Duration::from_secs(2),
            "obeys again: {:?}",
            p1.last
        );
        send(&mut ctl, &[("arm/p1", -0.5)]);
        std::thread::sleep(Duration::from_millis(50));
    }
    exec.stop_ok();
}

/// An enable asked for just before the command source fell silent, and finished only after
/// the watchdog's timeout, must not leave the servo driving with nobody commanding it: the
/// watchdog trips it too. (It skipped a device still marked by an earlier trip, and such a
/// device is marked until its enable completes: the soak's MIT motors back in motor mode
/// after a controller died while re-enabling them.)
#[test]
fn an_enable_that_completes_after_the_watchdog_fired_is_tripped_as_well() {
    // The servo answers 6 ms after each request: enabling (read where it is, then write the
    // goal and torque and read them back) takes longer than the 10 ms watchdog.
    let cfg = DxlSimConfig {
        return_delay_us: 6_000,
        ..ids(1)
    };
    let (_sim, port) = bus("late-enable", cfg);
    let (mut exec, d) = running("late-enable", &manifest(&port, 1, "watchdog_ms = 10", ""));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p1 = Watch::new(&bus, "arm/p1");
    let mut e1 = Watch::new(&bus, "arm/e1");
    let tripped = status::WATCHDOG | status::TRIPPED;
    // One frame, then silence: tripped.
    send(&mut ctl, &[("arm/p1", 0.2)]);
    p1.until(2.0, "tripped", |s| s.status & tripped == tripped);
    e1.until(2.0, "not enabled", |s| s.value == 0.0);
    // enable = 1, then silence again: it may finish enabling, but not stay so.
    send(&mut ctl, &[("arm/e1", 1.0)]);
    std::thread::sleep(Duration::from_millis(500));
    let p = p1.poll().unwrap();
    let e = e1.poll().unwrap();
    assert_eq!(
        (p.status & tripped, e.value),
        (tripped, 0.0),
        "driving with no command source: {p:?} {e:?}\n{:#?}",
        exec.log()
    );
    assert!(exec.stop().success());
}

/// An executor that does not run for longer than its watchdog (descheduled on a loaded machine;
/// here stopped with SIGSTOP) trips on its first tick back. Its hold must be where the servo is
/// then, not where it was last read before the pause: the servo kept moving to its last goal
/// meanwhile, and a hold written from the old reading sent it back there (the soak's one
/// unsafe stop). It reads the position again first.
#[test]
fn a_hold_after_the_executor_did_not_run_holds_where_the_servo_is() {
    let cfg = DxlSimConfig {
        tau_s: 0.4,
        ..ids(1)
    };
    let (sim, port) = bus("stalehold", cfg);
    let (r, d) = start("stalehold", &manifest(&port, 1, "watchdog_ms = 150", ""));
    let mut exec = r.unwrap_or_else(|(s, log)| panic!("{s}: {log:#?}"));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p1 = Watch::new(&bus, "arm/p1");
    p1.until(5.0, "enabled", |s| {
        s.status & (status::DISABLED | status::TRIPPED | status::STALE) == 0
    });
    let raw = |rad: f64| 2048 + (rad / PULSE).round() as i32;
    // One frame: it starts moving to 0.8 rad (slowly: tau 0.4 s).
    send(&mut ctl, &[("arm/p1", 0.8)]);
    eventually(2, "the goal written", || {
        ((sim.sim().servo(1).unwrap().goal_position() - raw(0.8)).abs() <= 1).then_some(())
    });
    std::thread::sleep(Duration::from_millis(30));
    let pid = nix::unistd::Pid::from_raw(exec.pid() as i32);
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGSTOP).unwrap();
    let before = sim.sim().servo(1).unwrap().present_position();
    // The servo moves on while the executor does not run, far longer than the watchdog.
    std::thread::sleep(Duration::from_millis(1000));
    let there = sim.sim().servo(1).unwrap().present_position();
    assert!(there - before > 300, "it moved on: {before} → {there}");
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGCONT).unwrap();
    p1.until(2.0, "tripped", |s| {
        s.status & (status::WATCHDOG | status::TRIPPED) == status::WATCHDOG | status::TRIPPED
    });
    exec.wait_log(2, "safe action confirmed on the wire");
    let servo = sim.sim().servo(1).unwrap().clone();
    let (goal, now) = (servo.goal_position(), servo.present_position());
    assert!(
        (goal - now).abs() <= 4 && goal >= there,
        "held at {goal} while the servo stood at {now} (at {there} when the executor came back, {before} when it stopped)"
    );
    exec.stop_ok();
}

#[test]
fn an_unplugged_port_is_reopened_and_the_servos_resume_without_a_restart() {
    let (sim, port) = bus("unplug", ids(2));
    let (mut exec, d) = running("unplug", &manifest(&port, 2, "", ""));
    let bus = Bus::open(&d, "t").unwrap();
    let mut ctl = Controller::new(&bus);
    let mut p1 = Watch::new(&bus, "arm/p1");
    send(&mut ctl, &[("arm/p1", 0.25), ("arm/p2", -0.25)]);
    p1.until(2.0, "moved", |s| (s.value - 0.25).abs() < 4.0 * PULSE);

    // USB unplug of the adapter (the servos stay powered and keep their state).
    p1.poll();
    let before = p1.all.len();
    sim.unplug();
    p1.until(1.0, "stale", |s| s.status & status::STALE != 0);
    exec.wait_log(2, "vanished");
    // Setpoints meanwhile are refused, not queued for later.
    send(&mut ctl, &[("arm/p1", -0.75)]);
    p1.until(1.0, "refused", |s| s.status & status::REJECTED != 0);
    std::thread::sleep(Duration::from_millis(500));

    sim.replug().unwrap();
    let back = Instant::now();
    let s = p1.until(3.0, "fresh again", |s| {
        s.status & (status::STALE | status::DISABLED) == 0
    });
    let took = back.elapsed();
    assert!(
        took < Duration::from_secs(1),
        "resumed {took:?} after the port came back"
    );
    assert!((s.value - 0.25).abs() < 4.0 * PULSE, "where it was: {s:?}");
    exec.wait_log(2, "is back after");
    // No wrong value since the unplug: every sample is the servo's position or flagged STALE.
    p1.poll();
    for s in &p1.all[before..] {
        let good = (s.value - 0.25).abs() < 4.0 * PULSE;
        assert!(good || s.status & status::STALE != 0, "{s:?}");
    }
    let mut stats = StatsSubscriber::new(&bus, "arm").unwrap();
    let st = eventually(2, "stats", || {
        stats.latest().unwrap().filter(|s| s.bus_outages > 0)
    });
    assert_eq!((st.bus_outages, st.links_down), (1, 0), "{st:?}");
    send(&mut ctl, &[("arm/p1", -0.25)]);
    p1.until(2.0, "obeys again", |s| (s.value + 0.25).abs() < 4.0 * PULSE);
    exec.stop_ok();
}

#[test]
fn hold_off_stays_limp_until_the_first_setpoint_then_moves_from_where_it_is() {
    let cfg = DxlSimConfig {
        initial_position: 2200,
        ..ids(1)
    };
    let (sim, port) = bus("holdoff", cfg);
    let (mut exec, d) = running("holdoff", &manifest(&port, 1, "", "startup = \"hold_off\""));
    let bus = Bus::open(&d, "t").unwrap();
    let mut p1 = Watch::new(&bus, "arm/p1");
    let s = p1.until(2.0, "published", |_| true);
    assert!(s.status & status::DISABLED != 0, "limp: {s:?}");
    assert!(!sim.sim().servo(1).unwrap().torque_on());
    // Someone moves the limp joint by hand.
    sim.sim().servo_mut(1).unwrap().set_present(2300);
    std::thread::sleep(Duration::from_millis(100));
    // The first setpoint enables it where it is now, then takes it to the target.
    {
        let s = sim.sim();
        assert_eq!(
            s.servo(1).unwrap().goal_position(),
            2200,
            "nothing written yet"
        );
    }
    let mut ctl = Controller::new(&bus);
    send(&mut ctl, &[("arm/p1", 0.0)]);
    p1.until(2.0, "at the target", |s| {
        s.status & status::DISABLED == 0 && s.value.abs() < 4.0 * PULSE
    });
    let s = sim.sim();
    let log = s.instruction_log();
    let goals: Vec<i32> = log
        .iter()
        .filter(|r| r.1 == 1 && r.3 == 116)
        .map(|r| i32::from_le_bytes(r.4[..4].try_into().unwrap()))
        .collect();
    assert_eq!(
        goals.first(),
        Some(&2300),
        "enabled where it was moved to: {goals:?}"
    );
    assert_eq!(goals.last(), Some(&2048), "then the setpoint: {goals:?}");
    drop(s);
    exec.stop_ok();
}

/// Six servos on a noisy bus at `link` (1 % of the bytes damaged, half corrupted and half
/// lost, both directions; `seed` chooses which), logging what they take.
fn noisy_bus(link: &std::path::Path, seed: u64) -> Running<DxlBusSim> {
    let noise = |seed| FaultConfig {
        corrupt: 0.005,
        drop: 0.005,
        seed,
        ..FaultConfig::default()
    };
    let sim = run_dxl(
        Endpoint::Pty(Pty::open(Some(link)).unwrap()),
        ids(6),
        noise(seed),
        noise(seed ^ 0x5EED),
    );
    sim.sim().start_log();
    sim
}

/// A noisy bus (1 % of the bytes damaged, half corrupted and half lost, both directions): every
/// servo is still brought up, since each lifecycle step is retried and a lost reply is not a
/// refusal (before, a step's ten tries were used up by losses: "does not answer").
#[test]
fn bring_up_survives_a_noisy_bus() {
    let link = std::env::temp_dir().join(format!("conductor-edge-noisy-{}", std::process::id()));
    for seed in 1..=3u64 {
        let sim = noisy_bus(&link, seed);
        let (r, _d) = start("noisy", &manifest(&link.display().to_string(), 6, "", ""));
        match r {
            Ok(mut exec) => {
                exec.stop_ok();
            }
            Err((status, log)) => {
                let s = sim.sim();
                let mine: Vec<_> = s
                    .instruction_log()
                    .iter()
                    .filter(|r| r.1 == 2 || r.1 == 0xFE)
                    .map(|r| format!("{:.1}ms i{:#x} a{} {:?}", r.0 as f64 / 1e6, r.2, r.3, r.4))
                    .collect();
                panic!("seed {seed}: {status}: {log:#?}\nservo 2: {mine:#?}");
            }
        }
    }
}

/// A stop that comes while the watchdog's holds are still on the wire (the controller died
/// just before the robot was stopped) confirms every servo's safe state on a noisy bus. A hold
/// whose write the line damaged is read back unchanged and sent again; that second round used
/// to keep the first round's read-back, so its answers were never taken and the stop could not
/// confirm (the soak's intermittent exit status 4).
#[test]
fn a_stop_during_a_watchdog_trip_confirms_every_hold() {
    let link = std::env::temp_dir().join(format!("conductor-edge-stoptrip-{}", std::process::id()));
    for (seed, after_ms) in [(1u64, 0u64), (2, 2), (3, 5), (4, 8), (5, 12), (6, 20)] {
        let sim = noisy_bus(&link, seed);
        let (mut exec, d) = running(
            "stoptrip",
            &manifest(&link.display().to_string(), 6, "watchdog_ms = 100", ""),
        );
        let bus = Bus::open(&d, "t").unwrap();
        let mut ctl = Controller::new(&bus);
        for k in 0..10 {
            let v = 0.1 * (k % 3) as f64;
            let sp: Vec<(String, f64)> = (1..=6).map(|i| (format!("arm/p{i}"), v)).collect();
            let sp: Vec<(&str, f64)> = sp.iter().map(|(n, v)| (n.as_str(), *v)).collect();
            send(&mut ctl, &sp);
            std::thread::sleep(Duration::from_millis(20));
        }
        exec.wait_log(3, "tripped by the command watchdog");
        std::thread::sleep(Duration::from_millis(after_ms));
        let status = exec.stop();
        if !status.success() {
            let s = sim.sim();
            let log: Vec<_> = s
                .instruction_log()
                .iter()
                .rev()
                .take(80)
                .map(|r| {
                    format!(
                        "{:.1}ms id{} i{:#x} a{} {:?}",
                        r.0 as f64 / 1e6,
                        r.1,
                        r.2,
                        r.3,
                        r.4
                    )
                })
                .collect();
            panic!(
                "seed {seed}, stop {after_ms} ms after the trip: {status}: {:#?}\nlast instructions (newest first): {log:#?}",
                exec.log()
            );
        }
    }
}

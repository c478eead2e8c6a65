//! score-gateway against the firmware in the emulator: a separate process (this test) sees the
//! board's ADC on the bus, commands a PWM duty that is measured at the pin, and the gateway
//! survives the board being unplugged and plugged back (the emulator killed and restarted); its
//! command watchdog makes a duty safe when the controller stops.
//!
//! Needs the firmware ELF (`score-fw build`) and the harness (`npm ci` in
//! score/firmware/emulator); fails with a message saying how to get them.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

use conductor_bus::{status, Bus, Controller, Domain, StateSample, StateSubscriber};
use score_firmware_tools::emulator::{fresh_pty_paths, Emulator};
use score_firmware_tools::port::Port;

const WAIT: Duration = Duration::from_secs(30);

struct Gw {
    child: Child,
    stdout: Receiver<String>,
}

impl Gw {
    fn spawn(link: &Path, domain: &Domain, extra: &[&str]) -> Self {
        let (child, stdout) = conductor_testkit::spawn_with_lines(
            Command::new(env!("CARGO_BIN_EXE_score-gateway"))
                .arg("--port")
                .arg(link)
                .args(extra)
                .env("CONDUCTOR_DOMAIN", domain.name())
                .stderr(Stdio::inherit()),
        );
        Self { child, stdout }
    }

    fn ready(&self) -> String {
        let l = self
            .stdout
            .recv_timeout(WAIT)
            .expect("gateway reports ready");
        assert!(l.starts_with("ready "), "{l}");
        l
    }
}

impl Drop for Gw {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status").is_ok_and(|s| {
        s.lines()
            .find(|l| l.starts_with("Uid:"))
            .and_then(|l| l.split_whitespace().nth(2))
            == Some("0")
    })
}

/// A process's main thread's scheduling policy and real-time priority, from `/proc/<pid>/stat`
/// (fields 41 and 40).
fn scheduling(pid: u32) -> (u32, u32) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    // Fields after the command name (which may hold spaces) start at field 3.
    let rest: Vec<&str> = stat
        .rsplit_once(')')
        .unwrap()
        .1
        .split_whitespace()
        .collect();
    (rest[41 - 3].parse().unwrap(), rest[40 - 3].parse().unwrap())
}

fn configure(emu: &mut Emulator, lines: &[&str]) {
    let mut t = Port::open(&emu.term, WAIT).unwrap();
    emu.dtr("term", true).unwrap();
    t.read_until_suffix("$> ", WAIT).unwrap();
    for l in lines {
        t.write_all(format!("{l}\r").as_bytes()).unwrap();
        let out = t.read_until_suffix("$> ", WAIT).unwrap();
        assert!(!out.contains("error"), "{l}: {out}");
    }
}

/// Waits for a sample that satisfies `ok`; returns it.
fn wait_sample(
    sub: &mut StateSubscriber,
    what: &str,
    ok: impl Fn(&StateSample) -> bool,
) -> StateSample {
    let end = Instant::now() + WAIT;
    let mut last = None;
    while Instant::now() < end {
        while let Some(s) = sub.receive().unwrap() {
            if ok(&s) {
                assert!(
                    s.t_sample_ns <= s.t_publish_ns,
                    "sampled after publishing: {s:?}"
                );
                return s;
            }
            last = Some(s);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    panic!("{what}: no matching sample within {WAIT:?} (last {last:?})");
}

/// Waits for a sample whose value satisfies `ok`; returns the value.
fn wait_for(sub: &mut StateSubscriber, what: &str, ok: impl Fn(f64) -> bool) -> f64 {
    wait_sample(sub, what, |s| ok(s.value)).value
}

/// Waits until the duty at GPIO `pin` is `duty` (0–1) within one count of 62 500 (1 kHz).
fn wait_duty(emu: &mut Emulator, pin: u8, duty: f64) {
    let end = Instant::now() + WAIT;
    loop {
        let m = emu.measure_pwm(pin, 4).unwrap();
        if (m.duty - duty).abs() * 62_500.0 <= 1.0 {
            return;
        }
        assert!(
            Instant::now() < end,
            "GPIO {pin} never reached duty {duty} (last {m:?})"
        );
    }
}

/// ADC volts as the board computes them: code · 3.3 / 4095 in f32 (< 1e-6 V of rounding).
fn volts(code: u16) -> f64 {
    code as f64 * 3.3 / 4095.0
}

#[test]
fn adc_on_the_bus_pwm_from_a_controller_and_replug() {
    let (term, link) = fresh_pty_paths().unwrap();
    let mut emu = Emulator::start_at(&term, &link).unwrap_or_else(|e| panic!("{e}"));
    configure(&mut emu, &["adc 0 100", "pwm 4 1000 10"]);
    let domain = Domain::unique("scoregw").unwrap();
    let gw = Gw::spawn(&link, &domain, &[]);
    let ready = gw.ready();
    assert_eq!(ready, "ready score-rp2040 3 states");

    let bus = Bus::open(&domain, "score-gateway-test").unwrap();
    let mut adc0 = StateSubscriber::new(&bus, "score-rp2040/adc0").unwrap();
    let meta = &adc0.info().meta;
    assert_eq!(
        (meta.units.as_str(), meta.rate_hz, meta.writable),
        ("V", 100.0, false)
    );
    for v in [0.8, 2.2, 3.0] {
        let code = emu.set_adc_volts(0, v).unwrap();
        wait_for(&mut adc0, &format!("adc0 = {v} V"), |x| {
            (x - volts(code)).abs() < 2e-6
        });
    }

    // A controller sets the writable PWM duty; the pin follows (1 kHz: 62 500 counts).
    let mut ctl = Controller::new(&bus);
    ctl.add_ctrl("score-rp2040/PWM4", 75.0).unwrap();
    assert_eq!(ctl.send_ctrl().unwrap(), 1);
    wait_duty(&mut emu, 4, 0.75);
    let mut pwm4 = StateSubscriber::new(&bus, "score-rp2040/PWM4").unwrap();
    wait_for(&mut pwm4, "PWM4 = 75 %", |x| (x - 75.0).abs() < 1e-3);
    // A read-only state refuses setpoints at the controller already.
    assert!(ctl.add_ctrl("score-rp2040/adc0", 1.0).is_err());

    // A variable typed on the terminal while the gateway runs becomes a state too.
    let mut t = Port::open(&emu.term, WAIT).unwrap();
    t.write_all(b"defexp k 5\r").unwrap();
    t.read_until_suffix("$> ", WAIT).unwrap();
    drop(t);
    let end = Instant::now() + WAIT;
    let mut k = loop {
        match StateSubscriber::new(&bus, "score-rp2040/k") {
            Ok(s) => break s,
            Err(e) if Instant::now() > end => panic!("k never became a state: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    assert_eq!(
        (k.info().meta.rate_hz, k.info().meta.writable),
        (10.0, true)
    );
    wait_for(&mut k, "k = 5", |x| x == 5.0);

    // Unplug: the board disappears; plug back in: a fresh board with an empty table.
    emu.kill();
    std::thread::sleep(Duration::from_millis(300));
    // Nothing is published while the board is away: what is queued is from before.
    while k.receive().unwrap().is_some() {}
    let mut emu = Emulator::start_at(&term, &link).unwrap_or_else(|e| panic!("{e}"));
    let code = emu.set_adc_volts(0, 1.2).unwrap();
    // The gateway reconnects, restores the configuration and publishing resumes on the same
    // state (the subscriber from before the replug).
    wait_for(&mut adc0, "adc0 after replug", |x| {
        (x - volts(code)).abs() < 2e-6
    });
    let m = emu.measure_pwm(4, 4).unwrap();
    assert!(
        m.periods == 4 && (m.period_ns.unwrap() - 1e6).abs() < 1.0,
        "PWM4 restored: {m:?}"
    );
}

/// The command watchdog (1 s): while a controller commands every 50 ms the duty holds and no
/// sample is flagged; when it stops, the gateway sets the duty to its safe value (0 %, a
/// constant low pin) and flags the state; a new command clears the flag and re-arms it.
#[test]
fn the_watchdog_makes_a_duty_safe_when_the_controller_stops() {
    let (term, link) = fresh_pty_paths().unwrap();
    let mut emu = Emulator::start_at(&term, &link).unwrap_or_else(|e| panic!("{e}"));
    configure(&mut emu, &["pwm 4 1000 10"]);
    let domain = Domain::unique("scoregw-wd").unwrap();
    // The link loop that carries the watchdog runs SCHED_FIFO when asked (as root here; a
    // user without the right gets a warning and normal scheduling).
    let gw = Gw::spawn(
        &link,
        &domain,
        &["--watchdog-ms", "1000", "--priority", "10"],
    );
    gw.ready();
    if is_root() {
        assert_eq!(
            scheduling(gw.child.id()),
            (1, 10),
            "the gateway's loop: SCHED_FIFO (policy 1) at priority 10"
        );
    } else {
        eprintln!("not root: the gateway's SCHED_FIFO priority is not checked");
    }
    let bus = Bus::open(&domain, "score-gateway-test").unwrap();
    let mut pwm4 = StateSubscriber::new(&bus, "score-rp2040/PWM4").unwrap();
    let mut ctl = Controller::new(&bus);
    // The period is announced on the bus (the commands service's `conductor.watchdog_ms`).
    assert_eq!(
        bus.command_watchdog("score-rp2040").unwrap(),
        Some(Some(Duration::from_secs(1)))
    );

    // Commands every 50 ms for two timeouts and until the pin shows 60 %: the watchdog must not
    // fire. (The pin is measured while commands go on, so a slow emulator cannot see the
    // watchdog's 0 % instead.)
    let start = Instant::now();
    let mut duty_seen = false;
    while start.elapsed() < Duration::from_secs(2) || !duty_seen {
        assert!(start.elapsed() < WAIT, "PWM4 never reached 60 %");
        ctl.add_ctrl("score-rp2040/PWM4", 60.0).unwrap();
        assert_eq!(ctl.send_ctrl().unwrap(), 1);
        std::thread::sleep(Duration::from_millis(50));
        while let Some(s) = pwm4.receive().unwrap() {
            assert_eq!(
                s.status & status::WATCHDOG,
                0,
                "fired while commanded: {s:?}"
            );
        }
        if !duty_seen {
            let m = emu.measure_pwm(4, 4).unwrap();
            duty_seen = (m.duty - 0.60).abs() * 62_500.0 <= 1.0;
        }
    }

    // The controller stops: the duty goes to 0 and the state says why.
    let s = wait_sample(&mut pwm4, "PWM4 made safe", |s| {
        s.status & status::WATCHDOG != 0
    });
    assert_eq!(s.value, 0.0, "{s:?}");
    let m = emu.measure_pwm(4, 4).unwrap();
    assert_eq!(
        (m.duty, m.period_ns),
        (0.0, None),
        "PWM4 after the watchdog: {m:?}"
    );

    // Commanding again re-arms it and clears the flag.
    ctl.add_ctrl("score-rp2040/PWM4", 30.0).unwrap();
    assert_eq!(ctl.send_ctrl().unwrap(), 1);
    let s = wait_sample(&mut pwm4, "PWM4 = 30 %", |s| (s.value - 30.0).abs() < 1e-3);
    assert_eq!(s.status & status::WATCHDOG, 0, "{s:?}");
}

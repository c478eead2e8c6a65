//! SocketCAN on a real Linux CAN stack: Debian's kernel booted in QEMU (conductor-testkit's
//! `can_vm`), the host's file system shared read-only, and this test binary run again inside
//! it (env `CONDUCTOR_IN_CAN_VM`) as root, where it has vcan, can-raw and slcan:
//!
//! 1. `mit_and_odrive_over_socketcan`: the shipped quadruped manifest with only its hardware
//!    table changed to `socketcan` on `vcan0`, plus an ODrive axis, against the project's motor
//!    simulators on the same interface; 2. `candump -L` records the bus and the checks read the
//!    executor's frames from that log: bring-up and safe-stop frames of each device kind, the
//!    command payloads byte for byte, one frame per motor per tick, nothing after the stop; the
//!    published values are exactly the replies' and their sample times the kernel's receive
//!    timestamps of those replies (the same timestamps candump shows).
//! 3. `slcan_through_the_kernel`: the SLCAN adapter simulator on a pty attached by `slcand` as
//!    `slcan0`: the same manifest with `kind = "socketcan"` drives it through the kernel's
//!    slcan driver; then the adapter stops reading, the interface's transmit queue fills
//!    (ENOBUFS) and empties again.
//! 4. `faults_only_a_kernel_shows`: other nodes' frames on the bus, error frames (error-passive,
//!    bus-off, restarted), the interface down and up, deleted and re-created, and a stop while
//!    it is deleted (exit status 4, no "safe state" claim).
//!
//! Every scenario runs in one boot (one VM for the whole file). The host side skips, saying
//! why, only where QEMU cannot run at all; a kernel not prepared by `cargo xtask setup` fails.

mod support;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use conductor_bus::{status, Bus, Controller, Domain, StatsSubscriber};
use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim, OdriveAxisSim};
use conductor_devices::sim::runner::{run_slcan, Endpoint, Pty};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_devices::sim::socketcan_bus::SocketCanSim;
use conductor_protocols::mit_can;
use conductor_protocols::odrive_can::{axis_state, CmdId, Message};
use conductor_protocols::slcan::Dialect;
use conductor_testkit::can_vm::{CanVm, Unavailable};
use support::edge::{send, shipped, Exec, Watch};

/// Set in the guest: run the scenarios.
const GUEST: &str = "CONDUCTOR_IN_CAN_VM";

/// Ticks in a measuring window (at least).
const WINDOW: u64 = 200;

/// Upper bound of the whole VM run (boot, every scenario, power off).
const VM_TIMEOUT: Duration = Duration::from_secs(300);

type Scenario = (&'static str, fn());

const SCENARIOS: &[Scenario] = &[
    (
        "mit_and_odrive_over_socketcan",
        mit_and_odrive_over_socketcan,
    ),
    ("slcan_through_the_kernel", slcan_through_the_kernel),
    ("faults_only_a_kernel_shows", faults_only_a_kernel_shows),
];

fn main() {
    // libtest's flags (cargo test passes some) are not scenario names.
    let filters: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    if std::env::var_os(GUEST).is_some() {
        guest(&filters);
    } else {
        host(&filters);
    }
}

fn host(filters: &[String]) {
    let vm = match CanVm::find() {
        Ok(vm) => vm,
        Err(Unavailable::NoQemu(why)) => {
            println!("can_vm: SKIPPED, QEMU cannot run here: {why}");
            return;
        }
        Err(Unavailable::NotPrepared(why)) => panic!("can_vm: {why}"),
    };
    let exe = std::env::current_exe().unwrap();
    let out = CanVm::cache_dir().join(format!("run-{}", std::process::id()));
    for p in [&exe, &out] {
        assert!(
            !p.display().to_string().contains(char::is_whitespace),
            "the VM's paths must not contain spaces: {}",
            p.display()
        );
    }
    let script = format!(
        "export {GUEST}=1 RUST_BACKTRACE=1\nexec {} {}\n",
        exe.display(),
        filters.join(" ")
    );
    println!(
        "can_vm: booting {} ({}) in QEMU",
        vm.release,
        if conductor_testkit::can_vm::has_hw_virt() {
            "KVM"
        } else {
            "TCG"
        }
    );
    let run = vm.run(&script, &out, VM_TIMEOUT).expect("QEMU starts");
    println!("{}", run.stdout);
    eprintln!("{}", run.stderr);
    println!("can_vm: VM ran {:.1} s", run.elapsed.as_secs_f64());
    if run.status != Some(0) {
        let tail: Vec<&str> = run.console.lines().rev().take(40).collect();
        eprintln!(
            "can_vm: guest console (last lines):\n{}",
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
        panic!(
            "can_vm: the scenarios in the VM failed (status {:?}); its files are in {}",
            run.status,
            run.out.display()
        );
    }
    let _ = std::fs::remove_dir_all(&out);
}

fn guest(filters: &[String]) {
    let mut failed = Vec::new();
    for (name, f) in SCENARIOS {
        if !filters.is_empty() && !filters.iter().any(|x| name.contains(x.as_str())) {
            continue;
        }
        println!("scenario {name} ...");
        let t = Instant::now();
        let r = std::panic::catch_unwind(f);
        let secs = t.elapsed().as_secs_f64();
        match r {
            Ok(()) => println!("scenario {name}: ok ({secs:.1} s)"),
            Err(_) => {
                println!("scenario {name}: FAILED ({secs:.1} s)");
                failed.push(*name);
            }
        }
    }
    if !failed.is_empty() {
        println!("failed: {failed:?}");
        std::process::exit(1);
    }
}

// ---------------------------------------------------------------------------------------------
// Guest helpers
// ---------------------------------------------------------------------------------------------

/// Runs `sh -c cmd`; panics if it fails.
fn sh(cmd: &str) {
    let o = Command::new("sh").args(["-c", cmd]).output().unwrap();
    assert!(
        o.status.success(),
        "`{cmd}`: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

fn vcan(name: &str) {
    sh(&format!(
        "ip link add {name} type vcan && ip link set {name} up"
    ));
}

/// CLOCK_REALTIME − CLOCK_MONOTONIC (ns): candump's timestamps are wall clock.
use conductor_devices::hw::realtime_offset_ns;

/// A frame as `candump -L` logged it.
#[derive(Debug, Clone, PartialEq)]
struct Logged {
    /// Wall clock (ns; candump prints µs).
    t_ns: i128,
    id: u32,
    extended: bool,
    remote: bool,
    data: Vec<u8>,
}

impl Logged {
    fn std(&self, id: u32) -> bool {
        !self.extended && self.id == id
    }
}

/// `candump -L <iface>` writing to a file.
struct Candump {
    child: Child,
    path: PathBuf,
}

impl Candump {
    fn start(iface: &str, tag: &str) -> Candump {
        let path = PathBuf::from(format!("/tmp/candump-{tag}.log"));
        // -r: a 16 MiB receive buffer, so that a starved candump loses nothing; -d: it says
        // so if it does (DROPCOUNT lines, which fail the parse).
        let child = Command::new("candump")
            .args(["-L", "-d", "-r", "16777216", iface])
            .stdout(std::fs::File::create(&path).unwrap())
            .stderr(Stdio::null())
            .spawn()
            .expect("candump (can-utils)");
        // candump binds before it prints anything: give it a moment.
        std::thread::sleep(Duration::from_millis(200));
        Candump { child, path }
    }

    /// Stops candump (SIGINT: it flushes) and parses its log.
    fn finish(mut self) -> Vec<Logged> {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.child.id() as i32),
            nix::sys::signal::Signal::SIGINT,
        );
        let _ = self.child.wait();
        // A copy in the run's folder on the host: kept there when a scenario fails.
        let name = self.path.file_name().unwrap();
        let _ = std::fs::copy(
            &self.path,
            Path::new(conductor_testkit::can_vm::GUEST_OUT).join(name),
        );
        parse_candump(&std::fs::read_to_string(&self.path).unwrap())
    }
}

/// Parses `candump -L` lines: `(1700000000.123456) vcan0 123#DEADBEEF`, `12345678#R`.
fn parse_candump(text: &str) -> Vec<Logged> {
    let mut out = Vec::new();
    for line in text.lines() {
        assert!(line.starts_with('('), "candump: {line}");
        let mut parts = line.split_whitespace();
        let (Some(t), Some(_iface), Some(frame)) = (parts.next(), parts.next(), parts.next())
        else {
            continue;
        };
        let t = t.trim_start_matches('(').trim_end_matches(')');
        let (s, us) = t.split_once('.').unwrap();
        let t_ns = s.parse::<i128>().unwrap() * 1_000_000_000 + us.parse::<i128>().unwrap() * 1000;
        let (id, rest) = frame.split_once('#').unwrap();
        let remote = rest.starts_with('R');
        let data = if remote {
            Vec::new()
        } else {
            (0..rest.len() / 2)
                .map(|i| u8::from_str_radix(&rest[2 * i..2 * i + 2], 16).unwrap())
                .collect()
        };
        out.push(Logged {
            t_ns,
            id: u32::from_str_radix(id, 16).unwrap(),
            extended: id.len() == 8,
            remote,
            data,
        });
    }
    out
}

/// A controller sending the same setpoints every 20 ms from its own thread, until dropped.
struct Feeder {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Feeder {
    fn start(domain: &Domain, setpoints: &[(&'static str, f64)]) -> Feeder {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (s2, name, sp) = (stop.clone(), domain.name().to_string(), setpoints.to_vec());
        let thread = std::thread::spawn(move || {
            let d = Domain::new(&name).unwrap();
            let bus = Bus::open(&d, "feeder").unwrap();
            let mut ctl = Controller::new(&bus);
            while !s2.load(std::sync::atomic::Ordering::Relaxed) {
                send(&mut ctl, &sp);
                std::thread::sleep(Duration::from_millis(20));
            }
        });
        Feeder {
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Feeder {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The quadruped leg of deploy/, its hardware table on SocketCAN interface `iface`. Its
/// command watchdog is raised from 0.1 s to 2 s: under emulation on a loaded machine a tick
/// can come 100 ms late, and a trip is not what these tests are about.
fn quadruped(iface: &str, extra: &str) -> PathBuf {
    let path = shipped(
        "quadruped-leg-mit-slcan.toml",
        &[
            (
                "kind = \"slcan\"\nport = \"/tmp/conductor-can0\"\nbitrate = 1000000\ndialect = \"canable\"\n",
                &format!("kind = \"socketcan\"\ninterface = \"{iface}\"\nbitrate = 1000000\n"),
            ),
            ("watchdog_ms = 100 ", "watchdog_ms = 2000 "),
        ],
    );
    if !extra.is_empty() {
        let mut text = std::fs::read_to_string(&path).unwrap();
        text.push_str(extra);
        std::fs::write(&path, text).unwrap();
    }
    path
}

fn mit_nodes(ids: &[u8]) -> Vec<Box<dyn CanNode>> {
    MitMotorSim::bus(ids.iter().copied(), mit_limits("ak80-9").unwrap())
}

const ENTER: [u8; 8] = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFC];
const EXIT: [u8; 8] = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFD];

/// The command frame data the executor must send for position `p` with the manifest's gains.
fn mit_command(p: f64) -> Vec<u8> {
    let l = mit_limits("ak80-9").unwrap();
    let cmd = mit_can::Command {
        p: p as f32,
        v: 0.0,
        kp: 20.0,
        kd: 1.0,
        t: 0.0,
    };
    cmd.encode(&l).unwrap().to_vec()
}

/// The position a reply frame (id 0, motor id in data[0]) carries, as the executor decodes it.
fn mit_reply(f: &Logged) -> Option<(u8, f64)> {
    if !f.std(0) || f.remote || !matches!(f.data.len(), 6 | 8) {
        return None;
    }
    let l = mit_limits("ak80-9").unwrap();
    let r = mit_can::Reply::decode(&f.data, &l).ok()?;
    Some((f.data[0], r.p as f64))
}

/// ODrive frames the host sends to `node`: remote requests and data frames of set commands
/// (the axis sends heartbeats and the answers to the remote requests).
fn odrive_from_host(f: &Logged, node: u8) -> bool {
    if f.extended || (f.id >> 5) as u8 != node {
        return false;
    }
    let cmd = (f.id & 0x1F) as u8;
    f.remote
        || !(cmd == CmdId::Heartbeat as u8
            || conductor_devices::protocol_stage::odrive_get(CmdId::from_code(cmd).unwrap())
                .is_some())
}

fn odrive_state_request(f: &Logged) -> Option<u32> {
    ((f.id & 0x1F) as u8 == CmdId::SetAxisState as u8 && !f.remote && f.data.len() >= 4)
        .then(|| u32::from_le_bytes(f.data[..4].try_into().unwrap()))
}

// ---------------------------------------------------------------------------------------------
// 1 + 2 + 5: MIT motors and an ODrive axis on vcan0, checked from candump's log
// ---------------------------------------------------------------------------------------------

fn mit_and_odrive_over_socketcan() {
    vcan("vcan0");
    let dump = Candump::start("vcan0", "quadruped");
    let mut nodes = mit_nodes(&[1, 2, 3]);
    nodes.push(Box::new(OdriveAxisSim::new(4, 100, 0)));
    let sim = SocketCanSim::start("vcan0", nodes).unwrap();
    let odrive = "\n[subsystems.front_left.devices.wheel]\nkind = \"odrive_axis\"\nprotocol = \"mit\"\nid = 4\n\
                  [subsystems.front_left.states.wheel]\ndevice = \"wheel\"\nchannel = \"position\"\nwritable = true\nmin = -3\nmax = 3\n";
    let manifest = quadruped("vcan0", odrive);
    let d = Domain::unique("canvm-quad").unwrap();
    let mut exec =
        Exec::start(&manifest, "front_left", &d).unwrap_or_else(|(s, l)| panic!("{s}: {l:#?}"));
    for i in 0..4 {
        assert!(sim.snapshot(i).enabled, "node {i} enabled after bring-up");
    }
    let targets = [0.2, -0.3, -1.0];
    let setpoints = [
        ("front_left/hip_ab", targets[0]),
        ("front_left/hip_fl", targets[1]),
        ("front_left/knee", targets[2]),
        ("front_left/wheel", 0.5),
    ];
    let feeder = Feeder::start(&d, &setpoints);
    let bus = Bus::open(&d, "t").unwrap();
    let mut watches: Vec<Watch> = ["hip_ab", "hip_fl", "knee"]
        .iter()
        .map(|s| Watch::new(&bus, &format!("front_left/{s}")))
        .collect();
    let mut wheel = Watch::new(&bus, "front_left/wheel");
    for (w, t) in watches.iter_mut().zip(targets) {
        w.until(30.0, "at its setpoint", |s| {
            s.status & status::STALE == 0 && (s.value - t).abs() < 0.01
        });
    }
    wheel.until(10.0, "wheel at its setpoint", |s| {
        (s.value - 0.5).abs() < 0.01
    });
    // A window of steady running between two fresh stats messages.
    let mut stats = StatsSubscriber::new(&bus, "front_left").unwrap();
    let mut fresh = |after: u64| stats_after(&mut stats, after);
    let s0 = fresh(0);
    let s0 = fresh(s0.seq);
    // At least WINDOW ticks (a slow emulated machine takes longer; the bound only fails).
    let mut s1 = s0;
    let end = Instant::now() + Duration::from_secs(60);
    while s1.ticks < s0.ticks + WINDOW {
        assert!(Instant::now() < end, "the executor stalled: {s1:?}");
        for w in &mut watches {
            w.poll();
        }
        wheel.poll();
        std::thread::sleep(Duration::from_millis(20));
        s1 = fresh(s1.seq);
    }
    let offset = realtime_offset_ns();
    let (w0, w1) = (s0.t_ns as i128 + offset, s1.t_ns as i128 + offset);
    drop(feeder);
    for w in &mut watches {
        w.poll();
    }
    exec.stop_confirmed(4);
    std::thread::sleep(Duration::from_millis(300));
    for i in 0..4 {
        assert!(!sim.snapshot(i).enabled, "node {i} off after the stop");
    }
    drop(sim);
    let frames = dump.finish();
    println!("  candump logged {} frames", frames.len());

    // Every frame the executor sent: to the MIT motors (ids 1-3) and to the ODrive (node 4).
    let from_host = |f: &Logged| (1..=3).any(|id| f.std(id)) || odrive_from_host(f, 4);
    for id in 1..=3u32 {
        let to_it: Vec<&Logged> = frames.iter().filter(|f| f.std(id)).collect();
        assert!(
            to_it.iter().all(|f| f.data.len() == 8 && !f.remote),
            "DLC 8"
        );
        assert_eq!(
            to_it[0].data, EXIT,
            "motor {id}: bring-up starts with a poll (exit)"
        );
        let enter = to_it.iter().position(|f| f.data == ENTER).expect("enter");
        let first_cmd = to_it
            .iter()
            .position(|f| f.data != ENTER && f.data != EXIT)
            .expect("commands");
        assert!(enter < first_cmd, "motor {id}: enter before any command");
        assert_eq!(
            to_it.last().unwrap().data,
            EXIT,
            "motor {id}: last frame exits"
        );
        // The command for its setpoint, byte for byte, through the whole steady window.
        let want = mit_command(targets[id as usize - 1]);
        let window: Vec<&&Logged> = to_it
            .iter()
            .filter(|f| f.t_ns >= w0 && f.t_ns < w1)
            .collect();
        assert!(
            window.len() as u64 >= WINDOW - 2,
            "motor {id}: {} frames in the window",
            window.len()
        );
        for f in &window {
            assert_eq!(f.data, want, "motor {id}: command payload");
        }
    }
    // The ODrive: closed loop at bring-up, idle at the stop; after it only the heartbeat
    // requests that read its state back (the confirmation).
    let to_axis: Vec<&Logged> = frames.iter().filter(|f| odrive_from_host(f, 4)).collect();
    let states: Vec<u32> = to_axis
        .iter()
        .filter_map(|f| odrive_state_request(f))
        .collect();
    assert_eq!(
        states.first(),
        Some(&axis_state::CLOSED_LOOP_CONTROL),
        "{states:?}"
    );
    let idle_at = to_axis.iter().rposition(|f| !f.remote).unwrap();
    let idle = to_axis[idle_at];
    assert_eq!(
        odrive_state_request(idle),
        Some(axis_state::IDLE),
        "{idle:?}"
    );
    let (bytes, len) = Message::SetAxisState {
        requested_state: axis_state::IDLE,
    }
    .encode()
    .unwrap();
    assert_eq!(idle.data, bytes[..len], "Set_Axis_State(IDLE) payload");
    let heartbeat = (4u32 << 5) | CmdId::Heartbeat as u32;
    assert!(
        to_axis[idle_at + 1..]
            .iter()
            .all(|f| f.remote && f.id == heartbeat),
        "after IDLE: {:?}",
        &to_axis[idle_at + 1..]
    );
    // No command from the host after the last safe-stop frame (read-backs aside).
    let last_safe = frames
        .iter()
        .rposition(|f| (1..=3).any(|id| f.std(id)) && f.data == EXIT)
        .unwrap()
        .max(frames.iter().rposition(|f| f == idle).unwrap());
    let after: Vec<&Logged> = frames[last_safe + 1..]
        .iter()
        .filter(|f| from_host(f) && !(f.remote && f.id == heartbeat))
        .collect();
    assert!(after.is_empty(), "frames after the safe stop: {after:?}");

    // One frame per motor per tick: in the window between the two stats messages, the command
    // frames go 1, 2, 3, 1, 2, 3, ... and there are as many rounds as the executor ticked.
    let ids: Vec<u32> = frames
        .iter()
        .filter(|f| f.t_ns >= w0 && f.t_ns < w1 && (1..=3).any(|id| f.std(id)))
        .map(|f| f.id)
        .collect();
    let start = ids.iter().position(|&i| i == 1).unwrap();
    for (k, id) in ids[start..].iter().enumerate() {
        assert_eq!(
            *id,
            (k % 3) as u32 + 1,
            "round-robin broken at frame {k}: {ids:?}"
        );
    }
    let rounds = ids.len() as f64 / 3.0;
    let ticks = (s1.ticks - s0.ticks) as f64;
    println!(
        "  {rounds:.0} rounds of frames in {ticks} ticks ({:.3} frames per motor per tick)",
        rounds / ticks
    );
    // The window's ends fall between ticks: a round either side.
    assert!(
        (rounds - ticks).abs() <= 2.0,
        "{rounds} rounds in {ticks} ticks"
    );

    // Reads exact, timed by the kernel: every fresh sample is the value of a reply from its
    // motor, and its sample time is that reply's receive timestamp (candump's, the same skb).
    let replies: Vec<(u8, f64, i128)> = frames
        .iter()
        .filter_map(|f| mit_reply(f).map(|(m, p)| (m, p, f.t_ns)))
        .collect();
    let mut by_motor: HashMap<u8, Vec<(f64, i128)>> = HashMap::new();
    for (m, p, t) in replies {
        by_motor.entry(m).or_default().push((p, t));
    }
    for (i, w) in watches.iter().enumerate() {
        let motor = i as u8 + 1;
        let seen = &by_motor[&motor];
        let fresh: Vec<_> = w
            .all
            .iter()
            .filter(|s| s.status & status::STALE == 0)
            .collect();
        assert!(
            fresh.len() > 20,
            "motor {motor}: {} fresh samples",
            fresh.len()
        );
        // Sample time minus the reply's kernel timestamp, signed. The two clock conversions
        // (the executor's and ours) may differ by a constant; the spread around it may not.
        let mut diffs = Vec::new();
        for s in &fresh {
            let t = s.t_sample_ns as i128 + offset;
            let best = seen
                .iter()
                .filter(|(p, _)| *p == s.value)
                .map(|(_, tr)| t - tr)
                .min_by_key(|d| d.abs());
            let Some(d) = best else {
                panic!(
                    "motor {motor}: published {} which no reply carried",
                    s.value
                );
            };
            diffs.push(d);
        }
        diffs.sort();
        let median = diffs[diffs.len() / 2];
        let timed = diffs
            .iter()
            .filter(|d| (*d - median).abs() <= 20_000)
            .count();
        println!(
            "  motor {motor}: {} fresh samples, {timed} stamped within 20 µs of their reply's kernel timestamp (clock conversions differ by {median} ns)",
            fresh.len()
        );
        assert!(median.abs() < 1_000_000, "motor {motor}: {median} ns off");
        assert!(
            timed as f64 >= 0.95 * fresh.len() as f64,
            "motor {motor}: only {timed} of {} samples carry their reply's receive time",
            fresh.len()
        );
    }
}

// ---------------------------------------------------------------------------------------------
// 3 (+ 4, ENOBUFS): the kernel's slcan driver on a pty, the SLCAN adapter simulator behind it
// ---------------------------------------------------------------------------------------------

fn slcan_through_the_kernel() {
    let adapter = SlcanAdapterSim::new(Dialect::CANABLE, mit_nodes(&[1, 2, 3])).with_log();
    let sim = run_slcan(Endpoint::Pty(Pty::open(None).unwrap()), adapter);
    let tty = sim.endpoint().trim_start_matches("/dev/").to_string();
    // -F: in the foreground, so that it is ours to stop.
    let mut slcand = Command::new("slcand")
        .args(["-F", "-o", "-c", "-s8", &tty, "slcan0"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("slcand (can-utils)");
    let end = Instant::now() + Duration::from_secs(5);
    while !Path::new("/sys/class/net/slcan0").exists() {
        assert!(Instant::now() < end, "slcand made no slcan0");
        std::thread::sleep(Duration::from_millis(20));
    }
    // A deeper queue than slcan's 10 frames, as for a real adapter (docs/hardware.md).
    sh("ip link set slcan0 txqueuelen 1000 up");
    let manifest = quadruped("slcan0", "");
    let d = Domain::unique("canvm-slcan").unwrap();
    let mut exec =
        Exec::start(&manifest, "front_left", &d).unwrap_or_else(|(s, l)| panic!("{s}: {l:#?}"));
    for i in 0..3 {
        assert!(
            sim.sim().nodes()[i].snapshot().enabled,
            "motor {} in motor mode through slcan0",
            i + 1
        );
    }
    let feeder = Feeder::start(
        &d,
        &[
            ("front_left/hip_ab", 0.1),
            ("front_left/hip_fl", -0.2),
            ("front_left/knee", -0.8),
        ],
    );
    let bus = Bus::open(&d, "t").unwrap();
    let mut knee = Watch::new(&bus, "front_left/knee");
    knee.until(30.0, "knee at its setpoint", |s| {
        s.status & status::STALE == 0 && (s.value + 0.8).abs() < 0.01
    });
    // One frame per motor per tick reaches the adapter through the kernel.
    let mut stats = StatsSubscriber::new(&bus, "front_left").unwrap();
    let mut snap = |after: u64| {
        let st = stats_after(&mut stats, after);
        let f: Vec<u64> = (0..3)
            .map(|i| sim.sim().nodes()[i].snapshot().frames_in)
            .collect();
        (st, f)
    };
    let (a, fa) = snap(0);
    let end = Instant::now() + Duration::from_secs(60);
    let (b, fb) = loop {
        std::thread::sleep(Duration::from_millis(200));
        let (b, fb) = snap(a.seq);
        if b.ticks >= a.ticks + WINDOW {
            break (b, fb);
        }
        assert!(Instant::now() < end, "the executor stalled: {b:?}");
    };
    let ticks = (b.ticks - a.ticks) as f64;
    for i in 0..3 {
        // Frames flow in the window: fewer than one per tick when the emulated kernel's slcan
        // worker falls behind and frames wait in slcan0's queue, more when such a backlog drains
        // into it. So "never more than one per tick" is checked over the whole run: every frame
        // the motor ever got against every tick the executor ever ran, plus the bring-up's few
        // frames and the ticks between the stats message and the counts read after it.
        let per_tick = (fb[i] - fa[i]) as f64 / ticks;
        println!(
            "  slcan0: motor {}: {per_tick:.3} frames per tick in the window, {} frames in {} ticks in all",
            i + 1,
            fb[i],
            b.ticks
        );
        assert!(per_tick >= 0.3, "motor {}: {per_tick}", i + 1);
        assert!(
            fb[i] <= b.ticks + 50,
            "motor {}: {} frames in {} ticks",
            i + 1,
            fb[i],
            b.ticks
        );
    }

    // The adapter stops reading: the pty fills, then slcan0's transmit queue (ENOBUFS). (On a
    // loaded machine the emulated kernel's slcan worker may fall behind even before: the queue
    // may already be full, or flap; every transition is still logged once.)
    sh("ip link set slcan0 txqueuelen 4");
    let before = snap(b.seq).0;
    sim.pause_reading(true);
    wait_last_tx_line(&exec, "transmit queue full (ENOBUFS)");
    let t_full = Instant::now();
    knee.until(10.0, "stale while nothing gets through", |s| {
        s.status & status::STALE != 0
    });
    // The tick goes on while the queue is full: its rate over a second, against before.
    let (f0, _) = snap(before.seq);
    std::thread::sleep(Duration::from_millis(1000));
    let (c, _) = snap(f0.seq);
    let rate = |x: &conductor_bus::ExecutorStats, y: &conductor_bus::ExecutorStats| {
        (y.ticks - x.ticks) as f64 / ((y.t_ns - x.t_ns) as f64 * 1e-9)
    };
    let (full_rate, normal_rate) = (rate(&f0, &c), rate(&a, &b));
    println!("  slcan0: {full_rate:.0} ticks/s with the queue full ({normal_rate:.0} before)");
    // A blocking tick would stop it; emulation on a loaded machine makes it vary.
    assert!(
        full_rate > 0.25 * normal_rate,
        "the tick slowed while the queue was full"
    );
    // The adapter reads again, the queue as deep as before: it drains.
    sh("ip link set slcan0 txqueuelen 1000");
    sim.pause_reading(false);
    wait_last_tx_line(&exec, "transmit queue takes frames again");
    knee.until(10.0, "fresh again", |s| {
        s.status & status::STALE == 0 && (s.value + 0.8).abs() < 0.01
    });
    println!(
        "  slcan0: queue full for {:.2} s; bus errors {} → {}",
        t_full.elapsed().as_secs_f64(),
        before.bus_errors,
        c.bus_errors
    );
    assert!(c.bus_errors > before.bus_errors, "the refusals are counted");
    // Once per transition: full and takes-again alternate, starting with full.
    let tx = tx_lines(&exec);
    for (k, l) in tx.iter().enumerate() {
        let want = if k % 2 == 0 {
            "full"
        } else {
            "takes frames again"
        };
        assert!(l.contains(want), "transition {k} is not {want:?}: {tx:#?}");
    }
    drop(feeder);
    exec.stop_confirmed(3);
    std::thread::sleep(Duration::from_millis(300));
    for i in 0..3 {
        assert!(
            !sim.sim().nodes()[i].snapshot().enabled,
            "motor {} off",
            i + 1
        );
    }
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(slcand.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
    let _ = slcand.wait();
}

// ---------------------------------------------------------------------------------------------
// 4: faults that only a kernel shows
// ---------------------------------------------------------------------------------------------

/// Sends an error frame with class bits `class` and data `data` on `iface`, as a driver would.
fn error_frame(iface: &str, class: u32, data: &[u8]) {
    use socketcan::{CanErrorFrame, CanFrame as SkFrame, CanSocket, Socket};
    let s = CanSocket::open(iface).unwrap();
    let f = SkFrame::Error(CanErrorFrame::new_error(class, data).unwrap());
    s.write_frame(&f).unwrap();
}

fn faults_only_a_kernel_shows() {
    vcan("vcan1");
    let dump = Candump::start("vcan1", "faults");
    let sim = SocketCanSim::start("vcan1", mit_nodes(&[1, 2, 3])).unwrap();
    // Other nodes on the bus: extended ids, and a standard id no device uses, random data.
    let mut others: Vec<Child> = [
        vec!["vcan1", "-e", "-g", "10", "-I", "r", "-L", "8", "-D", "r"],
        vec!["vcan1", "-g", "10", "-I", "7A0", "-L", "8", "-D", "r"],
    ]
    .iter()
    .map(|a| Command::new("cangen").args(a).spawn().expect("cangen"))
    .collect();
    let manifest = quadruped("vcan1", "");
    let d = Domain::unique("canvm-faults").unwrap();
    let mut exec =
        Exec::start(&manifest, "front_left", &d).unwrap_or_else(|(s, l)| panic!("{s}: {l:#?}"));
    let feeder = Feeder::start(
        &d,
        &[
            ("front_left/hip_ab", 0.3),
            ("front_left/hip_fl", 0.0),
            ("front_left/knee", -1.2),
        ],
    );
    let bus = Bus::open(&d, "t").unwrap();
    let mut p1 = Watch::new(&bus, "front_left/hip_ab");
    let fresh_at = |s: &conductor_bus::StateSample| {
        s.status & (status::STALE | status::DISABLED) == 0 && (s.value - 0.3).abs() < 0.01
    };
    p1.until(30.0, "at its setpoint", fresh_at);
    let mut stats = StatsSubscriber::new(&bus, "front_left").unwrap();
    let mut fresh_stats = |after: u64| stats_after(&mut stats, after);

    // Error frames from the driver: error-passive, bus-off, restarted.
    let e0 = fresh_stats(0);
    error_frame(
        "vcan1",
        libc::CAN_ERR_CRTL,
        &[0, libc::CAN_ERR_CRTL_TX_PASSIVE as u8, 0, 0, 0, 0, 0, 0],
    );
    exec.wait_log(5, "reports error-passive");
    error_frame("vcan1", libc::CAN_ERR_BUSOFF, &[]);
    exec.wait_log(5, "reports bus-off");
    error_frame("vcan1", libc::CAN_ERR_RESTARTED, &[]);
    exec.wait_log(5, "error-active again");
    // Bus-off again, reported twice: one transition, one line.
    error_frame("vcan1", libc::CAN_ERR_BUSOFF, &[]);
    let end = Instant::now() + Duration::from_secs(5);
    while count_lines(&exec, "reports bus-off") < 2 {
        assert!(Instant::now() < end, "{:#?}", exec.log());
        std::thread::sleep(Duration::from_millis(10));
    }
    error_frame("vcan1", libc::CAN_ERR_BUSOFF, &[]);
    std::thread::sleep(Duration::from_millis(300));
    error_frame("vcan1", libc::CAN_ERR_RESTARTED, &[]);
    let end = Instant::now() + Duration::from_secs(5);
    while count_lines(&exec, "error-active again") < 2 {
        assert!(Instant::now() < end, "{:#?}", exec.log());
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(300));
    let e1 = fresh_stats(e0.seq);
    let log = exec.log();
    let count = |text: &str| log.iter().filter(|l| l.contains(text)).count();
    assert_eq!(count("reports error-passive"), 1, "{log:#?}");
    assert_eq!(count("reports bus-off"), 2, "{log:#?}");
    assert_eq!(count("error-active again"), 2, "{log:#?}");
    assert!(
        e1.bus_errors >= e0.bus_errors + 6,
        "six error frames counted: {} → {}",
        e0.bus_errors,
        e1.bus_errors
    );
    p1.until(2.0, "still fresh", fresh_at);

    // Down for a second, then up: ENETDOWN once, stale meanwhile, the tick goes on.
    let a = fresh_stats(e1.seq);
    sh("ip link set vcan1 down");
    exec.wait_log(5, "vanished (ENETDOWN");
    p1.until(2.0, "stale while down", |s| s.status & status::STALE != 0);
    std::thread::sleep(Duration::from_millis(1000));
    let b = fresh_stats(a.seq);
    sh("ip link set vcan1 up");
    let up = Instant::now();
    p1.until(5.0, "fresh after up", fresh_at);
    let recovered = up.elapsed();
    exec.wait_log(2, "is back after");
    let c = fresh_stats(b.seq);
    let rate = |x: &conductor_bus::ExecutorStats, y: &conductor_bus::ExecutorStats| {
        (y.ticks - x.ticks) as f64 / ((y.t_ns - x.t_ns) as f64 * 1e-9)
    };
    let down_rate = rate(&a, &b);
    println!(
        "  down/up: recovered {:.3} s after up; {down_rate:.0} ticks/s while down ({:.0} before)",
        recovered.as_secs_f64(),
        rate(&e0, &e1)
    );
    assert!(
        down_rate > 0.25 * rate(&e0, &e1),
        "the tick slowed while the interface was down: {down_rate} ticks/s"
    );
    assert_eq!(b.links_down, 1, "down while down");
    let end = Instant::now() + Duration::from_secs(5);
    let mut c = c;
    while c.links_down != 0 {
        assert!(Instant::now() < end, "still down: {c:?}");
        c = fresh_stats(c.seq);
    }

    // Deleted and re-created under the same name (a USB-CAN adapter unplugged and back).
    let frames_before = dump.finish();
    let mark = exec.log().len();
    sh("ip link del vcan1");
    let gone = wait_log_after(&exec, mark, "vanished (EN");
    // The kernel takes it down before it unregisters it: ENETDOWN or ENODEV, whichever the
    // executor meets first (a send after that fails with ENXIO).
    assert!(
        ["ENETDOWN", "ENODEV", "ENXIO"]
            .iter()
            .any(|e| gone.contains(e)),
        "deleted: {gone}"
    );
    println!(
        "  deleted: {}",
        gone.split(") vanished ").nth(1).unwrap_or(&gone)
    );
    p1.until(2.0, "stale while deleted", |s| {
        s.status & status::STALE != 0
    });
    std::thread::sleep(Duration::from_millis(500));
    vcan("vcan1");
    let dump = Candump::start("vcan1", "faults-after");
    let back = Instant::now();
    p1.until(5.0, "fresh after re-creation", fresh_at);
    println!(
        "  deleted and re-created: fresh again {:.3} s after the interface came back",
        back.elapsed().as_secs_f64()
    );
    assert_eq!(count_lines(&exec, "is back after"), 2, "{:#?}", exec.log());
    std::thread::sleep(Duration::from_millis(300));

    // No wrong value: other nodes' frames never became a sample.
    for c in &mut others {
        let _ = c.kill();
        let _ = c.wait();
    }
    // cangen may have died with the interface: count what the logs show.
    let mut frames = frames_before;
    drop(feeder);
    let last_value = p1.poll();
    // Stop while the interface is gone: the exit frames fail (ENXIO/ENODEV); the executor must
    // not claim a safe state it could not confirm.
    let frames_after = dump.finish();
    frames.extend(frames_after);
    sh("ip link del vcan1");
    std::thread::sleep(Duration::from_millis(300));
    let status = exec.stop();
    let log = exec.log();
    assert_eq!(status.code(), Some(4), "{status}: {log:#?}");
    assert!(
        !log.iter()
            .any(|l| l.contains("devices in their safe state")),
        "{log:#?}"
    );
    assert!(
        log.iter()
            .any(|l| l.contains("NOT confirmed in their safe state")),
        "{log:#?}"
    );
    drop(sim);
    let foreign = frames.iter().filter(|f| f.extended || f.std(0x7A0)).count();
    println!("  {foreign} frames from other nodes on the bus during the run");
    assert!(foreign > 200, "the other nodes were on the bus: {foreign}");
    let values: Vec<f64> = frames
        .iter()
        .filter_map(mit_reply)
        .filter(|(m, _)| *m == 1)
        .map(|(_, p)| p)
        .collect();
    let fresh: Vec<_> = p1
        .all
        .iter()
        .filter(|s| s.status & status::STALE == 0)
        .collect();
    for s in &fresh {
        assert!(
            values.contains(&s.value),
            "published {} which motor 1 never replied: {s:?}",
            s.value
        );
    }
    println!(
        "  {} fresh samples, each a reply of motor 1 ({last_value:?})",
        fresh.len()
    );
}

/// The executor's transmit-queue lines, in order.
fn tx_lines(exec: &Exec) -> Vec<String> {
    exec.log()
        .into_iter()
        .filter(|l| l.contains("transmit queue"))
        .collect()
}

/// Waits (up to 30 s) until the executor's last transmit-queue line contains `text`.
fn wait_last_tx_line(exec: &Exec, text: &str) {
    let end = Instant::now() + Duration::from_secs(30);
    while !tx_lines(exec).last().is_some_and(|l| l.contains(text)) {
        assert!(Instant::now() < end, "no {text:?} last: {:#?}", exec.log());
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Waits (up to 20 s) for a stderr line after the first `mark` lines that contains `text`.
fn wait_log_after(exec: &Exec, mark: usize, text: &str) -> String {
    let end = Instant::now() + Duration::from_secs(20);
    loop {
        if let Some(l) = exec.log()[mark..].iter().find(|l| l.contains(text)) {
            return l.clone();
        }
        assert!(Instant::now() < end, "no {text:?}: {:#?}", exec.log());
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn count_lines(exec: &Exec, text: &str) -> usize {
    exec.log().iter().filter(|l| l.contains(text)).count()
}

/// The first stats message of `stats` newer than sequence number `after` (within 5 s).
fn stats_after(stats: &mut StatsSubscriber, after: u64) -> conductor_bus::ExecutorStats {
    let end = Instant::now() + Duration::from_secs(5);
    loop {
        if let Some(s) = stats.latest().unwrap().filter(|s| s.seq > after) {
            return s;
        }
        assert!(Instant::now() < end, "no stats");
        std::thread::sleep(Duration::from_millis(5));
    }
}

//! After start-up, the executor's tick (drain commands, run every stage, publish samples, notify
//! the tick, publish stats) allocates nothing: 10 000 ticks under a counting allocator.

mod support;

use conductor_bus::{
    prepare_thread, Bus, Controller, SnapshotReader, StateSubscriber, StatsSubscriber,
};
use conductor_executor::executor::Executor;
use conductor_executor::schedule::Wake;
use conductor_manifest::Manifest;
use conductor_testkit::alloc::{measure as measured, Counting};
use std::time::Duration;

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn ten_thousand_ticks_allocate_nothing() {
    // The counter counts (a test that cannot fail proves nothing).
    let (_, n) = measured(|| Box::new(7u64));
    assert_eq!(n, 1);

    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/manifests/two-subsystems.toml"
    );
    let m = Manifest::load(path).unwrap();
    // A watchdog makes the safe-action path part of the measurement too.
    let mut sub = m.subsystem("arm").unwrap().clone();
    sub.watchdog_ns = Some(50_000_000);

    prepare_thread();
    let (domain, _guard) = support::private_domain("noalloc");
    let bus = Bus::open(&domain, "executor/arm").unwrap();
    let mut exec = Executor::new(&bus, &sub).unwrap();
    let mut ctl = Controller::new(&bus);
    let mut sub_j0 = StateSubscriber::with_buffer(&bus, "arm/j0", 64).unwrap();
    // A snapshot reader too, so the tick sends the snapshot to a subscriber and its listener.
    let mut snapshots = SnapshotReader::new(&bus, "arm").unwrap();
    let mut stats = None;

    // Synthetic time: tick k at 5 ms steps (200 Hz), so 10 000 ticks span 50 s of executor time:
    // 500 stats publications and, with the controller silent in long stretches, watchdog trips.
    let t0 = conductor_bus::monotonic_ns();
    let mut k = 0u64;
    let tick = |exec: &mut Executor, k: u64| {
        let now = t0 + k * 5_000_000;
        let wake = Wake {
            slot: k,
            sched_ns: now,
            late_ns: k % 7 * 1000,
            skipped: 0,
        };
        measured(|| exec.tick(&wake, now)).1
    };
    // Warm-up: connections are set up lazily by the first sends and receives.
    for _ in 0..50 {
        for j in 0..6 {
            ctl.add_ctrl(&format!("arm/j{j}"), 0.1).unwrap();
        }
        ctl.send_ctrl().unwrap();
        tick(&mut exec, k);
        k += 1;
        sub_j0.drain(|_| {}).unwrap();
        snapshots.latest().unwrap();
        if stats.is_none() {
            stats = StatsSubscriber::new(&bus, "arm").ok();
        }
    }
    let names: Vec<String> = (0..6).map(|j| format!("arm/j{j}")).collect();
    let mut allocations = 0;
    let mut received = 0;
    let mut snapshots_read = 0;
    for i in 0..10_000u64 {
        // The controller talks for 100 ticks, then is silent for 100 (the watchdog fires).
        if (i / 100) % 2 == 0 && i % 4 == 0 {
            for (j, n) in names.iter().enumerate() {
                // Every 40th frame is out of limits (clamped).
                let v = if i % 40 == 0 { 5.0 } else { j as f64 * 0.3 };
                ctl.add_ctrl(n, v).unwrap();
            }
            ctl.send_ctrl().unwrap();
        }
        allocations += tick(&mut exec, k);
        k += 1;
        let mut j0 = None;
        received += sub_j0.drain(|s| j0 = Some(*s)).unwrap();
        let snap = snapshots.latest().unwrap().expect("a snapshot every tick");
        assert_eq!(
            Some(snap[0]),
            j0,
            "the snapshot carries j0's sample of the tick"
        );
        snapshots_read += 1;
    }
    assert_eq!(allocations, 0, "the tick allocated");
    // The work really happened.
    assert_eq!(received, 10_000, "one sample of j0 per tick");
    assert_eq!(snapshots_read, 10_000);
    let s = stats.unwrap().latest().unwrap().unwrap();
    assert!(s.watchdog_trips >= 40, "{}", s.watchdog_trips);
    assert!(s.frames_applied >= 1_000);
    assert!(s.setpoints_clamped > 0);
    // Stats go out every 100 ms of executor time (20 ticks): the newest is at most 20 ticks old.
    assert!((10_030..=10_050).contains(&s.ticks), "{}", s.ticks);
    // The watchdog period is on the bus for every client to read, not only in the manifest.
    // (Checked last: reading service records draws on the thread's pre-allocated pool.)
    assert_eq!(
        bus.command_watchdog("arm").unwrap(),
        Some(Some(std::time::Duration::from_millis(50)))
    );
}

/// The hardware edge allocates nothing either: a Dynamixel bus whose port vanishes (every read
/// and write failing with an OS error), is reopened by the link's helper thread and handed back,
/// and whose servos are brought up again (ping, configuration read, enable from where they
/// are); then setpoints, a watchdog trip, refused setpoints and an enable. Every tick of it
/// under the counting allocator, after the warm-up (the first bring-up and the bus's lazy
/// connections).
/// An executor for the `arm` subsystem on a private domain, with a controller, a subscriber to
/// `arm/p1` and (once the executor publishes them) its stats.
struct ArmRig {
    _domain: support::DomainGuard,
    bus: Bus,
    exec: Executor,
    ctl: Controller,
    p1: StateSubscriber,
    stats: Option<StatsSubscriber>,
}

impl ArmRig {
    fn open(sub: &conductor_manifest::Subsystem, tag: &str) -> Self {
        prepare_thread();
        let (domain, guard) = support::private_domain(tag);
        let bus = Bus::open(&domain, "executor/arm").unwrap();
        Self {
            _domain: guard,
            exec: Executor::new(&bus, sub).unwrap(),
            ctl: Controller::new(&bus),
            p1: StateSubscriber::with_buffer(&bus, "arm/p1", 64).unwrap(),
            stats: StatsSubscriber::new(&bus, "arm").ok(),
            bus,
        }
    }

    /// Subscribes to the stats if that failed at open (the executor had published none yet).
    fn subscribe_stats(&mut self) {
        if self.stats.is_none() {
            self.stats = StatsSubscriber::new(&self.bus, "arm").ok();
        }
    }
}

/// Real-time ticks 5 ms apart (the simulator answers on its own thread), each measured.
struct RealTimeTicks {
    t0: u64,
    k: u64,
}

impl RealTimeTicks {
    fn start() -> Self {
        Self {
            t0: conductor_bus::monotonic_ns(),
            k: 0,
        }
    }

    /// Sleeps until the next tick is due, runs it and returns what it allocated.
    fn tick(&mut self, exec: &mut Executor) -> u64 {
        let due = self.t0 + self.k * 5_000_000;
        let now = conductor_bus::monotonic_ns();
        if due > now {
            std::thread::sleep(Duration::from_nanos(due - now));
        }
        let now = conductor_bus::monotonic_ns();
        let wake = Wake {
            slot: self.k,
            sched_ns: now,
            late_ns: 0,
            skipped: 0,
        };
        self.k += 1;
        measured(|| exec.tick(&wake, now)).1
    }
}

/// The status flags of the newest sample `sub` holds (0 when it holds none).
fn last_status(sub: &mut StateSubscriber) -> u32 {
    let mut last = 0;
    sub.drain(|s| last = s.status).unwrap();
    last
}

#[test]
fn a_vanishing_bus_and_a_new_bring_up_allocate_nothing() {
    use conductor_devices::sim::dxl::DxlSimConfig;
    use conductor_devices::sim::runner::{run_dxl_faultless, Endpoint, Pty};

    let link = std::env::temp_dir().join(format!("conductor-noalloc-{}", std::process::id()));
    let sim = run_dxl_faultless(
        Endpoint::Pty(Pty::open(Some(&link)).unwrap()),
        DxlSimConfig {
            ids: vec![1, 2],
            ..DxlSimConfig::default()
        },
    );
    let mut text = format!(
        "system = \"na\"\n[subsystems.arm]\nrate_hz = 200\nwatchdog_ms = 100\n\
         [subsystems.arm.hardware.uart]\nkind = \"serial\"\nport = \"{}\"\n\
         [subsystems.arm.protocols.robotis]\nkind = \"dynamixel2\"\nhardware = \"uart\"\ntimeout_us = 10000\n",
        link.display()
    );
    for i in 1..=2 {
        text += &format!(
            "[subsystems.arm.devices.j{i}]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = {i}\n\
             [subsystems.arm.states.p{i}]\ndevice = \"j{i}\"\nchannel = \"position\"\nwritable = true\nmin = -1\nmax = 1\n\
             [subsystems.arm.states.e{i}]\ndevice = \"j{i}\"\nchannel = \"enable\"\nwritable = true\n"
        );
    }
    let m = Manifest::parse(&text, "na.toml").unwrap_or_else(|e| panic!("{e}"));
    let sub = m.subsystems[0].clone();

    let mut rig = ArmRig::open(&sub, "noalloc-edge");

    // Real time, 5 ms ticks: the simulator answers on its own thread.
    let mut ticks = RealTimeTicks::start();
    // Warm-up: the first bring-up, and a frame so every connection exists.
    for _ in 0..100 {
        ticks.tick(&mut rig.exec);
        rig.ctl.add_ctrl("arm/p1", 0.2).unwrap();
        rig.ctl.add_ctrl("arm/e1", 1.0).unwrap();
        rig.ctl.send_ctrl().unwrap();
    }
    assert!(rig.exec.stages().settled(), "brought up");
    rig.subscribe_stats();
    last_status(&mut rig.p1);

    let mut allocations = 0;
    // The port vanishes: reads and writes fail, the link hands the dead port to its helper.
    sim.unplug();
    for _ in 0..60 {
        allocations += ticks.tick(&mut rig.exec);
        rig.ctl.add_ctrl("arm/p1", 0.3).unwrap();
        rig.ctl.send_ctrl().unwrap();
    }
    let down = last_status(&mut rig.p1);
    assert!(
        down & conductor_bus::status::STALE != 0,
        "stale while down: {down:#x}"
    );
    // Back: the link takes the reopened port, the servos are brought up again.
    sim.replug().unwrap();
    for _ in 0..150 {
        allocations += ticks.tick(&mut rig.exec);
        rig.ctl.add_ctrl("arm/p1", 0.3).unwrap();
        rig.ctl.send_ctrl().unwrap();
    }
    let up = last_status(&mut rig.p1);
    assert_eq!(up & conductor_bus::status::STALE, 0, "fresh again: {up:#x}");
    // Silence: the watchdog trips them; a setpoint is refused; enable.
    for _ in 0..40 {
        allocations += ticks.tick(&mut rig.exec);
    }
    rig.ctl.add_ctrl("arm/p1", -0.3).unwrap();
    rig.ctl.send_ctrl().unwrap();
    allocations += ticks.tick(&mut rig.exec);
    allocations += ticks.tick(&mut rig.exec);
    let tripped = last_status(&mut rig.p1);
    assert!(
        tripped & conductor_bus::status::TRIPPED != 0,
        "{tripped:#x}"
    );
    assert!(
        tripped & conductor_bus::status::REJECTED != 0,
        "{tripped:#x}"
    );
    rig.ctl.add_ctrl("arm/e1", 1.0).unwrap();
    rig.ctl.send_ctrl().unwrap();
    for _ in 0..60 {
        allocations += ticks.tick(&mut rig.exec);
        rig.ctl.add_ctrl("arm/e1", 1.0).unwrap();
        rig.ctl.send_ctrl().unwrap();
    }
    assert_eq!(
        last_status(&mut rig.p1) & conductor_bus::status::TRIPPED,
        0,
        "enabled again"
    );
    assert_eq!(
        allocations, 0,
        "the hardware edge allocated on the real-time thread"
    );
    let s = rig.stats.unwrap().latest().unwrap().unwrap();
    assert_eq!(s.bus_outages, 1, "{s:?}");
    assert!(s.setpoints_refused >= 1, "{s:?}");
}

/// The descriptor of this process's UDP socket connected to `peer` (the executor's bus).
fn udp_socket_connected_to(peer: std::net::SocketAddr) -> std::os::fd::RawFd {
    let std::net::SocketAddr::V4(peer) = peer else {
        panic!("an IPv4 peer");
    };
    for entry in std::fs::read_dir("/proc/self/fd").unwrap() {
        let Ok(fd) = entry.unwrap().file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        // SAFETY: sockaddr_in is plain old data; all-zero is a valid value.
        let mut addr: libc::sockaddr_in = unsafe { std::mem::zeroed() };
        let mut len = std::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t;
        // SAFETY: getpeername writes at most `len` bytes to `addr`, which has that room; a
        // descriptor that is not a connected socket gives an error, which we skip.
        let r = unsafe {
            libc::getpeername(fd, (&mut addr as *mut libc::sockaddr_in).cast(), &mut len)
        };
        if r == 0
            && addr.sin_family == libc::AF_INET as libc::sa_family_t
            && u16::from_be(addr.sin_port) == peer.port()
            && u32::from_be(addr.sin_addr.s_addr) == u32::from(*peer.ip())
        {
            return fd;
        }
    }
    panic!("no socket connected to {peer}");
}

/// A transport that fails on every tick allocates nothing either: a Dynamixel bus over UDP
/// whose socket the OS stops sending on (shut for writing under the running executor, so every
/// `send(2)` fails with `EPIPE`: an I/O error that does not take the bus down). 200 ticks of
/// failed sends, requests that go unanswered, devices going stale, under the counting
/// allocator.
#[test]
fn a_udp_bus_refusing_every_send_allocates_nothing() {
    use conductor_devices::sim::dxl::DxlSimConfig;
    use conductor_devices::sim::runner::{run_dxl_faultless, Endpoint};

    let sim = run_dxl_faultless(
        Endpoint::udp("127.0.0.1:0".parse().unwrap()).unwrap(),
        DxlSimConfig {
            ids: vec![1, 2],
            ..DxlSimConfig::default()
        },
    );
    let sim_addr: std::net::SocketAddr = sim.endpoint().parse().unwrap();
    let mut text = format!(
        "system = \"na\"\n[subsystems.arm]\nrate_hz = 200\n\
         [subsystems.arm.hardware.net]\nkind = \"udp\"\nremote = \"{sim_addr}\"\nlocal = \"127.0.0.1:0\"\n\
         [subsystems.arm.protocols.robotis]\nkind = \"dynamixel2\"\nhardware = \"net\"\ntimeout_us = 10000\n"
    );
    for i in 1..=2 {
        text += &format!(
            "[subsystems.arm.devices.j{i}]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = {i}\n\
             [subsystems.arm.states.p{i}]\ndevice = \"j{i}\"\nchannel = \"position\"\nwritable = true\nmin = -1\nmax = 1\n"
        );
    }
    let m = Manifest::parse(&text, "na.toml").unwrap_or_else(|e| panic!("{e}"));
    let sub = m.subsystems[0].clone();

    let mut rig = ArmRig::open(&sub, "noalloc-udp");

    let mut ticks = RealTimeTicks::start();
    // Warm-up: the servos answer over UDP and are brought up; every connection exists.
    for _ in 0..100 {
        ticks.tick(&mut rig.exec);
        rig.ctl.add_ctrl("arm/p1", 0.2).unwrap();
        rig.ctl.send_ctrl().unwrap();
    }
    assert!(rig.exec.stages().settled(), "brought up over UDP");
    rig.subscribe_stats();
    let up = last_status(&mut rig.p1);
    assert_eq!(
        up & conductor_bus::status::STALE,
        0,
        "fresh over UDP: {up:#x}"
    );
    // Let a stats publication through, to count errors from.
    for _ in 0..25 {
        ticks.tick(&mut rig.exec);
    }
    let errors_before = rig
        .stats
        .as_mut()
        .unwrap()
        .latest()
        .unwrap()
        .unwrap()
        .bus_errors;

    // The OS stops sending on the executor's socket.
    let fd = udp_socket_connected_to(sim_addr);
    // SAFETY: shutdown(2) on a descriptor that stays open (the executor owns it); it changes no
    // memory, only what the socket may do.
    assert_eq!(unsafe { libc::shutdown(fd, libc::SHUT_WR) }, 0);
    let mut allocations = 0;
    for _ in 0..200 {
        allocations += ticks.tick(&mut rig.exec);
        rig.ctl.add_ctrl("arm/p1", 0.3).unwrap();
        rig.ctl.send_ctrl().unwrap();
    }
    assert_eq!(
        allocations, 0,
        "failing sends allocated on the real-time thread"
    );
    // The failures really happened, and were I/O errors, not a vanished bus.
    let down = last_status(&mut rig.p1);
    assert!(
        down & conductor_bus::status::STALE != 0,
        "stale while no request goes out: {down:#x}"
    );
    let s = rig.stats.unwrap().latest().unwrap().unwrap();
    assert!(
        s.bus_errors >= errors_before + 150,
        "one failed send a tick: {} then {}",
        errors_before,
        s.bus_errors
    );
    assert_eq!(s.bus_outages, 0, "{s:?}");
}

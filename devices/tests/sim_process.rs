//! The simulators as separate processes (`conductor-sim`), driven through the real transports:
//! `SerialHardware` on the simulator's pty, for the Dynamixel bus directly and for the SLCAN
//! adapter through `SlcanHardware`. Real time, so the assertions are about packets and bytes,
//! which do not depend on scheduling, and about values within what the model allows.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use conductor_devices::device::{mit_channel, x_channel, DxlXConfig, DynamixelX, MitMotor};
use conductor_devices::hw::{SerialHardware, SerialOptions, SlcanHardware, SlcanOptions};
use conductor_devices::protocol_stage::{
    mit_limits, CanMotorProtocol, Dxl2Protocol, Dxl2ReadMode, Timing,
};
use conductor_devices::{
    Bounded, Credential, Device, Link, LinkOf, Reply, Request, TickCtx, Update,
};
use conductor_protocols::can::CanFrame;

mod common;
use common::field;

struct Sim {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    _dir: PathBuf,
    link: PathBuf,
}

impl Sim {
    fn spawn(args: &[&str]) -> Self {
        // One directory per simulator: the tests of this file run in parallel.
        static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let dir = std::env::temp_dir().join(format!(
            "conductor-sim-test-{}-{}-{}",
            std::process::id(),
            args[0],
            N.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let link = dir.join("tty");
        let mut child = Command::new(env!("CARGO_BIN_EXE_conductor-sim"))
            .args(args)
            .arg("--pty-link")
            .arg(&link)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let stdin = child.stdin.take().unwrap();
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        stdout.read_line(&mut line).unwrap();
        assert!(line.starts_with("ready /dev/pts/"), "{line}");
        assert!(line.contains(&link.display().to_string()), "{line}");
        Sim {
            child,
            stdin,
            stdout,
            _dir: dir,
            link,
        }
    }

    fn stats(&mut self) -> String {
        self.cmd("stats")
    }

    /// Sends one command line; returns the one line it is answered with.
    fn cmd(&mut self, line: &str) -> String {
        writeln!(self.stdin, "{line}").unwrap();
        let mut answer = String::new();
        self.stdout.read_line(&mut answer).unwrap();
        answer.trim_end().to_string()
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = writeln!(self.stdin, "quit");
        let deadline = Instant::now() + Duration::from_secs(2);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.child.kill();
    }
}

fn num(json: &str, key: &str) -> u64 {
    field(json, key).parse().unwrap()
}

fn now_ns(t0: Instant) -> u64 {
    t0.elapsed().as_nanos() as u64
}

/// Runs `ticks` ticks of `period_ns` in real time, as the executor would: every device samples
/// `channel` and is sent `goal(i)` on it, the link carries the requests, and each reply goes to
/// its device (credential ID `i + 1`), whose updates `on_update(i, update)` sees. Replies from
/// other nodes go to `on_other`.
#[allow(clippy::too_many_arguments)]
fn drive<D: Device>(
    link: &mut impl Link,
    devs: &mut [D],
    ticks: u64,
    period_ns: u64,
    channel: usize,
    goal: impl Fn(usize) -> f64,
    mut on_update: impl FnMut(usize, &Update),
    mut on_other: impl FnMut(&Reply),
) {
    let mut reqs = Bounded::<Request>::with_capacity(64);
    let mut replies = Bounded::<Reply>::with_capacity(64);
    let mut ups = Bounded::with_capacity(64);
    let t0 = Instant::now();
    for k in 0..ticks {
        let due = k * period_ns;
        let now = now_ns(t0);
        if due > now {
            std::thread::sleep(Duration::from_nanos(due - now));
        }
        let ctx = TickCtx {
            tick: k,
            now_ns: now_ns(t0),
        };
        reqs.clear();
        for (i, d) in devs.iter_mut().enumerate() {
            d.sample(channel, ctx, &mut reqs);
            d.write(channel, goal(i), ctx);
            d.flush(ctx, &mut reqs);
        }
        // What arrived since the last tick, before anything new is sent.
        link.receive(ctx);
        link.encode(reqs.as_slice(), ctx);
        link.exchange(ctx).unwrap();
        replies.clear();
        link.decode(&mut replies, ctx);
        for r in replies.as_slice() {
            let i = r.cred.id as usize - 1;
            let Some(d) = devs.get_mut(i) else {
                on_other(r);
                continue;
            };
            ups.clear();
            d.reply(r, &mut ups);
            for u in ups.as_slice() {
                on_update(i, u);
            }
        }
    }
}

#[test]
fn dynamixel_process_over_a_pty_at_250_hz() {
    // About bundling and timing, not power-on: the servos start with torque on.
    let mut sim = Sim::spawn(&["dxl", "--servos", "6", "--torque-on"]);
    let hw = SerialHardware::open(sim.link.to_str().unwrap(), &SerialOptions::default()).unwrap();
    let timing = Timing {
        baud: 1_000_000,
        return_delay_ns: 0,
        timeout_ns: 2_000_000,
    };
    let mut link = LinkOf::new(
        Dxl2Protocol::new(timing, Dxl2ReadMode::Sync, 6, 48),
        hw,
        4096,
    );
    let mut devs: Vec<DynamixelX> = (1..=6)
        .map(|id| DynamixelX::new(Credential::id(id), DxlXConfig::default()))
        .collect();
    let (mut values, mut stale) = (0u32, 0u32);
    let mut last = [0.0f64; 6];
    drive(
        &mut link,
        &mut devs,
        250,
        4_000_000,
        x_channel::POSITION,
        |_| 0.25,
        |i, u| match u.value {
            Some(v) => {
                values += 1;
                last[i] = v;
            }
            None => stale += 1,
        },
        |r| panic!("a reply from a node that was not asked: {r:?}"),
    );
    // Let the last tick's bytes reach the simulator before comparing counts.
    std::thread::sleep(Duration::from_millis(50));
    let s = sim.stats();
    let c = link.counters();
    // Nothing is lost on a pty: the simulator saw every packet and byte the stage sent.
    assert_eq!(num(&s, "packets_in"), c.protocol.packets_out, "{s}");
    assert_eq!(num(&s, "bytes_in"), c.protocol.words_out, "{s}");
    assert_eq!(num(&s, "discarded_in"), 0);
    // One SYNC WRITE and one SYNC READ per bus window.
    assert_eq!(num(&s, "sync_write"), num(&s, "sync_read"));
    assert_eq!(num(&s, "sync_write") * 2, c.protocol.packets_out);
    assert!(num(&s, "sync_write") >= 200, "{s}");
    // Every reply that came is a value; a late one (scheduling) is stale and counted.
    assert_eq!(c.protocol.missing_replies, stale as u64);
    // Every request was answered or declared missing, except those of the last tick or two
    // (still on the wire, or queued while the bus was busy); late replies on a busy machine are
    // the stale ones.
    assert!(
        (6 * 248..=6 * 250).contains(&(values + stale)),
        "{values} values, {stale} stale"
    );
    assert!(values >= 6 * 125, "{values} values, {stale} stale");
    // 1 s at τ = 50 ms: at the goal (0.25 rad = 163 pulses from the middle).
    for v in last {
        assert!(
            (v - 0.25).abs() < 2.0 * 2.0 * std::f64::consts::PI / 4096.0,
            "{last:?}"
        );
    }
    assert_eq!(field(&s, "goal"), "[2211,2211,2211,2211,2211,2211]");
}

#[test]
fn slcan_process_with_three_mit_motors() {
    let mut sim = Sim::spawn(&["slcan", "--mit", "1,2,3", "--odrive", "4"]);
    let port = SerialHardware::open(sim.link.to_str().unwrap(), &SerialOptions::default()).unwrap();
    let hw = SlcanHardware::open(port, SlcanOptions::default()).unwrap();
    let proto = CanMotorProtocol::new(mit_limits("ak80-9").unwrap(), vec![], 0, 3_000_000, 32);
    let mut link = LinkOf::with_fill(proto, hw, 64, CanFrame::standard(0, &[]).unwrap());
    let mut devs: Vec<MitMotor> = (1..=3)
        .map(|id| MitMotor::new(Credential::id(id), 20.0, 1.0))
        .collect();
    // Unmanaged drivers: enter motor mode on the first tick, through the enable channel.
    for d in &mut devs {
        d.write(mit_channel::ENABLE, 1.0, TickCtx { tick: 0, now_ns: 0 });
    }
    let (mut values, mut stale) = (0u64, 0u64);
    let mut total_heartbeats = 0;
    let mut last = [0.0f64; 3];
    drive(
        &mut link,
        &mut devs,
        500,
        2_000_000,
        mit_channel::POSITION,
        |i| 0.4 * (i as f64 + 1.0),
        |i, u| match u.value {
            Some(v) => {
                values += 1;
                last[i] = v;
            }
            None => stale += 1,
        },
        // Node 4 is an ODrive: its cyclic heartbeat arrives unasked.
        |r| {
            assert_eq!(r.cred.id, 4, "{r:?}");
            total_heartbeats += 1;
        },
    );
    // 1 s of 100 ms heartbeats.
    assert!((8..=12).contains(&total_heartbeats), "{total_heartbeats}");
    std::thread::sleep(Duration::from_millis(50));
    let s = sim.stats();
    let hs = link.hardware().expect("the adapter is open").stats();
    assert_eq!(num(&s, "frames_from_host"), hs.frames_out, "{s}");
    assert_eq!(
        hs.frames_out,
        3 + 500 * 3,
        "one frame per motor and tick, plus the enables"
    );
    assert_eq!(hs.nacks, 0);
    // Every frame but the last tick's was answered or declared missing: one position update
    // each (the enables' replies included).
    assert!(
        (3 * 500..=3 * 501).contains(&(values + stale)),
        "{values} + {stale}"
    );
    assert_eq!(link.counters().protocol.missing_replies, stale);
    assert!(values >= 3 * 250, "{values} values, {stale} stale");
    for (i, v) in last.iter().enumerate() {
        assert!((v - 0.4 * (i as f64 + 1.0)).abs() < 0.01, "{last:?}");
    }
}

/// The simulator behind a UDP socket (what a serial-over-UDP bridge looks like) and the `udp`
/// transport: same packets, same answers.
#[test]
fn dynamixel_over_udp() {
    use conductor_devices::hw::UdpHardware;
    use conductor_devices::sim::dxl::DxlSimConfig;
    use conductor_devices::sim::runner::{run_dxl_faultless, Endpoint};

    let ep = Endpoint::udp("127.0.0.1:0".parse().unwrap()).unwrap();
    let sim = run_dxl_faultless(
        ep,
        DxlSimConfig {
            ids: vec![1, 2, 3],
            tau_s: 0.0,
            // About the transport, not power-on: the servos follow their goals.
            torque_on: true,
            ..DxlSimConfig::default()
        },
    );
    let peer = sim.endpoint().parse().unwrap();
    let hw = UdpHardware::open("127.0.0.1:0".parse().unwrap(), peer).unwrap();
    let timing = Timing {
        baud: 1_000_000,
        return_delay_ns: 0,
        timeout_ns: 5_000_000,
    };
    let mut link = LinkOf::new(
        Dxl2Protocol::new(timing, Dxl2ReadMode::Fast, 3, 8),
        hw,
        2048,
    );
    let mut devs: Vec<DynamixelX> = (1..=3)
        .map(|id| DynamixelX::new(Credential::id(id), DxlXConfig::default()))
        .collect();
    let mut last = [None; 3];
    drive(
        &mut link,
        &mut devs,
        100,
        4_000_000,
        x_channel::POSITION,
        |_| -0.5,
        |i, u| {
            if u.value.is_some() {
                last[i] = u.value;
            }
        },
        |r| panic!("a reply from a node that was not asked: {r:?}"),
    );
    std::thread::sleep(Duration::from_millis(50));
    let s = sim.sim().stats();
    let c = link.counters();
    assert_eq!(s.packets_in, c.protocol.packets_out);
    assert_eq!(s.bytes_in, c.protocol.words_out);
    assert!(s.fast_sync_read >= 90, "{s:?}");
    // τ = 0: the servos are at the goal (−0.5 rad → 2048 − 326 pulses) exactly.
    let want = (2048 - 326 - 2048) as f64 * 2.0 * std::f64::consts::PI / 4096.0;
    assert_eq!(last, [Some(want); 3]);
}

/// The stdin commands of `conductor-sim dxl`: a hardware error shows in the stats, the
/// adapter is unplugged (the link disappears) and plugged back (a fresh open talks to the same
/// servos), and commands that do not apply are refused with a reason.
#[test]
fn dynamixel_process_commands() {
    use conductor_protocols::dynamixel2::{self as dxl, Scanner, Status};
    use std::io::Read;

    let mut sim = Sim::spawn(&["dxl", "--servos", "2", "--model", "1060"]);
    assert_eq!(sim.cmd("fault 2 0x20"), "ok");
    let s = sim.stats();
    assert_eq!(field(&s, "hardware_error"), "[0,32]");
    assert_eq!(field(&s, "torque"), "[0,0]");
    assert!(sim.cmd("fault 9 1").starts_with("error no servo 9"));
    assert!(sim.cmd("fault 1").starts_with("error usage"));
    assert!(sim.cmd("stall 10").starts_with("error"));
    assert!(sim.cmd("clear 2").starts_with("error"));
    assert!(sim.cmd("frobnicate").starts_with("error"));
    assert_eq!(sim.cmd("unplug"), "ok");
    assert!(std::fs::symlink_metadata(&sim.link).is_err());
    assert_eq!(sim.cmd("replug"), "ok");
    assert!(sim.cmd("replug").starts_with("error"), "already plugged");
    let mut port = serialport::new(sim.link.to_str().unwrap(), 1_000_000)
        .timeout(Duration::from_secs(2))
        .open_native()
        .unwrap();
    let mut buf = [0u8; 64];
    let n = dxl::ping(&mut buf, 2).unwrap();
    port.write_all(&buf[..n]).unwrap();
    let mut scanner = Scanner::<256>::new();
    let status = loop {
        let k = port.read(&mut buf).unwrap();
        scanner.push(&buf[..k]);
        if let Some(p) = scanner.next_packet() {
            let s = Status::from_packet(&p).unwrap();
            break (s.error.0, s.data.to_vec());
        }
    };
    // The Alert bit of the latched error, and the model of --model.
    assert_eq!(status, (0x80, vec![0x24, 0x04, 45]));
}

/// The stdin commands of `conductor-sim slcan`: faults per node, and the adapter's odd
/// behaviours (no acks, latency, stall, raw bytes to the host).
#[test]
fn slcan_process_commands() {
    // No cyclic heartbeat: the host reads exact byte streams below.
    let mut sim = Sim::spawn(&[
        "slcan",
        "--mit",
        "1",
        "--odrive",
        "4",
        "--long-reply",
        "--heartbeat-ms",
        "0",
    ]);
    assert_eq!(sim.cmd("fault 1 5"), "ok");
    assert_eq!(sim.cmd("fault 4 0x800"), "ok");
    let s = sim.stats();
    assert!(
        s.contains("\"id\": 1, ") && s.contains("\"fault\": 5,"),
        "{s}"
    );
    assert!(s.contains("\"fault\": 2048,"), "{s}");
    assert_eq!(sim.cmd("clear 1"), "ok");
    assert!(sim.cmd("fault 7 1").starts_with("error no node 7"));
    assert!(
        sim.cmd("fault 1 256").starts_with("error node 1"),
        "not an MIT code"
    );
    assert!(sim.cmd("acks maybe").starts_with("error usage"));
    assert!(sim.cmd("inject 7G").starts_with("error"));
    let mut port = serialport::new(sim.link.to_str().unwrap(), 1_000_000)
        .timeout(Duration::from_secs(2))
        .open_native()
        .unwrap();
    let read_until = common::read_lines;
    assert_eq!(sim.cmd("inject 74 30 30 30 30 0D"), "ok");
    assert_eq!(read_until(&mut port, 1), "t0000\r");
    assert_eq!(sim.cmd("acks off"), "ok");
    assert_eq!(sim.cmd("latency 1000"), "ok");
    assert_eq!(sim.cmd("stall 20"), "ok");
    port.write_all(b"O\rt0018FFFFFFFFFFFFFFFC\r").unwrap();
    // Open's CR, then no ack for the frame: the motor's 8-byte reply alone (no fault any
    // more, 40 °C).
    assert_eq!(read_until(&mut port, 2), "\rt0008017FFF7FF7FF2800\r");
    let s = sim.stats();
    assert_eq!(field(&s, "frames_from_host"), "1");
}

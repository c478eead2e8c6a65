//! A simulator on a pty can be unplugged and plugged back at the same path, as a USB adapter
//! pulled out while the servos or motors behind it stay powered: the host's open descriptor
//! sees the hang-up, a fresh open after the replug works, and the simulator's state survived.
//! The runner also honours the SLCAN adapter's latency and stalls.
//!
//! The only time checks are lower bounds (a reply cannot come before the adapter's latency or
//! the end of its stall), which a slow or loaded machine cannot break.

use std::io::{Read, Write};
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

mod common;
use common::read_lines;

use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim};
use conductor_devices::sim::dxl::DxlSimConfig;
use conductor_devices::sim::runner::{run_dxl_faultless, run_slcan, Endpoint, Pty};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_protocols::dynamixel2::{self as dxl, Scanner, Status};
use conductor_protocols::slcan::Dialect;
use serialport::TTYPort;

fn link(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("conductor-sim-plug-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn open(path: &Path) -> TTYPort {
    serialport::new(path.to_str().unwrap(), 1_000_000)
        .timeout(Duration::from_secs(2))
        .open_native()
        .unwrap()
}

/// Sends one instruction and reads its status packet: (error byte, data).
fn exchange(port: &mut TTYPort, build: impl FnOnce(&mut [u8]) -> usize) -> (u8, Vec<u8>) {
    let mut buf = [0u8; 256];
    let n = build(&mut buf);
    port.write_all(&buf[..n]).unwrap();
    let mut scanner = Scanner::<1024>::new();
    let deadline = Instant::now() + Duration::from_secs(2);
    while Instant::now() < deadline {
        let k = port.read(&mut buf).unwrap();
        scanner.push(&buf[..k]);
        if let Some(p) = scanner.next_packet() {
            let s = Status::from_packet(&p).unwrap();
            return (s.error.0, s.data.to_vec());
        }
    }
    panic!("no status packet");
}

/// The host's descriptor after the simulator was unplugged: poll says readable or hung up,
/// and read(2) returns end of file or EIO rather than blocking.
fn assert_hung_up(port: &TTYPort) {
    let fd = port.as_raw_fd();
    let mut pfd = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: one valid pollfd.
    let r = unsafe { libc::poll(&mut pfd, 1, 2000) };
    assert_eq!(r, 1, "poll: the hang-up is an event");
    assert!(pfd.revents & (libc::POLLHUP | libc::POLLIN | libc::POLLERR) != 0);
    let mut b = [0u8; 16];
    // SAFETY: b is valid for 16 bytes.
    let n = unsafe { libc::read(fd, b.as_mut_ptr().cast(), b.len()) };
    let err = std::io::Error::last_os_error();
    assert!(
        n == 0 || (n < 0 && err.raw_os_error() == Some(libc::EIO)),
        "read after unplug: {n} {err}"
    );
}

#[test]
fn dynamixel_unplugged_and_replugged_at_the_same_path_keeps_the_servos_state() {
    let path = link("dxl");
    let sim = run_dxl_faultless(
        Endpoint::Pty(Pty::open(Some(&path)).unwrap()),
        DxlSimConfig {
            ids: vec![1, 2],
            tau_s: 0.0,
            ..DxlSimConfig::default()
        },
    );
    assert!(sim.is_plugged());
    assert_eq!(sim.link(), Some(path.as_path()));
    let mut port = open(&path);
    let goal = 3000i32.to_le_bytes();
    assert_eq!(
        exchange(&mut port, |b| dxl::write(b, 1, 116, &goal).unwrap()).0,
        0
    );
    assert_eq!(
        exchange(&mut port, |b| dxl::write(b, 1, 64, &[1]).unwrap()).0,
        0
    );

    sim.unplug();
    assert!(!sim.is_plugged());
    assert!(
        std::fs::symlink_metadata(&path).is_err(),
        "the link is gone"
    );
    assert_hung_up(&port);
    drop(port);
    sim.unplug(); // already unplugged: nothing happens
    assert!(serialport::new(path.to_str().unwrap(), 1_000_000)
        .open_native()
        .is_err());
    // The servos stayed powered.
    {
        let s = sim.sim();
        let servo = s.servo(1).unwrap();
        assert!(servo.torque_on());
        assert_eq!(servo.present_position(), 3000);
    }

    sim.replug().unwrap();
    assert!(sim.is_plugged());
    let e = sim.replug().unwrap_err();
    assert_eq!(e.kind(), std::io::ErrorKind::AlreadyExists);
    let mut port = open(&path);
    let (err, data) = exchange(&mut port, |b| dxl::read(b, 1, 64, 1).unwrap());
    assert_eq!((err, data), (0, vec![1]), "torque still on");
    let (_, data) = exchange(&mut port, |b| dxl::read(b, 1, 116, 4).unwrap());
    assert_eq!(data, goal, "goal kept");
    let (_, data) = exchange(&mut port, |b| dxl::read(b, 2, 64, 1).unwrap());
    assert_eq!(data, [0], "servo 2 never enabled");

    // A second unplug/replug cycle works the same.
    sim.unplug();
    assert_hung_up(&port);
    drop(port);
    sim.replug().unwrap();
    let mut port = open(&path);
    assert_eq!(exchange(&mut port, |b| dxl::ping(b, 2).unwrap()).0, 0);
}

#[test]
fn replug_needs_a_link() {
    let sim = run_slcan(
        Endpoint::Pty(Pty::open(None).unwrap()),
        SlcanAdapterSim::new(Dialect::CANABLE, vec![]),
    );
    assert_eq!(sim.link(), None);
    sim.unplug();
    let e = sim.replug().unwrap_err();
    assert_eq!(e.kind(), std::io::ErrorKind::Unsupported);
}

fn slcan_line(port: &mut TTYPort, cmd: &str) -> String {
    port.write_all(cmd.as_bytes()).unwrap();
    read_lines(port, 1)
}

#[test]
fn slcan_adapter_unplugged_forgets_its_channel_but_the_motors_keep_their_state() {
    let path = link("can");
    let nodes: Vec<Box<dyn CanNode>> = vec![Box::new(MitMotorSim::new(
        1,
        mit_limits("ak80-9").unwrap(),
        0,
        false,
    ))];
    let sim = run_slcan(
        Endpoint::Pty(Pty::open(Some(&path)).unwrap()),
        SlcanAdapterSim::new(Dialect::CANABLE, nodes),
    );
    let enter = "t0018FFFFFFFFFFFFFFFC\r";
    let mut port = open(&path);
    assert_eq!(slcan_line(&mut port, "O\r"), "\r");
    port.write_all(enter.as_bytes()).unwrap();
    assert_eq!(read_lines(&mut port, 2), "\rt0006017FFF7FF7FF\r");

    sim.unplug();
    assert_hung_up(&port);
    drop(port);
    assert!(!sim.sim().is_open(), "the adapter lost power");
    assert!(sim.sim().nodes()[0].snapshot().enabled, "the motor did not");
    sim.replug().unwrap();
    let mut port = open(&path);
    assert_eq!(
        slcan_line(&mut port, enter),
        "\x07",
        "closed until opened again"
    );
    assert_eq!(slcan_line(&mut port, "O\r"), "\r");
    assert_eq!(sim.sim().nodes()[0].snapshot().frames_in, 1);
}

#[test]
fn slcan_runner_honours_latency_and_stalls() {
    let path = link("can-lag");
    let sim = run_slcan(
        Endpoint::Pty(Pty::open(Some(&path)).unwrap()),
        SlcanAdapterSim::new(Dialect::CANABLE, vec![]),
    );
    let mut port = open(&path);
    sim.sim().set_latency(30_000_000);
    let t = Instant::now();
    assert_eq!(slcan_line(&mut port, "V\r"), "V1013\r");
    assert!(
        t.elapsed() >= Duration::from_millis(30),
        "{:?}",
        t.elapsed()
    );
    sim.sim().set_latency(0);
    let t = Instant::now();
    let until = sim.now_ns() + 50_000_000;
    sim.sim().stall_until(until);
    port.write_all(b"V\rN\r").unwrap();
    assert_eq!(read_lines(&mut port, 2), "V1013\rNSIM1\r");
    assert!(
        t.elapsed() >= Duration::from_millis(50),
        "{:?}",
        t.elapsed()
    );
    assert!(sim.now_ns() >= until);
}

//! `udp-gateway`: the documented SET/GET/SMP/INFO answers, 10 000 malformed datagrams, and the
//! MATLAB-style Python client of examples/ closing a loop on the simulated motor through it.

mod support;

use std::net::UdpSocket;
use std::process::Command;
use std::time::{Duration, Instant};

use conductor_bus::{Bus, Domain, StateSubscriber};
use conductor_cli::udp::protocol;
use conductor_examples::{motor, sim};
use support::*;

struct Client {
    sock: UdpSocket,
}

impl Client {
    fn new() -> Self {
        let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
        sock.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        Self { sock }
    }

    fn ask(&self, port: u16, req: &[u8]) -> String {
        self.sock.send_to(req, ("127.0.0.1", port)).unwrap();
        self.recv()
    }

    fn recv(&self) -> String {
        let mut buf = [0u8; 600];
        let (n, _) = self.sock.recv_from(&mut buf).expect("a reply within 2 s");
        String::from_utf8(buf[..n].to_vec()).unwrap()
    }

    /// Asks until the reply is `want` (a setpoint takes effect at the executor's next tick).
    fn ask_until(&self, port: u16, req: &[u8], want: &str) {
        let end = Instant::now() + Duration::from_secs(2);
        loop {
            let r = self.ask(port, req);
            if r == want {
                return;
            }
            assert!(Instant::now() < end, "still {r:?}, want {want:?}");
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

fn gateway(d: &Domain, pattern: &str, base: u16) -> Bg {
    let mut cmd = conductor(d);
    cmd.args(["udp-gateway", pattern, "--base-port", &base.to_string()]);
    Bg::spawn(&mut cmd)
}

#[test]
fn set_get_smp_info_give_the_documented_answers() {
    let (d, _leg) = domain_with_leg("udp", 200.0, leg);
    let base = free_udp_ports(3);
    let mut gw = gateway(&d, "leg/*", base);
    let map = gw.until(Duration::from_secs(10), |l| l == "READY");
    // The port map: base + state order (`conductor list` order).
    let rows: Vec<Vec<&str>> = map.iter().map(|l| l.split_whitespace().collect()).collect();
    assert_eq!(rows[1], ["PORT", "STATE", "UNITS", "RW"], "{map:?}");
    let (knee, hip, current) = (base, base + 1, base + 2);
    assert_eq!(
        rows[2],
        [knee.to_string().as_str(), "leg/knee", "rad", "rw"]
    );
    assert_eq!(rows[3], [hip.to_string().as_str(), "leg/hip", "rad", "rw"]);
    assert_eq!(
        rows[4],
        [current.to_string().as_str(), "leg/current", "A", "ro"]
    );

    let c = Client::new();
    assert_eq!(c.ask(knee, b"GET"), "0");
    assert_eq!(c.ask(knee, b"SET 0.5"), "OK 0.5");
    c.ask_until(knee, b"GET", "0.5");
    // Out of limits: clamped, and the reply says so.
    assert_eq!(c.ask(knee, b"SET 7"), "OK 2 CLAMPED");
    c.ask_until(knee, b"get\r\n", "2");
    assert_eq!(c.ask(hip, b"set -0.25"), "OK -0.25");
    c.ask_until(hip, b"GET", "-0.25");
    assert_eq!(c.ask(current, b"SET 1"), "ERR leg/current is read-only");
    assert_eq!(c.ask(current, b"GET"), "0");
    assert_eq!(c.ask(knee, b"INFO"), "leg/knee rad rw -1.5 2 200");
    assert_eq!(c.ask(current, b"INFO"), "leg/current A ro -5 5 200");

    // SMP: the next fresh sample, `<value> <t_sample_ns> <seq> <status>`.
    let smp = |port| -> (String, u64, u64, u32) {
        let r = c.ask(port, b"SMP");
        let f: Vec<&str> = r.split(' ').collect();
        assert_eq!(f.len(), 4, "{r}");
        (
            f[0].into(),
            f[1].parse().unwrap(),
            f[2].parse().unwrap(),
            f[3].parse().unwrap(),
        )
    };
    let a = smp(knee);
    let b = smp(knee);
    assert_eq!((a.0.as_str(), a.3), ("2", conductor_bus::status::SIMULATED));
    assert!(b.2 > a.2 && b.1 > a.1, "{a:?} then {b:?}");

    let (success, stderr) = gw.interrupt();
    assert!(success, "{stderr}");
    // 15 requests: none malformed, one refused (the read-only SET).
    assert!(stderr.contains("0 malformed, 1 refused"), "{stderr}");
}

/// Deterministic junk: every kind of malformed request, then pseudo-random bytes.
fn junk(i: u32, rng: &mut u64) -> Vec<u8> {
    let fixed: [&[u8]; 12] = [
        b"",
        b"   \r\n",
        b"FOO",
        b"SET",
        b"SET abc",
        b"SET nan",
        b"SET -inf",
        b"SET 1 2",
        b"GET now",
        b"SMP 3",
        b"\xff\xfe\x00\x01",
        b"\x1b[2J\x1b[H",
    ];
    let k = i as usize % 16;
    if k < fixed.len() {
        return fixed[k].to_vec();
    }
    let len = match k {
        12 => 300,  // over the 256-byte limit
        13 => 2000, // over the receive buffer
        _ => 1 + (*rng >> 58) as usize,
    };
    (0..len)
        .map(|_| {
            *rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (*rng >> 33) as u8
        })
        .collect()
}

#[test]
fn ten_thousand_malformed_datagrams_get_err_and_the_gateway_keeps_serving() {
    let (d, _leg) = domain_with_leg("udpjunk", 200.0, leg);
    let base = free_udp_ports(3);
    let mut gw = gateway(&d, "leg/*", base);
    gw.until(Duration::from_secs(10), |l| l == "READY");
    let c = Client::new();
    let mut rng = 0x5eed_u64;
    let mut sent = 0u32;
    // Batches of 100 in flight: well within the sockets' buffers, so nothing is dropped.
    while sent < 10_000 {
        let mut batch = 0;
        while batch < 100 {
            let mut d = junk(sent, &mut rng);
            if protocol::parse(&d).is_ok() {
                d = b"NOT A COMMAND".to_vec(); // random bytes that happen to parse
            }
            c.sock
                .send_to(&d, ("127.0.0.1", base + (sent % 3) as u16))
                .unwrap();
            sent += 1;
            batch += 1;
        }
        for _ in 0..batch {
            let r = c.recv();
            assert!(r.starts_with("ERR "), "{r:?}");
            assert!(r.len() < 200 && !r.contains('\x1b'), "{r:?}");
        }
    }
    // Still serving, correctly.
    assert_eq!(c.ask(base, b"SET 1"), "OK 1");
    c.ask_until(base, b"GET", "1");
    let (success, stderr) = gw.interrupt();
    assert!(success, "{stderr}");
    assert!(stderr.contains("10000 malformed, 0 refused"), "{stderr}");
}

#[test]
fn python_udp_client_closes_a_loop_on_the_motor() {
    let d = Domain::unique("udpmotor").unwrap();
    let _motor = sim::spawn(&d, motor::spec(500.0), motor::Motor::default()).unwrap();
    let base = free_udp_ports(3);
    let mut gw = gateway(&d, "motor/*", base);
    gw.until(Duration::from_secs(10), |l| l == "READY");
    let out = conductor_testkit::run_ok(
        Command::new(python())
            .arg(workspace().join("examples/python/udp_client.py"))
            .args([
                "--base-port",
                &base.to_string(),
                "--target",
                "1.0",
                "--seconds",
                "3",
            ]),
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(report["steps"].as_u64().unwrap() > 50, "{report}");

    // Check on the bus, not by the client's word. The PD loop (Kp 5, Kd 0.5) on this motor
    // (gain 2 rad/s/V, τ 0.1 s) has a double pole at −10 s⁻¹: the error after 3 s is
    // (1 + 10t)·e^{−10t} ≈ 3e-12 of the 1 rad step; 0.01 rad leaves room for the client's
    // 10 ms period and UDP round trips, which delay the loop but cannot leave a steady error
    // (the plant integrates, so any offset keeps driving the command).
    let bus = Bus::open(&d, "check").unwrap();
    let mut sub = StateSubscriber::new(&bus, "motor/position").unwrap();
    let end = Instant::now() + Duration::from_secs(2);
    let theta = loop {
        if let Some(s) = sub.latest().unwrap() {
            break s.value;
        }
        assert!(Instant::now() < end, "no position sample");
        std::thread::sleep(Duration::from_millis(5));
    };
    assert!(
        (theta - 1.0).abs() < 0.01,
        "position {theta}, client said {report}"
    );
    let (success, stderr) = gw.interrupt();
    assert!(success && stderr.contains(" 0 malformed"), "{stderr}");
}

//! The SLCAN adapter simulator can behave like a lagging or odd real adapter: latency, stalls
//! with a backlog, no TX acks, raw bytes to the host, listen-only, unplugging. Sans-IO: bytes
//! are fed and polled with explicit times.

use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{MitMotorSim, OdriveAxisSim};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_protocols::slcan::Dialect;

const MS: u64 = 1_000_000;

/// MIT motors 1 and 2 (6-byte replies) and, with `odrive`, ODrive node 4 with a 10 ms
/// heartbeat.
fn adapter(dialect: Dialect, odrive: bool) -> SlcanAdapterSim {
    let mut nodes = MitMotorSim::bus([1, 2], mit_limits("ak80-9").unwrap());
    if odrive {
        nodes.push(Box::new(OdriveAxisSim::new(4, 10, 0)));
    }
    SlcanAdapterSim::new(dialect, nodes)
}

fn feed(a: &mut SlcanAdapterSim, bytes: &str, t: u64) -> String {
    let mut out = Vec::new();
    a.feed(bytes.as_bytes(), t, &mut out);
    String::from_utf8(out).unwrap()
}

fn poll(a: &mut SlcanAdapterSim, t: u64) -> String {
    let mut out = Vec::new();
    a.poll(t, &mut out);
    String::from_utf8(out).unwrap()
}

/// Enter motor mode, for motor `id`.
fn enter(id: u8) -> String {
    format!("t00{id}8FFFFFFFFFFFFFFFC\r")
}

/// The reply line of an MIT motor at rest (position 0, velocity 0, torque 0), to master 0.
fn at_rest(id: u8) -> String {
    format!("t00060{id}7FFF7FF7FF\r")
}

#[test]
fn latency_delays_every_byte_in_order() {
    let mut a = adapter(Dialect::CANABLE, false);
    a.set_latency(2 * MS);
    assert_eq!(feed(&mut a, "S8\rO\r", 0), "");
    assert_eq!(poll(&mut a, 2 * MS - 1), "");
    assert_eq!(a.in_flight(), 2);
    assert_eq!(a.next_due(), Some(2 * MS));
    assert_eq!(poll(&mut a, 2 * MS), "\r\r");
    assert_eq!(a.stats().bytes_out, 2, "counted when the host gets them");
    // A frame at 10 ms: the ack and the motor's reply both arrive at 12 ms, ack first.
    assert_eq!(feed(&mut a, &enter(1), 10 * MS), "");
    assert_eq!(
        a.nodes()[0].snapshot().frames_in,
        1,
        "on the bus at once, only the host side lags"
    );
    assert_eq!(feed(&mut a, &enter(2), 11 * MS), "");
    assert_eq!(poll(&mut a, 12 * MS), format!("\r{}", at_rest(1)));
    assert_eq!(poll(&mut a, 13 * MS), format!("\r{}", at_rest(2)));
    assert_eq!(a.next_due(), None);
}

#[test]
fn a_stall_buffers_everything_then_works_through_the_backlog_in_order() {
    let mut a = adapter(Dialect::CANABLE, true);
    assert_eq!(feed(&mut a, "S8\rO\r", 0), "\r\r");
    let hb = poll(&mut a, 0);
    assert!(
        hb.starts_with("t0818") && hb.ends_with('\r'),
        "heartbeat: {hb}"
    );
    a.stall_until(100 * MS);
    assert!(a.is_stalled(50 * MS));
    assert_eq!(feed(&mut a, &enter(1), 10 * MS), "");
    assert_eq!(feed(&mut a, &enter(2), 20 * MS), "");
    // Nothing reaches the bus, no acks, no cyclic messages (the heartbeat is due every
    // 10 ms).
    assert_eq!(poll(&mut a, 50 * MS), "");
    assert!(a.nodes().iter().all(|n| n.snapshot().frames_in == 0));
    assert_eq!(a.next_due(), Some(100 * MS));
    // At 100 ms: ack 1, reply to 1, ack 2, reply to 2, then the heartbeat that is due.
    let out = poll(&mut a, 100 * MS);
    let hb = &out[out.rfind('t').unwrap()..];
    assert_eq!(
        out,
        format!("\r{}\r{}{hb}", at_rest(1), at_rest(2)),
        "in stream order"
    );
    assert!(hb.starts_with("t0818"), "{hb}");
    assert!(a.nodes()[..2].iter().all(|n| n.snapshot().enabled));
    // New bytes fed after the stall are processed after the backlog.
    a.stall_until(200 * MS);
    assert_eq!(feed(&mut a, "V\r", 150 * MS), "");
    assert_eq!(feed(&mut a, "F\r", 250 * MS), "V1013\rF00\r");
}

#[test]
fn without_acks_frames_go_on_the_bus_unacknowledged() {
    for (dialect, ack) in [(Dialect::CANABLE, "\r"), (Dialect::LAWICEL, "z\r")] {
        let mut a = adapter(dialect, false);
        assert_eq!(feed(&mut a, &enter(1), 0), "\x07", "closed: BEL");
        assert_eq!(feed(&mut a, "O\r", 0), "\r");
        assert_eq!(feed(&mut a, &enter(1), 0), format!("{ack}{}", at_rest(1)));
        a.set_acks(false);
        assert_eq!(
            feed(&mut a, &enter(2), 0),
            at_rest(2),
            "{dialect:?}: no ack"
        );
        assert_eq!(feed(&mut a, "V\r", 0), "V1013\r", "other commands answered");
        assert_eq!(feed(&mut a, "C\r", 0), "\r");
        let nacks = a.stats().nacks;
        assert_eq!(feed(&mut a, &enter(1), 0), "", "closed: dropped silently");
        assert_eq!(a.stats().nacks, nacks + 1);
        assert_eq!(a.stats().frames_from_host, 2);
    }
}

#[test]
fn injected_bytes_reach_the_host_after_what_is_on_its_way() {
    let mut a = adapter(Dialect::CANABLE, false);
    assert_eq!(feed(&mut a, "O\r", 0), "\r");
    // A frame line with a timestamp while timestamps are off, as odd firmware sends.
    let odd = "t0006018A3C7AD838ABCD\r";
    a.inject_to_host(odd.as_bytes());
    assert_eq!(poll(&mut a, 0), odd);
    a.inject_to_host(b"\xFFgarbage\r");
    let mut out = Vec::new();
    a.poll(0, &mut out);
    assert_eq!(out, b"\xFFgarbage\r");
    // Behind the latency queue: order kept.
    a.set_latency(MS);
    feed(&mut a, &enter(1), MS);
    a.inject_to_host(b"X\r");
    assert_eq!(poll(&mut a, MS), "");
    assert_eq!(poll(&mut a, 2 * MS), format!("\r{}X\r", at_rest(1)));
}

#[test]
fn timestamps_listen_only_double_open_and_unplug() {
    let mut a = adapter(Dialect::CANABLE, false);
    assert_eq!(feed(&mut a, "Z1\rO\r", 0), "\r\r");
    let out = feed(&mut a, &enter(1), 1234 * MS);
    // 4 more hex digits: 1234 ms.
    assert_eq!(out, format!("\r{}04D2\r", at_rest(1).trim_end()));
    let t = 2 * 1000 * MS;
    assert_eq!(feed(&mut a, "O\r", t), "\x07", "already open");
    assert_eq!(feed(&mut a, "S6\r", t), "\x07", "bitrate only while closed");
    assert_eq!(feed(&mut a, "C\rL\r", t), "\r\r");
    assert_eq!(
        feed(&mut a, &enter(1), t),
        "\x07",
        "listen-only cannot transmit"
    );
    // Unplugged: the adapter forgets everything (closed, no timestamps, nothing in
    // flight); the motors keep their state.
    a.set_latency(MS);
    feed(&mut a, "C\rO\r", t);
    feed(&mut a, &enter(2), t);
    a.unplug();
    assert!(!a.is_open());
    assert_eq!((a.in_flight(), a.next_due()), (0, None));
    assert!(a.nodes()[1].snapshot().enabled);
    a.set_latency(0);
    assert_eq!(
        feed(&mut a, &enter(1), t + MS),
        "\x07",
        "closed after replug"
    );
    assert_eq!(feed(&mut a, "O\r", t + MS), "\r");
    assert_eq!(
        feed(&mut a, &enter(1), t + MS),
        format!("\r{}", at_rest(1)),
        "timestamps off"
    );
}

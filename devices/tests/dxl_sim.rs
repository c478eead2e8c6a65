//! The Dynamixel bus simulator is as strict as an X-series servo (e-Manual, protocols.md §1):
//! power-on with torque off, goals kept but not followed until torque is enabled, EEPROM and
//! indirect addresses locked while torque is on, indirect data, hardware errors with the Alert
//! bit, REBOOT, Status Return Level, per-servo model and Return Delay Time. Sans-IO: every
//! instruction is fed with an explicit time, so nothing here depends on the machine's timing.

use conductor_devices::sim::dxl::{DxlBusSim, DxlSimConfig};
use conductor_protocols::dynamixel2::{self as dxl, BulkWriteEntry};

/// A status packet as the host decodes it.
#[derive(Debug, Clone, PartialEq, Eq)]
struct St {
    ready_ns: u64,
    id: u8,
    err: u8,
    data: Vec<u8>,
}

/// Feeds one instruction (built by `build` into a buffer) at `t` (ns); returns the replies.
fn tx(sim: &mut DxlBusSim, t: u64, build: impl FnOnce(&mut [u8]) -> usize) -> Vec<St> {
    let mut buf = [0u8; 512];
    let n = build(&mut buf);
    let mut out = Vec::new();
    sim.feed(&buf[..n], t, |r| {
        let mut b = r.bytes.clone();
        let p = dxl::parse_in_place(&mut b).expect("a valid status packet");
        assert!(p.is_status());
        out.push(St {
            ready_ns: r.ready_ns,
            id: p.id,
            err: p.params[0],
            data: p.params[1..].to_vec(),
        });
    });
    out
}

fn read(sim: &mut DxlBusSim, t: u64, id: u8, addr: u16, len: u16) -> Vec<St> {
    tx(sim, t, |b| dxl::read(b, id, addr, len).unwrap())
}

fn write(sim: &mut DxlBusSim, t: u64, id: u8, addr: u16, data: &[u8]) -> Vec<St> {
    tx(sim, t, |b| dxl::write(b, id, addr, data).unwrap())
}

/// The error byte of the one reply to a WRITE.
fn write_err(sim: &mut DxlBusSim, t: u64, id: u8, addr: u16, data: &[u8]) -> u8 {
    let r = write(sim, t, id, addr, data);
    assert_eq!(r.len(), 1, "one status packet: {r:?}");
    r[0].err
}

fn read_i32(sim: &mut DxlBusSim, t: u64, id: u8, addr: u16) -> i32 {
    let r = read(sim, t, id, addr, 4);
    assert_eq!((r.len(), r[0].err), (1, 0), "{r:?}");
    i32::from_le_bytes(r[0].data[..4].try_into().unwrap())
}

fn read_u8(sim: &mut DxlBusSim, t: u64, id: u8, addr: u16) -> u8 {
    let r = read(sim, t, id, addr, 1);
    assert_eq!(r.len(), 1, "{r:?}");
    r[0].data[0]
}

fn sync_write(sim: &mut DxlBusSim, t: u64, addr: u16, entries: &[(u8, &[u8])]) -> Vec<St> {
    let len = entries[0].1.len() as u16;
    tx(sim, t, |b| {
        dxl::sync_write(b, addr, len, entries.iter().copied()).unwrap()
    })
}

const MS: u64 = 1_000_000;
const S: u64 = 1_000_000_000;
const OK: u8 = 0;
const ACCESS: u8 = 0x07;
const ALERT: u8 = 0x80;

fn bus(ids: &[u8]) -> DxlBusSim {
    DxlBusSim::new(DxlSimConfig {
        ids: ids.to_vec(),
        ..DxlSimConfig::default()
    })
}

#[test]
fn power_on_torque_off_goals_kept_but_not_followed_then_a_stale_goal_is_followed() {
    let mut sim = bus(&[1, 2]);
    assert!(!DxlSimConfig::default().torque_on);
    assert_eq!(
        read_u8(&mut sim, 0, 1, 64),
        0,
        "Torque Enable 0 at power-on"
    );
    assert_eq!(
        read_i32(&mut sim, 0, 1, 116),
        2048,
        "Goal = Present at power-on"
    );
    assert_eq!(read_i32(&mut sim, 0, 1, 132), 2048);
    // A goal written with torque off is accepted and kept; the shaft does not move.
    assert_eq!(write_err(&mut sim, MS, 1, 116, &3000i32.to_le_bytes()), OK);
    sync_write(&mut sim, 2 * MS, 116, &[(2, &1000i32.to_le_bytes())]);
    assert_eq!(
        read_i32(&mut sim, S, 1, 132),
        2048,
        "limp: 1 s later, still there"
    );
    assert_eq!(read_i32(&mut sim, S, 2, 132), 2048);
    assert_eq!(read_i32(&mut sim, S, 1, 116), 3000, "the goal is kept");
    assert_eq!(read_i32(&mut sim, S, 2, 128), 0, "not moving");
    // Torque on: the servo goes to whatever Goal Position holds (τ = 50 ms; 1 s = 20 τ).
    assert_eq!(write_err(&mut sim, S, 1, 64, &[1]), OK);
    assert_eq!(read_i32(&mut sim, 2 * S, 1, 132), 3000);
    assert_eq!(
        read_i32(&mut sim, 2 * S, 2, 132),
        2048,
        "servo 2 still limp"
    );
    let s = sim.servo(1).unwrap();
    assert!(s.torque_on());
    assert_eq!(s.goal_position(), 3000);
    // Torque off again: the shaft stays where it is whatever the goal says.
    assert_eq!(write_err(&mut sim, 2 * S, 1, 64, &[0]), OK);
    assert_eq!(
        write_err(&mut sim, 2 * S, 1, 116, &100i32.to_le_bytes()),
        OK
    );
    assert_eq!(read_i32(&mut sim, 3 * S, 1, 132), 3000);
}

#[test]
fn legacy_torque_on_config_powers_up_following_its_goal() {
    let mut sim = DxlBusSim::new(DxlSimConfig {
        ids: vec![1],
        torque_on: true,
        ..DxlSimConfig::default()
    });
    assert_eq!(read_u8(&mut sim, 0, 1, 64), 1);
    assert_eq!(write_err(&mut sim, 0, 1, 116, &2500i32.to_le_bytes()), OK);
    assert_eq!(read_i32(&mut sim, S, 1, 132), 2500);
}

#[test]
fn eeprom_indirect_addresses_and_read_only_items_are_refused_and_change_nothing() {
    let mut sim = bus(&[1, 2]);
    // Torque off: EEPROM and indirect addresses are writable.
    assert_eq!(write_err(&mut sim, 0, 1, 11, &[4]), OK, "operating mode");
    assert_eq!(write_err(&mut sim, 0, 1, 168, &132u16.to_le_bytes()), OK);
    assert_eq!(write_err(&mut sim, 0, 1, 11, &[3]), OK);
    assert_eq!(write_err(&mut sim, 0, 1, 64, &[1]), OK);
    // Torque on: Access Error, nothing changes.
    assert_eq!(write_err(&mut sim, MS, 1, 11, &[4]), ACCESS);
    assert_eq!(write_err(&mut sim, MS, 1, 9, &[10]), ACCESS, "return delay");
    assert_eq!(
        write_err(&mut sim, MS, 1, 170, &133u16.to_le_bytes()),
        ACCESS
    );
    assert_eq!(
        write_err(&mut sim, MS, 1, 63, &[0, 1]),
        ACCESS,
        "spans EEPROM"
    );
    assert_eq!(read_u8(&mut sim, MS, 1, 11), 3);
    assert_eq!(
        read_u8(&mut sim, MS, 1, 170),
        225,
        "Indirect Address 2 default"
    );
    // Read-only items, torque or not.
    for (addr, data) in [
        (0u16, vec![1u8, 2]),
        (6, vec![1]),
        (69, vec![1]),
        (70, vec![0]),
        (132, vec![0, 0, 0, 0]),
        (126, vec![0, 0]),
    ] {
        assert_eq!(write_err(&mut sim, MS, 2, addr, &data), ACCESS, "{addr}");
    }
    // Past the table: Access Error for reads and writes.
    assert_eq!(read(&mut sim, MS, 2, 250, 8)[0].err, ACCESS);
    // SYNC WRITE and BULK WRITE have no reply: refused entries are silently ignored, the
    // others applied.
    assert_eq!(write_err(&mut sim, MS, 2, 64, &[1]), OK);
    let r = sync_write(&mut sim, 2 * MS, 11, &[(1, &[4]), (2, &[4])]);
    assert!(r.is_empty());
    assert_eq!(read_u8(&mut sim, 2 * MS, 1, 11), 3);
    assert_eq!(write_err(&mut sim, 2 * MS, 2, 64, &[0]), OK);
    let r = tx(&mut sim, 3 * MS, |b| {
        dxl::bulk_write(
            b,
            [
                BulkWriteEntry {
                    id: 1,
                    addr: 11,
                    data: &[4],
                },
                BulkWriteEntry {
                    id: 2,
                    addr: 11,
                    data: &[4],
                },
            ],
        )
        .unwrap()
    });
    assert!(r.is_empty());
    assert_eq!(read_u8(&mut sim, 3 * MS, 1, 11), 3, "torque on: refused");
    assert_eq!(read_u8(&mut sim, 3 * MS, 2, 11), 4, "torque off: written");
}

#[test]
fn out_of_range_values_and_goals_beyond_the_limits_are_refused() {
    let mut sim = bus(&[1]);
    assert_eq!(
        write_err(&mut sim, 0, 1, 64, &[2]),
        0x04,
        "Torque Enable 0–1"
    );
    assert_eq!(
        write_err(&mut sim, 0, 1, 68, &[3]),
        0x04,
        "Status Return Level 0–2"
    );
    assert_eq!(
        write_err(&mut sim, 0, 1, 11, &[2]),
        0x04,
        "no operating mode 2"
    );
    assert_eq!(
        write_err(&mut sim, 0, 1, 168, &[10, 0]),
        0x04,
        "indirect into EEPROM"
    );
    // Position mode: Goal Position within Min/Max Position Limit (0–4095).
    assert_eq!(write_err(&mut sim, 0, 1, 116, &4096i32.to_le_bytes()), 0x06);
    assert_eq!(write_err(&mut sim, 0, 1, 116, &(-1i32).to_le_bytes()), 0x06);
    assert_eq!(read_i32(&mut sim, 0, 1, 116), 2048, "unchanged");
    // Extended position mode takes it.
    assert_eq!(write_err(&mut sim, 0, 1, 11, &[4]), OK);
    assert_eq!(write_err(&mut sim, 0, 1, 116, &5000i32.to_le_bytes()), OK);
    // Velocity mode: Goal Velocity within the Velocity Limit (350).
    assert_eq!(write_err(&mut sim, 0, 1, 11, &[1]), OK);
    assert_eq!(write_err(&mut sim, 0, 1, 104, &351i32.to_le_bytes()), 0x06);
    assert_eq!(write_err(&mut sim, 0, 1, 104, &(-350i32).to_le_bytes()), OK);
}

#[test]
fn indirect_data_reads_the_mapped_present_registers_as_they_are_now() {
    let mut sim = bus(&[1, 2]);
    // Indirect Address 1–8 → Present Position (132..136) then Present Velocity (128..132),
    // on both servos (torque off, as DynamixelSDK's indirect example does).
    let map: Vec<u8> = (132u16..136)
        .chain(128..132)
        .flat_map(u16::to_le_bytes)
        .collect();
    for id in [1, 2] {
        assert_eq!(write_err(&mut sim, 0, id, 168, &map), OK);
        assert_eq!(write_err(&mut sim, 0, id, 116, &3000i32.to_le_bytes()), OK);
        assert_eq!(write_err(&mut sim, 0, id, 64, &[1]), OK);
    }
    // Mid-move, one READ of the indirect data equals Present Position and Velocity now.
    let t = 30 * MS;
    let direct = read(&mut sim, t, 1, 128, 8)[0].data.clone();
    let r = read(&mut sim, t, 1, 224, 8);
    assert_eq!(r[0].data[..4], direct[4..8]);
    assert_eq!(r[0].data[4..], direct[..4]);
    let pos = i32::from_le_bytes(r[0].data[..4].try_into().unwrap());
    assert!(pos > 2048 && pos < 3000, "mid-move: {pos}");
    assert_eq!(pos, sim.servo(1).unwrap().present_position());
    // SYNC READ and FAST SYNC READ of the indirect data.
    let t = 60 * MS;
    let r = tx(&mut sim, t, |b| dxl::sync_read(b, 224, 4, &[1, 2]).unwrap());
    assert_eq!(r.len(), 2);
    for (st, id) in r.iter().zip([1u8, 2]) {
        let p = sim.servo(id).unwrap().present_position();
        assert_eq!(st.data, p.to_le_bytes(), "servo {id}");
    }
    let mut buf = [0u8; 64];
    let n = dxl::fast_sync_read(&mut buf, 224, 4, &[1, 2]).unwrap();
    let mut got = Vec::new();
    sim.feed(&buf[..n], 90 * MS, |r| got.push(r));
    assert_eq!(got.len(), 1);
    let mut b = got[0].bytes.clone();
    let p = dxl::parse_in_place(&mut b).unwrap();
    let params = p.params.to_vec();
    for (k, id) in [1u8, 2].into_iter().enumerate() {
        let at = k * 8;
        assert_eq!((params[at], params[at + 1]), (0, id));
        let want = sim.servo(id).unwrap().present_position().to_le_bytes();
        assert_eq!(params[at + 2..at + 6], want);
    }
    // Writing through indirect data reaches the mapped item with its rules: Indirect Data 9
    // → Torque Enable.
    assert_eq!(write_err(&mut sim, S, 1, 64, &[0]), OK);
    assert_eq!(
        write_err(&mut sim, S, 1, 168 + 16, &64u16.to_le_bytes()),
        OK
    );
    assert_eq!(write_err(&mut sim, S, 1, 224 + 8, &[1]), OK);
    assert!(sim.servo(1).unwrap().torque_on());
    // With the default mapping (Indirect Address n = Indirect Data n) it is plain storage.
    assert_eq!(write_err(&mut sim, S, 2, 240, &[0xAB]), OK);
    assert_eq!(read_u8(&mut sim, S, 2, 240), 0xAB);
}

#[test]
fn hardware_error_sets_the_alert_bit_cuts_torque_and_refuses_it_until_reboot() {
    let mut sim = bus(&[1, 2]);
    for id in [1, 2] {
        assert_eq!(write_err(&mut sim, 0, id, 64, &[1]), OK);
    }
    // Input voltage (bit 0) is not in Shutdown (52): Alert only, torque stays on.
    sim.servo_mut(1).unwrap().inject_hardware_error(0x01);
    let r = tx(&mut sim, MS, |b| dxl::ping(b, 1).unwrap());
    assert_eq!(r[0].err, ALERT);
    assert!(sim.servo(1).unwrap().torque_on());
    // Overload (bit 5) is: torque off, Alert on every status packet, Torque Enable refused.
    sim.servo_mut(1).unwrap().inject_hardware_error(0x20);
    assert_eq!(sim.servo(1).unwrap().hardware_error(), 0x21);
    assert!(!sim.servo(1).unwrap().torque_on());
    let r = read(&mut sim, 2 * MS, 1, 70, 1);
    assert_eq!((r[0].err, r[0].data[0]), (ALERT, 0x21));
    assert_eq!(write_err(&mut sim, 2 * MS, 1, 64, &[1]), ALERT | ACCESS);
    assert_eq!(
        write_err(&mut sim, 2 * MS, 1, 65, &[1]),
        ALERT,
        "LED is fine"
    );
    sync_write(&mut sim, 3 * MS, 64, &[(1, &[1]), (2, &[1])]);
    assert!(!sim.servo(1).unwrap().torque_on(), "silently refused");
    // The other servo is unaffected; in a fast reply only servo 1's slice has the Alert bit.
    let mut buf = [0u8; 64];
    let n = dxl::fast_sync_read(&mut buf, 132, 4, &[1, 2]).unwrap();
    let mut got = Vec::new();
    sim.feed(&buf[..n], 4 * MS, |r| got.push(r.bytes));
    let p = dxl::parse_in_place(&mut got[0]).unwrap();
    assert_eq!((p.params[0], p.params[8]), (ALERT, 0));
    assert_eq!(read(&mut sim, 4 * MS, 2, 64, 1)[0].err, OK);
    // REBOOT: answered (still with the Alert bit), then RAM is back to power-on.
    let r = tx(&mut sim, 5 * MS, |b| dxl::reboot(b, 1).unwrap());
    assert_eq!((r.len(), r[0].id, r[0].err), (1, 1, ALERT));
    assert_eq!(sim.stats().reboot, 1);
    let s = sim.servo(1).unwrap();
    assert_eq!((s.hardware_error(), s.torque_on()), (0, false));
    assert_eq!(s.goal_position(), s.present_position());
    assert_eq!(
        tx(&mut sim, 6 * MS, |b| dxl::ping(b, 1).unwrap())[0].err,
        OK
    );
    assert_eq!(write_err(&mut sim, 6 * MS, 1, 64, &[1]), OK);
}

#[test]
fn reboot_restores_ram_and_keeps_eeprom() {
    let mut sim = bus(&[1]);
    assert_eq!(
        write_err(&mut sim, 0, 1, 11, &[4]),
        OK,
        "EEPROM: extended position"
    );
    assert_eq!(
        write_err(&mut sim, 0, 1, 9, &[5]),
        OK,
        "EEPROM: return delay"
    );
    assert_eq!(write_err(&mut sim, 0, 1, 168, &132u16.to_le_bytes()), OK);
    assert_eq!(write_err(&mut sim, 0, 1, 116, &2500i32.to_le_bytes()), OK);
    assert_eq!(write_err(&mut sim, 0, 1, 64, &[1]), OK);
    assert_eq!(write_err(&mut sim, 0, 1, 65, &[1]), OK);
    let r = tx(&mut sim, 0, |b| {
        dxl::reg_write(b, 1, 116, &2100i32.to_le_bytes()).unwrap()
    });
    assert_eq!(r[0].err, OK);
    assert_eq!(read_u8(&mut sim, 0, 1, 69), 1, "registered");
    // 30 ms into the move, the shaft is somewhere between 2048 and 2500.
    assert!(
        write(&mut sim, 30 * MS, 1, 68, &[1]).is_empty(),
        "level 1: no status"
    );
    let r = tx(&mut sim, 30 * MS, |b| dxl::reboot(b, 1).unwrap());
    assert!(
        r.is_empty(),
        "Status Return Level 1: REBOOT is not answered"
    );
    let at = sim.servo(1).unwrap().present_position();
    assert!(at > 2048 && at < 2500, "{at}");
    assert_eq!(read_u8(&mut sim, 31 * MS, 1, 11), 4, "EEPROM kept");
    assert_eq!(read_u8(&mut sim, 31 * MS, 1, 9), 5);
    assert_eq!(read_u8(&mut sim, 31 * MS, 1, 64), 0, "torque off");
    assert_eq!(read_u8(&mut sim, 31 * MS, 1, 65), 0, "LED off");
    assert_eq!(
        read_u8(&mut sim, 31 * MS, 1, 68),
        2,
        "Status Return Level 2"
    );
    assert_eq!(read_u8(&mut sim, 31 * MS, 1, 69), 0, "nothing registered");
    assert_eq!(read(&mut sim, 31 * MS, 1, 168, 2)[0].data, [224, 0]);
    assert_eq!(read_i32(&mut sim, 31 * MS, 1, 116), at, "Goal = Present");
    let r = tx(&mut sim, 31 * MS, |b| dxl::action(b, 1).unwrap());
    assert_eq!(r[0].err, 0x02, "ACTION without REG WRITE");
    // Nothing moves after the reboot.
    assert_eq!(read_i32(&mut sim, S, 1, 132), at);
}

#[test]
fn status_return_level_decides_who_answers() {
    let mut sim = bus(&[1, 2]);
    // Level 0: PING only. The write that sets it is not answered either.
    assert!(write(&mut sim, 0, 1, 68, &[0]).is_empty());
    assert_eq!(tx(&mut sim, MS, |b| dxl::ping(b, 1).unwrap()).len(), 1);
    assert!(read(&mut sim, MS, 1, 132, 4).is_empty());
    assert!(write(&mut sim, MS, 1, 65, &[1]).is_empty());
    assert_eq!(sim.servo(1).unwrap().table[65], 1, "written all the same");
    let r = tx(&mut sim, MS, |b| {
        dxl::sync_read(b, 132, 4, &[1, 2]).unwrap()
    });
    assert_eq!(r.iter().map(|s| s.id).collect::<Vec<_>>(), [2]);
    let r = tx(&mut sim, MS, |b| {
        dxl::fast_sync_read(b, 132, 4, &[1, 2]).unwrap()
    });
    assert!(r.is_empty(), "a silent servo breaks the fast reply chain");
    // Broadcast PING: everyone.
    assert_eq!(tx(&mut sim, MS, |b| dxl::ping(b, 0xFE).unwrap()).len(), 2);
    // Level 1: PING and reads.
    sim.servo_mut(1).unwrap().table[68] = 1;
    assert_eq!(read(&mut sim, 2 * MS, 1, 132, 4).len(), 1);
    assert!(write(&mut sim, 2 * MS, 1, 65, &[0]).is_empty());
    let r = tx(&mut sim, 2 * MS, |b| {
        dxl::fast_sync_read(b, 132, 4, &[1, 2]).unwrap()
    });
    assert_eq!(r.len(), 1);
    // Level 2 (back by a broadcast write, which nobody answers): everything.
    assert!(write(&mut sim, 3 * MS, 0xFE, 68, &[2]).is_empty());
    assert_eq!(write(&mut sim, 3 * MS, 1, 65, &[1]).len(), 1);
    // An ID that is not on the bus never answers.
    assert!(tx(&mut sim, 3 * MS, |b| dxl::ping(b, 9).unwrap()).is_empty());
    assert!(read(&mut sim, 3 * MS, 9, 132, 4).is_empty());
    assert!(write(&mut sim, 3 * MS, 9, 65, &[1]).is_empty());
}

#[test]
fn model_per_servo_and_a_shaft_moved_by_hand() {
    let mut sim = bus(&[1, 2]);
    sim.servo_mut(2).unwrap().set_model(1060);
    assert!(sim.servo_mut(7).is_none());
    let r = tx(&mut sim, 0, |b| dxl::ping(b, 0xFE).unwrap());
    let models: Vec<(u8, u16)> = r
        .iter()
        .map(|s| (s.id, u16::from_le_bytes([s.data[0], s.data[1]])))
        .collect();
    assert_eq!(models, [(1, 1020), (2, 1060)]);
    assert_eq!(read(&mut sim, 0, 2, 0, 2)[0].data, 1060u16.to_le_bytes());
    // The limp joint is turned by hand: Present Position follows; with torque on the servo
    // pulls back to its goal.
    sim.servo_mut(1).unwrap().set_present(1500);
    assert_eq!(read_i32(&mut sim, MS, 1, 132), 1500);
    assert_eq!(read_i32(&mut sim, S, 1, 132), 1500, "still limp");
    assert_eq!(write_err(&mut sim, S, 1, 64, &[1]), OK);
    assert_eq!(read_i32(&mut sim, 2 * S, 1, 132), 2048, "back to the goal");
}

#[test]
fn return_delay_comes_from_register_9_at_reply_time() {
    let mut sim = DxlBusSim::new(DxlSimConfig {
        ids: vec![1, 2],
        return_delay_us: 100,
        baud_timing: false,
        ..DxlSimConfig::default()
    });
    assert_eq!(read_u8(&mut sim, 0, 1, 9), 50, "100 µs = 50 × 2 µs");
    let t = 10 * MS;
    assert_eq!(
        tx(&mut sim, t, |b| dxl::ping(b, 1).unwrap())[0].ready_ns,
        t + 100_000
    );
    // The host sets servo 1's to 0 and servo 2's to 500 µs (the factory 250).
    let r = write(&mut sim, t, 1, 9, &[0]);
    assert_eq!(
        r[0].ready_ns, t,
        "the new value already applies to this status"
    );
    write(&mut sim, t, 2, 9, &[250]);
    assert_eq!(tx(&mut sim, t, |b| dxl::ping(b, 1).unwrap())[0].ready_ns, t);
    assert_eq!(
        tx(&mut sim, t, |b| dxl::ping(b, 2).unwrap())[0].ready_ns,
        t + 500_000
    );
    // SYNC READ: each status after the previous one and the servo's own delay.
    let r = tx(&mut sim, t, |b| dxl::sync_read(b, 132, 4, &[2, 1]).unwrap());
    assert_eq!(
        r.iter().map(|s| s.ready_ns).collect::<Vec<_>>(),
        [t + 500_000, t + 500_000]
    );
    // With baud timing the wire time adds on (1 Mbit/s: 10 µs a byte).
    let mut sim = DxlBusSim::new(DxlSimConfig {
        ids: vec![1],
        return_delay_us: 20,
        ..DxlSimConfig::default()
    });
    let r = tx(&mut sim, 0, |b| dxl::ping(b, 1).unwrap());
    assert_eq!(r[0].ready_ns, 10 * 10_000 + 20_000 + 14 * 10_000);
}

#[test]
fn instruction_log_shows_what_was_written_and_when() {
    let mut sim = bus(&[1, 2]).with_log();
    assert!(bus(&[1]).instruction_log().is_empty());
    let goal = |v: i32| v.to_le_bytes();
    read(&mut sim, 0, 1, 132, 4);
    sync_write(&mut sim, MS, 116, &[(1, &goal(2048)), (2, &goal(2048))]);
    sync_write(&mut sim, 2 * MS, 64, &[(1, &[1]), (2, &[1])]);
    tx(&mut sim, 3 * MS, |b| dxl::reboot(b, 2).unwrap());
    let log = sim.instruction_log();
    assert_eq!(
        log,
        [
            (0, 1, 0x02, 132, vec![4, 0]),
            (MS, 1, 0x83, 116, goal(2048).to_vec()),
            (MS, 2, 0x83, 116, goal(2048).to_vec()),
            (2 * MS, 1, 0x83, 64, vec![1]),
            (2 * MS, 2, 0x83, 64, vec![1]),
            (3 * MS, 2, 0x08, 0, vec![]),
        ]
    );
    // What a test of an executor's enable sequence checks: every Torque Enable = 1 comes
    // after a Goal Position equal to the Present Position for that servo.
    for id in [1, 2] {
        let torque = log
            .iter()
            .position(|e| e.1 == id && e.3 == 64 && e.4 == [1])
            .unwrap();
        let goal = log
            .iter()
            .position(|e| e.1 == id && e.3 == 116 && e.4 == 2048i32.to_le_bytes())
            .unwrap();
        assert!(goal < torque);
    }
}

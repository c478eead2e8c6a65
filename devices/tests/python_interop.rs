//! Interop with independent implementations (PyPI): ROBOTIS' official `dynamixel-sdk` drives
//! our Dynamixel simulator, and `python-can`'s `slcan` interface drives our SLCAN adapter
//! simulator, each over a pseudo-terminal, exactly as they would a U2D2 or a CANable.

use conductor_testkit::{python, run_ok};
use std::path::PathBuf;
use std::process::Command;

use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim, OdriveAxisSim};
use conductor_devices::sim::dxl::DxlSimConfig;
use conductor_devices::sim::runner::{run_dxl_faultless, run_slcan, Endpoint, Pty};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_protocols::slcan::Dialect;

mod common;
use common::field;

fn run_script(script: &str, args: &[&str]) -> String {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/python")
        .join(script);
    let out = run_ok(Command::new(python()).arg(path).args(args));
    String::from_utf8(out.stdout).unwrap()
}

fn numbers(s: &str) -> Vec<f64> {
    s.trim_matches(['[', ']'])
        .split(',')
        .filter(|x| !x.trim().is_empty())
        .map(|x| x.trim().parse().unwrap())
        .collect()
}

#[test]
fn dynamixel_sdk_pings_reads_writes_sync_writes_and_sync_reads_the_simulator() {
    let pty = Pty::open(None).unwrap();
    let path = pty.path().to_string();
    let ids: Vec<u8> = vec![1, 2, 3, 4, 5, 6];
    let cfg = DxlSimConfig {
        ids: ids.clone(),
        // Instant response: what the SDK reads back after a write is exactly the goal.
        tau_s: 0.0,
        initial_position: 2100,
        ..DxlSimConfig::default()
    };
    let sim = run_dxl_faultless(Endpoint::Pty(pty), cfg);
    sim.sim().start_log();
    let json = run_script("dxl_sdk_client.py", &[&path, "1,2,3,4,5,6"]);
    assert_eq!(field(&json, "ping_model"), "1020");
    assert_eq!(
        numbers(&field(&json, "broadcast_ids")),
        [1., 2., 3., 4., 5., 6.]
    );
    assert_eq!(numbers(&field(&json, "broadcast_models")), [1020.]);
    // Power-on: torque off; a goal written meanwhile is kept but not followed.
    assert_eq!(field(&json, "torque_at_power_on"), "0");
    assert_eq!(field(&json, "read_present"), "2100");
    assert_eq!(field(&json, "write_readback"), "3000");
    assert_eq!(field(&json, "present_after_goal_torque_off"), "2100");
    // Torque on: the servo goes to the goal it holds (τ = 0: at once).
    assert_eq!(field(&json, "present_after_torque_on"), "3000");
    assert_eq!(
        field(&json, "indirect_data"),
        "3000",
        "Indirect Data = Present Position"
    );
    assert_eq!(field(&json, "indirect_address_with_torque_error"), "7");
    assert_eq!(field(&json, "eeprom_with_torque_error"), "7");
    let goals = numbers(&field(&json, "sync_write_goals"));
    assert_eq!(numbers(&field(&json, "sync_read_present")), goals);
    let bulk = numbers(&field(&json, "bulk_read"));
    assert_eq!(bulk, [goals[0], 35.0]);
    // REBOOT: torque off, Goal = Present, indirect addresses back to their defaults.
    assert_eq!(field(&json, "torque_after_reboot"), "0");
    assert_eq!(
        numbers(&field(&json, "goal_present_after_reboot")),
        [goals[0], goals[0]]
    );
    assert_eq!(field(&json, "indirect_address_after_reboot"), "224");
    let s = sim.sim();
    for (i, id) in ids.iter().enumerate() {
        let servo = s.servo(*id).unwrap();
        assert_eq!(servo.goal_position() as f64, goals[i]);
        assert_eq!(servo.present_position() as f64, goals[i]);
        assert_eq!(
            servo.torque_on(),
            i != 0,
            "servo {id}: only the rebooted one is off"
        );
    }
    let st = s.stats();
    assert_eq!((st.sync_write, st.sync_read, st.bulk_read), (2, 1, 1));
    assert_eq!((st.ping, st.reboot), (2, 1));
    // What the SDK sent, as the servo saw it: the refused Indirect Address write came with
    // torque on, after the accepted ones.
    let log = s.instruction_log();
    let writes: Vec<(u16, &[u8])> = log
        .iter()
        .filter(|e| e.1 == 1 && e.2 == 0x03)
        .map(|e| (e.3, e.4.as_slice()))
        .collect();
    assert_eq!(
        writes,
        [
            (116, &3000i32.to_le_bytes()[..]),
            (168, &[132, 0][..]),
            (170, &[133, 0][..]),
            (172, &[134, 0][..]),
            (174, &[135, 0][..]),
            (64, &[1][..]),
            (168, &[128, 0][..]),
            (11, &[4][..]),
        ]
    );
    assert_eq!(
        st.discarded_in, 0,
        "every byte the SDK sent was a valid packet"
    );
}

#[test]
fn python_can_slcan_sends_and_receives_mit_frames() {
    let pty = Pty::open(None).unwrap();
    let path = pty.path().to_string();
    let nodes: Vec<Box<dyn CanNode>> = vec![
        Box::new(MitMotorSim::new(1, mit_limits("ak80-9").unwrap(), 0, false)),
        Box::new(OdriveAxisSim::new(4, 0, 0)),
    ];
    let sim = run_slcan(
        Endpoint::Pty(pty),
        SlcanAdapterSim::new(Dialect::CANABLE, nodes),
    );
    let json = run_script("slcan_client.py", &[&path]);
    assert_eq!(
        field(&json, "enter_reply_id"),
        "0",
        "MIT replies go to the master ID"
    );
    assert_eq!(field(&json, "enter_reply_dlc"), "6");
    // Position quantum: 25 rad / 65 535.
    let at_rest = |p: f64| p.abs() < 1e-3;
    let before = numbers(&field(&json, "before_enter"));
    assert!(
        before.iter().all(|&p| at_rest(p)),
        "ignored before Enter: {before:?}"
    );
    let after_enter: f64 = field(&json, "after_enter").parse().unwrap();
    assert!(at_rest(after_enter), "Enter gives no torque: {after_enter}");
    let p = numbers(&field(&json, "positions_first_last"));
    assert!(at_rest(p[0]), "starts at rest: {p:?}");
    // 300 commands 2 ms apart with kp = 20, kd = 1: settled near 1 rad.
    assert!((p[1] - 1.0).abs() < 0.01, "{p:?}");
    let after_exit = numbers(&field(&json, "after_exit"));
    assert!(
        after_exit.iter().all(|&q| (q - p[1]).abs() < 0.01),
        "ignored after Exit: {after_exit:?}"
    );
    assert_eq!(field(&json, "odrive_reply_id"), (4 * 32 + 9).to_string());
    assert_eq!(numbers(&field(&json, "odrive_estimates")), [0.0, 0.0]);
    let a = sim.sim();
    let s = a.stats();
    assert_eq!(s.frames_from_host, 2 + 2 + 300 + 1 + 2 + 1);
    assert_eq!(s.frames_to_host, s.frames_from_host, "every frame answered");
    let motor = a.nodes()[0].snapshot();
    assert!(!motor.enabled, "exit frame honoured");
    assert_eq!(
        motor.ignored, 4,
        "two commands before Enter, two after Exit"
    );
}

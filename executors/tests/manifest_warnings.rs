//! Warnings: a manifest with only warnings is valid and carries them in `Manifest::warnings`;
//! they are rendered like errors, as `warning:`. An actuator nothing commands, and an actuator
//! the watchdog switches off with no way back on.

use conductor_executor::manifest::{Manifest, Severity};

/// `n` X-series servos on one 1 Mbit/s bus at 250 Hz; each gets `states` with `{i}` replaced.
fn servos(n: usize, states: &str) -> String {
    let mut s = String::from(
        "system = \"arm\"\n[subsystems.arm]\nrate_hz = 250\n\
         [subsystems.arm.hardware.uart]\nkind = \"serial\"\nport = \"/dev/ttyUSB0\"\nbaud = 1000000\n\
         [subsystems.arm.protocols.robotis]\nkind = \"dynamixel2\"\nhardware = \"uart\"\n",
    );
    for i in 1..=n {
        s += &format!(
            "[subsystems.arm.devices.s{i}]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = {i}\n"
        );
    }
    for i in 1..=n {
        s += &states.replace("{i}", &i.to_string());
    }
    s
}

const POSITION: &str =
    "[subsystems.arm.states.p{i}]\ndevice = \"s{i}\"\nchannel = \"position\"\nwritable = true\n";

fn parse(text: &str) -> Manifest {
    Manifest::parse(text, "arm.toml").unwrap_or_else(|e| panic!("{e}"))
}

/// An actuator without a writable state: nothing can command it.
#[test]
fn an_actuator_nothing_commands_is_a_warning() {
    let states = "[subsystems.arm.states.p{i}]\ndevice = \"s{i}\"\nchannel = \"position\"\n";
    let m = parse(&servos(2, states));
    assert_eq!(m.warnings.len(), 2, "{}", m.render_warnings());
    for (w, dev) in m.warnings.iter().zip(["s1", "s2"]) {
        assert_eq!(w.severity, Severity::Warning);
        assert_eq!(w.key, format!("subsystems.arm.devices.{dev}"));
        assert!(w.message.contains("nothing can command it"), "{w}");
    }
    let shown = m.render_warnings();
    assert!(
        shown.contains(": warning: subsystems.arm.devices.s1: device \"s1\""),
        "{shown}"
    );
    assert!(
        shown.ends_with("2 warnings in the manifest (it is valid)"),
        "{shown}"
    );
    // A device nothing is bound to at all, too; a sensor-only kind never.
    let text = servos(1, POSITION)
        + "[subsystems.arm.devices.spare]\nkind = \"dynamixel_x\"\nprotocol = \"robotis\"\nid = 9\n";
    let m = parse(&text);
    assert_eq!(m.warnings.len(), 1, "{}", m.render_warnings());
    assert_eq!(m.warnings[0].key, "subsystems.arm.devices.spare");
}

fn mit_leg(watchdog: &str, safe: &str, enable: bool) -> String {
    let mut s = format!(
        "system = \"q\"\n[subsystems.leg]\nrate_hz = 500\n{watchdog}\n\
         [subsystems.leg.hardware.can0]\nkind = \"slcan\"\nport = \"/dev/ttyACM0\"\n\
         [subsystems.leg.protocols.mit]\nkind = \"can_motors\"\nhardware = \"can0\"\n\
         [subsystems.leg.devices.knee]\nkind = \"mit_motor\"\nprotocol = \"mit\"\nid = 1\n{safe}\n\
         [subsystems.leg.states.knee]\ndevice = \"knee\"\nchannel = \"position\"\nwritable = true\n"
    );
    if enable {
        s += "[subsystems.leg.states.knee_on]\ndevice = \"knee\"\nchannel = \"enable\"\nwritable = true\n";
    }
    s
}

/// With a watchdog whose safe action switches a motor off, a motor without a writable state
/// on its `enable` channel can only be switched on again by restarting the executor.
#[test]
fn a_watchdog_that_switches_off_for_good_is_a_warning() {
    let off = "safe_action = \"torque_off\"";
    let m = parse(&mit_leg("watchdog_ms = 100", off, false));
    assert_eq!(m.warnings.len(), 1, "{}", m.render_warnings());
    let w = &m.warnings[0];
    assert_eq!(w.key, "subsystems.leg.devices.knee");
    assert!(w.message.contains("`enable` channel"), "{w}");
    assert!(w.message.contains("restarting the executor"), "{w}");
    assert!(
        w.message.contains(
            "[subsystems.leg.states.knee_enable] device = \"knee\", channel = \"enable\""
        ),
        "{w}"
    );
    // Not with an enable state, without a watchdog, or with a safe action that keeps it on
    // (hold, the default).
    for ok in [
        mit_leg("watchdog_ms = 100", off, true),
        mit_leg("", off, false),
        mit_leg("watchdog_ms = 100", "", false),
        mit_leg("watchdog_ms = 100", "safe_action = \"hold\"", false),
    ] {
        let m = parse(&ok);
        assert!(m.warnings.is_empty(), "{ok}\n{}", m.render_warnings());
    }
}

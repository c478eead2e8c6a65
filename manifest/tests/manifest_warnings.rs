//! Warnings: a manifest with only warnings is valid and carries them in `Manifest::warnings`;
//! they are rendered like errors, as `warning:`. A bus loaded above 80 % of its wire, an
//! actuator nothing commands, and actuators that, once tripped, nothing could enable again.

use conductor_manifest::{Manifest, ManifestError, Severity};

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
    "[subsystems.arm.states.p{i}]\ndevice = \"s{i}\"\nchannel = \"position\"\nwritable = true\n\
     [subsystems.arm.states.e{i}]\ndevice = \"s{i}\"\nchannel = \"enable\"\nwritable = true\n";

const VELOCITY_CURRENT: &str =
    "[subsystems.arm.states.v{i}]\ndevice = \"s{i}\"\nchannel = \"velocity\"\n\
     [subsystems.arm.states.c{i}]\ndevice = \"s{i}\"\nchannel = \"current\"\n";

fn parse(text: &str) -> Manifest {
    Manifest::parse(text, "arm.toml").unwrap_or_else(|e| panic!("{e}"))
}

/// 12 servos reading position, velocity and current (126..136, 10 bytes) and written their
/// position at 250 Hz: SYNC WRITE 14 + 12·5 = 74 B, SYNC READ 14 + 12 = 26 B, 12 status packets
/// of 21 B = 252 B: 352 B = 3.52 ms of each 4 ms cycle, 88 %. Valid, with one warning.
#[test]
fn a_bus_above_80_percent_is_a_warning_and_the_manifest_loads() {
    let text = servos(12, &format!("{POSITION}{VELOCITY_CURRENT}"));
    let m = parse(&text);
    assert_eq!(m.subsystems.len(), 1);
    assert_eq!(m.warnings.len(), 1, "{}", m.render_warnings());
    let w = &m.warnings[0];
    assert_eq!(w.severity, Severity::Warning);
    assert_eq!(w.key, "subsystems.arm.protocols.robotis");
    // On the protocol's table header.
    let header = text
        .lines()
        .position(|l| l == "[subsystems.arm.protocols.robotis]")
        .unwrap();
    assert_eq!((w.line, w.column), (header + 1, 1));
    for figure in [
        "bus load 88 % of the wire",
        "above 80 %",
        "352 bytes",
        "SYNC WRITE 74 B, SYNC READ 26 B, 12 status packets 252 B",
        "in 3.52 ms at 1000000 baud",
        "250 cycles a second",
        "880 ms of wire time per second",
        "fast_sync",
    ] {
        assert!(w.message.contains(figure), "{figure:?} in {}", w.message);
    }
    let shown = m.render_warnings();
    assert!(
        shown.starts_with(&format!(
            "arm.toml:{}:1: warning: subsystems.arm.protocols.robotis: bus load 88 %",
            header + 1
        )),
        "{shown}"
    );
    assert!(
        shown.ends_with("1 warning in the manifest (it is valid)"),
        "{shown}"
    );
    // Below 80 %: no warning (6 servos: 44 + 20 + 6·21 = 190 B, 47.5 %).
    let m = parse(&servos(6, &format!("{POSITION}{VELOCITY_CURRENT}")));
    assert!(m.warnings.is_empty(), "{}", m.render_warnings());
    assert_eq!(m.render_warnings(), "");
}

/// Above 100 % the manifest is refused, with the figures; other warnings are still listed.
#[test]
fn a_bus_above_100_percent_is_an_error() {
    let text = servos(24, &format!("{POSITION}{VELOCITY_CURRENT}"));
    let Err(ManifestError::Invalid { diagnostics }) = Manifest::parse(&text, "arm.toml") else {
        panic!("accepted");
    };
    assert_eq!(diagnostics.len(), 1);
    assert_eq!(diagnostics[0].severity, Severity::Error);
    // 14 + 24·5 + 14 + 24 + 24·21 = 676 B = 6.76 ms per 4 ms cycle.
    assert!(
        diagnostics[0].message.contains("bus load 169 %"),
        "{}",
        diagnostics[0]
    );
    assert!(diagnostics[0].message.contains("expected at most 100 %"));

    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/bad_manifests/24-bus-load-dynamixel.toml");
    let e = Manifest::load(&path).unwrap_err().to_string();
    assert!(e.ends_with("1 error and 2 warnings in the manifest"), "{e}");
    assert!(e.contains(": warning: subsystems.arm.devices.s10: "), "{e}");
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

/// A trip (the watchdog's or a fault's, whatever the safe action) leaves a device refusing
/// setpoints until its `enable` channel is written 1: a motor without a writable state there
/// could only be enabled again by restarting the executor.
#[test]
fn an_actuator_nothing_could_enable_again_is_a_warning() {
    for (watchdog, safe) in [
        ("watchdog_ms = 100", "safe_action = \"torque_off\""),
        ("watchdog_ms = 100", "safe_action = \"hold\""),
        ("", ""),
    ] {
        let m = parse(&mit_leg(watchdog, safe, false));
        assert_eq!(m.warnings.len(), 1, "{}", m.render_warnings());
        let w = &m.warnings[0];
        assert_eq!(w.key, "subsystems.leg.devices.knee");
        assert!(w.message.contains("`enable` channel"), "{w}");
        assert!(w.message.contains("restarting the executor"), "{w}");
        assert!(
            w.message.contains(if watchdog.is_empty() {
                "tripped by a fault"
            } else {
                "tripped by the command watchdog"
            }),
            "{w}"
        );
        assert!(
            w.message.contains(
                "[subsystems.leg.states.knee_enable] device = \"knee\", channel = \"enable\""
            ),
            "{w}"
        );
        // Not with an enable state.
        let m = parse(&mit_leg(watchdog, safe, true));
        assert!(m.warnings.is_empty(), "{}", m.render_warnings());
    }
    // Several devices: one warning naming them all.
    let states = "[subsystems.arm.states.p{i}]\ndevice = \"s{i}\"\nchannel = \"position\"\nwritable = true\n";
    let m = parse(&servos(3, states));
    assert_eq!(m.warnings.len(), 1, "{}", m.render_warnings());
    assert!(
        m.warnings[0]
            .message
            .contains("(\"s1\", \"s2\", \"s3\") have"),
        "{}",
        m.warnings[0]
    );
}

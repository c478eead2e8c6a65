//! The manifests shipped in deploy/ and used by the tests validate, with the structure they claim.

use conductor_manifest::{GatewayDef, GatewayKind, GatewayOptions, Manifest, SafeSpec};

fn root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

fn load(rel: &str) -> Manifest {
    Manifest::load(root().join(rel)).unwrap_or_else(|e| panic!("{rel}:\n{e}"))
}

#[test]
fn minihubo_right_leg_matches_the_thesis_arrangement() {
    let m = load("deploy/minihubo-right-leg.toml");
    assert_eq!(m.system, "minihubo");
    assert_eq!(m.subsystems.len(), 1);
    let leg = &m.subsystems[0];
    assert_eq!(leg.name, "right_leg");
    assert_eq!(leg.period_ns, 2_000_000);
    let names: Vec<&str> = leg.states.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(
        names,
        ["RAR", "RAP", "RKP", "RHR", "RHP", "RHY", "Fz", "Mx", "My"]
    );
    // Fig. 3.2: six joint devices on the Robotis protocol over UART1, three sensor channels on
    // the ADC protocol over UART2.
    let proto_of = |s: &str| {
        let st = leg.states.iter().find(|x| x.name == s).unwrap();
        let dev = &leg.devices[st.device];
        let p = &leg.protocols[dev.protocol];
        (p.name.as_str(), leg.hardware[p.hardware].name.as_str())
    };
    for j in &names[..6] {
        assert_eq!(proto_of(j), ("robotis", "uart1"), "{j}");
    }
    for f in &names[6..] {
        assert_eq!(proto_of(f), ("adc", "uart2"), "{f}");
    }
    // Fig. 3.3: Device("dRAR", 5, 250, "Robotis", 46, 2.61, -1).
    let rar = &leg.devices[leg.states[0].device];
    assert_eq!((rar.name.as_str(), rar.credential.id), ("dRAR", 46));
    assert_eq!(leg.rate_of(rar.divisor), 250.0);
    assert_eq!(rar.calibration.offset, 2.61);
    assert_eq!(rar.calibration.direction, -1.0);
    assert_eq!(rar.safe, SafeSpec::Hold);
    assert!(leg.states[..6]
        .iter()
        .all(|s| s.writable && s.units == "rad"));
    assert!(leg.states[6..].iter().all(|s| !s.writable));
    assert_eq!(leg.rate_of(leg.states[6].divisor), 100.0);
    assert_eq!(leg.watchdog_ns, Some(500_000_000));
    assert!((0..leg.states.len()).all(|i| leg.state_is_simulated(i)));
}

#[test]
fn the_test_manifest_has_two_subsystems_at_several_rates() {
    let m = load("executors/tests/manifests/two-subsystems.toml");
    let arm = m.subsystem("arm").unwrap();
    let sensors = m.subsystem("sensors").unwrap();
    assert_eq!(arm.states.len(), 6);
    let j5 = &arm.states[5];
    // Calibration inherited from nothing (device defaults) and overridden on the state.
    assert_eq!(
        (
            j5.calibration.scale,
            j5.calibration.offset,
            j5.calibration.direction
        ),
        (2.0, 0.5, -1.0)
    );
    let rates: Vec<f64> = sensors
        .states
        .iter()
        .map(|s| sensors.rate_of(s.divisor))
        .collect();
    assert_eq!(rates, [250.0, 125.0, 50.0]);
}

#[test]
fn setpoint_safe_action_resolves_its_state() {
    let text = r#"
system = "bot"
[subsystems.leg]
rate_hz = 100
[subsystems.leg.hardware.bus]
kind = "loopback"
[subsystems.leg.protocols.p]
kind = "sim"
hardware = "bus"
[subsystems.leg.devices.d]
kind = "sim"
protocol = "p"
id = 1
safe_action = "setpoint"
safe_value = 0.25
[subsystems.leg.states.sensor_like]
device = "d"
writable = true
"#;
    let m = Manifest::parse(text, "inline.toml").unwrap();
    let leg = &m.subsystems[0];
    assert_eq!(
        leg.devices[0].safe,
        SafeSpec::Setpoint {
            state: 0,
            value: 0.25
        }
    );
    // Defaults: base rate for every stage, sleep-only, no watchdog, priority 80, unbounded.
    assert_eq!(leg.devices[0].divisor, 1);
    assert_eq!((leg.spin_ns, leg.watchdog_ns, leg.priority), (0, None, 80));
    assert_eq!(leg.states[0].min, f64::NEG_INFINITY);
    assert_eq!(leg.states[0].history, 256);
}

#[test]
fn the_score_board_manifest_is_one_gateway_and_no_executor() {
    let m = load("deploy/score-board.toml");
    assert!(m.subsystems.is_empty());
    assert_eq!(
        m.gateways,
        [GatewayDef {
            name: "score-rp2040".into(),
            kind: GatewayKind::Score,
            port: "/dev/score-link".into(),
            options: GatewayOptions {
                max_rate_hz: Some(1000.0),
                lazy_rate_hz: Some(10.0),
                restore: true,
                retry_ms: Some(200),
                watchdog_ms: Some(200),
                priority: None,
            },
        }]
    );
}

/// Optional gateway keys stay unset (the gateway's own defaults apply), `restore` is on unless
/// turned off, and gateways come in document order next to subsystems.
#[test]
fn gateways_sit_beside_subsystems_with_defaults() {
    let text = r#"
        system = "bot"
        [gateways.b2]
        kind = "score"
        port = "/dev/score-b2-link"
        restore = false
        [subsystems.leg]
        rate_hz = 100
        hardware.bus.kind = "loopback"
        protocols.p = { kind = "sim", hardware = "bus" }
        devices.d = { kind = "sim", protocol = "p", id = 1 }
        states.knee.device = "d"
        [gateways.b1]
        kind = "score"
        port = "/dev/score-b1-link"
    "#;
    let m = Manifest::parse(text, "inline.toml").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.subsystems.len(), 1);
    let names: Vec<&str> = m.gateways.iter().map(|g| g.name.as_str()).collect();
    assert_eq!(names, ["b2", "b1"]);
    let b1 = m.gateway("b1").unwrap();
    assert_eq!(b1.options, GatewayOptions::default());
    assert!(!m.gateway("b2").unwrap().options.restore);
    assert!(m.gateway("leg").is_none());
}

/// Every manifest shipped in deploy/ and tests/manifests/ validates without a warning.
#[test]
fn shipped_manifests_have_no_warnings() {
    for dir in ["deploy", "executors/tests/manifests"] {
        let mut n = 0;
        for e in std::fs::read_dir(root().join(dir)).unwrap() {
            let path = e.unwrap().path();
            if path.extension().is_some_and(|x| x == "toml") {
                let rel = path
                    .strip_prefix(root())
                    .unwrap()
                    .to_str()
                    .unwrap()
                    .to_string();
                let m = load(&rel);
                assert!(m.warnings.is_empty(), "{rel}:\n{}", m.render_warnings());
                n += 1;
            }
        }
        assert!(n > 0, "no manifests in {dir}");
    }
}

/// The `cubemars_ak` kind: its model is a choice (default AK80-9), its channels are the MIT
/// motor's, an unknown model is refused with the models it knows, and a model other than the
/// one its `can_motors` stage encodes that motor with is refused.
#[test]
fn a_cubemars_ak_manifest_validates() {
    let text = |model: &str| {
        format!(
            r#"
system = "bot"
[subsystems.leg]
rate_hz = 500
[subsystems.leg.hardware.can0]
kind = "slcan"
port = "/dev/ttyACM0"
[subsystems.leg.protocols.mit]
kind = "can_motors"
hardware = "can0"
model = "ak70-10"
[subsystems.leg.devices.knee]
kind = "cubemars_ak"
protocol = "mit"
id = 1
{model}
kp = 20.0
kd = 1.0
[subsystems.leg.states.knee]
device = "knee"
channel = "position"
writable = true
[subsystems.leg.states.knee_torque]
device = "knee"
channel = "torque"
writable = true
"#
        )
    };
    let m =
        Manifest::parse(&text("model = \"ak70-10\""), "ak.toml").unwrap_or_else(|e| panic!("{e}"));
    let knee = &m.subsystems[0].devices[0];
    assert_eq!(knee.kind, "cubemars_ak");
    assert_eq!(knee.params.str("model").unwrap(), "ak70-10");
    let names: Vec<&str> = knee.channels.iter().map(|c| c.name).collect();
    assert_eq!(&names[..3], ["position", "velocity", "torque"]);
    // The device's default model (AK80-9) disagrees with the stage's AK70-10: the stage would
    // encode this motor's torque with the other model's range, so it is refused where it is.
    let e = Manifest::parse(&text(""), "ak.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("subsystems.leg.devices.knee.model")
            && e.contains("disagrees with protocol \"mit\"")
            && e.contains("±25 N·m")
            && e.contains("±18 N·m"),
        "{e}"
    );
    // A per-motor entry of the stage is what counts for that motor.
    let m = Manifest::parse(
        &text("").replace(
            "model = \"ak70-10\"",
            "model = \"ak70-10\"\nmodels = \"1=ak80-9\"",
        ),
        "ak.toml",
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        m.subsystems[0].devices[0].params.str("model").unwrap(),
        "ak80-9"
    );
    let e = Manifest::parse(&text("model = \"ak80-64\""), "ak.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("subsystems.leg.devices.knee.model") && e.contains("ak60-6, ak70-10, ak80-9"),
        "{e}"
    );
}

#[test]
fn the_two_host_robots_bridge_table_validates_with_every_key_the_bridge_reads() {
    let rel = "deploy/two-host/robot.toml";
    let src = std::fs::read_to_string(root().join(rel)).unwrap();
    let m = load(rel);
    assert!(m.bridge.is_some(), "{rel} has a [bridge] table");
    // `cpus` is the one top-level bridge key the example leaves out.
    let with_cpus = src.replacen("[bridge]\n", "[bridge]\ncpus = [0]\n", 1);
    assert_ne!(with_cpus, src);
    Manifest::parse(&with_cpus, rel).unwrap_or_else(|e| panic!("{e}"));
}

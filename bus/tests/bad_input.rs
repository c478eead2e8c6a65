//! Bad input gets a typed error with a clear message, never a panic.

use conductor_bus::{
    Bus, BusError, CommandReceiver, Controller, Domain, StateMeta, StatePublisher, StateSpec,
    StateSubscriber,
};
use iceoryx2::prelude::*;

fn owner(bus: &Bus, sub: &str, states: &[(&str, bool)]) -> StatePublisher {
    let specs: Vec<StateSpec> = states
        .iter()
        .enumerate()
        .map(|(i, (n, w))| {
            StateSpec::new(
                *n,
                StateMeta {
                    index: i as u32,
                    writable: *w,
                    ..Default::default()
                },
            )
        })
        .collect();
    StatePublisher::create(bus, sub, &specs).unwrap()
}

#[test]
fn unknown_state_names_what_exists() {
    let d = Domain::unique("bad1").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let _o = owner(&bus, "leg", &[("knee", true), ("hip", true)]);
    let err = StateSubscriber::new(&bus, "leg/elbow").unwrap_err();
    assert!(matches!(err, BusError::UnknownState { .. }));
    assert_eq!(
        err.to_string(),
        format!(
            "unknown state \"leg/elbow\" in domain {:?}; known states: leg/knee, leg/hip",
            d.name()
        )
    );
    let empty = Domain::unique("bad1e").unwrap();
    let bus2 = Bus::open(&empty, "t").unwrap();
    let err = StateSubscriber::new(&bus2, "knee").unwrap_err();
    assert!(
        err.to_string().contains("no states are published there"),
        "{err}"
    );
    assert!(matches!(
        StateSubscriber::new(&bus, "leg/a b"),
        Err(BusError::InvalidName { .. })
    ));
}

#[test]
fn ambiguous_bare_name() {
    let d = Domain::unique("amb").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let _a = owner(&bus, "left", &[("knee", true)]);
    let _b = owner(&bus, "right", &[("knee", true)]);
    let err = StateSubscriber::new(&bus, "knee").unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "state name \"knee\" is ambiguous in domain {:?}: left/knee, right/knee",
            d.name()
        )
    );
    assert!(StateSubscriber::new(&bus, "left/knee").is_ok());
}

#[test]
fn wrong_type_service_of_the_same_name() {
    let d = Domain::unique("wrongt").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let node = NodeBuilder::new()
        .config(d.iceoryx2_config())
        .create::<ipc::Service>()
        .unwrap();
    // Someone else's u64 stream squats on a Conductor state name.
    let _svc = node
        .service_builder(&"conductor/leg/imposter".try_into().unwrap())
        .publish_subscribe::<u64>()
        .create()
        .unwrap();
    let err = StateSubscriber::new(&bus, "leg/imposter").unwrap_err();
    assert!(matches!(err, BusError::WrongServiceType { .. }), "{err:?}");
    assert_eq!(
        err.to_string(),
        "service \"conductor/leg/imposter\" is not a Conductor state (conductor.StateSample.v2): \
         a foreign service with payload type \"u64\""
    );
}

/// A payload from a hypothetical future ABI.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("conductor.StateSample.v3")]
#[repr(C)]
struct FutureSample {
    seq: u64,
    value: f64,
    extra: [u64; 4],
}

#[test]
fn abi_version_mismatch() {
    let d = Domain::unique("abi").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let node = NodeBuilder::new()
        .config(d.iceoryx2_config())
        .create::<ipc::Service>()
        .unwrap();
    let attrs = AttributeSpecifier::new()
        .define(
            &"conductor.abi".try_into().unwrap(),
            &"3".try_into().unwrap(),
        )
        .unwrap()
        .define(
            &"conductor.kind".try_into().unwrap(),
            &"state".try_into().unwrap(),
        )
        .unwrap();
    let _svc = node
        .service_builder(&"conductor/leg/future".try_into().unwrap())
        .publish_subscribe::<FutureSample>()
        .create_with_attributes(&attrs)
        .unwrap();
    let err = StateSubscriber::new(&bus, "leg/future").unwrap_err();
    assert_eq!(
        err,
        BusError::AbiMismatch {
            service: "conductor/leg/future".into(),
            found: "3".into(),
            expected: 2
        }
    );
    assert!(err.to_string().contains("rebuild one side"));
}

#[test]
fn commands_to_read_only_unknown_or_non_finite_are_refused() {
    let d = Domain::unique("cmdbad").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let _o = owner(&bus, "leg", &[("knee", true), ("force", false)]);
    let _rx = CommandReceiver::create(&bus, "leg").unwrap();
    let mut ctl = Controller::new(&bus);
    assert_eq!(
        ctl.add_ctrl("leg/force", 1.0).unwrap_err(),
        BusError::ReadOnly {
            name: "leg/force".into()
        }
    );
    assert!(matches!(
        ctl.add_ctrl("leg/knee", f64::NAN),
        Err(BusError::NotFinite { .. })
    ));
    assert!(matches!(
        ctl.add_ctrl("leg/knee", f64::INFINITY),
        Err(BusError::NotFinite { .. })
    ));
    assert!(matches!(
        ctl.add_ctrl("leg/ankle", 1.0),
        Err(BusError::UnknownState { .. })
    ));
    // Nothing was buffered by the refused calls.
    assert_eq!(ctl.send_ctrl().unwrap(), 0);

    // States published without a command service: the subsystem cannot be commanded.
    let _arm = owner(&bus, "arm", &[("elbow", true)]);
    let err = ctl.add_ctrl("arm/elbow", 0.0).unwrap_err();
    assert!(matches!(err, BusError::UnknownSubsystem { .. }), "{err:?}");
}

#[test]
fn reserved_and_misindexed_specs_are_rejected() {
    let d = Domain::unique("spec").unwrap();
    let bus = Bus::open(&d, "t").unwrap();
    let spec = |n: &str, i| {
        StateSpec::new(
            n,
            StateMeta {
                index: i,
                ..Default::default()
            },
        )
    };
    assert!(StatePublisher::create(&bus, "leg", &[spec("tick", 0)]).is_err());
    assert!(StatePublisher::create(&bus, "leg", &[spec("knee", 3)]).is_err());
    assert!(StatePublisher::create(&bus, "bad/name", &[spec("knee", 0)]).is_err());
}

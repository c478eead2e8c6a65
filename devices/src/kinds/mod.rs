//! The component kinds a manifest can name: the registry.
//!
//! Each driver module declares its own kind entry, a [`KindSpec`]: its name, its parameters as
//! data ([`ParamSpec`], which the executor's manifest validator checks and the manifest
//! reference lists), and how it is built ([`Build`]): hardware opens a transport of its
//! medium, a protocol stage binds itself to hardware of *its* medium (so a mismatch cannot be
//! expressed in the builders, only refused where the two are paired by name, in
//! [`build_link`]), a device is built at its bus address and names the safe actions it can
//! carry out. [`KINDS`] is the list of those entries: adding a kind is one driver file and one
//! line here.
//!
//! Choice parameters are enums declared with [`choices!`](crate::choices) ([`Choice`]): the
//! one place their names are written, so builders parse them and never fall back.

mod build;
mod choice;
mod common;
mod spec;

pub use build::{
    baud, id_list, socket_addr, AnyHardware, BuildError, DeviceBuild, Disagreement, HardwareBuild,
    Invalid, LinkBuild, OpenError, OpenedHardware, ProtocolBuild, ProtocolCheck, Word,
};
pub use choice::{Choice, UnknownChoice};
pub use common::{BAUD_DOC, RETURN_DELAY_US, TIMEOUT_US};
pub use spec::{Capacity, Medium, ParamDefault, ParamSpec, ParamType, ParamValue, Params};

use crate::component::{Device, SafeAction};
use crate::link::Link;
use crate::message::Credential;

/// What a kind is: which of the three components of a link it builds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// A transport ([`crate::Hardware`]).
    Hardware,
    /// A protocol stage ([`crate::Protocol`]).
    Protocol,
    /// A bus node ([`crate::Device`]).
    Device,
}

/// How a kind is built, by role.
#[derive(Debug, Clone, Copy)]
pub enum Build {
    /// A transport.
    Hardware {
        /// The parameter naming an exclusive OS resource (e.g. `port`), which two components
        /// anywhere in a manifest may not share.
        resource: Option<&'static str>,
        /// Opens it.
        open: HardwareBuild,
    },
    /// A protocol stage.
    Protocol(ProtocolBuild),
    /// A bus node.
    Device {
        /// The protocol kinds it can sit on.
        protocols: &'static [&'static str],
        /// The safe actions it can carry out, its declared one first.
        safe_actions: &'static [&'static str],
        /// Builds it.
        build: DeviceBuild,
        /// Its parameters checked against its protocol stage's, where both describe one thing.
        agrees: Option<ProtocolCheck>,
    },
}

/// A component kind: its description and its construction.
#[derive(Debug, Clone, Copy)]
pub struct KindSpec {
    /// `kind = "..."` in the manifest.
    pub kind: &'static str,
    /// Parameters.
    pub params: &'static [ParamSpec],
    /// One paragraph for the reference.
    pub doc: &'static str,
    /// How it is built.
    pub build: Build,
}

impl KindSpec {
    /// Hardware, protocol stage or device.
    pub fn role(&self) -> Role {
        match self.build {
            Build::Hardware { .. } => Role::Hardware,
            Build::Protocol(_) => Role::Protocol,
            Build::Device { .. } => Role::Device,
        }
    }

    /// For hardware and protocol stages: the medium carried or spoken.
    pub fn medium(&self) -> Option<Medium> {
        match &self.build {
            Build::Hardware { open, .. } => Some(open.medium()),
            Build::Protocol(p) => Some(p.medium()),
            Build::Device { .. } => None,
        }
    }

    /// For hardware: the parameter naming an exclusive OS resource.
    pub fn resource(&self) -> Option<&'static str> {
        match self.build {
            Build::Hardware { resource, .. } => resource,
            _ => None,
        }
    }

    /// For devices: the protocol kinds it can sit on.
    pub fn protocols(&self) -> &'static [&'static str] {
        match self.build {
            Build::Device { protocols, .. } => protocols,
            _ => &[],
        }
    }

    /// For devices: the safe actions it can carry out, its declared one first.
    pub fn safe_actions(&self) -> &'static [&'static str] {
        match self.build {
            Build::Device { safe_actions, .. } => safe_actions,
            _ => &[],
        }
    }

    /// For devices: the check of its parameters against its protocol stage's, if any.
    pub fn protocol_check(&self) -> Option<ProtocolCheck> {
        match self.build {
            Build::Device { agrees, .. } => agrees,
            _ => None,
        }
    }
}

/// Safe actions of the register-mapped servos.
pub const REGISTER_SAFE: &[&str] = &["hold", "torque_off", "setpoint"];

/// Every kind this build knows: each line is a driver's own entry.
pub const KINDS: &[KindSpec] = &[
    crate::hw::serial::KIND,
    crate::hw::udp::KIND,
    crate::sim::hardware::DYNAMIXEL_SIM,
    crate::hw::socketcan::KIND,
    crate::hw::slcan::KIND,
    crate::sim::hardware::CAN_SIM,
    crate::protocol_stage::dxl2::KIND,
    crate::protocol_stage::dxl1::KIND,
    crate::protocol_stage::can_motors::KIND,
    crate::device::dynamixel::DYNAMIXEL_X,
    crate::device::dynamixel::DYNAMIXEL1,
    crate::device::mit::KIND,
    crate::device::cubemars_ak::KIND,
    crate::device::odrive::KIND,
    crate::sim::basic::SINE,
    crate::sim::basic::LOOPBACK,
    crate::sim::basic::SIM_PROTOCOL,
    crate::sim::basic::SIM_DEVICE,
];

/// Looks up a kind.
pub fn find(role: Role, kind: &str) -> Option<&'static KindSpec> {
    KINDS.iter().find(|k| k.role() == role && k.kind == kind)
}

/// Kinds of one role.
pub fn of_role(role: Role) -> impl Iterator<Item = &'static KindSpec> {
    KINDS.iter().filter(move |k| k.role() == role)
}

fn spec(role: Role, kind: &str) -> Result<&'static KindSpec, BuildError> {
    find(role, kind).ok_or_else(|| BuildError::UnknownKind {
        role,
        kind: kind.into(),
    })
}

/// The safe action a device kind declares (what the executor does when commands stop, unless
/// the manifest says otherwise); `None` for unknown kinds.
pub fn safe_action(device_kind: &str) -> Option<SafeAction> {
    match *find(Role::Device, device_kind)?.safe_actions().first()? {
        "hold" => Some(SafeAction::Hold),
        "torque_off" => Some(SafeAction::TorqueOff),
        _ => None,
    }
}

/// Opens the hardware and binds the protocol stage to it (call at start-up).
pub fn build_link(
    protocol: &str,
    protocol_params: &Params,
    hardware: &str,
    hardware_params: &Params,
    cap: Capacity,
) -> Result<Box<dyn Link>, BuildError> {
    let ps = spec(Role::Protocol, protocol)?;
    let hs = spec(Role::Hardware, hardware)?;
    let (Build::Protocol(p), Build::Hardware { open, .. }) = (ps.build, hs.build) else {
        unreachable!("find() returns kinds of the role asked for")
    };
    let (pp, hp) = (protocol_params, hardware_params);
    match (p, open) {
        (ProtocolBuild::Bytes(p), HardwareBuild::Bytes(h)) => p(pp, h(hp, cap)?, cap),
        (ProtocolBuild::Can(p), HardwareBuild::Can(h)) => p(pp, h(hp, cap)?, cap),
        (ProtocolBuild::Sim(p), HardwareBuild::Sim(h)) => p(pp, h(hp, cap)?, cap),
        (p, h) => Err(BuildError::MediumMismatch {
            protocol: protocol.into(),
            protocol_medium: p.medium(),
            hardware: hardware.into(),
            hardware_medium: h.medium(),
        }),
    }
}

/// Builds a device at `cred` (its bus address from the manifest).
pub fn build_device(
    kind: &str,
    params: &Params,
    cred: Credential,
) -> Result<Box<dyn Device>, BuildError> {
    match spec(Role::Device, kind)?.build {
        Build::Device { build, .. } => build(params, cred),
        _ => unreachable!("find() returns kinds of the role asked for"),
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    #[test]
    fn specs_are_consistent() {
        for k in KINDS {
            assert_eq!(k.medium().is_some(), k.role() != Role::Device, "{}", k.kind);
            for p in k.params {
                if let (Some(ParamDefault::Float(d)), Some((lo, hi))) = (p.default, p.range) {
                    assert!(
                        (lo..=hi).contains(&d),
                        "{}.{} default out of range",
                        k.kind,
                        p.name
                    );
                }
                if let (Some(ParamDefault::Str(d)), false) = (p.default, p.choices.is_empty()) {
                    assert!(
                        p.choices.contains(&d),
                        "{}.{} default not a choice",
                        k.kind,
                        p.name
                    );
                }
            }
            for proto in k.protocols() {
                assert!(
                    find(Role::Protocol, proto).is_some(),
                    "{} names {proto}",
                    k.kind
                );
            }
        }
        // One kind per name and role.
        for (i, a) in KINDS.iter().enumerate() {
            for b in &KINDS[i + 1..] {
                assert!(a.kind != b.kind || a.role() != b.role(), "{} twice", a.kind);
            }
        }
    }

    #[test]
    fn defaults_fill_in_and_links_build() {
        let sine = find(Role::Hardware, "sine").unwrap();
        let p = Params::new(sine, BTreeMap::new());
        assert_eq!(p.float("amplitude").unwrap(), 1.0);
        let sim = Params::new(find(Role::Protocol, "sim").unwrap(), BTreeMap::new());
        let cap = Capacity {
            words: 8,
            in_flight: 8,
            devices: 2,
        };
        assert!(build_link("sim", &sim, "sine", &p, cap).is_ok());
        assert!(matches!(
            build_link("sim", &sim, "nope", &p, cap),
            Err(BuildError::UnknownKind {
                role: Role::Hardware,
                ..
            })
        ));
        assert!(build_device("sim", &Params::default(), Credential::id(1)).is_ok());
    }

    fn params(role: Role, kind: &str, given: &[(&str, ParamValue)]) -> Params {
        let spec = find(role, kind).unwrap();
        Params::new(
            spec,
            given
                .iter()
                .map(|(k, v)| (k.to_string(), v.clone()))
                .collect(),
        )
    }

    fn cap() -> Capacity {
        Capacity {
            words: 4096,
            in_flight: 64,
            devices: 8,
        }
    }

    #[test]
    fn every_device_kind_builds_with_defaults_and_declares_a_safe_action() {
        for k in of_role(Role::Device) {
            let d = build_device(
                k.kind,
                &params(Role::Device, k.kind, &[]),
                Credential::id(1),
            )
            .unwrap_or_else(|e| panic!("{}: {e}", k.kind));
            assert!(!d.channels().is_empty());
            assert!(safe_action(k.kind).is_some(), "{}", k.kind);
        }
        // The declared safe action (the first the kind lists) is the driver's own.
        use crate::device::{Dynamixel1, DynamixelX, MitMotor, OdriveAxis};
        for (kind, own) in [
            ("dynamixel_x", DynamixelX::SAFE_ACTION),
            ("dynamixel1", Dynamixel1::SAFE_ACTION),
            ("mit_motor", MitMotor::SAFE_ACTION),
            ("odrive_axis", OdriveAxis::SAFE_ACTION),
        ] {
            assert_eq!(safe_action(kind), Some(own), "{kind}");
        }
        // A writable `position` channel on every actuator.
        for kind in ["dynamixel_x", "dynamixel1", "mit_motor", "odrive_axis"] {
            let d =
                build_device(kind, &params(Role::Device, kind, &[]), Credential::id(1)).unwrap();
            let pos = d.channels().iter().find(|c| c.name == "position").unwrap();
            assert!(pos.readable && pos.writable, "{kind}");
        }
    }

    #[test]
    fn in_process_simulated_links_build() {
        let s = |v: &str| ParamValue::Str(v.into());
        for proto in ["dynamixel2", "dynamixel1"] {
            let pp = params(Role::Protocol, proto, &[]);
            let hp = params(Role::Hardware, "dynamixel_sim", &[]);
            assert!(
                build_link(proto, &pp, "dynamixel_sim", &hp, cap()).is_ok(),
                "{proto}"
            );
        }
        let pp = params(Role::Protocol, "can_motors", &[("models", s("2=ak10-9"))]);
        let hp = params(
            Role::Hardware,
            "can_sim",
            &[("mit", s("1,2")), ("odrive", s("3"))],
        );
        assert!(build_link("can_motors", &pp, "can_sim", &hp, cap()).is_ok());
        let bad = params(Role::Protocol, "can_motors", &[("models", s("2=ak99"))]);
        match build_link("can_motors", &bad, "can_sim", &hp, cap()) {
            Err(BuildError::Invalid {
                param,
                source: Invalid::ModelTable(e),
            }) => assert_eq!((param.as_str(), e.0.as_str()), ("models", "2=ak99")),
            other => panic!("{:?}", other.err()),
        }
    }

    /// A builder called without the validator gets an error for a name it does not know, never
    /// a default.
    #[test]
    fn unknown_choices_are_refused_not_defaulted() {
        let s = |v: &str| ParamValue::Str(v.into());
        let cases: [(Role, &str, &str); 3] = [
            (Role::Device, "dynamixel1", "model"),
            (Role::Device, "odrive_axis", "control_mode"),
            (Role::Device, "dynamixel_x", "model"),
        ];
        for (role, kind, key) in cases {
            let p = params(role, kind, &[(key, s("nope"))]);
            match build_device(kind, &p, Credential::id(1)) {
                Err(BuildError::Invalid { param, .. }) => assert_eq!(param, key),
                other => panic!("{kind}: {:?}", other.err()),
            }
        }
        let hp = params(Role::Hardware, "dynamixel_sim", &[]);
        for (proto, key) in [("dynamixel2", "read"), ("dynamixel1", "read")] {
            let pp = params(Role::Protocol, proto, &[(key, s("nope"))]);
            match build_link(proto, &pp, "dynamixel_sim", &hp, cap()) {
                Err(BuildError::Invalid {
                    param,
                    source: Invalid::Choice(c),
                }) => {
                    assert_eq!(param, key);
                    assert_eq!(c.value, "nope");
                    assert_eq!(
                        c.choices,
                        find(Role::Protocol, proto).unwrap().params[0].choices
                    );
                }
                other => panic!("{proto}: {:?}", other.err()),
            }
        }
        let pp = params(Role::Protocol, "can_motors", &[]);
        let hp = params(Role::Hardware, "can_sim", &[("model", s("ak99"))]);
        assert!(matches!(
            build_link("can_motors", &pp, "can_sim", &hp, cap()),
            Err(BuildError::Invalid {
                source: Invalid::Name { .. },
                ..
            })
        ));
    }

    /// Builds `protocol` on `hardware` whose `key` names an OS resource that does not exist.
    fn open_missing(protocol: &str, hardware: &str, key: &str, value: &str) -> BuildError {
        let pp = params(Role::Protocol, protocol, &[]);
        let hp = params(
            Role::Hardware,
            hardware,
            &[(key, ParamValue::Str(value.into()))],
        );
        match build_link(protocol, &pp, hardware, &hp, cap()) {
            Err(e) => e,
            Ok(_) => panic!("{hardware} {value} opened"),
        }
    }

    #[test]
    fn os_resources_fail_with_a_typed_error_not_a_panic() {
        let e = open_missing("dynamixel2", "serial", "port", "/dev/conductor-nonexistent");
        assert!(
            matches!(
                &e,
                BuildError::Open {
                    source: OpenError::Serial(_),
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("/dev/conductor-nonexistent"), "{e}");
        assert!(std::error::Error::source(&e).is_some());
        match open_missing("can_motors", "socketcan", "interface", "conductor-none0") {
            BuildError::Open {
                resource,
                source: OpenError::Io(_),
            } => assert_eq!(resource, "conductor-none0"),
            other => panic!("{other:?}"),
        }
        let hp = params(
            Role::Hardware,
            "socketcan",
            &[("interface", ParamValue::Str("conductor-none0".into()))],
        );
        // A byte protocol on CAN hardware is refused before anything is opened.
        let pp = params(Role::Protocol, "dynamixel2", &[]);
        assert!(matches!(
            build_link("dynamixel2", &pp, "socketcan", &hp, cap()),
            Err(BuildError::MediumMismatch {
                protocol_medium: Medium::Bytes,
                hardware_medium: Medium::Can,
                ..
            })
        ));
    }

    #[test]
    fn exclusive_resources_are_declared() {
        for (kind, res) in [
            ("serial", "port"),
            ("slcan", "port"),
            ("socketcan", "interface"),
        ] {
            let k = find(Role::Hardware, kind).unwrap();
            assert_eq!(k.resource(), Some(res));
            assert!(k
                .params
                .iter()
                .any(|p| p.name == res && p.default.is_none()));
        }
    }

    #[test]
    fn x_model_names_are_the_table_and_any() {
        use crate::device::{X_MODELS, X_MODEL_NAMES};
        let mut names: Vec<&str> = X_MODELS.iter().map(|m| m.1).collect();
        names.push("any");
        let mut listed = X_MODEL_NAMES.to_vec();
        names.sort_unstable();
        listed.sort_unstable();
        assert_eq!(names, listed);
    }
}

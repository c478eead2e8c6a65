//! The component kinds a manifest can name, their parameters, and the factories that build them.
//!
//! Each kind declares its parameters as data ([`ParamSpec`]) so that the executor's manifest
//! validator can check every key, type and range (and report all errors with their location)
//! before anything is built, and so that the manifest reference lists exactly what the code
//! accepts.

use std::collections::BTreeMap;

use crate::message::Credential;
use crate::sim::{LoopbackHardware, SimDevice, SimProtocol, SineHardware};
use crate::stage::{Device, Link, LinkOf};

/// Which stage a kind belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// A transport.
    Hardware,
    /// A packet format.
    Protocol,
    /// A bus node.
    Device,
}

/// The unit a hardware carries and a protocol speaks; they must match to be linked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Medium {
    /// Byte stream (UART, pty, UDP).
    Bytes,
    /// Classic CAN frames.
    Can,
    /// The built-in simulated bus.
    Sim,
}

impl Medium {
    /// Human name for messages.
    pub fn name(self) -> &'static str {
        match self {
            Medium::Bytes => "a byte stream",
            Medium::Can => "CAN frames",
            Medium::Sim => "simulated words",
        }
    }
}

/// Type of a parameter value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamType {
    /// Integer.
    Int,
    /// Number (an integer literal is accepted).
    Float,
    /// true/false.
    Bool,
    /// String.
    Str,
}

impl ParamType {
    /// Name for messages ("an integer", ...).
    pub fn expected(self) -> &'static str {
        match self {
            ParamType::Int => "an integer",
            ParamType::Float => "a number",
            ParamType::Bool => "true or false",
            ParamType::Str => "a string",
        }
    }
}

/// One parameter of a kind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamSpec {
    /// Key in the manifest.
    pub name: &'static str,
    /// Value type.
    pub ty: ParamType,
    /// Default when absent; `None` means the key is required.
    pub default: Option<ParamDefault>,
    /// Inclusive numeric range, if any.
    pub range: Option<(f64, f64)>,
    /// Allowed string values, if restricted.
    pub choices: &'static [&'static str],
    /// One line for the reference.
    pub doc: &'static str,
}

/// A default value (const-constructible).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ParamDefault {
    /// Integer default.
    Int(i64),
    /// Number default.
    Float(f64),
    /// Bool default.
    Bool(bool),
    /// String default.
    Str(&'static str),
}

/// A component kind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KindSpec {
    /// Stage.
    pub stage: Stage,
    /// `kind = "..."` in the manifest.
    pub kind: &'static str,
    /// For hardware and protocols: the medium.
    pub medium: Option<Medium>,
    /// For hardware: the parameter naming an exclusive OS resource (e.g. `port`), which two
    /// components anywhere in a manifest may not share.
    pub resource: Option<&'static str>,
    /// For devices: the protocol kinds it can sit on.
    pub protocols: &'static [&'static str],
    /// Parameters.
    pub params: &'static [ParamSpec],
    /// One paragraph for the reference.
    pub doc: &'static str,
}

/// A validated parameter value.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    /// Integer.
    Int(i64),
    /// Number.
    Float(f64),
    /// Bool.
    Bool(bool),
    /// String.
    Str(String),
}

/// Validated parameters of one component, with the spec's defaults filled in.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Params {
    values: BTreeMap<String, ParamValue>,
}

impl Params {
    /// Parameters from validated values; absent keys take the spec's default.
    pub fn new(spec: &KindSpec, given: BTreeMap<String, ParamValue>) -> Self {
        let mut values = given;
        for p in spec.params {
            if !values.contains_key(p.name) {
                if let Some(d) = p.default {
                    values.insert(
                        p.name.into(),
                        match d {
                            ParamDefault::Int(v) => ParamValue::Int(v),
                            ParamDefault::Float(v) => ParamValue::Float(v),
                            ParamDefault::Bool(v) => ParamValue::Bool(v),
                            ParamDefault::Str(v) => ParamValue::Str(v.into()),
                        },
                    );
                }
            }
        }
        Self { values }
    }

    /// Integer parameter.
    pub fn int(&self, name: &str) -> Result<i64, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Int(v)) => Ok(*v),
            _ => Err(BuildError::Param(name.into())),
        }
    }

    /// Number parameter (integers widen).
    pub fn float(&self, name: &str) -> Result<f64, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Float(v)) => Ok(*v),
            Some(ParamValue::Int(v)) => Ok(*v as f64),
            _ => Err(BuildError::Param(name.into())),
        }
    }

    /// Bool parameter.
    pub fn bool(&self, name: &str) -> Result<bool, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Bool(v)) => Ok(*v),
            _ => Err(BuildError::Param(name.into())),
        }
    }

    /// String parameter.
    pub fn str(&self, name: &str) -> Result<&str, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Str(v)) => Ok(v),
            _ => Err(BuildError::Param(name.into())),
        }
    }
}

/// Failure to build a component from validated parameters (opening a port, ...).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BuildError {
    /// No such kind for this stage.
    #[error("unknown {stage:?} kind {kind:?}")]
    UnknownKind {
        /// Stage asked for.
        stage: Stage,
        /// Kind asked for.
        kind: String,
    },
    /// Protocol and hardware carry different units.
    #[error("protocol {protocol:?} speaks {} but hardware {hardware:?} carries {}", .protocol_medium.name(), .hardware_medium.name())]
    MediumMismatch {
        /// Protocol kind.
        protocol: String,
        /// Its medium.
        protocol_medium: Medium,
        /// Hardware kind.
        hardware: String,
        /// Its medium.
        hardware_medium: Medium,
    },
    /// A parameter the validator should have guaranteed is missing or mistyped.
    #[error("parameter {0:?} missing or of the wrong type")]
    Param(String),
    /// The OS refused (port does not exist, permission, ...).
    #[error("{0}")]
    Open(String),
}

/// Sizes of the per-tick buffers, fixed at build time from the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Capacity {
    /// Words per tick each way between protocol and hardware.
    pub words: usize,
    /// Requests in flight on one link.
    pub in_flight: usize,
    /// Devices on one link.
    pub devices: usize,
}

const SIM_TIMEOUT: ParamSpec = ParamSpec {
    name: "timeout_us",
    ty: ParamType::Int,
    default: Some(ParamDefault::Int(10_000)),
    range: Some((1.0, 10_000_000.0)),
    choices: &[],
    doc: "a sample request unanswered after this long is reported missing (µs)",
};

/// Every kind this build knows.
pub const KINDS: &[KindSpec] = &[
    KindSpec {
        stage: Stage::Hardware,
        kind: "sine",
        medium: Some(Medium::Sim),
        resource: None,
        protocols: &[],
        params: &[
            ParamSpec {
                name: "amplitude",
                ty: ParamType::Float,
                default: Some(ParamDefault::Float(1.0)),
                range: None,
                choices: &[],
                doc: "amplitude of the answered sine",
            },
            ParamSpec {
                name: "frequency_hz",
                ty: ParamType::Float,
                default: Some(ParamDefault::Float(1.0 / (2.0 * core::f64::consts::PI))),
                range: Some((0.0, 1e6)),
                choices: &[],
                doc: "frequency (default 1/2π Hz, i.e. sin(t) as in the thesis)",
            },
            ParamSpec {
                name: "phase_per_id",
                ty: ParamType::Float,
                default: Some(ParamDefault::Float(0.0)),
                range: None,
                choices: &[],
                doc: "phase offset added per device id (rad)",
            },
        ],
        doc: "Simulated hardware of the thesis' stress test: answers every sample request at time t \
              with amplitude·sin(2π·frequency·t + phase·id), t in seconds of CLOCK_MONOTONIC.",
    },
    KindSpec {
        stage: Stage::Hardware,
        kind: "loopback",
        medium: Some(Medium::Sim),
        resource: None,
        protocols: &[],
        params: &[ParamSpec {
            name: "tau_s",
            ty: ParamType::Float,
            default: Some(ParamDefault::Float(0.0)),
            range: Some((0.0, 1e3)),
            choices: &[],
            doc: "first-order lag between setpoint and sampled value (s); 0 = immediate",
        }],
        doc: "Simulated hardware that answers a sample request with the last setpoint written to \
              the same device, optionally through a first-order lag (a stand-in for a servo).",
    },
    KindSpec {
        stage: Stage::Protocol,
        kind: "sim",
        medium: Some(Medium::Sim),
        resource: None,
        protocols: &[],
        params: &[SIM_TIMEOUT],
        doc: "Protocol of the simulated hardware: one word per request, replies matched by device id.",
    },
    KindSpec {
        stage: Stage::Device,
        kind: "sim",
        medium: None,
        resource: None,
        protocols: &["sim"],
        params: &[],
        doc: "A device on the simulated bus with one read/write channel, `value`.",
    },
];

/// Looks up a kind.
pub fn find(stage: Stage, kind: &str) -> Option<&'static KindSpec> {
    KINDS.iter().find(|k| k.stage == stage && k.kind == kind)
}

/// Kinds of one stage.
pub fn of_stage(stage: Stage) -> impl Iterator<Item = &'static KindSpec> {
    KINDS.iter().filter(move |k| k.stage == stage)
}

fn spec(stage: Stage, kind: &str) -> Result<&'static KindSpec, BuildError> {
    find(stage, kind).ok_or_else(|| BuildError::UnknownKind {
        stage,
        kind: kind.into(),
    })
}

/// Builds a protocol bound to its hardware.
pub fn build_link(
    protocol: &str,
    protocol_params: &Params,
    hardware: &str,
    hardware_params: &Params,
    cap: Capacity,
) -> Result<Box<dyn Link>, BuildError> {
    let ps = spec(Stage::Protocol, protocol)?;
    let hs = spec(Stage::Hardware, hardware)?;
    if ps.medium != hs.medium {
        return Err(BuildError::MediumMismatch {
            protocol: protocol.into(),
            protocol_medium: ps.medium.expect("protocols have a medium"),
            hardware: hardware.into(),
            hardware_medium: hs.medium.expect("hardware has a medium"),
        });
    }
    match (protocol, hardware) {
        ("sim", hw) => {
            let p = SimProtocol::new(
                cap.in_flight,
                protocol_params.int("timeout_us")? as u64 * 1000,
            );
            let hp = hardware_params;
            Ok(match hw {
                "sine" => Box::new(LinkOf::new(
                    p,
                    SineHardware::new(
                        hp.float("amplitude")?,
                        hp.float("frequency_hz")?,
                        hp.float("phase_per_id")?,
                        cap.words,
                    ),
                    cap.words,
                )),
                "loopback" => Box::new(LinkOf::new(
                    p,
                    LoopbackHardware::new(hp.float("tau_s")?, cap.devices, cap.words),
                    cap.words,
                )),
                other => {
                    return Err(BuildError::UnknownKind {
                        stage: Stage::Hardware,
                        kind: other.into(),
                    })
                }
            })
        }
        (other, _) => Err(BuildError::UnknownKind {
            stage: Stage::Protocol,
            kind: other.into(),
        }),
    }
}

/// Builds a device.
pub fn build_device(
    kind: &str,
    _params: &Params,
    cred: Credential,
) -> Result<Box<dyn Device>, BuildError> {
    spec(Stage::Device, kind)?;
    match kind {
        "sim" => Ok(Box::new(SimDevice::new(cred))),
        other => Err(BuildError::UnknownKind {
            stage: Stage::Device,
            kind: other.into(),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_are_consistent() {
        for k in KINDS {
            assert_eq!(k.medium.is_some(), k.stage != Stage::Device, "{}", k.kind);
            for p in k.params {
                if let (Some(ParamDefault::Float(d)), Some((lo, hi))) = (p.default, p.range) {
                    assert!(
                        (lo..=hi).contains(&d),
                        "{}.{} default out of range",
                        k.kind,
                        p.name
                    );
                }
            }
            for proto in k.protocols {
                assert!(
                    find(Stage::Protocol, proto).is_some(),
                    "{} names {proto}",
                    k.kind
                );
            }
        }
    }

    #[test]
    fn defaults_fill_in_and_links_build() {
        let sine = find(Stage::Hardware, "sine").unwrap();
        let p = Params::new(sine, BTreeMap::new());
        assert_eq!(p.float("amplitude").unwrap(), 1.0);
        let sim = Params::new(find(Stage::Protocol, "sim").unwrap(), BTreeMap::new());
        let cap = Capacity {
            words: 8,
            in_flight: 8,
            devices: 2,
        };
        assert!(build_link("sim", &sim, "sine", &p, cap).is_ok());
        assert!(matches!(
            build_link("sim", &sim, "nope", &p, cap),
            Err(BuildError::UnknownKind { .. })
        ));
        assert!(build_device("sim", &Params::default(), Credential::id(1)).is_ok());
    }
}

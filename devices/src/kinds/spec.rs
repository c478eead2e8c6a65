//! How a kind describes itself: its parameters as data ([`ParamSpec`]), so that the manifest
//! validator can check every key, type, range and choice before anything is built, and the
//! manifest reference lists exactly what the code accepts; and the validated values
//! ([`Params`]) its builder reads.

use std::collections::BTreeMap;

use super::build::{BuildError, Invalid};
use super::choice::Choice;
use super::KindSpec;

/// The unit a hardware carries and a protocol stage speaks; they must match to be linked.
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
    /// Optional: absent means "leave it as the device has it" (a configuration register).
    Unset,
}

impl ParamSpec {
    /// An integer in `lo..=hi`; `default: None` makes it required.
    pub const fn int(
        name: &'static str,
        default: Option<i64>,
        lo: f64,
        hi: f64,
        doc: &'static str,
    ) -> Self {
        Self {
            name,
            ty: ParamType::Int,
            default: match default {
                Some(v) => Some(ParamDefault::Int(v)),
                None => None,
            },
            range: Some((lo, hi)),
            choices: &[],
            doc,
        }
    }

    /// An optional integer in `lo..=hi`: absent leaves the device's own value.
    pub const fn unset_int(name: &'static str, lo: f64, hi: f64, doc: &'static str) -> Self {
        Self {
            name,
            ty: ParamType::Int,
            default: Some(ParamDefault::Unset),
            range: Some((lo, hi)),
            choices: &[],
            doc,
        }
    }

    /// A number, in `range` if one is given.
    pub const fn float(
        name: &'static str,
        default: f64,
        range: Option<(f64, f64)>,
        doc: &'static str,
    ) -> Self {
        Self {
            name,
            ty: ParamType::Float,
            default: Some(ParamDefault::Float(default)),
            range,
            choices: &[],
            doc,
        }
    }

    /// true/false.
    pub const fn bool(name: &'static str, default: bool, doc: &'static str) -> Self {
        Self {
            name,
            ty: ParamType::Bool,
            default: Some(ParamDefault::Bool(default)),
            range: None,
            choices: &[],
            doc,
        }
    }

    /// Free text; `default: None` makes it required.
    pub const fn text(
        name: &'static str,
        default: Option<&'static str>,
        doc: &'static str,
    ) -> Self {
        Self::names(name, default, &[], doc)
    }

    /// One of `choices` (a table's names); `default: None` makes it required.
    pub const fn names(
        name: &'static str,
        default: Option<&'static str>,
        choices: &'static [&'static str],
        doc: &'static str,
    ) -> Self {
        Self {
            name,
            ty: ParamType::Str,
            default: match default {
                Some(v) => Some(ParamDefault::Str(v)),
                None => None,
            },
            range: None,
            choices,
            doc,
        }
    }

    /// One of the names of the choice enum `C` (read back with [`Params::choice`]).
    pub const fn choice<C: Choice>(
        name: &'static str,
        default: &'static str,
        doc: &'static str,
    ) -> Self {
        Self::names(name, Some(default), C::NAMES, doc)
    }
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
            if values.contains_key(p.name) {
                continue;
            }
            let v = match p.default {
                None | Some(ParamDefault::Unset) => continue,
                Some(ParamDefault::Int(v)) => ParamValue::Int(v),
                Some(ParamDefault::Float(v)) => ParamValue::Float(v),
                Some(ParamDefault::Bool(v)) => ParamValue::Bool(v),
                Some(ParamDefault::Str(v)) => ParamValue::Str(v.into()),
            };
            values.insert(p.name.into(), v);
        }
        Self { values }
    }

    fn missing(name: &str) -> BuildError {
        BuildError::Param(name.into())
    }

    /// Integer parameter.
    pub fn int(&self, name: &str) -> Result<i64, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Int(v)) => Ok(*v),
            _ => Err(Self::missing(name)),
        }
    }

    /// Integer parameter that must fit `T` (the validator's range guarantees it; a caller that
    /// skipped the validator gets an error, not a wrapped value).
    pub fn int_as<T: TryFrom<i64>>(&self, name: &str) -> Result<T, BuildError> {
        let v = self.int(name)?;
        T::try_from(v).map_err(|_| BuildError::Invalid {
            param: name.into(),
            source: Invalid::OutOfRange(v),
        })
    }

    /// Number parameter (integers widen).
    pub fn float(&self, name: &str) -> Result<f64, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Float(v)) => Ok(*v),
            Some(ParamValue::Int(v)) => Ok(*v as f64),
            _ => Err(Self::missing(name)),
        }
    }

    /// Bool parameter.
    pub fn bool(&self, name: &str) -> Result<bool, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Bool(v)) => Ok(*v),
            _ => Err(Self::missing(name)),
        }
    }

    /// String parameter.
    pub fn str(&self, name: &str) -> Result<&str, BuildError> {
        match self.values.get(name) {
            Some(ParamValue::Str(v)) => Ok(v),
            _ => Err(Self::missing(name)),
        }
    }

    /// A choice parameter, parsed by its enum: an unknown name is an error, never a default.
    pub fn choice<C: Choice>(&self, name: &str) -> Result<C, BuildError> {
        self.str(name)?
            .parse::<C>()
            .map_err(|e| BuildError::Invalid {
                param: name.into(),
                source: Invalid::Choice(e),
            })
    }

    /// Optional integer parameter (`None` when the manifest leaves it unset).
    pub fn opt_int(&self, name: &str) -> Option<i64> {
        match self.values.get(name) {
            Some(ParamValue::Int(v)) => Some(*v),
            _ => None,
        }
    }
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

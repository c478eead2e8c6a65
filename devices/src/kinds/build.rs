//! What a kind's builder returns: hardware opened for a link ([`OpenedHardware`]), the typed
//! builders by medium ([`HardwareBuild`], [`ProtocolBuild`]) and [`BuildError`].
//!
//! A protocol stage's builder takes hardware *of its medium*: a byte protocol is handed
//! `OpenedHardware<u8>`, a CAN one `OpenedHardware<CanFrame>`, so a protocol cannot be bound
//! to hardware that carries other words; the one place the two are paired by name is
//! [`build_link`](super::build_link).

use std::io;

use conductor_protocols::can::CanFrame;

use super::choice::UnknownChoice;
use super::spec::{Capacity, Medium, Params};
use super::Role;
use crate::component::{Device, Hardware, Protocol};
use crate::link::{Link, LinkOf, Opener};
use crate::message::Credential;
use crate::protocol_stage::ModelTableError;
use crate::sim::SimWord;

/// Failure to build a component from validated parameters (opening a port, ...).
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// No such kind in this role.
    #[error("unknown {role:?} kind {kind:?}")]
    UnknownKind {
        /// Role asked for.
        role: Role,
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
    /// A parameter's value cannot be used (the validator checks types and ranges, not these).
    #[error("{param}: {source}")]
    Invalid {
        /// The parameter.
        param: String,
        /// What is wrong with it.
        #[source]
        source: Invalid,
    },
    /// The OS or the device refused (port does not exist, permission, adapter silent, ...).
    #[error("{resource}: {source}")]
    Open {
        /// The port, interface or address being opened.
        resource: String,
        /// Why it failed.
        #[source]
        source: OpenError,
    },
}

/// What is wrong with a parameter's value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Invalid {
    /// Not one of the choice's names.
    #[error(transparent)]
    Choice(#[from] UnknownChoice),
    /// Not one of a table's names (a model).
    #[error("{value:?} is not one of: {}", .names.join(", "))]
    Name {
        /// What was given.
        value: String,
        /// What the table holds.
        names: &'static [&'static str],
    },
    /// A list entry is not a bus ID.
    #[error("{0:?} is not an ID (0-253)")]
    NotAnId(String),
    /// An integer outside what the component can take.
    #[error("{0} is out of range")]
    OutOfRange(i64),
    /// A CAN bitrate without an SLCAN `Sn` code.
    #[error("{0} bit/s is not a standard SLCAN rate (10k, 20k, 50k, 100k, 125k, 250k, 500k, 750k/800k, 1M)")]
    Bitrate(i64),
    /// An address that resolves to nothing.
    #[error("{0:?} resolves to no address")]
    NoAddress(String),
    /// A per-motor model table that does not parse.
    #[error(transparent)]
    ModelTable(#[from] ModelTableError),
}

/// Why opening hardware failed.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The serial port could not be opened or configured.
    #[error(transparent)]
    Serial(#[from] serialport::Error),
    /// A system call failed (socket, bind, interface lookup, address resolution, thread).
    #[error(transparent)]
    Io(#[from] io::Error),
    /// The SLCAN adapter did not open its channel.
    #[error(transparent)]
    Slcan(#[from] crate::hw::SlcanOpenError),
}

impl BuildError {
    /// `resource` could not be opened because of `source`.
    pub fn open(resource: &str, source: impl Into<OpenError>) -> Self {
        BuildError::Open {
            resource: resource.into(),
            source: source.into(),
        }
    }

    /// Parameter `param` holds a value the component cannot use.
    pub fn invalid(param: &str, source: impl Into<Invalid>) -> Self {
        BuildError::Invalid {
            param: param.into(),
            source: source.into(),
        }
    }
}

/// The unit of a medium: what its hardware moves and its protocol stages speak.
pub trait Word: Copy + Send + 'static {
    /// The medium these words travel on.
    const MEDIUM: Medium;
    /// A value to initialise receive buffers with.
    fn fill() -> Self;
}

impl Word for u8 {
    const MEDIUM: Medium = Medium::Bytes;
    fn fill() -> Self {
        0
    }
}

impl Word for CanFrame {
    const MEDIUM: Medium = Medium::Can;
    fn fill() -> Self {
        CanFrame::standard(0, &[]).expect("ID 0 with no data is a valid standard frame")
    }
}

impl Word for SimWord {
    const MEDIUM: Medium = Medium::Sim;
    fn fill() -> Self {
        SimWord::default()
    }
}

/// Any hardware of one medium, as a link holds it when built by kind.
pub type AnyHardware<W> = Box<dyn Hardware<Word = W> + Send>;

/// Hardware opened for a link: the transport, the line speed a protocol stage times its
/// transactions with, and (for a port or interface that can vanish) how to reopen it.
pub struct OpenedHardware<W: Word> {
    hardware: AnyHardware<W>,
    baud: u32,
    reopen: Option<(String, Opener<AnyHardware<W>>)>,
}

impl<W: Word> OpenedHardware<W> {
    /// Wraps `hardware`; its line speed is 1 Mbit/s until [`at_baud`](Self::at_baud) says
    /// otherwise.
    pub fn new(hardware: impl Hardware<Word = W> + Send + 'static) -> Self {
        Self {
            hardware: Box::new(hardware),
            baud: 1_000_000,
            reopen: None,
        }
    }

    /// The line runs at `baud` bit/s.
    pub fn at_baud(mut self, baud: u32) -> Self {
        self.baud = baud;
        self
    }

    /// When the bus vanishes, the link reopens it with `open` (on a helper thread named after
    /// `name`), polling `present` between attempts.
    pub fn reopening<H: Hardware<Word = W> + Send + 'static>(
        mut self,
        name: &str,
        mut open: impl FnMut() -> Result<H, String> + Send + 'static,
        present: impl Fn() -> bool + Send + 'static,
    ) -> Self {
        let opener = Opener {
            open: Box::new(move || open().map(|h| Box::new(h) as AnyHardware<W>)),
            present: Box::new(present),
        };
        self.reopen = Some((name.into(), opener));
        self
    }

    /// As [`reopening`](Self::reopening) for a device node at `path` (a serial port): it is
    /// present when the node exists.
    pub fn reopening_node<H: Hardware<Word = W> + Send + 'static, E: std::fmt::Display>(
        self,
        path: &str,
        mut open: impl FnMut(&str) -> Result<H, E> + Send + 'static,
    ) -> Self {
        let (again, node) = (path.to_string(), path.to_string());
        self.reopening(
            path,
            move || open(&again).map_err(|e| e.to_string()),
            move || std::path::Path::new(&node).exists(),
        )
    }

    /// The line speed (bit/s).
    pub fn baud(&self) -> u32 {
        self.baud
    }

    /// Binds `protocol` to this hardware with room for `cap.words` words each way per tick.
    pub fn link<P: Protocol<Word = W> + 'static>(
        self,
        protocol: P,
        cap: Capacity,
    ) -> Result<Box<dyn Link>, BuildError> {
        let link = LinkOf::with_fill(protocol, self.hardware, cap.words, W::fill());
        Ok(match self.reopen {
            None => Box::new(link),
            Some((name, opener)) => Box::new(
                link.with_reopen(&name, opener)
                    .map_err(|e| BuildError::open(&name, e))?,
            ),
        })
    }
}

/// How a hardware kind opens its transport, typed by the words it carries.
#[derive(Debug, Clone, Copy)]
pub enum HardwareBuild {
    /// A byte stream.
    Bytes(fn(&Params, Capacity) -> Result<OpenedHardware<u8>, BuildError>),
    /// A CAN bus.
    Can(fn(&Params, Capacity) -> Result<OpenedHardware<CanFrame>, BuildError>),
    /// The built-in simulated bus.
    Sim(fn(&Params, Capacity) -> Result<OpenedHardware<SimWord>, BuildError>),
}

/// Builds a protocol stage from its parameters and binds it to opened hardware of words `W`.
pub type LinkBuild<W> =
    fn(&Params, OpenedHardware<W>, Capacity) -> Result<Box<dyn Link>, BuildError>;

/// How a protocol kind builds its stage and binds it to hardware of its medium.
#[derive(Debug, Clone, Copy)]
pub enum ProtocolBuild {
    /// Speaks a byte stream.
    Bytes(LinkBuild<u8>),
    /// Speaks CAN frames.
    Can(LinkBuild<CanFrame>),
    /// Speaks simulated words.
    Sim(LinkBuild<SimWord>),
}

/// How a device kind builds a device at its bus address.
pub type DeviceBuild = fn(&Params, Credential) -> Result<Box<dyn Device>, BuildError>;

/// A device kind's check that its parameters agree with those of the protocol stage it sits on
/// (`device`, `protocol`, its bus `id`), run by the manifest validator: where the two describe
/// the same thing (a motor model's ranges), a disagreement would encode commands wrongly.
pub type ProtocolCheck =
    fn(device: &Params, protocol: &Params, id: u32) -> Result<(), Disagreement>;

/// What a [`ProtocolCheck`] found: the device parameter at fault and what was expected.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Disagreement {
    /// The device's parameter that disagrees.
    pub param: &'static str,
    /// What the protocol stage says and what the device should say instead.
    pub expected: String,
}

impl HardwareBuild {
    /// The medium carried.
    pub fn medium(&self) -> Medium {
        match self {
            HardwareBuild::Bytes(_) => u8::MEDIUM,
            HardwareBuild::Can(_) => CanFrame::MEDIUM,
            HardwareBuild::Sim(_) => SimWord::MEDIUM,
        }
    }
}

impl ProtocolBuild {
    /// The medium spoken.
    pub fn medium(&self) -> Medium {
        match self {
            ProtocolBuild::Bytes(_) => u8::MEDIUM,
            ProtocolBuild::Can(_) => CanFrame::MEDIUM,
            ProtocolBuild::Sim(_) => SimWord::MEDIUM,
        }
    }
}

/// Bus IDs from a comma-separated list (`"1, 2,3"`; empty entries ignored).
pub fn id_list(params: &Params, name: &str) -> Result<Vec<u8>, BuildError> {
    params
        .str(name)?
        .split(',')
        .map(str::trim)
        .filter(|x| !x.is_empty())
        .map(|x| {
            x.parse::<u8>()
                .map_err(|_| BuildError::invalid(name, Invalid::NotAnId(x.into())))
        })
        .collect()
}

/// The line speed parameter `baud` of a byte hardware.
pub fn baud(params: &Params) -> Result<u32, BuildError> {
    params.int_as("baud")
}

/// The socket address in parameter `name` (`host:port`, resolved now).
pub fn socket_addr(params: &Params, name: &str) -> Result<std::net::SocketAddr, BuildError> {
    use std::net::ToSocketAddrs;
    let s = params.str(name)?;
    s.to_socket_addrs()
        .map_err(|e| BuildError::open(name, e))?
        .next()
        .ok_or_else(|| BuildError::invalid(name, Invalid::NoAddress(s.into())))
}

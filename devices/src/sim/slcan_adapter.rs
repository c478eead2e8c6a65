//! An SLCAN USB-CAN adapter with CAN nodes behind it: parses host commands (open, close,
//! bitrate, transmit, queries), acknowledges them as the chosen dialect does, hands
//! transmitted frames to the nodes and reports their answers as `t…` lines.

use conductor_protocols::can::CanFrame;
use conductor_protocols::slcan::{Command, DeviceScanner, Dialect, Response, TxAck};
use embedded_can::Frame;

use super::can_motors::CanNode;

/// Counters of the adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SlcanSimStats {
    /// Bytes from the host.
    pub bytes_in: u64,
    /// Commands parsed.
    pub commands: u64,
    /// Frames the host transmitted onto the bus.
    pub frames_from_host: u64,
    /// Frames reported to the host.
    pub frames_to_host: u64,
    /// Commands refused with BEL.
    pub nacks: u64,
    /// Bytes sent to the host.
    pub bytes_out: u64,
}

/// The adapter.
pub struct SlcanAdapterSim {
    dialect: Dialect,
    scanner: DeviceScanner<64>,
    open: bool,
    timestamps: bool,
    nodes: Vec<Box<dyn CanNode>>,
    stats: SlcanSimStats,
    scratch: Vec<CanFrame>,
    /// Frames seen on the bus (host's and nodes'), for tests.
    log: Option<Vec<(bool, CanFrame)>>,
}

impl std::fmt::Debug for SlcanAdapterSim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SlcanAdapterSim")
            .field("open", &self.open)
            .field("stats", &self.stats)
            .finish()
    }
}

impl SlcanAdapterSim {
    /// An adapter speaking `dialect`, with `nodes` on its bus.
    pub fn new(dialect: Dialect, nodes: Vec<Box<dyn CanNode>>) -> Self {
        Self {
            dialect,
            scanner: DeviceScanner::new(dialect),
            open: false,
            timestamps: false,
            nodes,
            stats: SlcanSimStats::default(),
            scratch: Vec::new(),
            log: None,
        }
    }

    /// Records every frame on the bus: `(from_host, frame)`.
    pub fn with_log(mut self) -> Self {
        self.log = Some(Vec::new());
        self
    }

    /// The bus log.
    pub fn log(&self) -> &[(bool, CanFrame)] {
        self.log.as_deref().unwrap_or(&[])
    }

    /// Counters since creation.
    pub fn stats(&self) -> SlcanSimStats {
        self.stats
    }

    /// Whether the channel is open.
    pub fn is_open(&self) -> bool {
        self.open
    }

    /// The nodes.
    pub fn nodes(&self) -> &[Box<dyn CanNode>] {
        &self.nodes
    }

    fn respond(&mut self, r: Response<'_>, now_ns: u64, out: &mut Vec<u8>) {
        let mut buf = [0u8; 40];
        let r = match r {
            Response::Frame { frame, .. } if self.timestamps => Response::Frame {
                frame,
                timestamp: Some(((now_ns / 1_000_000) % 60_000) as u16),
            },
            other => other,
        };
        if let Ok(n) = r.encode(&mut buf) {
            out.extend_from_slice(&buf[..n]);
            self.stats.bytes_out += n as u64;
        }
    }

    fn deliver(&mut self, frames: &[CanFrame], now_ns: u64, out: &mut Vec<u8>) {
        for f in frames {
            if let Some(l) = &mut self.log {
                l.push((false, *f));
            }
            if self.open {
                self.stats.frames_to_host += 1;
                self.respond(
                    Response::Frame {
                        frame: *f,
                        timestamp: None,
                    },
                    now_ns,
                    out,
                );
            }
        }
    }

    /// Bytes from the host at `now_ns`; what the adapter sends back is appended to `out`.
    pub fn feed(&mut self, bytes: &[u8], now_ns: u64, out: &mut Vec<u8>) {
        self.stats.bytes_in += bytes.len() as u64;
        let mut cmds = Vec::new();
        self.scanner.feed(bytes, |c| cmds.push(c));
        for c in cmds {
            self.stats.commands += 1;
            let ok = match c {
                Err(_) => false,
                Ok(Command::Open) | Ok(Command::ListenOnly) => {
                    self.open = true;
                    true
                }
                Ok(Command::Close) => {
                    let was = self.open;
                    self.open = false;
                    was
                }
                Ok(Command::Bitrate(_)) | Ok(Command::Btr { .. }) => !self.open,
                Ok(Command::Timestamps(on)) => {
                    self.timestamps = on;
                    true
                }
                Ok(Command::AcceptanceCode(_)) | Ok(Command::AcceptanceMask(_)) => true,
                Ok(Command::Version) => {
                    self.respond(Response::Version(b"1013"), now_ns, out);
                    continue;
                }
                Ok(Command::SerialNumber) => {
                    self.respond(Response::Serial(b"SIM1"), now_ns, out);
                    continue;
                }
                Ok(Command::ReadStatus) => {
                    self.respond(Response::Status(0), now_ns, out);
                    continue;
                }
                Ok(Command::Transmit(f)) => {
                    if !self.open {
                        false
                    } else {
                        let ack = match self.dialect.tx_ack {
                            TxAck::Cr => Response::Ok,
                            TxAck::Z => Response::TxAck {
                                extended: f.is_extended(),
                            },
                        };
                        self.respond(ack, now_ns, out);
                        self.stats.frames_from_host += 1;
                        if let Some(l) = &mut self.log {
                            l.push((true, f));
                        }
                        let mut answers = std::mem::take(&mut self.scratch);
                        answers.clear();
                        for n in &mut self.nodes {
                            n.on_frame(&f, now_ns, &mut answers);
                        }
                        self.deliver(&answers, now_ns, out);
                        self.scratch = answers;
                        continue;
                    }
                }
            };
            if ok {
                self.respond(Response::Ok, now_ns, out);
            } else {
                self.stats.nacks += 1;
                self.respond(Response::Error, now_ns, out);
            }
        }
    }

    /// Time passes: cyclic frames of the nodes are reported.
    pub fn poll(&mut self, now_ns: u64, out: &mut Vec<u8>) {
        let mut frames = std::mem::take(&mut self.scratch);
        frames.clear();
        for n in &mut self.nodes {
            n.poll(now_ns, &mut frames);
        }
        self.deliver(&frames, now_ns, out);
        self.scratch = frames;
    }
}

//! `conductor udp-gateway`: every selected state on its own UDP port, speaking the thesis'
//! plain-text protocol ([`protocol`]). One thread, non-blocking sockets, `poll(2)`.
//!
//! The port of the i-th selected state (in `conductor list` order: by subsystem, then index) is
//! `base + i`, so a client can derive it from the manifest. Malformed datagrams are answered
//! with `ERR <reason>` and counted; nothing a client sends can stop the gateway.

pub use conductor_cli_formats::udp as protocol;

use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::os::fd::AsRawFd;
use std::time::{Duration, Instant};

use conductor_bus::{Bus, Controller, StateInfo, StateSubscriber};

use crate::cli::UdpArgs;
use crate::error::{CliError, Result};
use crate::{out, select};
use protocol::{Request, MAX_REQUEST};

/// Most SMP requests waiting on one state; more are answered `ERR busy`.
const MAX_PENDING: usize = 64;

/// Counters of a gateway run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GatewayReport {
    /// Datagrams received.
    pub requests: u64,
    /// Malformed datagrams (answered `ERR`).
    pub malformed: u64,
    /// Well-formed requests refused (read-only state, no sample yet, SMP timeout, bus error).
    pub refused: u64,
}

struct Pending {
    to: SocketAddr,
    after_seq: Option<u64>,
    deadline: Instant,
}

struct Port {
    info: StateInfo,
    name: String,
    socket: UdpSocket,
    sub: StateSubscriber,
    pending: Vec<Pending>,
}

/// The port of each state: `base + i`.
pub fn port_map(states: &[StateInfo], base: u16) -> Result<Vec<u16>> {
    states
        .iter()
        .enumerate()
        .map(|(i, s)| {
            u16::try_from(base as usize + i).map_err(|_| {
                CliError::Usage(format!(
                    "--base-port {base}: state {} would need port {} (> 65535)",
                    s.qualified_name(),
                    base as usize + i
                ))
            })
        })
        .collect()
}

fn smp_reply(s: &conductor_bus::StateSample) -> String {
    format!(
        "{} {} {} {}",
        out::value(s.value),
        s.t_sample_ns,
        s.seq,
        s.status
    )
}

struct Gateway {
    ports: Vec<Port>,
    ctl: Controller,
    report: GatewayReport,
    smp_timeout: Duration,
}

impl Gateway {
    fn reply(&self, port: usize, to: SocketAddr, text: &str) {
        // A client that went away is not our problem: UDP has no connection to fail.
        let _ = self.ports[port].socket.send_to(text.as_bytes(), to);
    }

    fn refuse(&mut self, port: usize, to: SocketAddr, reason: &str) {
        self.report.refused += 1;
        self.reply(port, to, &format!("ERR {reason}"));
    }

    fn handle(&mut self, port: usize, to: SocketAddr, datagram: &[u8]) -> Result<()> {
        self.report.requests += 1;
        let req = match protocol::parse(datagram) {
            Ok(r) => r,
            Err(m) => {
                self.report.malformed += 1;
                self.reply(port, to, &format!("ERR {m}"));
                return Ok(());
            }
        };
        match req {
            Request::Set(v) => {
                let p = &self.ports[port];
                if !p.info.meta.writable {
                    let reason = format!("{} is read-only", p.name);
                    self.refuse(port, to, &reason);
                    return Ok(());
                }
                let (c, clamped) = p.info.meta.clamp(v);
                let name = p.name.clone();
                let sent = self
                    .ctl
                    .add_ctrl(&name, c)
                    .and_then(|()| self.ctl.send_ctrl_checked());
                match sent {
                    Ok(_) => {
                        let text = format!(
                            "OK {}{}",
                            out::value(c),
                            if clamped { " CLAMPED" } else { "" }
                        );
                        self.reply(port, to, &text);
                    }
                    Err(e) => {
                        self.ctl.clear_ctrl();
                        self.refuse(port, to, &format!("bus: {e}"));
                    }
                }
            }
            Request::Get => match self.ports[port].sub.latest()? {
                Some(s) => self.reply(port, to, &out::value(s.value)),
                None => self.refuse(port, to, "no sample yet"),
            },
            Request::Smp => {
                let p = &mut self.ports[port];
                if p.pending.len() >= MAX_PENDING {
                    self.refuse(port, to, "busy (too many SMP requests waiting)");
                    return Ok(());
                }
                let after_seq = p.sub.latest()?.map(|s| s.seq);
                p.pending.push(Pending {
                    to,
                    after_seq,
                    deadline: Instant::now() + self.smp_timeout,
                });
            }
            Request::Info => {
                let p = &self.ports[port];
                let m = &p.info.meta;
                let text = format!(
                    "{} {} {} {} {} {}",
                    p.name,
                    if m.units.is_empty() { "-" } else { &m.units },
                    if m.writable { "rw" } else { "ro" },
                    m.min,
                    m.max,
                    m.rate_hz
                );
                self.reply(port, to, &text);
            }
        }
        Ok(())
    }

    /// Answers the SMP requests whose fresh sample arrived, or whose time ran out.
    fn serve_pending(&mut self) -> Result<()> {
        let now = Instant::now();
        for i in 0..self.ports.len() {
            if self.ports[i].pending.is_empty() {
                continue;
            }
            let latest = self.ports[i].sub.latest()?;
            let pending = std::mem::take(&mut self.ports[i].pending);
            for p in pending {
                match latest {
                    Some(s) if p.after_seq.is_none_or(|a| s.seq > a) => {
                        self.reply(i, p.to, &smp_reply(&s));
                    }
                    _ if now >= p.deadline => self.refuse(
                        i,
                        p.to,
                        "timeout (no fresh sample; is the executor ticking?)",
                    ),
                    _ => self.ports[i].pending.push(p),
                }
            }
        }
        Ok(())
    }
}

/// Serves until Ctrl-C/SIGTERM; prints the port map first (then `READY`) on stdout.
pub fn run(bus: &Bus, args: &UdpArgs) -> Result<GatewayReport> {
    let pattern = args.pattern.as_deref().unwrap_or("*");
    let states = select::states_wait(bus, pattern, args.wait)?;
    let ports_no = port_map(&states, args.base_port)?;
    let mut ports = Vec::with_capacity(states.len());
    for (info, port) in states.into_iter().zip(&ports_no) {
        let addr = SocketAddr::new(args.bind, *port);
        let socket =
            UdpSocket::bind(addr).map_err(|e| CliError::os(format!("binding UDP {addr}"), e))?;
        socket
            .set_nonblocking(true)
            .map_err(|e| CliError::os("non-blocking socket", e))?;
        let name = info.qualified_name();
        ports.push(Port {
            sub: StateSubscriber::with_buffer(bus, &name, 4)?,
            info,
            name,
            socket,
            pending: Vec::new(),
        });
    }
    if !is_loopback(args.bind) {
        eprintln!(
            "warning: bound to {}: anyone who reaches this address can command the robot",
            args.bind
        );
    }
    let mut rows = vec![["PORT", "STATE", "UNITS", "RW"].map(String::from).to_vec()];
    for (p, n) in ports.iter().zip(&ports_no) {
        let m = &p.info.meta;
        rows.push(vec![
            n.to_string(),
            p.name.clone(),
            if m.units.is_empty() {
                "-".into()
            } else {
                m.units.clone()
            },
            if m.writable { "rw" } else { "ro" }.into(),
        ]);
    }
    println!(
        "udp-gateway on {} for domain {:?} (port = {} + state order):",
        args.bind,
        bus.domain().name(),
        args.base_port
    );
    print!("{}", out::table(&rows));
    println!("READY");
    use std::io::Write;
    let _ = std::io::stdout().flush();

    let mut gw = Gateway {
        ports,
        ctl: Controller::new(bus),
        report: GatewayReport::default(),
        smp_timeout: Duration::from_secs_f64(args.smp_timeout.max(0.0)),
    };
    let mut fds: Vec<libc::pollfd> = gw
        .ports
        .iter()
        .map(|p| libc::pollfd {
            fd: p.socket.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        })
        .collect();
    let mut buf = [0u8; MAX_REQUEST + 1];
    while !conductor_bus::shutdown::requested() {
        let waiting = gw.ports.iter().any(|p| !p.pending.is_empty());
        let timeout_ms = if waiting { 1 } else { 50 };
        // SAFETY: `fds` is a live, correctly sized array of pollfd for the duration of the call;
        // the descriptors belong to sockets owned by `gw`, which outlives the call.
        let n = unsafe { libc::poll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, timeout_ms) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            return Err(CliError::os("poll", e));
        }
        for (i, fd) in fds.iter_mut().enumerate() {
            if fd.revents == 0 {
                continue;
            }
            fd.revents = 0;
            loop {
                match gw.ports[i].socket.recv_from(&mut buf) {
                    Ok((len, from)) => gw.handle(i, from, &buf[..len])?,
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                    // E.g. an ICMP error queued by an earlier reply: nothing to answer.
                    Err(_) => break,
                }
            }
        }
        gw.serve_pending()?;
    }
    let r = gw.report;
    eprintln!(
        "udp-gateway: {} request(s), {} malformed, {} refused",
        r.requests, r.malformed, r.refused
    );
    Ok(r)
}

fn is_loopback(a: IpAddr) -> bool {
    a.is_loopback()
}

#[cfg(test)]
mod tests {
    use super::*;
    use conductor_bus::StateMeta;
    use protocol::Malformed;

    fn info(n: &str) -> StateInfo {
        StateInfo {
            subsystem: "s".into(),
            name: n.into(),
            meta: StateMeta::default(),
            nodes: vec![],
        }
    }

    #[test]
    fn ports_follow_state_order() {
        let s = [info("a"), info("b"), info("c")];
        assert_eq!(port_map(&s, 2827).unwrap(), [2827, 2828, 2829]);
        assert!(matches!(port_map(&s, 65534), Err(CliError::Usage(_))));
    }

    #[test]
    fn malformed_replies_start_with_err() {
        let m = protocol::parse(b"BOGUS").unwrap_err();
        assert!(matches!(m, Malformed::UnknownCommand(_)));
        assert!(format!("ERR {m}").starts_with("ERR unknown command"));
    }
}

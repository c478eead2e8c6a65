//! The Dynamixel Protocol 2.0 stage: bundles a tick's writes into SYNC WRITEs (one per
//! register) and its reads into one SYNC READ or FAST SYNC READ (BULK / FAST BULK READ when the
//! devices read different spans), and matches status packets back to the requests.

use conductor_protocols::dynamixel2::{
    self as dxl, BulkReadEntry, Dxl2Framing, FastReply, Packet, Status,
};

use conductor_protocols::scan::ScanStats;

use super::register_bus::{protocol_over_register_bus, Dialect, ReadTxn, RegisterBus};
use super::transactions::{Core, Entry, ReadShape, StatusErr, Timing};
use crate::component::Protocol;
use crate::message::Reply;
use crate::queue::Bounded;

/// How the stage reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dxl2ReadMode {
    /// SYNC READ (or BULK READ): one status packet per device.
    Sync,
    /// FAST SYNC READ (or FAST BULK READ): one combined status packet (X430/540 FW ≥ 45).
    Fast,
}

/// Largest packet the stage builds, and the largest combined FAST reply it asks for (before
/// byte stuffing): the DynamixelSDK's limit too.
const MAX_PACKET: usize = 1024;
/// Largest packet the stage receives: a [`MAX_PACKET`] reply with worst-case byte stuffing
/// (one 0xFD added per three bytes).
const MAX_RECEIVED: usize = MAX_PACKET + MAX_PACKET / 3 + 1;

/// Dynamixel 2.0 protocol stage. Word = byte.
pub struct Dxl2Protocol {
    stage: RegisterBus<Dxl2, MAX_RECEIVED>,
}

impl std::fmt::Debug for Dxl2Protocol {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dxl2Protocol")
            .field("mode", &self.mode())
            .field("counters", &self.counters())
            .finish()
    }
}

/// What Protocol 2.0 adds to the register-bus stage.
struct Dxl2 {
    mode: Dxl2ReadMode,
    bulk: Vec<BulkReadEntry>,
    ids: Vec<u8>,
    /// Entry lengths of the open fast read, to split its combined reply.
    lens: Vec<usize>,
}

impl Dxl2Protocol {
    /// A stage for up to `devices` servos and `in_flight` read requests per transaction.
    pub fn new(timing: Timing, mode: Dxl2ReadMode, devices: usize, in_flight: usize) -> Self {
        let devices = devices.clamp(1, 253);
        let dialect = Dxl2 {
            mode,
            bulk: Vec::with_capacity(devices),
            ids: Vec::with_capacity(devices),
            lens: Vec::with_capacity(devices),
        };
        Self {
            stage: RegisterBus::new(
                dialect,
                timing,
                dxl::MAX_DEVICE_ID,
                devices,
                in_flight,
                MAX_PACKET,
            ),
        }
    }

    /// The configured read mode.
    pub fn mode(&self) -> Dxl2ReadMode {
        self.stage.dialect().mode
    }

    /// The scanner's discard statistics.
    pub fn scan_stats(&self) -> ScanStats {
        *self.stage.scan_stats()
    }

    /// Valid status packets nobody was waiting for (late, duplicated or foreign).
    pub fn unsolicited(&self) -> u64 {
        self.stage.unsolicited()
    }
}

/// Bytes (before stuffing) of the combined status packet of a FAST SYNC / FAST BULK READ
/// whose servos read `lens` bytes each: a slice (ERR, ID, data, CRC) per servo, plus header,
/// ID, LEN and INST.
pub fn fast_reply_len(lens: impl IntoIterator<Item = usize>) -> usize {
    8 + lens.into_iter().map(|l| 4 + l).sum::<usize>()
}

/// Whether a FAST read of `lens` gets its combined reply: at most `MAX_PACKET` bytes (before
/// stuffing, which `MAX_RECEIVED` leaves room for). Otherwise the stage reads with SYNC /
/// BULK READ, one status packet per servo.
pub fn fast_read_fits(lens: impl IntoIterator<Item = usize>) -> bool {
    fast_reply_len(lens) <= MAX_PACKET
}

/// Interprets a 2.0 error byte.
fn status_err(e: dxl::ErrorByte) -> StatusErr {
    StatusErr {
        failed: e.error().is_some(),
        alert: e.alert(),
        code: e.0,
    }
}

impl Dialect for Dxl2 {
    type Framing = Dxl2Framing;

    fn single(&self) -> bool {
        false
    }

    // Model number (2) and firmware version (1).
    const PING_LEN: u16 = 3;

    fn sync_write(
        &mut self,
        buf: &mut [u8],
        addr: u16,
        len: u8,
        values: &[(u8, [u8; 4])],
    ) -> Option<usize> {
        let l = len as usize;
        let entries = values.iter().map(|(id, b)| (*id, &b[..l]));
        dxl::sync_write(buf, addr, len as u16, entries).ok()
    }

    fn read(&mut self, buf: &mut [u8], entries: &[Entry], shape: ReadShape) -> Option<ReadTxn> {
        // A combined reply longer than the packet buffer could never be received (nor by the
        // DynamixelSDK, whose buffer is the same 1 KiB): such a read goes out as SYNC/BULK READ,
        // one status packet per servo, which always fits.
        let fast = self.mode == Dxl2ReadMode::Fast
            && fast_read_fits(entries.iter().map(|e| e.len as usize));
        if let ReadShape::Ping | ReadShape::Reboot = shape {
            let e = entries.first()?;
            let (bytes, data) = match shape {
                ReadShape::Ping => (dxl::ping(buf, e.id).ok()?, Self::PING_LEN as usize),
                _ => (dxl::reboot(buf, e.id).ok()?, 0),
            };
            return Some(ReadTxn {
                bytes,
                fast: false,
                reply_bytes: dxl::status_len(data),
                replies: 1,
            });
        }
        let bytes = match shape {
            ReadShape::Uniform => {
                let first = entries.first()?;
                self.ids.clear();
                self.ids.extend(entries.iter().map(|e| e.id));
                if fast {
                    dxl::fast_sync_read(buf, first.addr, first.len, &self.ids)
                } else {
                    dxl::sync_read(buf, first.addr, first.len, &self.ids)
                }
            }
            ReadShape::Mixed | ReadShape::Ping | ReadShape::Reboot => {
                self.bulk.clear();
                self.bulk.extend(entries.iter().map(|e| BulkReadEntry {
                    id: e.id,
                    addr: e.addr,
                    len: e.len,
                }));
                if fast {
                    dxl::fast_bulk_read(buf, self.bulk.iter().copied())
                } else {
                    dxl::bulk_read(buf, self.bulk.iter().copied())
                }
            }
        }
        .ok()?;
        let (reply_bytes, replies) = if fast {
            (fast_reply_len(entries.iter().map(|e| e.len as usize)), 1)
        } else {
            let packets = entries.iter().map(|e| dxl::status_len(e.len as usize));
            (packets.sum(), entries.len())
        };
        Some(ReadTxn {
            bytes,
            fast,
            reply_bytes,
            replies,
        })
    }

    fn on_packet(&mut self, core: &mut Core, p: Packet<'_>, fence: u64, out: &mut Bounded<Reply>) {
        if !p.is_status() {
            // An instruction packet: the echo of an adapter that hears itself. Not ours to answer.
            return;
        }
        if p.id == dxl::BROADCAST_ID {
            let Ok(fr) = FastReply::from_packet(&p) else {
                core.counters.rejected_packets += 1;
                return;
            };
            if !core.fast_lens(fence, &mut self.lens) {
                core.unsolicited += 1;
                return;
            }
            for s in fr.slices(self.lens.iter().copied()) {
                match s {
                    Ok(s) => core.on_status(s.id, status_err(s.error), s.data, fence, out),
                    Err(_) => {
                        // The slices after a bad embedded CRC cannot be trusted; their requests
                        // expire as missing.
                        core.counters.rejected_packets += 1;
                        break;
                    }
                }
            }
            return;
        }
        match Status::from_packet(&p) {
            Ok(s) => core.on_status(s.id, status_err(s.error), s.data, fence, out),
            Err(_) => core.counters.rejected_packets += 1,
        }
    }
}

protocol_over_register_bus!(Dxl2Protocol);

crate::choices!(Dxl2ReadMode { Sync = "sync", Fast = "fast_sync" });

/// The `dynamixel2` protocol kind.
pub const KIND: crate::kinds::KindSpec = crate::kinds::KindSpec {
    kind: "dynamixel2",
    params: &[
        crate::kinds::ParamSpec::choice::<Dxl2ReadMode>("read", "sync", "one SYNC READ (a status packet per servo) or one FAST SYNC READ (one combined packet, X430/540 firmware ≥ 45) per transaction; servos reading different spans get a (FAST) BULK READ"),
        crate::kinds::RETURN_DELAY_US,
        crate::kinds::TIMEOUT_US,
    ],
    doc: "ROBOTIS Dynamixel Protocol 2.0: a tick's writes become one SYNC WRITE per register, its \
          reads one SYNC READ / FAST SYNC READ; status packets are matched to the requests by ID; \
          missing replies make the states stale. Bus timing comes from the hardware's `baud`.",
    build: crate::kinds::Build::Protocol(crate::kinds::ProtocolBuild::Bytes(|p, hw, cap| {
        super::register_bus::link_kind(p, hw, cap, Dxl2Protocol::new)
    })),
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::component::TickCtx;
    use crate::message::{Credential, Op, ReplyData, Request};

    fn req(id: u32, op: Op, tick: u64) -> Request {
        Request::new(Credential::id(id), op, ctx(tick))
    }

    fn ctx(tick: u64) -> TickCtx {
        TickCtx {
            tick,
            now_ns: tick * 100_000,
        }
    }

    fn timing() -> Timing {
        Timing {
            baud: 1_000_000,
            return_delay_ns: 0,
            timeout_ns: 1_000_000,
        }
    }

    /// Ticks faster than the bus: while the previous transaction's replies may still come
    /// nothing is sent, and the requests that pile up are coalesced (latest goal wins, one read).
    #[test]
    fn busy_bus_defers_and_coalesces() {
        let mut p = Dxl2Protocol::new(timing(), Dxl2ReadMode::Sync, 2, 16);
        let mut out = Bounded::with_capacity(512);
        let goal = |v, t| {
            req(
                1,
                Op::Write {
                    addr: 116,
                    len: 4,
                    value: v,
                },
                t,
            )
        };
        let read = |t| req(1, Op::Read { addr: 132, len: 4 }, t);
        p.encode(&[goal(100, 0), read(0)], &mut out, ctx(0));
        let first = out.len();
        assert!(first > 0);
        // 0.1 ms later: the read's reply (15 bytes, 0.15 ms at 1 Mbit/s) is still due.
        p.encode(&[goal(200, 1), read(1)], &mut out, ctx(1));
        p.encode(&[goal(300, 2), read(2)], &mut out, ctx(2));
        // Past the reply's expected end, but it has not come: it may still (until the deadline,
        // expected end + 1 ms timeout), and a packet now would collide with it.
        p.encode(&[], &mut out, ctx(10));
        assert_eq!(
            out.len(),
            first,
            "nothing sent while a reply may still come"
        );
        // The deadline passes with the reply missing: the line must then stay quiet for one
        // more timeout, so that a late reply is not taken for the next transaction's.
        let mut replies = Bounded::with_capacity(8);
        p.expire(&mut replies, ctx(14));
        assert!(matches!(replies.as_slice(), [r] if matches!(r.data, ReplyData::Missing { .. })));
        p.encode(&[], &mut out, ctx(20));
        assert_eq!(out.len(), first, "quiet guard after missing replies");
        // Then: one SYNC WRITE carrying the newest goal, one SYNC READ.
        out.clear();
        p.encode(&[], &mut out, ctx(25));
        let mut buf = out.as_slice().to_vec();
        let pk = conductor_protocols::dynamixel2::parse_in_place(&mut buf).unwrap();
        assert_eq!(pk.instruction, 0x83);
        assert_eq!(&pk.params[4..], &[1, 0x2C, 0x01, 0, 0], "goal 300");
        assert_eq!(p.counters().packets_out, 4);
        assert_eq!(p.counters().dropped_requests, 0);
    }

    /// On a tty the OS may still hold a reply when the line looks quiet (its receive worker
    /// kept off the CPU). After missing replies, the next transaction waits until the
    /// hardware says everything that arrived before the quiet time has been decoded: the late
    /// reply, with the same ID and length, would otherwise answer it with an old value.
    #[test]
    fn after_missing_replies_the_next_read_waits_for_the_os_to_deliver() {
        let mut p = Dxl2Protocol::new(timing(), Dxl2ReadMode::Sync, 2, 16);
        let mut out = Bounded::with_capacity(512);
        let read = |t| req(1, Op::Read { addr: 132, len: 4 }, t);
        p.line_drained(0);
        p.encode(&[read(0)], &mut out, ctx(0));
        let first = out.len();
        let mut replies = Bounded::with_capacity(8);
        p.expire(&mut replies, ctx(14));
        assert!(matches!(replies.as_slice(), [r] if matches!(r.data, ReplyData::Missing { .. })));
        // Quiet for one timeout (to 2.4 ms), but the OS was last seen caught up at 1 ms.
        p.line_drained(100_000);
        p.encode(&[read(25)], &mut out, ctx(25));
        p.encode(&[], &mut out, ctx(40));
        assert_eq!(
            out.len(),
            first,
            "nothing sent while a reply may be held up"
        );
        // Caught up at 2.5 ms, after the quiet time: nothing came; the read goes out.
        p.line_drained(2_500_000);
        p.encode(&[], &mut out, ctx(41));
        assert!(out.len() > first);
    }

    #[test]
    fn unsendable_reads_are_missing_not_silent() {
        let mut p = Dxl2Protocol::new(timing(), Dxl2ReadMode::Sync, 2, 16);
        let mut out = Bounded::with_capacity(8); // too small for any packet
        p.encode(
            &[req(3, Op::Read { addr: 132, len: 4 }, 0)],
            &mut out,
            ctx(0),
        );
        assert!(out.is_empty());
        let mut replies = Bounded::with_capacity(4);
        p.expire(&mut replies, ctx(0));
        assert!(matches!(
            replies.as_slice()[0].data,
            ReplyData::Missing { .. }
        ));
        assert_eq!(p.counters().dropped_requests, 1);
        // An ID the protocol cannot address is refused the same way.
        p.encode(
            &[req(300, Op::Read { addr: 132, len: 4 }, 1)],
            &mut out,
            ctx(1),
        );
        replies.clear();
        p.expire(&mut replies, ctx(1));
        assert_eq!(replies.len(), 1);
        assert_eq!(p.counters().dropped_requests, 2);
    }

    /// A FAST read whose combined reply could not be received goes out as SYNC READ (one
    /// status packet per servo); one that fits stays FAST.
    #[test]
    fn a_fast_read_too_long_for_one_reply_goes_out_as_sync_read() {
        let instruction = |len: u8| {
            let mut p = Dxl2Protocol::new(timing(), Dxl2ReadMode::Fast, 41, 64);
            let mut out = Bounded::with_capacity(4096);
            let reads: Vec<Request> = (1..=41)
                .map(|id| req(id, Op::Read { addr: 70, len }, 0))
                .collect();
            p.encode(&reads, &mut out, ctx(0));
            let mut buf = out.as_slice().to_vec();
            let pk = conductor_protocols::dynamixel2::parse_in_place(&mut buf).unwrap();
            (pk.instruction, pk.params.len())
        };
        // 8 + 41 · (4 + 11) = 623 bytes: FAST SYNC READ.
        assert_eq!(instruction(11), (0x8A, 4 + 41));
        // 8 + 41 · (4 + 66) = 2878 bytes: SYNC READ of the same span from the same servos.
        assert_eq!(instruction(66), (0x82, 4 + 41));
    }
}

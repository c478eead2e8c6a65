//! The Dynamixel Protocol 1.0 stage (AX-12, MX on Protocol 1.0 firmware, RX): a tick's writes
//! become SYNC WRITEs (one per register); reads become one BULK READ (MX series) or, for
//! servos without it (AX), one READ per bus window, round robin over the devices.

use conductor_protocols::dynamixel1::{
    self as dxl, BulkReadEntry, Dxl1Framing, ErrorBits, Packet, Status,
};

use super::register_bus::{protocol_over_register_bus, Dialect, ReadTxn, RegisterBus};
use super::transactions::{Core, Entry, ReadShape, StatusErr, Timing};
use crate::message::Reply;
use crate::queue::Bounded;

/// How the stage reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dxl1ReadMode {
    /// BULK READ: one instruction, one status packet per device (MX series only).
    Bulk,
    /// One READ per bus window (AX series): each device is read every N-th window.
    Single,
}

/// Dynamixel 1.0 protocol stage. Word = byte.
pub struct Dxl1Protocol {
    stage: RegisterBus<Dxl1, 512>,
}

impl std::fmt::Debug for Dxl1Protocol {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dxl1Protocol")
            .field("mode", &self.stage.dialect().mode)
            .finish()
    }
}

/// What Protocol 1.0 adds to the register-bus stage.
struct Dxl1 {
    mode: Dxl1ReadMode,
}

/// Bits meaning the instruction was not carried out (its data is not to be trusted).
const FAILED: u8 = ErrorBits::INSTRUCTION | ErrorBits::CHECKSUM | ErrorBits::RANGE;

impl Dxl1Protocol {
    /// A stage for up to `devices` servos and `in_flight` read requests.
    pub fn new(timing: Timing, mode: Dxl1ReadMode, devices: usize, in_flight: usize) -> Self {
        let devices = devices.clamp(1, 254);
        let dialect = Dxl1 { mode };
        Self {
            stage: RegisterBus::new(
                dialect,
                timing,
                dxl::MAX_DEVICE_ID,
                devices,
                in_flight,
                dxl::MAX_PACKET,
            ),
        }
    }
}

impl Dialect for Dxl1 {
    type Framing = Dxl1Framing;

    fn single(&self) -> bool {
        self.mode == Dxl1ReadMode::Single
    }

    // A 1.0 PING status carries no data (the model number is read at address 0).
    const PING_LEN: u16 = 0;

    fn sync_write(
        &mut self,
        buf: &mut [u8],
        addr: u16,
        len: u8,
        values: &[(u8, [u8; 4])],
    ) -> Option<usize> {
        let addr = u8::try_from(addr).ok()?;
        let l = len as usize;
        dxl::sync_write(buf, addr, len, values.iter().map(|(id, b)| (*id, &b[..l]))).ok()
    }

    fn read(&mut self, buf: &mut [u8], entries: &[Entry], shape: ReadShape) -> Option<ReadTxn> {
        match shape {
            ReadShape::Ping => {
                let e = entries.first()?;
                return Some(ReadTxn {
                    bytes: dxl::ping(buf, e.id).ok()?,
                    fast: false,
                    reply_bytes: 6,
                    replies: 1,
                });
            }
            // Protocol 1.0 has no REBOOT (its RESET is a factory reset).
            ReadShape::Reboot => return None,
            ReadShape::Uniform | ReadShape::Mixed => {}
        }
        let fits = entries
            .iter()
            .all(|e| e.addr <= 255 && e.len <= 255 && e.len > 0);
        if !fits {
            return None;
        }
        let bytes = if self.single() {
            let e = entries.first()?;
            dxl::read(buf, e.id, e.addr as u8, e.len as u8)
        } else {
            dxl::bulk_read(
                buf,
                entries.iter().map(|e| BulkReadEntry {
                    len: e.len as u8,
                    id: e.id,
                    addr: e.addr as u8,
                }),
            )
        }
        .ok()?;
        Some(ReadTxn {
            bytes,
            fast: false,
            // Status: FF FF ID LEN ERR data… CHK.
            reply_bytes: entries.iter().map(|e| 6 + e.len as usize).sum(),
            replies: entries.len(),
        })
    }

    fn on_packet(&mut self, core: &mut Core, p: Packet<'_>, fence: u64, out: &mut Bounded<Reply>) {
        let s = Status::from_packet(&p);
        let err = StatusErr {
            failed: s.error.0 & FAILED != 0,
            alert: s.error.0 & !FAILED != 0,
            code: s.error.0,
        };
        core.on_status(s.id, err, s.data, fence, out);
    }
}

protocol_over_register_bus!(Dxl1Protocol);

crate::choices!(Dxl1ReadMode { Bulk = "bulk", Single = "single" });

/// The `dynamixel1` protocol kind.
pub const KIND: crate::kinds::KindSpec = crate::kinds::KindSpec {
    kind: "dynamixel1",
    params: &[
        crate::kinds::ParamSpec::choice::<Dxl1ReadMode>("read", "bulk", "one BULK READ for all servos (MX series) or one READ per bus window, round robin (AX series)"),
        crate::kinds::RETURN_DELAY_US,
        crate::kinds::TIMEOUT_US,
    ],
    doc: "ROBOTIS Dynamixel Protocol 1.0 (AX/MX/RX): writes become SYNC WRITEs, reads one BULK \
          READ (or single READs in turn).",
    build: crate::kinds::Build::Protocol(crate::kinds::ProtocolBuild::Bytes(|p, hw, cap| {
        super::register_bus::link_kind(p, hw, cap, Dxl1Protocol::new)
    })),
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::component::{Protocol, TickCtx};
    use crate::message::{Credential, Op, ReplyData, Request};

    fn req(id: u32, op: Op, tick: u64) -> Request {
        Request::new(Credential::id(id), op, ctx(tick))
    }

    fn ctx(tick: u64) -> TickCtx {
        TickCtx {
            tick,
            now_ns: tick * 1_000_000,
        }
    }

    /// A status packet from servo `id` (what an AX/MX sends).
    fn status(id: u8, err: u8, data: &[u8]) -> Vec<u8> {
        let mut b = [0u8; 64];
        let n = dxl::status(&mut b, id, ErrorBits(err), data).unwrap();
        b[..n].to_vec()
    }

    #[test]
    fn sync_write_and_bulk_read_then_matched_replies() {
        let timing = Timing {
            baud: 1_000_000,
            return_delay_ns: 0,
            timeout_ns: 500_000,
        };
        let mut p = Dxl1Protocol::new(timing, Dxl1ReadMode::Bulk, 4, 16);
        let reqs = [
            req(
                1,
                Op::Write {
                    addr: 30,
                    len: 2,
                    value: 512,
                },
                0,
            ),
            req(
                2,
                Op::Write {
                    addr: 30,
                    len: 2,
                    value: 512,
                },
                0,
            ),
            req(1, Op::Read { addr: 36, len: 2 }, 0),
            req(2, Op::Read { addr: 36, len: 2 }, 0),
        ];
        let mut out = Bounded::with_capacity(256);
        p.encode(&reqs, &mut out, ctx(0));
        // protocols.md §1.11: SYNC WRITE goal 512 to ids 1, 2.
        let sync_write = [
            0xFF, 0xFF, 0xFE, 0x0A, 0x83, 0x1E, 0x02, 0x01, 0x00, 0x02, 0x02, 0x00, 0x02, 0x4D,
        ];
        assert_eq!(&out.as_slice()[..14], &sync_write);
        let (bulk, n) = dxl::parse(&out.as_slice()[14..]).unwrap();
        assert_eq!(14 + n, out.len(), "exactly two packets");
        assert_eq!((bulk.id, bulk.code), (0xFE, 0x92));
        assert_eq!(bulk.params, &[0x00, 2, 1, 36, 2, 2, 36]);
        let mut replies = Bounded::with_capacity(16);
        let mut wire = status(1, 0, &[0x00, 0x02]);
        // Servo 2 is overloaded: an alarm bit, the data still valid.
        wire.extend(status(2, ErrorBits::OVERLOAD, &[0x10, 0x01]));
        p.decode(&wire, &[], &mut replies, ctx(1));
        p.expire(&mut replies, ctx(1));
        let r = replies.as_slice();
        assert_eq!(r.len(), 3, "{r:?}");
        assert_eq!(
            r[0].data,
            ReplyData::Register {
                addr: 36,
                len: 2,
                value: 512
            }
        );
        assert_eq!(r[1].data, ReplyData::DeviceError { code: 0x20 });
        assert_eq!(
            r[2].data,
            ReplyData::Register {
                addr: 36,
                len: 2,
                value: 0x110
            }
        );
        let c = p.counters();
        assert_eq!(
            (c.packets_in, c.device_errors, c.missing_replies),
            (2, 1, 0)
        );
    }

    #[test]
    fn single_mode_reads_one_servo_per_window_and_keeps_the_others_queued() {
        let timing = Timing {
            baud: 1_000_000,
            return_delay_ns: 0,
            timeout_ns: 200_000,
        };
        let mut p = Dxl1Protocol::new(timing, Dxl1ReadMode::Single, 4, 16);
        let mut out = Bounded::with_capacity(256);
        let mut replies = Bounded::with_capacity(16);
        let reads = [
            req(1, Op::Read { addr: 36, len: 2 }, 0),
            req(2, Op::Read { addr: 36, len: 2 }, 0),
        ];
        p.encode(&reads, &mut out, ctx(0));
        let (pk, _) = dxl::parse(out.as_slice()).unwrap();
        assert_eq!((pk.id, pk.code, pk.params), (1, 0x02, &[36u8, 2][..]));
        p.decode(&status(1, 0, &[1, 0]), &[], &mut replies, ctx(1));
        p.expire(&mut replies, ctx(1));
        assert_eq!(replies.len(), 1);
        // Next window: servo 2, whose request waited (no new requests needed).
        out.clear();
        p.encode(&[], &mut out, ctx(1));
        let (pk, _) = dxl::parse(out.as_slice()).unwrap();
        assert_eq!(pk.id, 2);
        // Servo 2 never answers: missing at the deadline, counted.
        replies.clear();
        p.expire(&mut replies, ctx(3));
        assert!(matches!(
            replies.as_slice()[0].data,
            ReplyData::Missing { .. }
        ));
        assert_eq!(p.counters().missing_replies, 1);
    }
}

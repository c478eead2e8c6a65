//! What travels on Zenoh, and the checks every received message passes before anything is
//! published on the local bus.
//!
//! | key expression | payload | attachment |
//! |---|---|---|
//! | `conductor/<domain>/<subsystem>` | a tick message: the exported states of the subsystem that have a sample of one tick, each as its owner's index and the 48 ABI bytes of its `StateSample`, unchanged (see [`encode_tick`]) | [`Envelope`] |
//! | `conductor/<domain>/@bridge/<host>/hb` | [`Heartbeat`] (24 bytes) | — |
//! | `conductor/<domain>/@bridge/<host>/catalog` | [`Catalog`] as JSON | — |
//! | `conductor/<domain>/@cmd/<subsystem>` | the 1048 ABI bytes of a `CommandFrame` | [`Envelope`] |
//!
//! `@bridge` and `@cmd` are Zenoh verbatim chunks: `*` and `**` never match them, so a
//! subscriber on `conductor/<domain>/*` sees only tick messages.
//!
//! One message per subsystem and tick, not one per state: at 1 000 states × 1 kHz that is 1 000
//! Zenoh messages a second instead of a million, which is what lets that load cross the link.

use conductor_bus::{CommandFrame, Setpoint, StateMeta, StateSample, MAX_SETPOINTS};
use serde::{Deserialize, Serialize};

/// First bytes of every envelope and heartbeat: "cdrb" and the wire version 1.
pub const MAGIC: [u8; 5] = *b"cdrb\x01";
/// Size of a `StateSample` on the wire (its ABI layout).
pub const SAMPLE_BYTES: usize = 48;
/// Size of a `CommandFrame` on the wire (its ABI layout).
pub const FRAME_BYTES: usize = 24 + 16 * MAX_SETPOINTS;
/// Longest host name (it is a key-expression chunk and part of an iceoryx2 node name).
pub const MAX_HOST: usize = 64;
/// Bytes before the entries of a tick message: entry count u32, 4 zero bytes.
pub const TICK_HEADER_BYTES: usize = 8;
/// Bytes of one entry of a tick message: the owner's state index u32, 4 zero bytes, the sample.
pub const TICK_ENTRY_BYTES: usize = 8 + SAMPLE_BYTES;
/// Every status bit the ABI defines (bits 0–8); a sample with another bit set is foreign.
pub const KNOWN_STATUS: u32 = (1 << 9) - 1;

/// Why a received message was dropped.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Malformed {
    /// The payload does not have the ABI size.
    #[error("payload of {got} bytes, expected {expected}")]
    Size {
        /// Bytes received.
        got: usize,
        /// Bytes expected.
        expected: usize,
    },
    /// No envelope, or not a Conductor bridge envelope.
    #[error(
        "no Conductor bridge envelope (attachment missing or not starting with \"cdrb\\x01\")"
    )]
    Envelope,
    /// Envelope host name empty, too long or not `[A-Za-z0-9_.-]`.
    #[error("bad host name in the envelope")]
    Host,
    /// A sample with a status bit the ABI does not define, or a non-zero reserved field.
    #[error("status {status:#x} / reserved {reserved} are not Conductor ABI v2 values")]
    Fields {
        /// The status word.
        status: u32,
        /// The reserved word.
        reserved: u32,
    },
    /// A key that is not `conductor/<domain>/<subsystem>` with a valid name.
    #[error("key {0:?} is not conductor/<domain>/<subsystem>")]
    Key(String),
    /// A tick message whose header does not match its length, or with a non-zero pad.
    #[error("tick message of {len} bytes does not hold {count} entries")]
    Tick {
        /// Bytes received.
        len: usize,
        /// Entries the header announces.
        count: u32,
    },
    /// A catalog that is not valid JSON of the expected shape.
    #[error("catalog: {0}")]
    Catalog(String),
}

/// Sender identity and ordering of one state sample or command frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Envelope {
    /// The sending bridge's host name.
    pub host: String,
    /// Random per bridge run: a new session restarts sequence checks.
    pub session: u64,
    /// Per key, +1 per message sent by this session.
    pub seq: u64,
}

impl Envelope {
    /// `MAGIC | session u64 | seq u64 | host_len u8 | host`, little-endian.
    pub fn encode(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(MAGIC.len() + 17 + self.host.len());
        v.extend_from_slice(&MAGIC);
        v.extend_from_slice(&self.session.to_le_bytes());
        v.extend_from_slice(&self.seq.to_le_bytes());
        v.push(self.host.len() as u8);
        v.extend_from_slice(self.host.as_bytes());
        v
    }

    /// Rewrites the sequence number of encoded envelope bytes in place (no allocation per
    /// message on the sending side).
    pub fn set_seq(encoded: &mut [u8], seq: u64) {
        encoded[MAGIC.len() + 8..MAGIC.len() + 16].copy_from_slice(&seq.to_le_bytes());
    }

    /// Parses an attachment.
    pub fn decode(b: &[u8]) -> Result<Self, Malformed> {
        let rest = b.strip_prefix(&MAGIC[..]).ok_or(Malformed::Envelope)?;
        if rest.len() < 17 {
            return Err(Malformed::Envelope);
        }
        let session = u64::from_le_bytes(rest[0..8].try_into().expect("8 bytes"));
        let seq = u64::from_le_bytes(rest[8..16].try_into().expect("8 bytes"));
        let n = rest[16] as usize;
        let host = rest.get(17..17 + n).ok_or(Malformed::Envelope)?;
        if rest.len() != 17 + n {
            return Err(Malformed::Envelope);
        }
        let host = std::str::from_utf8(host).map_err(|_| Malformed::Host)?;
        if !valid_host(host) {
            return Err(Malformed::Host);
        }
        Ok(Self {
            host: host.into(),
            session,
            seq,
        })
    }
}

/// Whether `h` can be a host name here: 1–64 of `[A-Za-z0-9_.-]`, not starting with `.`/`-`.
pub fn valid_host(h: &str) -> bool {
    !h.is_empty()
        && h.len() <= MAX_HOST
        && !h.starts_with(['.', '-'])
        && h.bytes()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, b'_' | b'.' | b'-'))
}

/// The ABI bytes of a sample (see bus/ABI.md).
pub fn encode_sample(s: &StateSample) -> [u8; SAMPLE_BYTES] {
    let mut b = [0u8; SAMPLE_BYTES];
    b[0..8].copy_from_slice(&s.seq.to_le_bytes());
    b[8..16].copy_from_slice(&s.tick.to_le_bytes());
    b[16..24].copy_from_slice(&s.t_sample_ns.to_le_bytes());
    b[24..32].copy_from_slice(&s.t_publish_ns.to_le_bytes());
    b[32..40].copy_from_slice(&s.value.to_le_bytes());
    b[40..44].copy_from_slice(&s.status.to_le_bytes());
    b[44..48].copy_from_slice(&s.reserved.to_le_bytes());
    b
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

/// Parses and checks the ABI bytes of a sample.
pub fn decode_sample(b: &[u8]) -> Result<StateSample, Malformed> {
    if b.len() != SAMPLE_BYTES {
        return Err(Malformed::Size {
            got: b.len(),
            expected: SAMPLE_BYTES,
        });
    }
    let s = StateSample {
        seq: u64_at(b, 0),
        tick: u64_at(b, 8),
        t_sample_ns: u64_at(b, 16),
        t_publish_ns: u64_at(b, 24),
        value: f64::from_bits(u64_at(b, 32)),
        status: u32_at(b, 40),
        reserved: u32_at(b, 44),
    };
    if s.status & !KNOWN_STATUS != 0 || s.reserved != 0 {
        return Err(Malformed::Fields {
            status: s.status,
            reserved: s.reserved,
        });
    }
    Ok(s)
}

/// Starts a tick message in `buf` (cleared; its capacity is kept, so a reused buffer does not
/// allocate). Add entries with [`push_tick_entry`].
pub fn begin_tick(buf: &mut Vec<u8>) {
    buf.clear();
    buf.extend_from_slice(&[0u8; TICK_HEADER_BYTES]);
}

/// Appends the sample of the owner's state `index` to the tick message in `buf`.
pub fn push_tick_entry(buf: &mut Vec<u8>, index: u32, s: &StateSample) {
    buf.extend_from_slice(&index.to_le_bytes());
    buf.extend_from_slice(&[0u8; 4]);
    buf.extend_from_slice(&encode_sample(s));
    let count = ((buf.len() - TICK_HEADER_BYTES) / TICK_ENTRY_BYTES) as u32;
    buf[0..4].copy_from_slice(&count.to_le_bytes());
}

/// A whole tick message: `count u32 | 0u32 | count × (index u32 | 0u32 | 48 ABI bytes)`.
pub fn encode_tick(entries: &[(u32, StateSample)]) -> Vec<u8> {
    let mut b = Vec::with_capacity(TICK_HEADER_BYTES + entries.len() * TICK_ENTRY_BYTES);
    begin_tick(&mut b);
    for (i, s) in entries {
        push_tick_entry(&mut b, *i, s);
    }
    b
}

/// Checks a whole tick message (header, length, every sample) and returns its entries, in the
/// order sent. One bad entry makes the whole message malformed: nothing of it is published.
pub fn decode_tick(b: &[u8]) -> Result<TickEntries<'_>, Malformed> {
    if b.len() < TICK_HEADER_BYTES {
        return Err(Malformed::Size {
            got: b.len(),
            expected: TICK_HEADER_BYTES + TICK_ENTRY_BYTES,
        });
    }
    let count = u32_at(b, 0);
    let body = &b[TICK_HEADER_BYTES..];
    if count == 0
        || u32_at(b, 4) != 0
        || !body.len().is_multiple_of(TICK_ENTRY_BYTES)
        || body.len() / TICK_ENTRY_BYTES != count as usize
    {
        return Err(Malformed::Tick {
            len: b.len(),
            count,
        });
    }
    for e in body.chunks_exact(TICK_ENTRY_BYTES) {
        if u32_at(e, 4) != 0 {
            return Err(Malformed::Tick {
                len: b.len(),
                count,
            });
        }
        decode_sample(&e[8..])?;
    }
    Ok(TickEntries {
        chunks: body.chunks_exact(TICK_ENTRY_BYTES),
    })
}

/// `t_sample_ns` of the first entry of a tick message, unchecked (for profiling).
pub fn tick_first_t_sample(b: &[u8]) -> Option<u64> {
    let at = TICK_HEADER_BYTES + 8 + 16;
    b.get(at..at + 8).map(|_| u64_at(b, at))
}

/// The entries of a checked tick message: `(owner's state index, sample)`.
pub struct TickEntries<'a> {
    chunks: std::slice::ChunksExact<'a, u8>,
}

impl Iterator for TickEntries<'_> {
    type Item = (u32, StateSample);

    fn next(&mut self) -> Option<Self::Item> {
        let e = self.chunks.next()?;
        let s = decode_sample(&e[8..]).expect("checked by decode_tick");
        Some((u32_at(e, 0), s))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        self.chunks.size_hint()
    }
}

impl ExactSizeIterator for TickEntries<'_> {}

/// The ABI bytes of a command frame.
pub fn encode_frame(f: &CommandFrame) -> Vec<u8> {
    let mut b = Vec::with_capacity(FRAME_BYTES);
    b.extend_from_slice(&f.seq.to_le_bytes());
    b.extend_from_slice(&f.t_send_ns.to_le_bytes());
    b.extend_from_slice(&f.count.to_le_bytes());
    b.extend_from_slice(&f.flags.to_le_bytes());
    for e in &f.entries {
        b.extend_from_slice(&e.index.to_le_bytes());
        b.extend_from_slice(&e.flags.to_le_bytes());
        b.extend_from_slice(&e.value.to_le_bytes());
    }
    b
}

/// Parses the ABI bytes of a command frame (values are checked by the owning executor, as for a
/// local frame).
pub fn decode_frame(b: &[u8]) -> Result<CommandFrame, Malformed> {
    if b.len() != FRAME_BYTES {
        return Err(Malformed::Size {
            got: b.len(),
            expected: FRAME_BYTES,
        });
    }
    let mut f = CommandFrame {
        seq: u64_at(b, 0),
        t_send_ns: u64_at(b, 8),
        count: u32_at(b, 16).min(MAX_SETPOINTS as u32),
        flags: u32_at(b, 20),
        ..CommandFrame::default()
    };
    for (i, e) in f.entries.iter_mut().enumerate() {
        let at = 24 + 16 * i;
        *e = Setpoint {
            index: u32_at(b, at),
            flags: u32_at(b, at + 4),
            value: f64::from_bits(u64_at(b, at + 8)),
        };
    }
    Ok(f)
}

/// A bridge's periodic liveness message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Heartbeat {
    /// The sender's session.
    pub session: u64,
    /// Changes whenever the exported catalog changes.
    pub catalog_version: u64,
}

impl Heartbeat {
    /// `MAGIC | session | catalog_version | 3 zero bytes`: 24 bytes.
    pub fn encode(&self) -> [u8; 24] {
        let mut b = [0u8; 24];
        b[..5].copy_from_slice(&MAGIC);
        b[5..13].copy_from_slice(&self.session.to_le_bytes());
        b[13..21].copy_from_slice(&self.catalog_version.to_le_bytes());
        b
    }

    /// Parses a heartbeat.
    pub fn decode(b: &[u8]) -> Result<Self, Malformed> {
        if b.len() != 24 || b[..5] != MAGIC {
            return Err(Malformed::Envelope);
        }
        Ok(Self {
            session: u64_at(b, 5),
            catalog_version: u64_at(b, 13),
        })
    }
}

/// One exported state as the catalog describes it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CatalogEntry {
    /// Owning subsystem.
    pub subsystem: String,
    /// State name.
    pub state: String,
    /// Index within the owner's subsystem (setpoints address it).
    pub index: u32,
    /// Units.
    pub units: String,
    /// Whether remote commands are accepted for it (writable *and* declared for remote commands).
    pub writable: bool,
    /// Rate at which it is exported (Hz).
    pub rate_hz: f64,
    /// Lower limit (`null` = unbounded).
    pub min: Option<f64>,
    /// Upper limit (`null` = unbounded).
    pub max: Option<f64>,
    /// Owning device.
    pub device: String,
}

impl CatalogEntry {
    /// The metadata a mirror of this state gets, at mirror index `index`.
    pub fn meta(&self, index: u32) -> StateMeta {
        StateMeta {
            index,
            units: self.units.clone(),
            writable: self.writable,
            rate_hz: self.rate_hz,
            min: self.min.unwrap_or(f64::NEG_INFINITY),
            max: self.max.unwrap_or(f64::INFINITY),
            device: self.device.clone(),
        }
    }
}

/// Everything one bridge exports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Catalog {
    /// The exporting host.
    pub host: String,
    /// Its session.
    pub session: u64,
    /// See [`Heartbeat::catalog_version`].
    pub version: u64,
    /// Heartbeat period (ms): importers mark its states STALE after two missed.
    pub heartbeat_ms: u64,
    /// The states.
    pub states: Vec<CatalogEntry>,
}

impl Catalog {
    /// Parses and checks a catalog.
    pub fn decode(b: &[u8]) -> Result<Self, Malformed> {
        let c: Catalog =
            serde_json::from_slice(b).map_err(|e| Malformed::Catalog(e.to_string()))?;
        if !valid_host(&c.host) {
            return Err(Malformed::Host);
        }
        for e in &c.states {
            if conductor_bus::naming::validate("subsystem", &e.subsystem).is_err()
                || conductor_bus::naming::validate("state", &e.state).is_err()
            {
                return Err(Malformed::Catalog(format!(
                    "bad state name {}/{}",
                    e.subsystem, e.state
                )));
            }
        }
        Ok(c)
    }
}

/// Key of a subsystem's tick messages: `conductor/<domain>/<subsystem>`.
pub fn tick_key(domain: &str, subsystem: &str) -> String {
    format!("conductor/{domain}/{subsystem}")
}

/// Key of a bridge's heartbeat.
pub fn heartbeat_key(domain: &str, host: &str) -> String {
    format!("conductor/{domain}/@bridge/{host}/hb")
}

/// Key of a bridge's catalog.
pub fn catalog_key(domain: &str, host: &str) -> String {
    format!("conductor/{domain}/@bridge/{host}/catalog")
}

/// Key of a subsystem's remote commands.
pub fn command_key(domain: &str, subsystem: &str) -> String {
    format!("conductor/{domain}/@cmd/{subsystem}")
}

/// The subsystem of a tick key of `domain`.
pub fn split_tick_key<'a>(domain: &str, key: &'a str) -> Result<&'a str, Malformed> {
    let bad = || Malformed::Key(key.into());
    let sub = key
        .strip_prefix("conductor/")
        .and_then(|r| r.strip_prefix(domain))
        .and_then(|r| r.strip_prefix('/'))
        .ok_or_else(bad)?;
    if conductor_bus::naming::validate("subsystem", sub).is_err() {
        return Err(bad());
    }
    Ok(sub)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_roundtrip_keeps_every_abi_byte() {
        let s = StateSample {
            seq: 7,
            tick: 9,
            t_sample_ns: 11,
            t_publish_ns: 13,
            value: -0.25,
            status: 0b101,
            reserved: 0,
        };
        let b = encode_sample(&s);
        assert_eq!(&b[32..40], &(-0.25f64).to_le_bytes());
        assert_eq!(decode_sample(&b), Ok(s));
    }

    #[test]
    fn foreign_samples_are_refused() {
        assert!(matches!(
            decode_sample(b"hello"),
            Err(Malformed::Size { got: 5, .. })
        ));
        let mut b = encode_sample(&StateSample::default());
        b[42] = 0xff; // a status bit the ABI does not define
        assert!(matches!(decode_sample(&b), Err(Malformed::Fields { .. })));
    }

    #[test]
    fn envelope_roundtrip_and_checks() {
        let e = Envelope {
            host: "robot-1".into(),
            session: 42,
            seq: 3,
        };
        assert_eq!(Envelope::decode(&e.encode()), Ok(e.clone()));
        let mut b = e.encode();
        Envelope::set_seq(&mut b, 99);
        assert_eq!(Envelope::decode(&b).map(|x| x.seq), Ok(99));
        assert_eq!(Envelope::decode(b"junk"), Err(Malformed::Envelope));
        let mut b = e.encode();
        b.push(0);
        assert_eq!(Envelope::decode(&b), Err(Malformed::Envelope));
        let bad = Envelope {
            host: "a/b".into(),
            ..e
        };
        assert_eq!(Envelope::decode(&bad.encode()), Err(Malformed::Host));
    }

    #[test]
    fn frame_roundtrip() {
        let mut f = CommandFrame {
            seq: 5,
            t_send_ns: 6,
            ..CommandFrame::default()
        };
        f.push(3, 1.5);
        let b = encode_frame(&f);
        assert_eq!(b.len(), FRAME_BYTES);
        assert_eq!(decode_frame(&b), Ok(f));
        assert!(decode_frame(&b[1..]).is_err());
    }

    #[test]
    fn keys_split_only_for_the_domain() {
        assert_eq!(split_tick_key("robot", "conductor/robot/leg"), Ok("leg"));
        assert!(split_tick_key("robot", "conductor/other/leg").is_err());
        assert!(split_tick_key("robot", "conductor/robot/leg/knee").is_err());
        assert!(split_tick_key("robot", "conductor/robot/@cmd").is_err());
    }

    #[test]
    fn tick_message_roundtrip_keeps_every_abi_byte() {
        let s = |tick: u64, value: f64| StateSample {
            seq: tick,
            tick,
            t_sample_ns: 100 + tick,
            t_publish_ns: 200 + tick,
            value,
            status: 0b10,
            reserved: 0,
        };
        let entries = [(0, s(7, 1.5)), (3, s(7, -2.0)), (41, s(7, f64::NAN))];
        let b = encode_tick(&entries);
        assert_eq!(b.len(), TICK_HEADER_BYTES + 3 * TICK_ENTRY_BYTES);
        // The sample's ABI bytes are carried unchanged.
        let at = TICK_HEADER_BYTES + TICK_ENTRY_BYTES + 8;
        assert_eq!(&b[at..at + SAMPLE_BYTES], &encode_sample(&entries[1].1));
        let got: Vec<(u32, StateSample)> = decode_tick(&b).unwrap().collect();
        assert_eq!(got.len(), 3);
        assert_eq!((got[0].0, got[1].0, got[2].0), (0, 3, 41));
        assert_eq!(got[1].1, entries[1].1);
        assert!(got[2].1.value.is_nan());
        // A reused buffer starts over.
        let mut buf = b.clone();
        begin_tick(&mut buf);
        push_tick_entry(&mut buf, 9, &s(8, 0.0));
        assert_eq!(
            decode_tick(&buf).unwrap().collect::<Vec<_>>(),
            vec![(9, s(8, 0.0))]
        );
    }

    #[test]
    fn bad_tick_messages_are_refused_whole() {
        let good = encode_tick(&[(1, StateSample::default()), (2, StateSample::default())]);
        assert!(decode_tick(&good).is_ok());
        assert!(decode_tick(&good[..good.len() - 1]).is_err());
        assert!(decode_tick(b"short").is_err());
        assert!(decode_tick(&encode_tick(&[])).is_err());
        let mut lie = good.clone();
        lie[0] = 3; // announces 3 entries, holds 2
        assert!(matches!(
            decode_tick(&lie),
            Err(Malformed::Tick { count: 3, .. })
        ));
        let mut pad = good.clone();
        pad[TICK_HEADER_BYTES + 5] = 1;
        assert!(decode_tick(&pad).is_err());
        // One foreign sample spoils the whole message.
        let mut foreign = good;
        foreign[TICK_HEADER_BYTES + TICK_ENTRY_BYTES + 8 + 42] = 0xff;
        assert!(matches!(
            decode_tick(&foreign),
            Err(Malformed::Fields { .. })
        ));
    }
}

//! The MCAP layout of a Conductor recording, shared by `record`, `replay` and `plot`, and its
//! reader ([`Recording`]).
//!
//! * profile `conductor`; chunked (zstd), with message, chunk and metadata indexes;
//! * one schema, `conductor.StateSample`, encoding `jsonschema` ([`SCHEMA`]);
//! * one channel per state, topic `/<subsystem>/<state>`, message encoding `json`, channel
//!   metadata = the state's bus metadata as strings (`conductor_bus::StateInfo::metadata_strings`:
//!   `subsystem`, `state`, `index`, `units`, `writable`, `rate_hz`, `min`, `max`, `device`);
//! * one message per sample: `log_time` = `t_sample_ns`, `publish_time` = `t_publish_ns`
//!   (CLOCK_MONOTONIC), `sequence` = the sample's `seq` (low 32 bits), body [`Message`];
//! * metadata records `conductor` (at start), `conductor.manifest` (when given) and
//!   `conductor.summary` (at the end).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use conductor_bus_meta::StateMeta;
use mcap::sans_io::MessageReadEvent;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Why a recording cannot be read.
#[derive(Debug, Error)]
pub enum RecordingError {
    /// The file could not be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The MCAP library refused the file or a record.
    #[error("{}: MCAP: {detail}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The library's message.
        detail: String,
    },
    /// A recording that `conductor` did not write, or that is damaged, or that has nothing the
    /// command needs.
    #[error("{}: {detail}", path.display())]
    Bad {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
}

/// Result of reading a recording.
pub type Result<T, E = RecordingError> = std::result::Result<T, E>;

/// MCAP profile of the files.
pub const PROFILE: &str = "conductor";
/// Name of the schema record.
pub const SCHEMA_NAME: &str = "conductor.StateSample";
/// Encoding of the schema record.
pub const SCHEMA_ENCODING: &str = "jsonschema";
/// Encoding of every channel.
pub const MESSAGE_ENCODING: &str = "json";
/// Name of the metadata record written at the start.
pub const META_START: &str = "conductor";
/// Name of the metadata record holding the manifest.
pub const META_MANIFEST: &str = "conductor.manifest";
/// Name of the metadata record written when the recording ends.
pub const META_SUMMARY: &str = "conductor.summary";

/// The JSON Schema (draft 2020-12) of every message.
pub const SCHEMA: &str = r#"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "conductor.StateSample",
  "description": "One sample of a Conductor state (bus ABI v1, StateSample).",
  "type": "object",
  "properties": {
    "value": {
      "type": ["number", "null"],
      "description": "Value in the state's units (channel metadata 'units'), the shortest decimal that reads back to the same double; null for NaN or infinity (then 'bits' has it)."
    },
    "bits": {
      "type": "string",
      "pattern": "^[0-9a-f]{16}$",
      "description": "Only when value is null: the IEEE 754 bits of the double as 16 hex digits (7ff0000000000000 = +inf, fff0000000000000 = -inf, 7ff8000000000000 = NaN)."
    },
    "status": {
      "type": "integer",
      "minimum": 0,
      "maximum": 4294967295,
      "description": "Status flags: 1 stale, 2 clamped, 4 rejected, 8 watchdog, 16 device-fault, 32 replayed, 64 simulated, 128 disabled, 256 tripped."
    },
    "t_sample": {
      "type": "number",
      "description": "Sample time, CLOCK_MONOTONIC seconds (the message log_time, in ns)."
    },
    "seq": {
      "type": "integer",
      "minimum": 0,
      "description": "Per-state sample counter; a gap means samples were lost."
    },
    "tick": {
      "type": "integer",
      "minimum": 0,
      "description": "Executor tick that produced the sample."
    }
  },
  "required": ["value", "status", "t_sample", "seq", "tick"],
  "additionalProperties": false
}"#;

/// The body of one message. Every `f64` round-trips bit for bit: finite values are written as
/// the shortest decimal that reads back exactly (and read with correct rounding), the others as
/// `null` with their bits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Message {
    /// Value; `None` for NaN/inf (JSON has no such numbers).
    pub value: Option<f64>,
    /// The bits of a non-finite value, 16 hex digits; absent for finite values.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bits: Option<String>,
    /// Status flags.
    pub status: u32,
    /// Sample time (s).
    pub t_sample: f64,
    /// Sample counter.
    pub seq: u64,
    /// Executor tick.
    pub tick: u64,
}

impl Message {
    /// The message of one sample (a bus `StateSample`'s fields): `value` as a number when
    /// finite, else `null` and its bits; `t_sample_ns` in seconds.
    pub fn of_sample(value: f64, status: u32, t_sample_ns: u64, seq: u64, tick: u64) -> Self {
        let finite = value.is_finite();
        Self {
            value: finite.then_some(value),
            bits: (!finite).then(|| format!("{:016x}", value.to_bits())),
            status,
            t_sample: t_sample_ns as f64 * 1e-9,
            seq,
            tick,
        }
    }

    /// The value: the number, else the double of `bits`, else NaN (a `null` without bits).
    pub fn value_or_nan(&self) -> f64 {
        self.value.unwrap_or_else(|| {
            self.bits
                .as_deref()
                .and_then(|b| u64::from_str_radix(b, 16).ok())
                .map_or(f64::NAN, f64::from_bits)
        })
    }
}

/// Appends the JSON body of `m` to `out`.
pub fn write_message(out: &mut Vec<u8>, m: &Message) {
    serde_json::to_writer(out, m).expect("a Message always serialises");
}

/// Reads a JSON body (decimal floats are read with correct rounding: `float_roundtrip`).
pub fn read_message(body: &[u8]) -> serde_json::Result<Message> {
    serde_json::from_slice(body)
}

/// `/<subsystem>/<state>`.
pub fn topic(subsystem: &str, state: &str) -> String {
    format!("/{subsystem}/{state}")
}

/// A recorded channel, as `replay` and `plot` see it.
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    /// Subsystem.
    pub subsystem: String,
    /// State name.
    pub state: String,
    /// Metadata as recorded.
    pub meta: StateMeta,
}

impl Channel {
    /// `subsystem/state`.
    pub fn qualified_name(&self) -> String {
        format!("{}/{}", self.subsystem, self.state)
    }

    fn from_mcap(path: &Path, c: &mcap::Channel<'_>) -> Result<Self> {
        let bad = |detail: String| RecordingError::Bad {
            path: path.into(),
            detail,
        };
        let schema_ok = c
            .schema
            .as_ref()
            .is_some_and(|s| s.name == SCHEMA_NAME && s.encoding == SCHEMA_ENCODING);
        if !schema_ok || c.message_encoding != MESSAGE_ENCODING {
            return Err(bad(format!(
                "channel {:?} is not a Conductor state channel (schema {SCHEMA_NAME}, encoding {MESSAGE_ENCODING})",
                c.topic
            )));
        }
        let md = &c.metadata;
        let get = |k: &str| {
            md.get(k)
                .ok_or_else(|| bad(format!("channel {:?} lacks metadata {k:?}", c.topic)))
        };
        let num = |k: &str| -> Result<f64> {
            get(k)?.parse().map_err(|_| {
                bad(format!(
                    "channel {:?}: metadata {k:?} is not a number",
                    c.topic
                ))
            })
        };
        Ok(Self {
            subsystem: get("subsystem")?.clone(),
            state: get("state")?.clone(),
            meta: StateMeta {
                index: num("index")? as u32,
                units: get("units")?.clone(),
                writable: get("writable")? == "true",
                rate_hz: num("rate_hz")?,
                min: num("min")?,
                max: num("max")?,
                device: md.get("device").cloned().unwrap_or_default(),
            },
        })
    }
}

/// One recorded sample, compact (replay keeps every sample of a file in memory).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// `log_time`: sample time, CLOCK_MONOTONIC ns.
    pub t_ns: u64,
    /// Index into [`Recording::channels`].
    pub channel: u16,
    /// Status flags.
    pub status: u32,
    /// Value (NaN for `null`).
    pub value: f64,
    /// Executor tick.
    pub tick: u64,
}

/// A whole recording in memory, samples sorted by time.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// The channels, in order of first appearance.
    pub channels: Vec<Channel>,
    /// Every sample, sorted by `t_ns` (stable: equal times keep file order).
    pub samples: Vec<Sample>,
    /// Whether the file ended early (no footer); what was readable is kept.
    pub truncated: bool,
}

impl Recording {
    /// Reads `path`. A file without its end (killed writer) yields what is readable, with
    /// `truncated` set.
    pub fn load(path: &Path) -> Result<Self> {
        let buf = std::fs::read(path).map_err(|e| RecordingError::Io {
            path: path.into(),
            source: e,
        })?;
        Self::from_bytes(path, &buf)
    }

    /// Reads a recording already in memory; `path` names it in errors. As [`Recording::load`].
    ///
    /// Records are read with a length limit ([`record_length_limit`]), so a damaged length is
    /// an error before the reader allocates, and the reader is given no more than the bytes
    /// left (a length past the end costs no buffer of that size): mcap 0.26's `MessageStream`
    /// sets no limit, and a
    /// record length near `u64::MAX` inside a chunk overflowed its arithmetic or asked for an
    /// impossible allocation, which aborts the process (both found by the `recording` fuzz
    /// target; kept in `fuzz/regressions/recording/`). A file that still makes the reader panic
    /// is refused like any malformed file.
    pub fn from_bytes(path: &Path, buf: &[u8]) -> Result<Self> {
        std::panic::catch_unwind(|| Self::parse(path, buf)).unwrap_or_else(|_| {
            Err(RecordingError::Bad {
                path: path.into(),
                detail: "malformed MCAP (the reader failed on a damaged record)".into(),
            })
        })
    }

    fn parse(path: &Path, buf: &[u8]) -> Result<Self> {
        let options = mcap::sans_io::LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_record_length_limit(record_length_limit(buf.len()));
        let mut reader = mcap::sans_io::MessageReader::new_with_options(options);
        let mut rest = buf;
        let stream = std::iter::from_fn(|| loop {
            match reader.next_event()? {
                Ok(MessageReadEvent::ReadRequest(need)) => {
                    // Only what the buffer still holds: the reader sizes (and zero-fills) its
                    // buffer to the request, which for a damaged length is up to the limit.
                    let n = need.min(rest.len());
                    reader.insert(n).copy_from_slice(&rest[..n]);
                    reader.notify_read(n); // 0: the end of the file
                    rest = &rest[n..];
                }
                Ok(MessageReadEvent::Message(m)) => return Some(Ok(m)),
                Err(e) => return Some(Err(e)),
            }
        });
        let mut rec = Recording::default();
        let mut ids: BTreeMap<u16, u16> = BTreeMap::new();
        for m in stream {
            let m = match m {
                Ok(m) => m,
                Err(_) if !rec.samples.is_empty() || !rec.channels.is_empty() => {
                    rec.truncated = true;
                    break;
                }
                Err(e) => {
                    return Err(RecordingError::Mcap {
                        path: path.into(),
                        detail: e.to_string(),
                    })
                }
            };
            let idx = match ids.get(&m.channel.id) {
                Some(&i) => i,
                None => {
                    let c = Channel::from_mcap(path, &m.channel)?;
                    let i = u16::try_from(rec.channels.len()).map_err(|_| RecordingError::Bad {
                        path: path.into(),
                        detail: "more than 65535 channels".into(),
                    })?;
                    rec.channels.push(c);
                    ids.insert(m.channel.id, i);
                    i
                }
            };
            let body = read_message(&m.data).map_err(|e| RecordingError::Bad {
                path: path.into(),
                detail: format!("message on {:?}: {e}", m.channel.topic),
            })?;
            rec.samples.push(Sample {
                t_ns: m.log_time,
                channel: idx,
                status: body.status,
                value: body.value_or_nan(),
                tick: body.tick,
            });
        }
        if !rec.truncated && mcap::read::footer(buf).is_err() {
            rec.truncated = true;
        }
        rec.samples.sort_by_key(|s| s.t_ns);
        Ok(rec)
    }
}

/// Length of one pass over `rec` (non-empty, `states` states published) in ns: the recording's
/// span plus one mean sample period, so that a loop's first sample does not land on the
/// previous pass's last; never 0.
pub fn pass_ns(rec: &Recording, states: usize) -> u64 {
    let (Some(first), Some(last)) = (rec.samples.first(), rec.samples.last()) else {
        return 1_000_000;
    };
    let span = last.t_ns - first.t_ns;
    let per_channel = (rec.samples.len() / states.max(1)).max(2) as u64;
    // Saturating: a damaged file's times can span nearly all of u64 (found by the `recording`
    // fuzz target; tools/cli/fuzz/regressions/recording/replay-span-overflows-pass-length).
    let pass_ns = span.saturating_add(span / (per_channel - 1));
    if pass_ns > 0 {
        return pass_ns;
    }
    // One instant only (e.g. a single sample): repeat it at the fastest recorded rate.
    let rate = rec
        .channels
        .iter()
        .map(|c| c.meta.rate_hz)
        .fold(0.0, f64::max);
    if rate > 0.0 {
        ((1e9 / rate) as u64).max(1)
    } else {
        1_000_000
    }
}

/// The longest record (or chunk padding, or buffered compressed input) read from a file of
/// `file_len` bytes. A record outside a chunk cannot be longer than the file; one inside a
/// compressed chunk can (a truncated recording's first chunk holds the ~2 KB schema in fewer
/// bytes), so the limit is never below 16 MiB, far above any record Conductor writes (a
/// message is ~150 bytes). It bounds what the reader allocates for a damaged length.
pub fn record_length_limit(file_len: usize) -> usize {
    const MIN: usize = 16 << 20;
    file_len.max(MIN)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schema_is_json_and_names_every_field() {
        let v: serde_json::Value = serde_json::from_str(SCHEMA).unwrap();
        let props = v["properties"].as_object().unwrap();
        let req = conductor_testkit::json_strings(&v["required"]);
        // Every field of Message is described and required.
        let m = serde_json::to_value(Message::of_sample(0.0, 0, 0, 0, 0)).unwrap();
        for k in m.as_object().unwrap().keys() {
            assert!(props.contains_key(k), "{k}");
            assert!(req.contains(&k.as_str()), "{k}");
        }
        // `bits` is the one optional field: only non-finite values carry it.
        assert_eq!(props.len(), m.as_object().unwrap().len() + 1);
        assert!(props.contains_key("bits") && !req.contains(&"bits"));
        let m = serde_json::to_value(Message::of_sample(f64::INFINITY, 0, 0, 0, 0)).unwrap();
        assert_eq!(m["bits"], "7ff0000000000000");
    }

    #[test]
    fn non_finite_values_become_null() {
        let json = serde_json::to_string(&Message::of_sample(f64::NAN, 0, 0, 0, 0)).unwrap();
        assert!(json.contains("\"value\":null"), "{json}");
        let back: Message = serde_json::from_str(&json).unwrap();
        assert!(back.value_or_nan().is_nan());
    }

    /// Encodes and decodes `v` as a recording does; returns the bits read back.
    fn round_trip(v: f64) -> u64 {
        let mut body = Vec::new();
        write_message(&mut body, &Message::of_sample(v, 0, 0, 0, 0));
        read_message(&body).unwrap().value_or_nan().to_bits()
    }

    #[test]
    fn every_double_round_trips_bit_for_bit() {
        // The edges: zeros, subnormals, extremes, infinities, NaNs with sign and payload.
        let edges = [
            0.0,
            -0.0,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            f64::from_bits(1),
            f64::from_bits(0x000f_ffff_ffff_ffff),
            f64::MAX,
            f64::MIN,
            f64::EPSILON,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
            f64::from_bits(0x7ff0_0000_0000_0001),
            f64::from_bits(0xfff8_dead_beef_0001),
            0.1,
            1.0 / 3.0,
            2.61,
            9007199254740993.0,
        ];
        for v in edges {
            assert_eq!(round_trip(v), v.to_bits(), "{v:e} ({:016x})", v.to_bits());
        }
        // Random bit patterns (every exponent and sign), and the doubles of a sensor's and a
        // joint's everyday range, where the decimal reader's rounding used to be 1 ULP off.
        let mut x = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let mut off = 0;
        for i in 0..200_000 {
            let v = match i % 2 {
                0 => f64::from_bits(next()),
                _ => (next() >> 11) as f64 / (1u64 << 53) as f64 * 200.0 - 100.0,
            };
            off += usize::from(round_trip(v) != v.to_bits());
        }
        assert_eq!(
            off, 0,
            "{off} of 200000 doubles did not come back bit for bit"
        );
    }

    /// `magic, header, chunk(records), data end` with an uncompressed chunk of `records`
    /// (`compressed_size` as given).
    fn file_with_chunk(records: &[u8], compressed_size: u64) -> Vec<u8> {
        let mut f = b"\x89MCAP0\r\n".to_vec();
        // Header: empty profile and library.
        f.push(0x01);
        f.extend(8u64.to_le_bytes());
        f.extend([0; 8]);
        let mut chunk = Vec::new();
        chunk.extend([0; 8 + 8]); // message start and end time
        chunk.extend((records.len() as u64).to_le_bytes()); // uncompressed size
        chunk.extend([0; 4 + 4]); // uncompressed crc (none), compression "" (none)
        chunk.extend(compressed_size.to_le_bytes());
        chunk.extend(records);
        f.push(0x06);
        f.extend((chunk.len() as u64).to_le_bytes());
        f.extend(chunk);
        f.push(0x0f); // data end, crc 0
        f.extend(4u64.to_le_bytes());
        f.extend([0; 4]);
        f
    }

    #[test]
    fn damaged_record_lengths_are_refused_not_a_crash() {
        let path = Path::new("damaged.mcap");
        // A record in a chunk whose length is near u64::MAX: refused by the length limit.
        let mut huge = vec![0x03];
        huge.extend((u64::MAX - 3).to_le_bytes());
        let err = Recording::from_bytes(path, &file_with_chunk(&huge, huge.len() as u64));
        assert!(
            matches!(&err, Err(RecordingError::Mcap { detail, .. }) if detail.contains("exceeds limit")),
            "{err:?}"
        );
        // A record (29 bytes) longer than its chunk says it holds (14): within the limit, and
        // mcap 0.26 overflows subtracting it from the chunk's remainder (a panic in a debug
        // build), which `from_bytes` refuses like any malformed file.
        let mut overrun = vec![0x03];
        overrun.extend(20u64.to_le_bytes());
        overrun.extend([0; 20]);
        let err = Recording::from_bytes(path, &file_with_chunk(&overrun, 14));
        assert!(
            matches!(
                &err,
                Err(RecordingError::Bad { .. } | RecordingError::Mcap { .. })
            ),
            "{err:?}"
        );
    }
}

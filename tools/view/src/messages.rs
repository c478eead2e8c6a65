//! What the view puts on its Foxglove channels: one JSON message per state sample and per stats
//! message, each channel with a JSON Schema so that Foxglove's panels (Plot, Raw Messages, State
//! Transitions, ...) know the fields.
//!
//! Times are the bus's own: CLOCK_MONOTONIC, as `{sec, nsec}` objects, which Foxglove reads as
//! time values. A message's log time (the timestamp of the WebSocket message, Foxglove's
//! "receive time") is the sample time, as in `conductor record`'s MCAP files.

use std::collections::BTreeMap;

use conductor_bus::{status, ExecutorStats, StateInfo, StateSample};
use serde::Serialize;

/// Schema name of the state channels.
pub const SAMPLE_SCHEMA_NAME: &str = "conductor.LiveSample";
/// Schema name of the stats channels.
pub const STATS_SCHEMA_NAME: &str = "conductor.ExecutorStats";
/// Schema encoding of every channel.
pub const SCHEMA_ENCODING: &str = "jsonschema";
/// Message encoding of every channel (and of what clients may publish).
pub const MESSAGE_ENCODING: &str = "json";

/// The names of the status bits, in bit order (the `flags` object has one boolean per name).
pub use conductor_bus::status::NAMES as FLAG_NAMES;

const TIME: &str = r#"{
      "type": "object",
      "properties": {
        "sec": { "type": "integer", "minimum": 0 },
        "nsec": { "type": "integer", "minimum": 0, "maximum": 999999999 }
      },
      "required": ["sec", "nsec"]
    }"#;

/// The JSON Schema (draft 2020-12) of a state channel's messages.
pub fn sample_schema() -> String {
    let flags: Vec<String> = FLAG_NAMES
        .iter()
        .enumerate()
        .map(|(bit, n)| {
            format!(r#"        "{n}": {{ "type": "boolean", "description": "status bit {bit}" }}"#)
        })
        .collect();
    format!(
        r#"{{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "{SAMPLE_SCHEMA_NAME}",
  "description": "One sample of a Conductor state (bus ABI StateSample). Settable states take {{\"value\": x}} published on the same topic.",
  "type": "object",
  "properties": {{
    "value": {{
      "type": ["number", "null"],
      "description": "Value in the state's unit; null encodes NaN or infinity."
    }},
    "unit": {{ "type": "string", "description": "The state's unit (empty when unitless)." }},
    "status": {{
      "type": "integer",
      "minimum": 0,
      "description": "Status bits: 1 stale, 2 clamped, 4 rejected, 8 watchdog, 16 device-fault, 32 replayed, 64 simulated, 128 disabled, 256 tripped."
    }},
    "flags": {{
      "type": "object",
      "description": "The status bits by name.",
      "properties": {{
{}
      }}
    }},
    "t_sample": {{
      "description": "When the quantity was sampled (CLOCK_MONOTONIC).",
      "$comment": "also the message's log time",
      {}
    }},
    "t_publish": {{
      "description": "When the executor published the sample (CLOCK_MONOTONIC).",
      {}
    }},
    "seq": {{ "type": "integer", "minimum": 0, "description": "Per-state sample counter." }},
    "tick": {{ "type": "integer", "minimum": 0, "description": "Executor tick of the sample." }}
  }},
  "required": ["value", "unit", "status", "flags", "t_sample", "t_publish", "seq", "tick"]
}}"#,
        flags.join(",\n"),
        time_body(),
        time_body()
    )
}

/// The properties of the time object, without its braces (spliced into a property that also
/// has a description).
fn time_body() -> String {
    let t = TIME.trim();
    t[1..t.len() - 1].trim().to_string()
}

/// A CLOCK_MONOTONIC time as Foxglove's `{sec, nsec}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Time {
    /// Seconds.
    pub sec: u64,
    /// Nanoseconds within the second.
    pub nsec: u32,
}

impl Time {
    /// From nanoseconds.
    pub fn from_ns(ns: u64) -> Self {
        Self {
            sec: ns / 1_000_000_000,
            nsec: (ns % 1_000_000_000) as u32,
        }
    }
}

/// The body of one state message.
#[derive(Debug, Clone, Serialize)]
pub struct LiveSample<'a> {
    /// The value; `None` (JSON null) for NaN/inf.
    pub value: Option<f64>,
    /// The state's unit.
    pub unit: &'a str,
    /// The status bits.
    pub status: u32,
    /// The status bits by name.
    pub flags: BTreeMap<&'static str, bool>,
    /// Sample time.
    pub t_sample: Time,
    /// Publish time.
    pub t_publish: Time,
    /// Sample counter.
    pub seq: u64,
    /// Executor tick.
    pub tick: u64,
}

impl<'a> LiveSample<'a> {
    /// The message of sample `s` of a state in `unit`.
    pub fn of(s: &StateSample, unit: &'a str) -> Self {
        Self {
            value: s.value.is_finite().then_some(s.value),
            unit,
            status: s.status,
            flags: FLAG_NAMES
                .iter()
                .enumerate()
                .map(|(bit, n)| (*n, s.status & (1 << bit) != 0))
                .collect(),
            t_sample: Time::from_ns(s.t_sample_ns),
            t_publish: Time::from_ns(s.t_publish_ns),
            seq: s.seq,
            tick: s.tick,
        }
    }
}

/// The JSON Schema of a stats channel's messages.
pub fn stats_schema() -> String {
    let ints = [
        ("seq", "Stats message counter."),
        ("ticks", "Base ticks executed since start."),
        ("misses", "Deadlines missed."),
        ("lateness_p50_ns", "Tick lateness p50 (ns, a bucket bound)."),
        ("lateness_p99_ns", "Tick lateness p99 (ns, a bucket bound)."),
        (
            "lateness_p999_ns",
            "Tick lateness p99.9 (ns, a bucket bound).",
        ),
        ("lateness_max_ns", "Largest tick lateness (ns)."),
        ("bus_errors", "Bus errors."),
        ("frames_applied", "Command frames received."),
        ("setpoints_rejected", "Setpoints rejected."),
        ("setpoints_clamped", "Setpoints clamped to limits."),
        (
            "setpoints_refused",
            "Setpoints refused: device disabled or tripped.",
        ),
        ("watchdog_trips", "Command watchdog trips."),
        ("stale_states", "States flagged stale now."),
        ("states", "States of the executor."),
        ("rt_active", "1 when the RT thread runs SCHED_FIFO."),
        ("bus_outages", "Times a bus vanished."),
        ("device_faults", "Device fault transitions."),
        ("late_replies", "Replies after their request was given up."),
        ("devices", "Devices."),
        ("devices_enabled", "Devices driving."),
        ("devices_tripped", "Devices tripped."),
        ("devices_faulted", "Devices reporting a fault."),
        ("links_down", "Buses down now."),
    ];
    let mut props: Vec<String> = ints
        .iter()
        .map(|(k, d)| format!(r#"    "{k}": {{ "type": "integer", "description": "{d}" }}"#))
        .collect();
    props.push(r#"    "cpu": { "type": "integer", "description": "CPU of the RT thread, -1 when not pinned." }"#.into());
    props.push(
        r#"    "base_rate_hz": { "type": "number", "description": "Configured base rate (Hz)." }"#
            .into(),
    );
    props.push(r#"    "achieved_rate_hz": { "type": "number", "description": "Achieved tick rate over the last stats interval (Hz)." }"#.into());
    props.push(format!(
        r#"    "t": {{ "description": "When the figures were taken (CLOCK_MONOTONIC).", {} }}"#,
        time_body()
    ));
    props.push(r#"    "histogram": { "type": "array", "items": { "type": "integer" }, "description": "Tick lateness histogram (bus/ABI.md gives the buckets)." }"#.into());
    format!(
        r#"{{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "{STATS_SCHEMA_NAME}",
  "description": "An executor's health (bus ABI ExecutorStats), about 10 per second.",
  "type": "object",
  "properties": {{
{}
  }}
}}"#,
        props.join(",\n")
    )
}

/// The body of one stats message.
pub fn stats_json(s: &ExecutorStats) -> serde_json::Value {
    serde_json::json!({
        "seq": s.seq,
        "t": Time::from_ns(s.t_ns),
        "ticks": s.ticks,
        "misses": s.misses,
        "base_rate_hz": s.base_rate_hz,
        "achieved_rate_hz": s.achieved_rate_hz,
        "lateness_p50_ns": s.lateness_p50_ns,
        "lateness_p99_ns": s.lateness_p99_ns,
        "lateness_p999_ns": s.lateness_p999_ns,
        "lateness_max_ns": s.lateness_max_ns,
        "bus_errors": s.bus_errors,
        "frames_applied": s.frames_applied,
        "setpoints_rejected": s.setpoints_rejected,
        "setpoints_clamped": s.setpoints_clamped,
        "setpoints_refused": s.setpoints_refused,
        "watchdog_trips": s.watchdog_trips,
        "stale_states": s.stale_states,
        "states": s.states,
        "rt_active": s.rt_active,
        "cpu": s.cpu,
        "bus_outages": s.bus_outages,
        "device_faults": s.device_faults,
        "late_replies": s.late_replies,
        "devices": s.devices,
        "devices_enabled": s.devices_enabled,
        "devices_tripped": s.devices_tripped,
        "devices_faulted": s.devices_faulted,
        "links_down": s.links_down,
        "histogram": s.histogram.to_vec(),
    })
}

/// `/<subsystem>/<state>`: the topic of a state (as in `conductor record`'s files).
pub fn state_topic(subsystem: &str, state: &str) -> String {
    format!("/{subsystem}/{state}")
}

/// `/<subsystem>/stats`: the topic of an executor's stats (no state may be called `stats`: its
/// service would clash with the stats service).
pub fn stats_topic(subsystem: &str) -> String {
    format!("/{subsystem}/stats")
}

/// Channel metadata of a state: its bus metadata as strings.
pub fn state_metadata(info: &StateInfo) -> BTreeMap<String, String> {
    info.metadata_strings()
}

/// What a client may publish on a settable state's topic: `{"value": x}` (other fields, such as
/// the rest of a [`LiveSample`] a Publish panel fills in, are ignored) or a bare number.
pub fn parse_setpoint(payload: &[u8]) -> Result<f64, String> {
    let v: serde_json::Value = serde_json::from_slice(payload)
        .map_err(|e| format!("not JSON ({e}); expected {{\"value\": <number>}}"))?;
    let n = match &v {
        serde_json::Value::Object(o) => o.get("value"),
        other => Some(other),
    };
    n.and_then(serde_json::Value::as_f64)
        .ok_or_else(|| format!("expected {{\"value\": <number>}} or a number, got {v}"))
}

/// Whether `status` has bit `name` (one of [`FLAG_NAMES`]).
pub fn has_flag(status_bits: u32, name: &str) -> bool {
    FLAG_NAMES
        .iter()
        .position(|n| *n == name)
        .is_some_and(|bit| status_bits & (1 << bit) != 0)
}

// The flag names must be the bus's, in bit order.
const _: () = assert!(status::TRIPPED == 1 << 8);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemas_are_json_and_name_every_field() {
        let s: serde_json::Value = serde_json::from_str(&sample_schema()).unwrap();
        let props = s["properties"].as_object().unwrap();
        for k in [
            "value",
            "unit",
            "status",
            "flags",
            "t_sample",
            "t_publish",
            "seq",
            "tick",
        ] {
            assert!(props.contains_key(k), "{k}");
        }
        assert_eq!(s["properties"]["t_sample"]["required"][1], "nsec");
        assert_eq!(
            s["properties"]["flags"]["properties"]
                .as_object()
                .unwrap()
                .len(),
            9
        );
        let st: serde_json::Value = serde_json::from_str(&stats_schema()).unwrap();
        let body = stats_json(&ExecutorStats::default());
        // Every field of the message is in the schema and the other way round.
        let a: Vec<_> = st["properties"].as_object().unwrap().keys().collect();
        let b: Vec<_> = body.as_object().unwrap().keys().collect();
        assert_eq!(a, b);
    }

    #[test]
    fn flag_names_are_the_bus_names() {
        let all = (1u32 << 9) - 1;
        let bus: Vec<&str> = status::names(all).collect();
        assert_eq!(bus, FLAG_NAMES);
        assert!(has_flag(status::CLAMPED | status::SIMULATED, "clamped"));
        assert!(!has_flag(status::SIMULATED, "clamped"));
    }

    #[test]
    fn a_sample_message() {
        let s = StateSample {
            seq: 7,
            tick: 9,
            t_sample_ns: 12_000_000_123,
            t_publish_ns: 12_000_050_000,
            value: -0.25,
            status: status::CLAMPED | status::SIMULATED,
            reserved: 0,
        };
        let v = serde_json::to_value(LiveSample::of(&s, "rad")).unwrap();
        assert_eq!(v["value"], -0.25);
        assert_eq!(v["t_sample"]["sec"], 12);
        assert_eq!(v["t_sample"]["nsec"], 123);
        assert_eq!(v["t_publish"]["nsec"], 50_000);
        assert_eq!(v["flags"]["clamped"], true);
        assert_eq!(v["flags"]["stale"], false);
        let nan = StateSample {
            value: f64::NAN,
            ..s
        };
        assert!(serde_json::to_value(LiveSample::of(&nan, "")).unwrap()["value"].is_null());
    }

    #[test]
    fn setpoints_from_clients() {
        assert_eq!(parse_setpoint(br#"{"value": 0.5}"#), Ok(0.5));
        assert_eq!(parse_setpoint(br#"{"value": -2, "unit": "rad"}"#), Ok(-2.0));
        assert_eq!(parse_setpoint(b"1.25"), Ok(1.25));
        assert!(parse_setpoint(br#"{"v": 1}"#).is_err());
        assert!(parse_setpoint(b"nope").is_err());
        assert!(parse_setpoint(br#"{"value": "1"}"#).is_err());
    }
}

//! State metadata carried as iceoryx2 service attributes, so any client can discover it.
//!
//! iceoryx2 allows 8 attributes per service; a state uses all of them:
//!
//! | key | value |
//! |---|---|
//! | `conductor.abi` | [`crate::ABI_VERSION`] in decimal |
//! | `conductor.kind` | `state`, `commands`, `tick` or `stats` |
//! | `conductor.index` | index of the state within its subsystem (the setpoint address) |
//! | `conductor.units` | SI-style unit string, e.g. `rad`, `A`, `V` (absent when unitless) |
//! | `conductor.writable` | `true` or `false` |
//! | `conductor.rate_hz` | publish rate in Hz |
//! | `conductor.limits` | `min,max` (either may be `-inf`/`inf`) |
//! | `conductor.device` | the device the state belongs to (absent when none) |
//!
//! A subsystem's `commands` service carries, besides the first two, its command watchdog:
//!
//! | key | value |
//! |---|---|
//! | `conductor.watchdog_ms` | the watchdog period in ms (decimal), or `off`; absent when the owner does not say |

use core::time::Duration;

use iceoryx2::prelude::{AttributeSet, AttributeSpecifier};
use iceoryx2::service::attribute::{AttributeKey, AttributeValue};

use crate::abi::ABI_VERSION;
use crate::error::{BusError, Result};

/// Attribute key of the ABI version.
pub const KEY_ABI: &str = "conductor.abi";
/// Attribute key of the service kind.
pub const KEY_KIND: &str = "conductor.kind";
/// Attribute key of the state index.
pub const KEY_INDEX: &str = "conductor.index";
/// Attribute key of the units.
pub const KEY_UNITS: &str = "conductor.units";
/// Attribute key of the writable flag.
pub const KEY_WRITABLE: &str = "conductor.writable";
/// Attribute key of the rate.
pub const KEY_RATE: &str = "conductor.rate_hz";
/// Attribute key of the limits.
pub const KEY_LIMITS: &str = "conductor.limits";
/// Attribute key of the device.
pub const KEY_DEVICE: &str = "conductor.device";
/// Attribute key of the command watchdog period (on a subsystem's `commands` service).
pub const KEY_WATCHDOG: &str = "conductor.watchdog_ms";
/// Value of [`KEY_WATCHDOG`] for an owner without a command watchdog.
pub const WATCHDOG_OFF: &str = "off";

/// What a Conductor service is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServiceKind {
    /// Pub/sub of `StateSample`.
    State,
    /// Pub/sub of `CommandFrame`.
    Commands,
    /// Event, notified once per state-stage tick.
    Tick,
    /// Pub/sub of `ExecutorStats`.
    Stats,
    /// Pub/sub of `[StateSample]`, one per tick, every state of the subsystem; and its event.
    Snapshot,
}

impl ServiceKind {
    /// The attribute value.
    pub fn as_str(self) -> &'static str {
        match self {
            ServiceKind::State => "state",
            ServiceKind::Commands => "commands",
            ServiceKind::Tick => "tick",
            ServiceKind::Stats => "stats",
            ServiceKind::Snapshot => "snapshot",
        }
    }
}

pub use conductor_bus_meta::StateMeta;

fn key(k: &str) -> Result<AttributeKey> {
    k.try_into()
        .map_err(|e| BusError::iceoryx("attribute key", e))
}

fn value(v: &str) -> Result<AttributeValue> {
    v.try_into()
        .map_err(|e| BusError::iceoryx(format!("attribute value {v:?}"), e))
}

fn define(spec: AttributeSpecifier, k: &str, v: &str) -> Result<AttributeSpecifier> {
    spec.define(&key(k)?, &value(v)?)
        .map_err(|e| BusError::iceoryx("define attribute", e))
}

/// The attributes every Conductor service carries: ABI version and kind.
pub(crate) fn base_attributes(kind: ServiceKind) -> Result<AttributeSpecifier> {
    let spec = define(AttributeSpecifier::new(), KEY_ABI, &ABI_VERSION.to_string())?;
    define(spec, KEY_KIND, kind.as_str())
}

/// The attributes of a `commands` service whose owner runs a command watchdog of `watchdog`
/// (`None`: no watchdog, published as [`WATCHDOG_OFF`]).
pub(crate) fn command_attributes(watchdog: Option<Duration>) -> Result<AttributeSpecifier> {
    let spec = base_attributes(ServiceKind::Commands)?;
    define(spec, KEY_WATCHDOG, &fmt_watchdog(watchdog))
}

fn fmt_watchdog(watchdog: Option<Duration>) -> String {
    match watchdog {
        // Whole milliseconds print as integers ("500"), others with their fraction ("2.5").
        Some(d) => format!("{}", d.as_nanos() as f64 / 1e6),
        None => WATCHDOG_OFF.into(),
    }
}

/// Reads a `commands` service's watchdog attribute: `Some(Some(period))`, `Some(None)` for
/// [`WATCHDOG_OFF`], `None` when absent or malformed (the owner does not say).
pub fn watchdog_from_attributes(attrs: &AttributeSet) -> Option<Option<Duration>> {
    let v = get(attrs, KEY_WATCHDOG)?;
    if v == WATCHDOG_OFF {
        return Some(None);
    }
    let ms: f64 = v.parse().ok()?;
    (ms.is_finite() && ms > 0.0).then(|| Some(Duration::from_secs_f64(ms / 1e3)))
}

fn fmt_limit(x: f64) -> String {
    if x == f64::INFINITY {
        "inf".into()
    } else if x == f64::NEG_INFINITY {
        "-inf".into()
    } else {
        format!("{x}")
    }
}

/// The full attribute set of a state service.
pub(crate) fn state_attributes(meta: &StateMeta) -> Result<AttributeSpecifier> {
    let mut spec = base_attributes(ServiceKind::State)?;
    spec = define(spec, KEY_INDEX, &meta.index.to_string())?;
    // iceoryx2 rejects empty values: absent means empty.
    if !meta.units.is_empty() {
        spec = define(spec, KEY_UNITS, &meta.units)?;
    }
    spec = define(
        spec,
        KEY_WRITABLE,
        if meta.writable { "true" } else { "false" },
    )?;
    spec = define(spec, KEY_RATE, &format!("{}", meta.rate_hz))?;
    spec = define(
        spec,
        KEY_LIMITS,
        &format!("{},{}", fmt_limit(meta.min), fmt_limit(meta.max)),
    )?;
    if !meta.device.is_empty() {
        spec = define(spec, KEY_DEVICE, &meta.device)?;
    }
    Ok(spec)
}

/// Reads a state's metadata back from its service's attributes; `None` if a required key is
/// missing or malformed (i.e. this is not a Conductor state service).
pub fn state_meta_from_attributes(attrs: &AttributeSet) -> Option<StateMeta> {
    let limits = get(attrs, KEY_LIMITS)?;
    let (min, max) = limits.split_once(',')?;
    Some(StateMeta {
        index: get(attrs, KEY_INDEX)?.parse().ok()?,
        units: get(attrs, KEY_UNITS).unwrap_or_default(),
        writable: get(attrs, KEY_WRITABLE)? == "true",
        rate_hz: get(attrs, KEY_RATE)?.parse().ok()?,
        min: min.trim().parse().ok()?,
        max: max.trim().parse().ok()?,
        device: get(attrs, KEY_DEVICE).unwrap_or_default(),
    })
}

/// First value of attribute `k`, as a string.
pub fn get(attrs: &AttributeSet, k: &str) -> Option<String> {
    let k = key(k).ok()?;
    attrs.key_value(&k, 0).map(|v| v.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roundtrip_through_attributes() {
        let m = StateMeta {
            index: 3,
            units: "rad".into(),
            writable: true,
            rate_hz: 250.0,
            min: -2.6,
            max: f64::INFINITY,
            device: "dRAR".into(),
        };
        let spec = state_attributes(&m).unwrap();
        let attrs = spec.attributes();
        assert_eq!(attrs.number_of_attributes(), 8);
        assert_eq!(get(attrs, KEY_KIND).as_deref(), Some("state"));
        assert_eq!(get(attrs, KEY_ABI).as_deref(), Some("2"));
        assert_eq!(state_meta_from_attributes(attrs), Some(m));
    }

    #[test]
    fn empty_units_and_device_are_omitted() {
        let m = StateMeta::default();
        let spec = state_attributes(&m).unwrap();
        assert_eq!(spec.attributes().number_of_attributes(), 6);
        assert_eq!(state_meta_from_attributes(spec.attributes()), Some(m));
    }

    #[test]
    fn watchdog_roundtrip() {
        for w in [
            Some(Duration::from_millis(500)),
            Some(Duration::from_micros(2500)),
            None,
        ] {
            let spec = command_attributes(w).unwrap();
            let attrs = spec.attributes();
            assert_eq!(get(attrs, KEY_KIND).as_deref(), Some("commands"));
            assert_eq!(watchdog_from_attributes(attrs), Some(w));
        }
        let spec = command_attributes(Some(Duration::from_millis(500))).unwrap();
        assert_eq!(get(spec.attributes(), KEY_WATCHDOG).as_deref(), Some("500"));
        let spec = command_attributes(Some(Duration::from_micros(2500))).unwrap();
        assert_eq!(get(spec.attributes(), KEY_WATCHDOG).as_deref(), Some("2.5"));
        let spec = command_attributes(None).unwrap();
        assert_eq!(get(spec.attributes(), KEY_WATCHDOG).as_deref(), Some("off"));
        // An owner that does not say.
        let spec = base_attributes(ServiceKind::Commands).unwrap();
        assert_eq!(watchdog_from_attributes(spec.attributes()), None);
    }

    #[test]
    fn clamp_flags() {
        let m = StateMeta {
            min: -1.0,
            max: 1.0,
            ..Default::default()
        };
        assert_eq!(m.clamp(0.5), (0.5, false));
        assert_eq!(m.clamp(2.0), (1.0, true));
        assert_eq!(m.clamp(-3.0), (-1.0, true));
    }
}

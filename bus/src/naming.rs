//! Service naming: `conductor/<subsystem>/<state>`, `.../commands`, `.../tick`, `.../stats`,
//! `.../snapshot`.

use crate::error::{BusError, Result};

/// Root of every Conductor service name.
pub const ROOT: &str = "conductor";
/// Last path element of the command service.
pub const COMMANDS: &str = "commands";
/// Last path element of the tick event service.
pub const TICK: &str = "tick";
/// Last path element of the executor stats service.
pub const STATS: &str = "stats";
/// Last path element of the per-tick snapshot (a pub/sub service and an event of that name).
pub const SNAPSHOT: &str = "snapshot";
/// Names a state may not take because the subsystem's own services use them.
pub const RESERVED: [&str; 5] = [COMMANDS, TICK, STATS, SNAPSHOT, "surface"];

/// Longest subsystem or state name.
pub const MAX_NAME_LEN: usize = 64;

/// Checks a subsystem or state name: 1–64 of `[A-Za-z0-9_.-]`, not starting with `.` or `-`.
pub fn validate(what: &'static str, name: &str) -> Result<()> {
    let bad = |reason| {
        Err(BusError::InvalidName {
            what,
            name: name.into(),
            reason,
        })
    };
    if name.is_empty() || name.len() > MAX_NAME_LEN {
        return bad("expected 1 to 64 characters");
    }
    if !name
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
    {
        return bad("expected only letters, digits, '_', '-' and '.'");
    }
    if name.starts_with(['.', '-']) {
        return bad("must not start with '.' or '-'");
    }
    if what == "state" && RESERVED.contains(&name) {
        return bad(
            "reserved for the subsystem's own services (commands, tick, stats, snapshot, surface)",
        );
    }
    Ok(())
}

/// `conductor/<subsystem>/<state>`.
pub fn state(subsystem: &str, state: &str) -> String {
    format!("{ROOT}/{subsystem}/{state}")
}

/// `conductor/<subsystem>/commands`.
pub fn commands(subsystem: &str) -> String {
    format!("{ROOT}/{subsystem}/{COMMANDS}")
}

/// `conductor/<subsystem>/tick`.
pub fn tick(subsystem: &str) -> String {
    format!("{ROOT}/{subsystem}/{TICK}")
}

/// `conductor/<subsystem>/stats`.
pub fn stats(subsystem: &str) -> String {
    format!("{ROOT}/{subsystem}/{STATS}")
}

/// `conductor/<subsystem>/snapshot`.
pub fn snapshot(subsystem: &str) -> String {
    format!("{ROOT}/{subsystem}/{SNAPSHOT}")
}

/// Splits `conductor/<subsystem>/<leaf>` into `(subsystem, leaf)`.
pub fn split(service: &str) -> Option<(&str, &str)> {
    let rest = service.strip_prefix(ROOT)?.strip_prefix('/')?;
    let (sub, leaf) = rest.split_once('/')?;
    (!sub.is_empty() && !leaf.is_empty() && !leaf.contains('/')).then_some((sub, leaf))
}

/// A state reference as users write it: `subsystem/state` or a bare `state`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct StateRef {
    /// The subsystem, when given.
    pub subsystem: Option<String>,
    /// The state name.
    pub state: String,
}

impl StateRef {
    /// Parses `subsystem/state` or `state` (a leading `conductor/` is accepted too).
    pub fn parse(s: &str) -> Result<Self> {
        let s = s.strip_prefix("conductor/").unwrap_or(s);
        match s.split_once('/') {
            Some((sub, st)) => {
                validate("subsystem", sub)?;
                validate("state", st)?;
                Ok(Self {
                    subsystem: Some(sub.into()),
                    state: st.into(),
                })
            }
            None => {
                validate("state", s)?;
                Ok(Self {
                    subsystem: None,
                    state: s.into(),
                })
            }
        }
    }
}

impl core::fmt::Display for StateRef {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match &self.subsystem {
            Some(sub) => write!(f, "{sub}/{}", self.state),
            None => f.write_str(&self.state),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_split() {
        assert_eq!(state("leg", "RAR"), "conductor/leg/RAR");
        assert_eq!(split("conductor/leg/RAR"), Some(("leg", "RAR")));
        assert_eq!(split("conductor/leg/commands"), Some(("leg", "commands")));
        assert_eq!(split("other/leg/RAR"), None);
        assert_eq!(split("conductor/leg"), None);
        assert_eq!(split("conductor/leg/a/b"), None);
    }

    #[test]
    fn validation() {
        assert!(validate("state", "RAR").is_ok());
        assert!(validate("state", "hip_pitch.pos").is_ok());
        for bad in ["", "a/b", "a b", ".x", "-x", "tick", &"x".repeat(65)] {
            assert!(validate("state", bad).is_err(), "{bad:?}");
        }
        assert!(validate("subsystem", "tick").is_ok());
    }

    #[test]
    fn state_refs() {
        let r = StateRef::parse("leg/RAR").unwrap();
        assert_eq!(r.subsystem.as_deref(), Some("leg"));
        assert_eq!(r.to_string(), "leg/RAR");
        assert_eq!(StateRef::parse("conductor/leg/RAR").unwrap(), r);
        assert_eq!(StateRef::parse("RAR").unwrap().subsystem, None);
        assert!(StateRef::parse("leg/a/b").is_err());
    }
}

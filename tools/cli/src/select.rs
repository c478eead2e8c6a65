//! Choosing states by name or glob.

use std::time::{Duration, Instant};

use conductor_bus::{Bus, StateInfo};
use glob::{MatchOptions, Pattern};

use crate::error::{CliError, Result};

const OPTIONS: MatchOptions = MatchOptions {
    case_sensitive: true,
    require_literal_separator: true,
    require_literal_leading_dot: false,
};

/// A state selector: a glob over `subsystem/state`, or over the bare state name when the
/// pattern has no `/`.
#[derive(Debug, Clone)]
pub struct Selector {
    text: String,
    pattern: Pattern,
    qualified: bool,
}

impl Selector {
    /// Parses `pattern` (a leading `conductor/` or `/` is ignored).
    pub fn new(pattern: &str) -> Result<Self> {
        let text = pattern
            .strip_prefix("conductor/")
            .or_else(|| pattern.strip_prefix('/'))
            .unwrap_or(pattern);
        let glob = Pattern::new(text).map_err(|e| CliError::BadPattern {
            pattern: pattern.into(),
            reason: e.msg.into(),
        })?;
        Ok(Self {
            text: pattern.into(),
            pattern: glob,
            qualified: text.contains('/'),
        })
    }

    /// Whether `subsystem/name` is selected.
    pub fn matches(&self, subsystem: &str, name: &str) -> bool {
        if self.qualified {
            self.pattern
                .matches_with(&format!("{subsystem}/{name}"), OPTIONS)
        } else {
            self.pattern.matches_with(name, OPTIONS)
        }
    }

    /// The pattern as the user wrote it.
    pub fn text(&self) -> &str {
        &self.text
    }
}

/// The states of the domain matching `pattern`, in `conductor list` order.
pub fn states(bus: &Bus, pattern: &str) -> Result<Vec<StateInfo>> {
    let sel = Selector::new(pattern)?;
    Ok(bus
        .list_states()?
        .into_iter()
        .filter(|s| sel.matches(&s.subsystem, &s.name))
        .collect())
}

/// As [`states`], waiting up to `wait` seconds for at least one match to appear.
pub fn states_wait(bus: &Bus, pattern: &str, wait: f64) -> Result<Vec<StateInfo>> {
    let deadline = Instant::now() + Duration::from_secs_f64(wait.max(0.0));
    loop {
        let found = states(bus, pattern)?;
        if !found.is_empty() {
            return Ok(found);
        }
        if Instant::now() >= deadline || conductor_bus::shutdown::requested() {
            let known = bus
                .list_states()?
                .iter()
                .take(12)
                .map(StateInfo::qualified_name)
                .collect();
            return Err(CliError::NoMatch {
                pattern: pattern.into(),
                domain: bus.domain().name().into(),
                known,
            });
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn qualified_and_bare_patterns() {
        let s = Selector::new("leg/*").unwrap();
        assert!(s.matches("leg", "knee"));
        assert!(!s.matches("arm", "knee"));
        let s = Selector::new("knee").unwrap();
        assert!(s.matches("leg", "knee") && s.matches("arm", "knee"));
        assert!(!s.matches("leg", "knee2"));
        let s = Selector::new("*").unwrap();
        assert!(s.matches("leg", "knee"));
        let s = Selector::new("conductor/l?g/k*").unwrap();
        assert!(s.matches("leg", "knee"));
        // `*` does not cross the subsystem separator.
        assert!(!Selector::new("*/x/*").unwrap().matches("leg", "knee"));
    }

    #[test]
    fn bad_glob_is_an_error() {
        assert!(matches!(
            Selector::new("leg/[kn"),
            Err(CliError::BadPattern { .. })
        ));
    }
}

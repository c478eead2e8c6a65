//! Domains isolate sets of services, like `ROS_DOMAIN_ID`: two robots, or two parallel test runs,
//! on one machine never see each other's states.
//!
//! A domain maps to an iceoryx2 [`Config`] with its own file prefix (`cdr_<domain>_` for every
//! `/dev/shm` segment) and its own root directory (`/tmp/conductor/<domain>/` for service and node
//! records). Every process of one domain must use the same mapping; `bus/ABI.md` spells it out for
//! other languages.

use iceoryx2::config::Config;
use iceoryx2::prelude::{FileName, Path, SemanticString as _};
use std::sync::atomic::{AtomicU32, Ordering};

use crate::error::{BusError, Result};

/// Environment variable naming the domain (default [`Domain::DEFAULT`]).
pub const ENV: &str = "CONDUCTOR_DOMAIN";

/// Longest domain name (the shm prefix must stay well under the file-name limit).
pub const MAX_DOMAIN_LEN: usize = 48;

/// A named, isolated set of Conductor services.
#[derive(Debug, Clone)]
pub struct Domain {
    name: String,
    config: Config,
}

impl Domain {
    /// The domain used when neither the API nor `CONDUCTOR_DOMAIN` names one.
    pub const DEFAULT: &'static str = "default";

    /// The domain called `name`: 1–48 of `[A-Za-z0-9_-]`.
    pub fn new(name: &str) -> Result<Self> {
        let invalid = |reason| BusError::InvalidName {
            what: "domain",
            name: name.into(),
            reason,
        };
        if name.is_empty() || name.len() > MAX_DOMAIN_LEN {
            return Err(invalid("expected 1 to 48 characters"));
        }
        if !name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
        {
            return Err(invalid("expected only letters, digits, '_' and '-'"));
        }
        let mut config = Config::default();
        let prefix = prefix(name);
        config.global.prefix =
            FileName::new(prefix.as_bytes()).map_err(|e| BusError::iox("domain prefix", e))?;
        let root = root_path(name);
        config.global.set_root_path(
            &Path::new(root.as_bytes()).map_err(|e| BusError::iox("domain root path", e))?,
        );
        Ok(Self {
            name: name.into(),
            config,
        })
    }

    /// The domain named by `CONDUCTOR_DOMAIN`, or [`Domain::DEFAULT`].
    pub fn from_env() -> Result<Self> {
        match std::env::var(ENV) {
            Ok(name) if !name.is_empty() => Self::new(&name),
            _ => Self::new(Self::DEFAULT),
        }
    }

    /// A fresh domain no other process uses: `<tag>-<pid>-<n>-<nanos>`. For tests and benchmarks.
    pub fn unique(tag: &str) -> Result<Self> {
        static COUNTER: AtomicU32 = AtomicU32::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let nanos = crate::clock::monotonic_ns() % 1_000_000;
        let tag: String = tag
            .chars()
            .filter(|c| c.is_ascii_alphanumeric())
            .take(16)
            .collect();
        Self::new(&format!("{tag}-{}-{n}-{nanos}", std::process::id()))
    }

    /// The domain's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The iceoryx2 configuration that realises this domain.
    pub fn iceoryx2_config(&self) -> &Config {
        &self.config
    }

    /// The shm file prefix (`cdr_<domain>_`).
    pub fn prefix(&self) -> String {
        prefix(&self.name)
    }

    /// The iceoryx2 root directory (`/tmp/conductor/<domain>/`).
    pub fn root_path(&self) -> String {
        root_path(&self.name)
    }
}

fn prefix(name: &str) -> String {
    format!("cdr_{name}_")
}

fn root_path(name: &str) -> String {
    format!("/tmp/conductor/{name}/")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_map_to_prefix_and_root() {
        let d = Domain::new("robot_1").unwrap();
        assert_eq!(d.prefix(), "cdr_robot_1_");
        assert_eq!(d.root_path(), "/tmp/conductor/robot_1/");
        assert_eq!(
            d.iceoryx2_config().global.prefix.as_bytes(),
            b"cdr_robot_1_"
        );
    }

    #[test]
    fn bad_names_rejected() {
        for bad in ["", "a b", "a/b", "ä", &"x".repeat(49)] {
            assert!(
                matches!(Domain::new(bad), Err(BusError::InvalidName { .. })),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn unique_domains_differ() {
        let a = Domain::unique("t").unwrap();
        let b = Domain::unique("t").unwrap();
        assert_ne!(a.name(), b.name());
    }
}

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

/// The directory that holds every domain's root directory. Shared by all users, like `/tmp`
/// (mode 1777): each user's processes create and own their domains' directories in it.
pub const ROOT_BASE: &str = "/tmp/conductor";

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
            FileName::new(prefix.as_bytes()).map_err(|e| BusError::iceoryx("domain prefix", e))?;
        let root = root_path(name);
        config.global.set_root_path(
            &Path::new(root.as_bytes()).map_err(|e| BusError::iceoryx("domain root path", e))?,
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

    /// Makes the domain's directories safe to use before joining it ([`crate::Bus::open`] calls
    /// this):
    ///
    /// * [`ROOT_BASE`] exists with mode 1777 (sticky, writable by all, like `/tmp`), so an
    ///   executor running as a dedicated user can create its domain even after a process of
    ///   another user (root running `conductor list`, say) created the base first. A base that
    ///   iceoryx2 created with its own mode (0750) is opened up by its owner; one that is not a
    ///   directory, or not writable and owned by someone else, is an error saying so.
    /// * The domain's directory, if it exists, belongs to this user and is writable by no one
    ///   else: iceoryx2 makes every segment of a domain readable and writable by its creator
    ///   only, so processes of one domain must run as one user (root too: root can open the
    ///   files, but the executor cannot open root's, so root's samples and commands never
    ///   arrive). A directory another user made first (to squat the name or to read what is
    ///   put in it) is refused instead of used.
    pub fn prepare_dirs(&self) -> Result<()> {
        use std::os::unix::fs::{MetadataExt as _, PermissionsExt as _};
        let err = |path: &str, reason: String| BusError::DomainAccess {
            domain: self.name.clone(),
            path: path.into(),
            reason,
        };
        let euid = effective_uid();
        let base = std::path::Path::new(ROOT_BASE);
        if let Err(e) = std::fs::create_dir(base) {
            if e.kind() != std::io::ErrorKind::AlreadyExists {
                return Err(err(ROOT_BASE, format!("cannot create it: {e}")));
            }
        }
        let m = std::fs::symlink_metadata(base).map_err(|e| err(ROOT_BASE, e.to_string()))?;
        if !m.file_type().is_dir() {
            return Err(err(
                ROOT_BASE,
                "is not a directory (a symbolic link or a file); remove it".into(),
            ));
        }
        if m.mode() & 0o7777 != 0o1777 {
            if m.uid() == euid {
                std::fs::set_permissions(base, std::fs::Permissions::from_mode(0o1777))
                    .map_err(|e| err(ROOT_BASE, format!("cannot make it mode 1777: {e}")))?;
            } else if euid != 0 && m.mode() & 0o002 == 0 {
                return Err(err(
                    ROOT_BASE,
                    format!(
                        "mode {:04o}, owned by uid {}: users other than its owner cannot create \
                         domains in it; make it shared like /tmp: sudo chmod 1777 {ROOT_BASE}",
                        m.mode() & 0o7777,
                        m.uid()
                    ),
                ));
            }
        }
        let dir = root_path(&self.name);
        let dir = dir.trim_end_matches('/');
        match std::fs::symlink_metadata(dir) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(err(dir, e.to_string())),
            Ok(m) if !m.file_type().is_dir() => Err(err(
                dir,
                "is not a directory (a symbolic link or a file); refusing to use it".into(),
            )),
            Ok(m) if m.uid() != euid => Err(err(
                dir,
                format!(
                    "belongs to uid {0}, not to this process (uid {euid}): every process of a \
                     domain, root included, must run as the same user (`sudo -u '#{0}' ...`, see \
                     docs/permissions.md); if no process uses the domain any more, remove the \
                     directory",
                    m.uid()
                ),
            )),
            Ok(m) if m.mode() & 0o022 != 0 => Err(err(
                dir,
                format!(
                    "mode {:04o} lets other users change the domain's records; refusing to use it",
                    m.mode() & 0o7777
                ),
            )),
            Ok(_) => Ok(()),
        }
    }
}

/// This process's effective user id.
fn effective_uid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

fn prefix(name: &str) -> String {
    format!("cdr_{name}_")
}

fn root_path(name: &str) -> String {
    format!("{ROOT_BASE}/{name}/")
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

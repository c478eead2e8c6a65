//! Discovery: which states exist in a domain, with their metadata, read from iceoryx2's service
//! records (no daemon, no registry process).

use iceoryx2::node::NodeView;
use iceoryx2::prelude::{CallbackProgression, MessagingPattern, NodeState, Service as _};
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern as StaticPattern;

use core::time::Duration;

use crate::abi::{CommandFrame, StateSample, ABI_VERSION};
use crate::bus::Bus;
use crate::error::{BusError, Result};
use crate::metadata::{self, ServiceKind, StateMeta, KEY_ABI, KEY_KIND};
use crate::naming::{self, StateRef};
use crate::variant::RtIpc;

/// A state as discovery sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct StateInfo {
    /// Owning subsystem.
    pub subsystem: String,
    /// State name.
    pub name: String,
    /// Metadata from the service attributes.
    pub meta: StateMeta,
    /// Names of the live processes (iceoryx2 nodes) attached to the service; the owning
    /// executor's node is called `executor/<subsystem>`.
    pub nodes: Vec<String>,
}

impl StateInfo {
    /// `subsystem/state`.
    pub fn qualified_name(&self) -> String {
        format!("{}/{}", self.subsystem, self.name)
    }

    /// Its metadata as strings, one entry per attribute plus `subsystem` and `state`: what a
    /// recording's channel and a live view's channel carry.
    pub fn metadata_strings(&self) -> std::collections::BTreeMap<String, String> {
        self.meta.strings(&self.subsystem, &self.name)
    }

    /// The iceoryx2 service name.
    pub fn service_name(&self) -> String {
        naming::state(&self.subsystem, &self.name)
    }
}

impl Bus {
    /// Every Conductor state of the domain speaking this ABI, sorted by subsystem and index.
    pub fn list_states(&self) -> Result<Vec<StateInfo>> {
        let mut out = Vec::new();
        let abi = ABI_VERSION.to_string();
        RtIpc::list(self.domain().iceoryx2_config(), |details| {
            let stat = &details.static_details;
            if !matches!(stat.messaging_pattern(), StaticPattern::PublishSubscribe(_)) {
                return CallbackProgression::Continue;
            }
            let attrs = stat.attributes();
            if metadata::get(attrs, KEY_KIND).as_deref() != Some(ServiceKind::State.as_str())
                || metadata::get(attrs, KEY_ABI).as_deref() != Some(abi.as_str())
            {
                return CallbackProgression::Continue;
            }
            let Some((sub, name)) = naming::split(stat.name().as_str()) else {
                return CallbackProgression::Continue;
            };
            let Some(meta) = metadata::state_meta_from_attributes(attrs) else {
                return CallbackProgression::Continue;
            };
            let nodes = details
                .dynamic_details
                .as_ref()
                .map(|d| {
                    d.nodes
                        .iter()
                        .filter_map(|n| match n {
                            NodeState::Alive(v) => {
                                v.details().as_ref().map(|d| d.name().to_string())
                            }
                            _ => None,
                        })
                        .collect()
                })
                .unwrap_or_default();
            out.push(StateInfo {
                subsystem: sub.into(),
                name: name.into(),
                meta,
                nodes,
            });
            CallbackProgression::Continue
        })
        .map_err(|e| BusError::iceoryx("listing services", e))?;
        out.sort_by(|a, b| {
            (a.subsystem.as_str(), a.meta.index).cmp(&(b.subsystem.as_str(), b.meta.index))
        });
        Ok(out)
    }

    /// The command watchdog `subsystem`'s owner announces on its `commands` service
    /// (`conductor.watchdog_ms`): `Some(Some(period))`, `Some(None)` when it runs none, `None`
    /// when it does not say. An error when the subsystem has no `commands` service.
    pub fn command_watchdog(&self, subsystem: &str) -> Result<Option<Option<Duration>>> {
        naming::validate("subsystem", subsystem)?;
        let name = naming::commands(subsystem);
        let details =
            self.conductor_details::<CommandFrame>(subsystem, &name, ServiceKind::Commands)?;
        Ok(metadata::watchdog_from_attributes(
            details.static_details.attributes(),
        ))
    }

    /// Subsystems that publish at least one state.
    pub fn list_subsystems(&self) -> Result<Vec<String>> {
        let mut subs: Vec<String> = self
            .list_states()?
            .into_iter()
            .map(|s| s.subsystem)
            .collect();
        subs.dedup();
        Ok(subs)
    }

    /// Resolves `subsystem/state` (or a bare state name that is unique in the domain) to its
    /// [`StateInfo`], with a typed error naming what exists when it does not.
    pub fn resolve(&self, name: &str) -> Result<StateInfo> {
        let r = StateRef::parse(name)?;
        if let Some(sub) = &r.subsystem {
            // Direct lookup first: it also catches foreign services that squat the name.
            let service = naming::state(sub, &r.state);
            if let Some(details) = self.details(&service, MessagingPattern::PublishSubscribe)? {
                // SAFETY: type_name() has no preconditions; it is unsafe only for implementors.
                let tn = unsafe { <StateSample as iceoryx2::prelude::ZeroCopySend>::type_name() };
                self.check_conductor_service(&service, &details, ServiceKind::State, tn)?;
            }
        }
        let all = self.list_states()?;
        let hits: Vec<&StateInfo> = all
            .iter()
            .filter(|s| {
                s.name == r.state && r.subsystem.as_ref().is_none_or(|sub| *sub == s.subsystem)
            })
            .collect();
        match hits.as_slice() {
            [one] => Ok((*one).clone()),
            [] => Err(BusError::UnknownState {
                name: r.to_string(),
                domain: self.domain().name().into(),
                known: all.iter().take(12).map(StateInfo::qualified_name).collect(),
            }),
            many => Err(BusError::AmbiguousState {
                name: r.to_string(),
                domain: self.domain().name().into(),
                candidates: many.iter().map(|s| s.qualified_name()).collect(),
            }),
        }
    }
}

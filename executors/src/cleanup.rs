//! The iceoryx2 nodes of a domain: which are alive (and whose), and removing what dead ones left
//! behind (a crashed or killed process cannot remove its own shared memory and records).

use conductor_bus::{Domain, RtIpc};
use iceoryx2::node::{Node, NodeState, NodeView};
use iceoryx2::prelude::CallbackProgression;

/// A live node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LiveNode {
    /// Node name (`executor/<subsystem>` for executors).
    pub name: String,
    /// Owning process, when it can be read.
    pub pid: Option<u32>,
}

/// What a scan found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Scan {
    /// Nodes whose process is alive.
    pub alive: Vec<LiveNode>,
    /// Dead nodes whose resources were removed by this scan.
    pub removed: usize,
    /// Dead nodes whose resources could not be removed (permissions, another cleaner).
    pub failed: usize,
    /// Nodes this process may not inspect.
    pub inaccessible: usize,
}

/// Lists the domain's nodes, removing the stale resources of every dead one.
pub fn scan_and_clean(domain: &Domain) -> Result<Scan, String> {
    let mut scan = Scan::default();
    domain.prepare_dirs().map_err(|e| e.to_string())?;
    Node::<RtIpc>::list(domain.iceoryx2_config(), |state| {
        match state {
            NodeState::Alive(view) => {
                let name = view
                    .details()
                    .as_ref()
                    .map(|d| d.name().to_string())
                    .unwrap_or_default();
                let pid = view.id().pid::<RtIpc>().ok().map(|p| p.value() as u32);
                scan.alive.push(LiveNode { name, pid });
            }
            NodeState::Dead(view) => match view.try_remove_stale_resources() {
                Ok(()) => scan.removed += 1,
                Err(_) => scan.failed += 1,
            },
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => scan.inaccessible += 1,
        }
        CallbackProgression::Continue
    })
    .map_err(|e| format!("listing the nodes of domain {:?}: {e:?}", domain.name()))?;
    Ok(scan)
}

/// The name of the node an executor of `subsystem` runs as.
pub fn executor_node_name(subsystem: &str) -> String {
    format!("executor/{subsystem}")
}

/// The name of the node a gateway publishing `subsystem` runs as (`score-gateway --subsystem`
/// uses it, so a launcher can tell that the gateway already runs).
pub fn gateway_node_name(subsystem: &str) -> String {
    format!("gateway/{subsystem}")
}

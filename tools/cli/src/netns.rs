//! Two network namespaces joined by a veth pair, for running two bridges on one machine as if on
//! two hosts (`conductor bench --bridge`, and the CLI's bridge tests). Needs root; dropping a
//! [`VethPair`] deletes both namespaces, and with them the veth ends inside.

use std::process::Command;

/// Runs `ip ARGS…`; the error names the command and carries its stderr.
pub fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Namespaces `ns[0]`, `ns[1]` holding veth ends `veth[0]`, `veth[1]` with addresses
/// `addr[0]`, `addr[1]` (one /30), both up, and `lo` up in each.
#[derive(Debug)]
pub struct VethPair {
    /// The two namespaces.
    pub ns: [String; 2],
    /// The veth end in each namespace.
    pub veth: [String; 2],
    /// The address of each end.
    pub addr: [String; 2],
}

impl VethPair {
    /// Makes the pair. Names carry `tag` and this process's id (`cdr-<tag>a-<pid>`, veth
    /// `c<tag>a<pid mod 10^5>`), so concurrent users do not collide; addresses are in
    /// `10.<net>.x.0/30`. On an error, what was made is deleted again.
    pub fn make(tag: &str, net: u8) -> Result<Self, String> {
        let pid = std::process::id();
        let ns = [format!("cdr-{tag}a-{pid}"), format!("cdr-{tag}b-{pid}")];
        let veth = [
            format!("c{tag}a{}", pid % 100_000),
            format!("c{tag}b{}", pid % 100_000),
        ];
        let sub = 1 + pid % 250;
        let addr = [format!("10.{net}.{sub}.1"), format!("10.{net}.{sub}.2")];
        // Made before the namespaces, so that a failure below deletes them (Drop).
        let pair = VethPair { ns, veth, addr };
        let (ns, veth, addr) = (&pair.ns, &pair.veth, &pair.addr);
        ip(&["netns", "add", &ns[0]])?;
        ip(&["netns", "add", &ns[1]])?;
        ip(&[
            "link", "add", &veth[0], "type", "veth", "peer", "name", &veth[1],
        ])?;
        for i in 0..2 {
            ip(&["link", "set", &veth[i], "netns", &ns[i]])?;
            ip(&[
                "-n",
                &ns[i],
                "addr",
                "add",
                &format!("{}/30", addr[i]),
                "dev",
                &veth[i],
            ])?;
            ip(&["-n", &ns[i], "link", "set", &veth[i], "up"])?;
            ip(&["-n", &ns[i], "link", "set", "lo", "up"])?;
        }
        Ok(pair)
    }

    /// Sets the veth end in the first namespace down (`false`) or up (`true`): the link cut
    /// and restored.
    pub fn set_link(&self, up: bool) -> Result<(), String> {
        let state = if up { "up" } else { "down" };
        ip(&["-n", &self.ns[0], "link", "set", &self.veth[0], state])
    }
}

impl Drop for VethPair {
    fn drop(&mut self) {
        // Deleting a namespace deletes the veth end inside it, and so the pair.
        for n in &self.ns {
            let _ = ip(&["netns", "delete", n]);
        }
    }
}

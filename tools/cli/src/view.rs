//! `conductor view`: the live view of `conductor-view` on this command line.

use std::io::Write as _;

use conductor_bus::Bus;
use conductor_view::{View, ViewOptions, ViewReport};

use crate::cli::ViewArgs;
use crate::error::Result;

/// Serves until Ctrl-C/SIGTERM. Prints `ready view <url>` on stdout once listening (what the
/// launcher waits for when it supervises a manifest's `[view]`), then a summary on stderr.
pub fn run(bus: &Bus, a: &ViewArgs) -> Result<ViewReport> {
    let opts = ViewOptions {
        listen: a.listen,
        clamp: a.clamp,
        ..ViewOptions::default()
    };
    let view = View::start(bus, opts)?;
    let url = view.url();
    let r = view.report();
    println!("ready view {url}");
    let _ = std::io::stdout().flush();
    eprintln!(
        "conductor view: {url} ({} states of {} executor(s) in domain {:?} so far); open it in \
         Foxglove or Lichtblick (Open connection > Foxglove WebSocket){}",
        r.states,
        r.executors,
        bus.domain().name(),
        if a.listen.ip().is_loopback() {
            ""
        } else {
            "; NOT loopback: anyone who reaches this address can command the robot"
        }
    );
    let report = view.run(conductor_bus::shutdown::requested)?;
    eprintln!(
        "conductor view: stopped ({} states, {} messages relayed, {} setpoints sent, {} refused)",
        report.states, report.messages, report.setpoints_sent, report.setpoints_refused
    );
    Ok(report)
}

//! The gateway loop: connect, handshake, publish, forward commands, reconnect.
//!
//! ```text
//!  board ──score_link──► BoardClient ──Event::Samples──► ClockMap (board µs → host ns)
//!                                                   └► StatePublisher conductor/score-<board>/<var>
//!  Controller ──CommandFrame──► CommandReceiver ──► BoardClient::request(Set) ──► board
//! ```
//!
//! The states of a gateway only grow: a variable keeps its state (and index) for the gateway's
//! lifetime, whatever the board does; a variable that disappears just stops publishing. When a
//! board comes back with an empty table (power cycle, replug, emulator restart) the gateway
//! replays the board's last `save` script, so the same states resume.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bus::{
    monotonic_ns, status, Bus, CommandReceiver, StateMeta, StatePublisher, StateSpec,
};
use conductor_protocols::score_link::{Request, VERSION};

use crate::client::{Answer, BoardClient, BoardVar, Event};
use crate::clock::ClockMap;
use crate::error::GatewayError;

/// How the gateway runs.
#[derive(Debug, Clone)]
pub struct Options {
    /// The board's link device (its second CDC-ACM port).
    pub port: PathBuf,
    /// Subsystem name; default `score-<board name from the hello>`.
    pub subsystem: Option<String>,
    /// Highest publish rate asked of the board per variable.
    pub max_rate_hz: f64,
    /// Publish rate of bare expressions and constants (they have no rate of their own).
    pub lazy_rate_hz: f64,
    /// Replay the last configuration onto a board that comes back empty.
    pub restore: bool,
    /// Pause between reconnection attempts.
    pub retry: Duration,
    /// Interval of clock pings.
    pub ping: Duration,
    /// Command watchdog: once commands have come, none for this long sets every commanded
    /// variable to its safe value (0, clamped into its limits) and flags it `WATCHDOG`.
    pub watchdog: Option<Duration>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            port: PathBuf::new(),
            subsystem: None,
            max_rate_hz: 1000.0,
            lazy_rate_hz: 10.0,
            restore: true,
            retry: Duration::from_millis(200),
            ping: Duration::from_secs(1),
            watchdog: None,
        }
    }
}

struct VarState {
    name: String,
    meta: StateMeta,
    board_id: Option<u8>,
    status: u32,
    /// A controller has set it since the watchdog last fired.
    commanded: bool,
}

/// Counters for logs and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Successful handshakes.
    pub connects: u64,
    /// Samples published.
    pub published: u64,
    /// Setpoints forwarded and accepted by the board.
    pub commands: u64,
    /// Setpoints refused (read-only, not finite, unknown index, board refusal).
    pub rejected: u64,
    /// Configurations replayed onto an empty board.
    pub restores: u64,
    /// Times the command watchdog fired.
    pub watchdog_trips: u64,
}

/// One board on the bus.
pub struct Gateway {
    opts: Options,
    bus: Bus,
    subsystem: Option<String>,
    states: Vec<VarState>,
    by_id: HashMap<u8, usize>,
    publisher: Option<StatePublisher>,
    commands: Option<CommandReceiver>,
    clock: ClockMap,
    generation: Option<u32>,
    script: Vec<String>,
    /// A restore was started and has not finished (its link was lost): what the board holds
    /// is part of it, not the board's own configuration.
    restore_unfinished: bool,
    tick: u64,
    stop: Arc<AtomicBool>,
    announced: bool,
    /// When the newest setpoint forwarded was sent (its frame's `t_send_ns`, CLOCK_MONOTONIC).
    last_command: Option<u64>,
    /// When the watchdog last fired (ns): frames sent before it are not applied after it.
    tripped_ns: u64,
    /// Counters.
    pub stats: Stats,
}

impl Gateway {
    /// A gateway on `bus`; `stop` ends [`Gateway::run`].
    pub fn new(opts: Options, bus: Bus, stop: Arc<AtomicBool>) -> Self {
        Self {
            subsystem: opts.subsystem.clone(),
            opts,
            bus,
            states: Vec::new(),
            by_id: HashMap::new(),
            publisher: None,
            commands: None,
            clock: ClockMap::new(),
            generation: None,
            script: Vec::new(),
            restore_unfinished: false,
            tick: 0,
            stop,
            announced: false,
            last_command: None,
            tripped_ns: 0,
            stats: Stats::default(),
        }
    }

    /// Runs until `stop` is set: connects, serves, and reconnects whenever the link is lost.
    pub fn run(&mut self) -> Result<(), GatewayError> {
        let mut last_error = String::new();
        while !self.stop.load(Ordering::Relaxed) {
            let r = BoardClient::open(&self.opts.port).and_then(|mut link| self.serve(&mut link));
            match r {
                Ok(()) => return Ok(()),
                Err(e) if e.is_link_loss() || matches!(e, GatewayError::Board { .. }) => {
                    let msg = e.to_string();
                    if msg != last_error {
                        eprintln!("score-gateway: {msg}; retrying every {:?}", self.opts.retry);
                        last_error = msg;
                    }
                }
                Err(e) => return Err(e),
            }
            for s in &mut self.states {
                s.board_id = None;
            }
            self.by_id.clear();
            self.generation = None;
            std::thread::sleep(self.opts.retry);
        }
        Ok(())
    }

    fn serve(&mut self, link: &mut BoardClient) -> Result<(), GatewayError> {
        self.handshake(link)?;
        let mut last_ping = Instant::now();
        while !self.stop.load(Ordering::Relaxed) {
            link.poll()?;
            self.handle_events(link)?;
            self.forward_commands(link)?;
            self.watchdog(link)?;
            if last_ping.elapsed() >= self.opts.ping {
                self.ping(link)?;
                last_ping = Instant::now();
            }
        }
        Ok(())
    }

    /// Publishes the samples and acts on the table changes the link has queued.
    fn handle_events(&mut self, link: &mut BoardClient) -> Result<(), GatewayError> {
        while let Some(ev) = link.next_event() {
            match ev {
                Event::Samples { t_us, values, .. } => self.publish(t_us, &values)?,
                Event::TableChanged(g) if Some(g) != self.generation => self.sync(link)?,
                Event::TableChanged(_) => {}
            }
        }
        Ok(())
    }

    fn handshake(&mut self, link: &mut BoardClient) -> Result<(), GatewayError> {
        let (board, firmware, number_type) = match link.request(Request::Hello)? {
            Answer::Hello {
                board,
                firmware,
                number_type,
                ..
            } => (board, firmware, number_type),
            other => {
                return Err(GatewayError::Unexpected {
                    request: "hello",
                    answer: Box::new(other),
                })
            }
        };
        let subsystem = self
            .subsystem
            .get_or_insert_with(|| format!("score-{board}"))
            .clone();
        eprintln!(
            "score-gateway: {} on {}: {firmware}, numbers {number_type}, protocol {VERSION} -> {subsystem}",
            board,
            self.opts.port.display()
        );
        self.clock.reset();
        for _ in 0..4 {
            self.ping(link)?;
        }
        link.request(Request::UnsubscribeAll)?;
        self.sync(link)?;
        self.stats.connects += 1;
        if !self.announced {
            // For a launcher: the states exist from here on.
            println!("ready {subsystem} {} states", self.states.len());
            self.announced = true;
        }
        Ok(())
    }

    fn ping(&mut self, link: &mut BoardClient) -> Result<(), GatewayError> {
        let h0 = monotonic_ns();
        if let Answer::Time(b) = link.request(Request::Time)? {
            self.clock.add(h0, b, monotonic_ns());
        }
        Ok(())
    }

    fn list(link: &mut BoardClient) -> Result<(Vec<BoardVar>, u32), GatewayError> {
        match link.request(Request::ListVars)? {
            Answer::Vars(v, g) => Ok((v, g)),
            other => Err(GatewayError::Unexpected {
                request: "list",
                answer: Box::new(other),
            }),
        }
    }

    fn exec(link: &mut BoardClient, line: &str) -> Result<(String, bool), GatewayError> {
        match link.request(Request::Exec { line })? {
            Answer::Exec(text, ok, _) => Ok((text, ok)),
            other => Err(GatewayError::Unexpected {
                request: "exec",
                answer: Box::new(other),
            }),
        }
    }

    /// Lists the board's table, restores it if the board came back empty, records its script,
    /// extends the states, and subscribes every variable.
    fn sync(&mut self, link: &mut BoardClient) -> Result<(), GatewayError> {
        let (mut vars, mut generation) = Self::list(link)?;
        if self.restore_unfinished && !vars.is_empty() {
            // The last restore lost its link half-way (an `Exec` is not repeated): the board
            // holds part of the configuration. Clear it (a variable others depend on goes in
            // a later pass) and restore from the start.
            eprintln!(
                "score-gateway: the last restore was interrupted; clearing its {} variables to restore again",
                vars.len()
            );
            for _ in 0..4 {
                for v in &vars {
                    Self::exec(link, &format!("del {}", v.name))?;
                }
                (vars, generation) = Self::list(link)?;
                if vars.is_empty() {
                    break;
                }
            }
        }
        if vars.is_empty() && self.opts.restore && !self.script.is_empty() {
            self.restore_unfinished = true;
            eprintln!(
                "score-gateway: the board's table is empty; restoring its last configuration ({} lines)",
                self.script.len()
            );
            for line in self.script.clone() {
                let (text, ok) = Self::exec(link, &line)?;
                if !ok {
                    eprintln!(
                        "score-gateway: restore stopped at {line:?}: {}",
                        text.trim()
                    );
                    break;
                }
            }
            self.stats.restores += 1;
            self.restore_unfinished = false;
            (vars, generation) = Self::list(link)?;
        }
        if !vars.is_empty() {
            let mut vote = ScriptVote::default();
            for _ in 0..4 {
                let (text, ok) = Self::exec(link, "save")?;
                if !ok {
                    break;
                }
                if let Some(script) = vote.offer(&text) {
                    self.script = script;
                    break;
                }
            }
        }
        self.update_states(&vars)?;
        for v in &vars {
            let Some(&i) = self.by_id.get(&v.id) else {
                continue;
            };
            let period = (1e6 / self.states[i].meta.rate_hz).round().max(100.0) as u32;
            match link.request(Request::Subscribe {
                id: v.id,
                period_us: period,
                generation,
            }) {
                Ok(_) => {}
                // The table changed under us: its TableChanged event will resync.
                Err(GatewayError::Board { stale: true, .. }) => break,
                Err(e) => return Err(e),
            }
        }
        self.generation = Some(generation);
        Ok(())
    }

    fn meta_for(&self, v: &BoardVar, index: u32) -> StateMeta {
        let rate = v
            .rate_hz
            .map_or(self.opts.lazy_rate_hz, |r| r.min(self.opts.max_rate_hz));
        let (min, max) = if v.writable && v.unit == "%" {
            (0.0, 100.0)
        } else {
            (f64::NEG_INFINITY, f64::INFINITY)
        };
        StateMeta {
            index,
            units: v.unit.clone(),
            writable: v.writable,
            rate_hz: rate,
            min,
            max,
            device: self.subsystem.clone().unwrap_or_default(),
        }
    }

    fn update_states(&mut self, vars: &[BoardVar]) -> Result<(), GatewayError> {
        for s in &mut self.states {
            s.board_id = None;
        }
        self.by_id.clear();
        let mut grew = false;
        for v in vars {
            if conductor_bus::naming::validate("state", &v.name).is_err() {
                eprintln!(
                    "score-gateway: variable {:?} cannot be a state name; not published",
                    v.name
                );
                continue;
            }
            let i = match self.states.iter().position(|s| s.name == v.name) {
                Some(i) => {
                    let fresh = self.meta_for(v, i as u32);
                    let s = &self.states[i];
                    if (fresh.units != s.meta.units
                        || fresh.writable != s.meta.writable
                        || fresh.rate_hz != s.meta.rate_hz)
                        && self.publisher.is_some()
                    {
                        eprintln!(
                            "score-gateway: {} changed (units {:?}, rate {} Hz, writable {}); its state keeps the first metadata",
                            v.name, fresh.units, fresh.rate_hz, fresh.writable
                        );
                    }
                    i
                }
                None => {
                    let meta = self.meta_for(v, self.states.len() as u32);
                    self.states.push(VarState {
                        name: v.name.clone(),
                        meta,
                        board_id: None,
                        status: 0,
                        commanded: false,
                    });
                    grew = true;
                    self.states.len() - 1
                }
            };
            self.states[i].board_id = Some(v.id);
            self.by_id.insert(v.id, i);
        }
        let subsystem = self.subsystem.clone().unwrap_or_else(|| "score".into());
        if grew || self.publisher.is_none() {
            let specs: Vec<StateSpec> = self
                .states
                .iter()
                .map(|s| StateSpec::new(s.name.clone(), s.meta.clone()))
                .collect();
            // The new publisher reopens the existing services (same attributes) before the old
            // one is dropped, so subscribers never see a state vanish.
            let p = StatePublisher::create(&self.bus, &subsystem, &specs)?;
            self.publisher = Some(p);
        }
        if self.commands.is_none() {
            self.commands = Some(CommandReceiver::with_watchdog(
                &self.bus,
                &subsystem,
                self.opts.watchdog,
            )?);
        }
        Ok(())
    }

    fn publish(&mut self, t_us: u64, values: &[(u8, f64)]) -> Result<(), GatewayError> {
        let Some(p) = self.publisher.as_mut() else {
            return Ok(());
        };
        // Never stamp a sample in the future (the fit extrapolates between pings).
        let t_ns = self.clock.to_host_ns(t_us).min(monotonic_ns());
        let mut any = false;
        for &(id, v) in values {
            if let Some(&i) = self.by_id.get(&id) {
                p.publish(i, self.tick, t_ns, v, self.states[i].status)?;
                self.stats.published += 1;
                any = true;
            }
        }
        if any {
            p.notify_tick()?;
            self.tick += 1;
        }
        Ok(())
    }

    fn forward_commands(&mut self, link: &mut BoardClient) -> Result<(), GatewayError> {
        let Some(rx) = self.commands.as_mut() else {
            return Ok(());
        };
        // The watchdog goes by when a frame was sent, not when this loop got to it: a gateway
        // that was behind (or starved of CPU) must not apply a dead controller's queued frames
        // after the watchdog made the board safe. A frame without a send time counts as sent
        // now.
        let now = monotonic_ns();
        let tripped = self.tripped_ns;
        let mut stale = 0u64;
        let mut pending: Vec<(u32, f64, u64)> = Vec::new();
        rx.drain(|frame| {
            let sent = match frame.t_send_ns {
                0 => now,
                t => t.min(now),
            };
            if tripped > 0 && sent <= tripped {
                stale += frame.setpoints().len() as u64;
                return;
            }
            pending.extend(frame.setpoints().iter().map(|s| (s.index, s.value, sent)));
        })?;
        self.stats.rejected += stale;
        for (index, value, sent) in pending {
            let Some(s) = self.states.get_mut(index as usize) else {
                self.stats.rejected += 1;
                continue;
            };
            if !s.meta.writable || !value.is_finite() {
                s.status |= status::REJECTED;
                self.stats.rejected += 1;
                continue;
            }
            let (v, clamped) = s.meta.clamp(value);
            let Some(id) = s.board_id else {
                s.status |= status::REJECTED;
                self.stats.rejected += 1;
                continue;
            };
            self.last_command = Some(self.last_command.map_or(sent, |l| l.max(sent)));
            if self.set(link, index as usize, id, v)? {
                let s = &mut self.states[index as usize];
                s.status &= !(status::REJECTED | status::CLAMPED | status::WATCHDOG);
                if clamped {
                    s.status |= status::CLAMPED;
                }
                s.commanded = true;
                self.stats.commands += 1;
            } else {
                self.states[index as usize].status |= status::REJECTED;
                self.stats.rejected += 1;
            }
        }
        Ok(())
    }

    /// Sets variable `index` (board id `id`) to `value` on the board; `false` when the board
    /// refuses (it says why on stderr; a stale table is re-read).
    fn set(
        &mut self,
        link: &mut BoardClient,
        index: usize,
        id: u8,
        value: f64,
    ) -> Result<bool, GatewayError> {
        let generation = self.generation.unwrap_or(0);
        match link.request(Request::Set {
            id,
            value,
            generation,
        }) {
            Ok(_) => {
                // Samples queued while waiting for the answer were taken before the board
                // applied the value: publish them under the flags they were taken with, before
                // the caller flags the state (WATCHDOG, CLAMPED) for the new value.
                self.handle_events(link)?;
                Ok(true)
            }
            Err(GatewayError::Board { stale, message }) => {
                eprintln!(
                    "score-gateway: set {} = {value}: {message}",
                    self.states[index].name
                );
                if stale {
                    self.sync(link)?;
                }
                Ok(false)
            }
            Err(e) => Err(e),
        }
    }

    /// The command watchdog: no setpoint for `opts.watchdog` after some came → every commanded
    /// variable goes to its safe value, once, until a controller commands again.
    fn watchdog(&mut self, link: &mut BoardClient) -> Result<(), GatewayError> {
        let (Some(limit), Some(last)) = (self.opts.watchdog, self.last_command) else {
            return Ok(());
        };
        let now = monotonic_ns();
        if now.saturating_sub(last) < limit.as_nanos() as u64 {
            return Ok(());
        }
        self.tripped_ns = now;
        self.stats.watchdog_trips += 1;
        let mut names = Vec::new();
        for i in 0..self.states.len() {
            let s = &self.states[i];
            let (true, Some(id)) = (s.commanded, s.board_id) else {
                continue;
            };
            let (safe, _) = s.meta.clamp(0.0);
            // A link lost here leaves the watchdog armed: it fires again on the next
            // connection, so the board does not keep the dead controller's value.
            let ok = self.set(link, i, id, safe)?;
            let s = &mut self.states[i];
            s.commanded = false;
            s.status |= status::WATCHDOG;
            if ok {
                names.push(format!("{} = {safe}", s.name));
            }
        }
        self.last_command = None;
        eprintln!(
            "score-gateway: no command for {} ms: {}",
            limit.as_millis(),
            if names.is_empty() {
                "nothing to make safe".to_string()
            } else {
                names.join(", ")
            }
        );
        Ok(())
    }
}

/// The board's script from successive answers to `save`. The script comes back in several
/// `Output` frames and nothing says how many: one lost on the link would leave a script missing
/// lines, which a restore would then replay. So a script is kept only when two answers in a row
/// agree, and never an empty one (asked only while the board has variables: two answers whose
/// every frame was lost agree too, and an empty script would leave the next empty board
/// unrestored for good).
#[derive(Default)]
struct ScriptVote(Option<Vec<String>>);

impl ScriptVote {
    /// One more answer: the script, once two in a row agree.
    fn offer(&mut self, text: &str) -> Option<Vec<String>> {
        let script: Vec<String> = text
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .map(String::from)
            .collect();
        if !script.is_empty() && self.0.as_ref() == Some(&script) {
            return Some(script);
        }
        self.0 = Some(script);
        None
    }
}

#[cfg(test)]
mod tests {
    use super::ScriptVote;

    #[test]
    fn a_script_is_kept_when_two_answers_agree_without_comments_or_blanks() {
        let mut vote = ScriptVote::default();
        assert_eq!(vote.offer("# saved\nx = adc0\n"), None);
        assert_eq!(
            vote.offer("# saved\n\nx = adc0\n"),
            Some(vec!["x = adc0".to_string()])
        );
    }

    #[test]
    fn an_answer_that_lost_a_frame_is_outvoted() {
        let mut vote = ScriptVote::default();
        assert_eq!(vote.offer("x = adc0\n"), None);
        assert_eq!(vote.offer("x = adc0\ny = x * 2\n"), None);
        assert_eq!(
            vote.offer("x = adc0\ny = x * 2\n"),
            Some(vec!["x = adc0".to_string(), "y = x * 2".to_string()])
        );
    }

    /// Two answers whose every frame was lost agree too: keeping that would leave the next
    /// empty board unrestored for good (the board of the hour's campaign, 44 minutes in).
    #[test]
    fn two_empty_answers_are_never_a_script() {
        let mut vote = ScriptVote::default();
        for _ in 0..4 {
            assert_eq!(vote.offer(""), None);
        }
        assert_eq!(vote.offer("# only a comment\n"), None);
    }
}

//! [`View`]: the loop that joins a domain, discovers its states, relays their samples and the
//! executors' stats to the WebSocket server's channels, and turns client requests into setpoints.

use std::collections::{BTreeSet, HashMap};
use std::net::SocketAddr;
use std::sync::mpsc::{self, Receiver};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_bus::setpoint::{self, NotSent, VerdictWatch};
use conductor_bus::{
    monotonic_ns, status, Bus, Controller, StateInfo, StateSample, StateSubscriber, StatsSubscriber,
};
use foxglove::websocket::{AnyClient, Capability, Client, Parameter, Status};
use foxglove::{
    Context, PartialMetadata, RawChannel, Schema, WebSocketServer, WebSocketServerHandle,
};

use crate::messages::{
    sample_schema, state_metadata, state_topic, stats_json, stats_schema, stats_topic, LiveSample,
    MESSAGE_ENCODING, SAMPLE_SCHEMA_NAME, SCHEMA_ENCODING, STATS_SCHEMA_NAME,
};
use crate::requests::{Forward, Request};
use crate::{ViewError, ViewOptions};

/// Samples a state's subscriber may queue between two polls.
const QUEUE: usize = 256;
/// Pause between two polls of the bus when nothing came.
const POLL: Duration = Duration::from_millis(2);
/// How often subscribed parameters are refreshed.
const PARAMETER_PERIOD: Duration = Duration::from_millis(250);
/// Verdicts a state may wait for at once (a client publishing faster than the state's rate
/// gets its oldest ones reported as not checked).
const MAX_PENDING: usize = 64;

/// Totals of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ViewReport {
    /// States discovered.
    pub states: usize,
    /// Executors whose stats are relayed.
    pub executors: usize,
    /// Messages handed to the server (samples and stats of subscribed channels).
    pub messages: u64,
    /// Setpoints sent to executors.
    pub setpoints_sent: u64,
    /// Setpoints refused: by the view's checks (not sent) or by the executor (`REJECTED`).
    pub setpoints_refused: u64,
}

struct Tracked {
    info: StateInfo,
    name: String,
    sub: StateSubscriber,
    channel: Arc<RawChannel>,
    latest: Option<StateSample>,
    /// Value last sent to parameter subscribers.
    published: Option<f64>,
    pending: Vec<Pending>,
}

struct Stats {
    sub: StatsSubscriber,
    channel: Arc<RawChannel>,
    last_seq: Option<u64>,
}

/// Who waits for a verdict.
enum Origin {
    /// Slot `slot` of parameter request `request`.
    Parameter { request: u64, slot: usize },
    /// A message a client published.
    Publish(Client),
}

struct Pending {
    watch: VerdictWatch,
    deadline: Instant,
    sent: f64,
    clamped_from: Option<f64>,
    origin: Origin,
}

/// A `setParameters` request waiting for its verdicts.
struct SetRequest {
    responder: Option<foxglove::websocket::SetParametersResponder>,
    results: Vec<Option<Parameter>>,
}

/// A running view: the server is listening; [`View::run`] (or [`View::poll`]) relays.
pub struct View {
    bus: Bus,
    opts: ViewOptions,
    ctx: Arc<Context>,
    server: Option<WebSocketServerHandle>,
    addr: SocketAddr,
    requests: Receiver<Request>,
    ctl: Controller,
    states: Vec<Tracked>,
    by_name: HashMap<String, usize>,
    by_topic: HashMap<String, usize>,
    stats: HashMap<String, Stats>,
    sets: HashMap<u64, SetRequest>,
    next_set: u64,
    subscribed: BTreeSet<String>,
    next_discovery: Instant,
    next_parameters: Instant,
    buf: Vec<u8>,
    report: ViewReport,
}

impl core::fmt::Debug for View {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("View")
            .field("addr", &self.addr)
            .field("states", &self.states.len())
            .finish()
    }
}

impl View {
    /// Opens the server on `opts.listen` and discovers the domain's states once.
    pub fn start(bus: &Bus, opts: ViewOptions) -> Result<Self, ViewError> {
        let (tx, rx) = mpsc::channel();
        let forward = Arc::new(Forward::new(tx));
        let ctx = Context::new();
        let server = WebSocketServer::new()
            .context(&ctx)
            .name(opts.name.clone())
            .bind(opts.listen.ip().to_string(), opts.listen.port())
            .capabilities([Capability::ClientPublish, Capability::Parameters])
            .supported_encodings([MESSAGE_ENCODING])
            .listener(forward.clone())
            .parameter_handler(forward)
            .start_blocking()
            .map_err(|e| ViewError::Listen {
                addr: opts.listen,
                reason: e.to_string(),
            })?;
        let addr = SocketAddr::new(opts.listen.ip(), server.port());
        let now = Instant::now();
        let mut view = Self {
            bus: bus.clone(),
            opts,
            ctx,
            server: Some(server),
            addr,
            requests: rx,
            ctl: Controller::new(bus),
            states: Vec::new(),
            by_name: HashMap::new(),
            by_topic: HashMap::new(),
            stats: HashMap::new(),
            sets: HashMap::new(),
            next_set: 0,
            subscribed: BTreeSet::new(),
            next_discovery: now,
            next_parameters: now,
            buf: Vec::with_capacity(512),
            report: ViewReport::default(),
        };
        view.discover()?;
        Ok(view)
    }

    /// Where the server listens (the port the OS chose when `listen` asked for port 0).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `ws://<addr>`: what to open in Foxglove or Lichtblick.
    pub fn url(&self) -> String {
        format!("ws://{}", self.addr)
    }

    /// Totals so far.
    pub fn report(&self) -> ViewReport {
        ViewReport {
            states: self.states.len(),
            executors: self.stats.len(),
            ..self.report
        }
    }

    /// Relays until `stop()` says so, then closes the server.
    pub fn run(mut self, stop: impl Fn() -> bool) -> Result<ViewReport, ViewError> {
        while !stop() {
            if !self.poll()? {
                std::thread::sleep(POLL);
            }
        }
        let report = self.report();
        if let Some(s) = self.server.take() {
            drop(s.stop());
        }
        Ok(report)
    }

    /// One pass: discovery when due, every queued sample and stats message, client requests,
    /// verdicts. Returns whether anything came.
    pub fn poll(&mut self) -> Result<bool, ViewError> {
        let now = Instant::now();
        if now >= self.next_discovery {
            self.discover()?;
            self.next_discovery = now + self.opts.discover_every;
        }
        let mut busy = false;
        for i in 0..self.states.len() {
            busy |= self.relay_state(i)?;
        }
        self.relay_stats()?;
        while let Ok(r) = self.requests.try_recv() {
            busy = true;
            self.handle(r)?;
        }
        self.expire_verdicts(now);
        if now >= self.next_parameters {
            self.publish_parameters();
            self.next_parameters = now + PARAMETER_PERIOD;
        }
        Ok(busy)
    }

    /// Subscribes to states (and executors' stats) that appeared since the last look.
    fn discover(&mut self) -> Result<(), ViewError> {
        for info in self.bus.list_states()? {
            let name = info.qualified_name();
            if self.by_name.contains_key(&name) {
                continue;
            }
            // A state that vanished between the listing and now is found again next time.
            let Ok(sub) = StateSubscriber::with_buffer(&self.bus, &name, QUEUE) else {
                continue;
            };
            let topic = state_topic(&info.subsystem, &info.name);
            let channel = self
                .ctx
                .channel_builder(topic.clone())
                .message_encoding(MESSAGE_ENCODING)
                .schema(Schema::new(
                    SAMPLE_SCHEMA_NAME,
                    SCHEMA_ENCODING,
                    sample_schema().into_bytes(),
                ))
                .metadata(state_metadata(&info))
                .build_raw()
                .map_err(|e| ViewError::Channel {
                    topic: topic.clone(),
                    reason: e.to_string(),
                })?;
            let i = self.states.len();
            self.by_name.insert(name.clone(), i);
            self.by_topic.insert(topic, i);
            self.states.push(Tracked {
                info,
                name,
                sub,
                channel,
                latest: None,
                published: None,
                pending: Vec::new(),
            });
        }
        let subsystems: BTreeSet<String> = self
            .states
            .iter()
            .map(|t| t.info.subsystem.clone())
            .collect();
        for s in subsystems {
            if self.stats.contains_key(&s) {
                continue;
            }
            // No stats service (a gateway, a replay): nothing to relay, look again later.
            let Ok(sub) = StatsSubscriber::new(&self.bus, &s) else {
                continue;
            };
            let topic = stats_topic(&s);
            let channel = self
                .ctx
                .channel_builder(topic.clone())
                .message_encoding(MESSAGE_ENCODING)
                .schema(Schema::new(
                    STATS_SCHEMA_NAME,
                    SCHEMA_ENCODING,
                    stats_schema().into_bytes(),
                ))
                .build_raw()
                .map_err(|e| ViewError::Channel {
                    topic: topic.clone(),
                    reason: e.to_string(),
                })?;
            self.stats.insert(
                s,
                Stats {
                    sub,
                    channel,
                    last_seq: None,
                },
            );
        }
        Ok(())
    }

    /// Drains state `i`'s queue: each sample to the channel (when a client listens) and to the
    /// verdicts waiting on it.
    fn relay_state(&mut self, i: usize) -> Result<bool, ViewError> {
        let mut any = false;
        loop {
            let t = &mut self.states[i];
            let Some(s) = t.sub.receive()? else { break };
            any = true;
            t.latest = Some(s);
            if t.channel.has_sinks() {
                self.buf.clear();
                serde_json::to_writer(&mut self.buf, &LiveSample::of(&s, &t.info.meta.units))
                    .map_err(|e| ViewError::Encode(e.to_string()))?;
                t.channel.log_with_meta(
                    &self.buf,
                    PartialMetadata {
                        log_time: Some(s.t_sample_ns),
                    },
                );
                self.report.messages += 1;
            }
            if !self.states[i].pending.is_empty() {
                self.judge(i, &s);
            }
        }
        Ok(any)
    }

    fn relay_stats(&mut self) -> Result<(), ViewError> {
        for st in self.stats.values_mut() {
            let Some(s) = st.sub.latest()? else { continue };
            if st.last_seq == Some(s.seq) {
                continue;
            }
            st.last_seq = Some(s.seq);
            if st.channel.has_sinks() {
                let body = serde_json::to_vec(&stats_json(&s))
                    .map_err(|e| ViewError::Encode(e.to_string()))?;
                st.channel.log_with_meta(
                    &body,
                    PartialMetadata {
                        log_time: Some(s.t_ns),
                    },
                );
                self.report.messages += 1;
            }
        }
        Ok(())
    }

    fn handle(&mut self, r: Request) -> Result<(), ViewError> {
        match r {
            Request::GetParameters { names, responder } => {
                let params = self.parameters(&names);
                responder.respond(params);
            }
            Request::SetParameters {
                client,
                parameters,
                responder,
            } => self.set_parameters(client, parameters, responder),
            Request::SubscribeParameters(names) => {
                // New subscribers get the current values at the next refresh.
                for n in &names {
                    if let Some(&i) = self.by_name.get(n) {
                        self.states[i].published = None;
                    }
                }
                self.subscribed.extend(names);
            }
            Request::UnsubscribeParameters(names) => {
                for n in names {
                    self.subscribed.remove(&n);
                }
            }
            Request::Advertise { client, topic } => {
                if let Err(why) = self.settable(&topic) {
                    client.send_status(Status::warning(format!(
                        "conductor view: nothing published on {topic} will be sent: {why}"
                    )));
                }
            }
            Request::Publish {
                client,
                topic,
                value,
            } => {
                let outcome = value.and_then(|v| {
                    let i = self.settable(&topic)?;
                    self.command(i, v).map(|p| (i, p, v))
                });
                match outcome {
                    Ok((i, (watch, sent, clamped_from), _)) => self.wait_verdict(
                        i,
                        Pending {
                            watch,
                            deadline: Instant::now() + self.opts.verdict_timeout,
                            sent,
                            clamped_from,
                            origin: Origin::Publish(client),
                        },
                    ),
                    Err(why) => {
                        self.report.setpoints_refused += 1;
                        client
                            .send_status(Status::error(format!("conductor view: {topic}: {why}")));
                    }
                }
            }
        }
        Ok(())
    }

    /// The writable state published on `topic`.
    fn settable(&self, topic: &str) -> Result<usize, String> {
        let Some(&i) = self.by_topic.get(topic) else {
            let some: Vec<&str> = self
                .states
                .iter()
                .filter(|t| t.info.meta.writable)
                .take(3)
                .map(|t| t.name.as_str())
                .collect();
            return Err(format!(
                "no state of domain {:?} has this topic; settable states take \
                 {{\"value\": <number>}} on /<subsystem>/<state> (e.g. {})",
                self.bus.domain().name(),
                if some.is_empty() {
                    "none is settable".to_string()
                } else {
                    some.iter()
                        .map(|n| format!("/{n}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ));
        };
        if !self.states[i].info.meta.writable {
            return Err(format!("{} is read-only", self.states[i].name));
        }
        Ok(i)
    }

    /// The same checks as `conductor set` ([`setpoint::check`]), then one command frame.
    /// Returns the verdict watch, the value sent and the value asked for when it was clamped.
    fn command(
        &mut self,
        i: usize,
        value: f64,
    ) -> Result<(VerdictWatch, f64, Option<f64>), String> {
        let t = &self.states[i];
        let name = t.name.clone();
        let m = &t.info.meta;
        let (send, clamped) = match setpoint::check(m, value, self.opts.clamp) {
            Ok(v) => v,
            Err(NotSent::NotFinite) => {
                return Err(format!("{value} is not a finite number: refused"))
            }
            Err(NotSent::ReadOnly) => return Err(format!("{name} is read-only")),
            Err(NotSent::OutOfLimits { min, max, nearest }) => {
                return Err(format!(
                    "{value} is outside the limits [{min}, {max}] of {name}: refused, nothing \
                     sent (a view started with --clamp sends the nearest limit, {nearest})"
                ))
            }
        };
        self.ctl
            .add_ctrl(&name, send)
            .map_err(|e| format!("{name} <- {send}: {e}"))?;
        let t_send = monotonic_ns();
        self.ctl
            .send_ctrl()
            .map_err(|e| format!("{name} <- {send}: {e}"))?;
        self.report.setpoints_sent += 1;
        Ok((VerdictWatch::new(t_send), send, clamped.then_some(value)))
    }

    fn wait_verdict(&mut self, i: usize, p: Pending) {
        let pending = &mut self.states[i].pending;
        if pending.len() >= MAX_PENDING {
            let old = pending.remove(0);
            let latest = self.states[i].latest;
            self.resolve(i, old, latest.as_ref(), true);
        }
        self.states[i].pending.push(p);
    }

    fn set_parameters(
        &mut self,
        client: AnyClient,
        parameters: Vec<Parameter>,
        responder: foxglove::websocket::SetParametersResponder,
    ) {
        let id = self.next_set;
        self.next_set += 1;
        let mut results = vec![None; parameters.len()];
        let mut waits = Vec::new();
        for (slot, p) in parameters.into_iter().enumerate() {
            let outcome = (|| {
                let &i = self.by_name.get(&p.name).ok_or_else(|| {
                    format!(
                        "no state {:?} in domain {:?}",
                        p.name,
                        self.bus.domain().name()
                    )
                })?;
                let v = match &p.value {
                    Some(foxglove::websocket::ParameterValue::Float64(v)) => *v,
                    Some(foxglove::websocket::ParameterValue::Integer(v)) => *v as f64,
                    other => {
                        return Err(format!(
                            "{} takes a number, not {other:?}",
                            self.states[i].name
                        ))
                    }
                };
                if !self.states[i].info.meta.writable {
                    return Err(format!("{} is read-only", self.states[i].name));
                }
                self.command(i, v).map(|c| (i, c))
            })();
            match outcome {
                Ok((i, (watch, sent, clamped_from))) => waits.push((
                    i,
                    Pending {
                        watch,
                        deadline: Instant::now() + self.opts.verdict_timeout,
                        sent,
                        clamped_from,
                        origin: Origin::Parameter { request: id, slot },
                    },
                )),
                Err(why) => {
                    self.report.setpoints_refused += 1;
                    client.send_error(format!("conductor view: {}: {why}", p.name));
                    // Answer with what the state holds, so the client's field reverts.
                    results[slot] = Some(self.parameter_of(&p.name));
                }
            }
        }
        self.sets.insert(
            id,
            SetRequest {
                responder: Some(responder),
                results,
            },
        );
        for (i, p) in waits {
            self.wait_verdict(i, p);
        }
        self.finish_set(id);
    }

    /// The current value of state `name` as a parameter (no value while none is known).
    fn parameter_of(&self, name: &str) -> Parameter {
        let v = self
            .by_name
            .get(name)
            .and_then(|&i| self.states[i].latest)
            .map(|s| s.value)
            .filter(|v| v.is_finite());
        match v {
            Some(v) => Parameter::float64(name, v),
            None => Parameter::empty(name),
        }
    }

    /// The settable states as parameters (all of them when `names` is empty).
    fn parameters(&self, names: &[String]) -> Vec<Parameter> {
        self.states
            .iter()
            .filter(|t| t.info.meta.writable)
            .filter(|t| names.is_empty() || names.contains(&t.name))
            .map(|t| self.parameter_of(&t.name))
            .collect()
    }

    /// Responds to set request `id` once every slot has its answer.
    fn finish_set(&mut self, id: u64) {
        let done = self
            .sets
            .get(&id)
            .is_some_and(|r| r.results.iter().all(Option::is_some));
        if done {
            if let Some(mut r) = self.sets.remove(&id) {
                let params = r.results.drain(..).flatten().collect();
                if let Some(responder) = r.responder.take() {
                    responder.respond(params);
                }
            }
        }
    }

    /// Offers sample `s` of state `i` to the verdicts waiting on it.
    fn judge(&mut self, i: usize, s: &StateSample) {
        let mut k = 0;
        while k < self.states[i].pending.len() {
            if self.states[i].pending[k].watch.offer(s) {
                let p = self.states[i].pending.remove(k);
                self.resolve(i, p, Some(s), false);
            } else {
                k += 1;
            }
        }
    }

    /// Reports a verdict: the executor's (from `s`, the verdict sample) or none (`timed_out`).
    /// A parameter set is answered with the value sent, or with the state's value when refused.
    fn resolve(&mut self, i: usize, p: Pending, s: Option<&StateSample>, timed_out: bool) {
        let name = self.states[i].name.clone();
        let note = if timed_out {
            Some((
                false,
                format!(
                    "{name} <- {}: sent, but no sample of it came within {:?}: not checked \
                     whether the executor took it",
                    p.sent, self.opts.verdict_timeout
                ),
            ))
        } else if let Some(s) = s.filter(|s| setpoint::refused(s)) {
            self.report.setpoints_refused += 1;
            let states: Vec<StateInfo> = self.states.iter().map(|t| t.info.clone()).collect();
            let enable = setpoint::enable_state(&states, &self.states[i].info);
            Some((
                true,
                format!(
                    "the executor refused {name} <- {}: {}",
                    p.sent,
                    setpoint::refusal(s.status, &self.states[i].info, enable.as_ref())
                ),
            ))
        } else if let Some(from) = p.clamped_from {
            Some((
                false,
                format!("{name} <- {} (clamped from {from} to its limits)", p.sent),
            ))
        } else if s.is_some_and(|s| s.status & status::CLAMPED != 0) {
            Some((
                false,
                format!(
                    "{name} <- {}: the executor clamped it to its limits",
                    p.sent
                ),
            ))
        } else {
            None
        };
        // Taken (or not known to be refused): answer with what was sent; a measured state (a
        // position) reaches it only over the next ticks, and the panel should show the command,
        // not the lag. Refused: answer with what the state holds, so the client's field reverts.
        let refused = matches!(note, Some((true, _)));
        match p.origin {
            Origin::Publish(client) => {
                if let Some((error, text)) = note {
                    let text = format!("conductor view: {text}");
                    client.send_status(if error {
                        Status::error(text)
                    } else {
                        Status::warning(text)
                    });
                }
            }
            Origin::Parameter { request, slot } => {
                let answer = if refused {
                    self.parameter_of(&name)
                } else {
                    Parameter::float64(&name, p.sent)
                };
                if let Some(r) = self.sets.get_mut(&request) {
                    if let (Some((error, text)), Some(resp)) = (&note, &r.responder) {
                        let text = format!("conductor view: {text}");
                        if *error {
                            resp.client().send_error(text);
                        } else {
                            resp.client().send_warning(text);
                        }
                    }
                    r.results[slot] = Some(answer);
                }
                self.finish_set(request);
                // Everyone watching this parameter sees the new value at the next refresh.
                self.states[i].published = None;
            }
        }
    }

    fn expire_verdicts(&mut self, now: Instant) {
        for i in 0..self.states.len() {
            let mut k = 0;
            while k < self.states[i].pending.len() {
                if self.states[i].pending[k].deadline <= now {
                    let p = self.states[i].pending.remove(k);
                    let latest = self.states[i].latest;
                    self.resolve(i, p, latest.as_ref(), true);
                } else {
                    k += 1;
                }
            }
        }
    }

    /// Sends subscribed parameters whose value changed since they were last sent.
    fn publish_parameters(&mut self) {
        if self.subscribed.is_empty() {
            return;
        }
        let mut out = Vec::new();
        for t in &mut self.states {
            if !t.info.meta.writable || !self.subscribed.contains(&t.name) {
                continue;
            }
            let Some(v) = t.latest.map(|s| s.value).filter(|v| v.is_finite()) else {
                continue;
            };
            if t.published != Some(v) {
                t.published = Some(v);
                out.push(Parameter::float64(&t.name, v));
            }
        }
        if let (false, Some(server)) = (out.is_empty(), &self.server) {
            server.publish_parameter_values(out);
        }
    }
}

impl Drop for View {
    fn drop(&mut self) {
        if let Some(s) = self.server.take() {
            drop(s.stop());
        }
    }
}

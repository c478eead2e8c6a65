//! `conductor view` against a real WebSocket client speaking the Foxglove WebSocket protocol
//! (`foxglove.websocket.v1`; the official `foxglove` crate's server negotiates it under its newer
//! name `foxglove.sdk.v1`, which is the same protocol, so the client offers both, as Foxglove and
//! current Lichtblick do), with real executors launched from a manifest on simulated hardware.

mod support;

use std::net::TcpStream;
use std::time::{Duration, Instant};

use conductor_bus::{monotonic_ns, Domain};
use conductor_testkit::json_strings;
use serde_json::{json, Value};
use support::*;
use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, WebSocket};

const PROTOCOLS: &str = "foxglove.websocket.v1, foxglove.sdk.v1";

/// What the server sent.
#[derive(Debug, Clone)]
enum Msg {
    /// A JSON (text) message.
    Json(Value),
    /// A binary message-data frame: subscription id, log time (ns), JSON payload.
    Data { sub: u32, time: u64, body: Value },
}

/// A minimal Foxglove WebSocket client.
struct Fox {
    ws: WebSocket<TcpStream>,
    protocol: String,
    /// Status messages and parameter updates seen so far (they may arrive while a step waits
    /// for something else).
    statuses: Vec<Value>,
    updates: Vec<Value>,
    /// Subscriptions asked for: (subscription id, channel id).
    subscriptions: Vec<(u32, u64)>,
}

impl Fox {
    fn connect(url: &str) -> Self {
        let addr = url.strip_prefix("ws://").expect("a ws:// url");
        let stream = TcpStream::connect(addr).expect("connect to the view");
        let mut req = url.into_client_request().unwrap();
        req.headers_mut()
            .insert("Sec-WebSocket-Protocol", PROTOCOLS.parse().unwrap());
        let (ws, resp) = tungstenite::client(req, stream).expect("WebSocket handshake");
        let protocol = resp
            .headers()
            .get("sec-websocket-protocol")
            .map(|h| h.to_str().unwrap().to_string())
            .unwrap_or_default();
        ws.get_ref()
            .set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        Self {
            ws,
            protocol,
            statuses: Vec::new(),
            updates: Vec::new(),
            subscriptions: Vec::new(),
        }
    }

    fn send(&mut self, v: Value) {
        self.ws.send(Message::text(v.to_string())).unwrap();
    }

    /// Subscribes `(subscription id, channel)` pairs.
    fn subscribe(&mut self, subs: &[(u32, &Value)]) {
        let list: Vec<(u32, u64)> = subs
            .iter()
            .map(|(id, c)| (*id, c["id"].as_u64().unwrap()))
            .collect();
        self.subscriptions.extend(&list);
        self.send_subscribe(&list);
    }

    fn send_subscribe(&mut self, list: &[(u32, u64)]) {
        let subs: Vec<Value> = list
            .iter()
            .map(|(id, c)| json!({"id": id, "channelId": c}))
            .collect();
        self.send(json!({"op": "subscribe", "subscriptions": subs}));
    }

    /// Client message data on client channel `channel`.
    fn publish(&mut self, channel: u32, body: Value) {
        let mut b = vec![0x01];
        b.extend_from_slice(&channel.to_le_bytes());
        b.extend_from_slice(body.to_string().as_bytes());
        self.ws.send(Message::binary(b)).unwrap();
    }

    fn next(&mut self) -> Option<Msg> {
        match self.ws.read() {
            Ok(Message::Text(t)) => {
                let v: Value = serde_json::from_str(t.as_str()).unwrap();
                if v["op"] == "status" {
                    // foxglove 0.30.3 sends a channel's advertisement before it records the
                    // channel for the client, so a client that subscribes at once may be told
                    // the channel is unknown: subscribe again, as a client should.
                    let msg = v["message"].as_str().unwrap_or("");
                    if let Some(id) = msg.strip_prefix("Unknown channel ID: ") {
                        let id: u64 = id.trim().parse().unwrap();
                        let again: Vec<(u32, u64)> = self
                            .subscriptions
                            .iter()
                            .copied()
                            .filter(|(_, c)| *c == id)
                            .collect();
                        if !again.is_empty() {
                            std::thread::sleep(Duration::from_millis(20));
                            self.send_subscribe(&again);
                            return None;
                        }
                    }
                    self.statuses.push(v.clone());
                }
                if v["op"] == "parameterValues" && v.get("id").is_none() {
                    self.updates.push(v.clone());
                }
                Some(Msg::Json(v))
            }
            Ok(Message::Binary(b)) => {
                assert_eq!(b[0], 0x01, "message data opcode");
                let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
                let time = u64::from_le_bytes(b[5..13].try_into().unwrap());
                let body = serde_json::from_slice(&b[13..]).unwrap();
                Some(Msg::Data { sub, time, body })
            }
            Ok(_) => None,
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                None
            }
            Err(e) => panic!("WebSocket: {e}"),
        }
    }

    /// Reads until `f` returns something (at most `secs` seconds).
    fn until<T>(&mut self, secs: u64, what: &str, mut f: impl FnMut(&Msg) -> Option<T>) -> T {
        let end = Instant::now() + Duration::from_secs(secs);
        let mut ops = Vec::new();
        while Instant::now() < end {
            if let Some(m) = self.next() {
                if let Some(t) = f(&m) {
                    return t;
                }
                if let Msg::Json(v) = &m {
                    ops.push(v["op"].to_string());
                }
            }
        }
        panic!(
            "no {what} within {secs} s; text messages seen: {ops:?}; statuses: {:?}",
            self.statuses
        );
    }

    /// The response to request `id` (parameterValues).
    fn response(&mut self, id: &str) -> Value {
        self.until(10, &format!("response {id}"), |m| match m {
            Msg::Json(v) if v["op"] == "parameterValues" && v["id"] == id => Some(v.clone()),
            _ => None,
        })
    }

    /// The first status message (seen or to come) whose text contains `text`.
    fn status(&mut self, text: &str) -> Value {
        if let Some(s) = self
            .statuses
            .iter()
            .find(|s| s["message"].as_str().unwrap_or("").contains(text))
        {
            return s.clone();
        }
        self.until(10, &format!("status {text:?}"), |m| match m {
            Msg::Json(v)
                if v["op"] == "status" && v["message"].as_str().unwrap_or("").contains(text) =>
            {
                Some(v.clone())
            }
            _ => None,
        })
    }

    /// The first parameter update (seen or to come) that gives `name` the value `value`.
    fn update(&mut self, name: &str, value: f64) {
        let hit = |v: &Value| param(v, name).is_some_and(|p| p["value"] == value);
        if self.updates.iter().any(hit) {
            return;
        }
        self.until(
            10,
            &format!("a parameter update of {name} to {value}"),
            |m| match m {
                Msg::Json(v) if v["op"] == "parameterValues" && v.get("id").is_none() && hit(v) => {
                    Some(())
                }
                _ => None,
            },
        )
    }

    /// Channels advertised until every topic of `topics` is (topic → channel).
    fn advertised(&mut self, topics: &[&str]) -> Vec<Value> {
        let mut seen: Vec<Value> = Vec::new();
        self.until(20, &format!("advertisement of {topics:?}"), |m| {
            if let Msg::Json(v) = m {
                if v["op"] == "advertise" {
                    seen.extend(v["channels"].as_array().unwrap().iter().cloned());
                }
            }
            topics
                .iter()
                .all(|t| seen.iter().any(|c| c["topic"] == *t))
                .then(|| seen.clone())
        })
    }
}

fn channel<'a>(channels: &'a [Value], topic: &str) -> &'a Value {
    channels.iter().find(|c| c["topic"] == topic).unwrap()
}

fn param<'a>(resp: &'a Value, name: &str) -> Option<&'a Value> {
    resp["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == name)
}

/// Starts `conductor view` with `args`; returns it and the URL from its `ready view` line.
fn view(d: &Domain, args: &[&str]) -> (Bg, String) {
    let mut v = Bg::spawn(conductor(d).arg("view").args(args));
    let lines = v.until(Duration::from_secs(30), |l| l.starts_with("ready view "));
    let url = lines.last().unwrap()["ready view ".len()..].to_string();
    (v, url)
}

fn launch_testbot(d: &Domain) -> Bg {
    let manifest = workspace().join("executors/tests/manifests/two-subsystems.toml");
    let launcher = Bg::spawn(
        conductor(d)
            .arg("launch")
            .arg(manifest)
            .args(["--no-rt", "--quiet"]),
    );
    // Ready when every state answers.
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        let out = ok(conductor(d).arg("list"));
        if out.lines().skip(1).count() == 9 {
            break;
        }
        assert!(Instant::now() < end, "the testbot never came up: {out}");
        std::thread::sleep(Duration::from_millis(100));
    }
    launcher
}

/// The newest sample of subscription `sub` whose body satisfies `pred`.
fn sample(fox: &mut Fox, sub: u32, what: &str, pred: impl Fn(&Value) -> bool) -> (u64, Value) {
    fox.until(10, what, |m| match m {
        Msg::Data { sub: s, time, body } if *s == sub && pred(body) => Some((*time, body.clone())),
        _ => None,
    })
}

fn ns(t: &Value) -> u64 {
    t["sec"].as_u64().unwrap() * 1_000_000_000 + t["nsec"].as_u64().unwrap()
}

#[test]
fn foxglove_sees_a_launched_robot_and_sets_through_the_checks_of_set() {
    let d = Domain::unique("view").unwrap();
    let _robot = launch_testbot(&d);
    let (_view, url) = view(&d, &["--listen", "127.0.0.1:0"]);
    assert!(url.starts_with("ws://127.0.0.1:"), "{url}");
    let mut fox = Fox::connect(&url);
    assert_eq!(fox.protocol, "foxglove.sdk.v1");

    // serverInfo: parameters and client publishing, JSON.
    let info = fox.until(10, "serverInfo", |m| match m {
        Msg::Json(v) if v["op"] == "serverInfo" => Some(v.clone()),
        _ => None,
    });
    let caps = json_strings(&info["capabilities"]);
    for c in ["clientPublish", "parameters", "parametersSubscribe"] {
        assert!(caps.contains(&c), "{info}");
    }
    assert_eq!(info["supportedEncodings"], json!(["json"]));

    // Every state and both executors' stats, each channel with its JSON schema.
    let states = [
        "/arm/j0",
        "/arm/j1",
        "/arm/j2",
        "/arm/j3",
        "/arm/j4",
        "/arm/j5",
        "/sensors/a",
        "/sensors/b",
        "/sensors/c",
    ];
    let mut topics = states.to_vec();
    topics.extend(["/arm/stats", "/sensors/stats"]);
    let channels = fox.advertised(&topics);
    for t in states {
        let c = channel(&channels, t);
        assert_eq!(c["encoding"], "json", "{c}");
        assert_eq!(c["schemaName"], "conductor.LiveSample", "{c}");
        assert_eq!(c["schemaEncoding"], "jsonschema", "{c}");
        let schema: Value = serde_json::from_str(c["schema"].as_str().unwrap()).unwrap();
        for k in [
            "value",
            "unit",
            "flags",
            "t_sample",
            "t_publish",
            "seq",
            "tick",
        ] {
            assert!(
                schema["properties"].get(k).is_some(),
                "{t}: {k} in {schema}"
            );
        }
    }
    let stats = channel(&channels, "/arm/stats");
    assert_eq!(stats["schemaName"], "conductor.ExecutorStats");

    // Subscribe to a joint, a sensor and the arm's stats.
    let ch = |t: &str| channel(&channels, t);
    fox.subscribe(&[
        (1, ch("/arm/j3")),
        (2, ch("/sensors/a")),
        (3, ch("/arm/stats")),
        (4, ch("/arm/j2")),
    ]);
    let (time, s) = sample(&mut fox, 2, "a sensor sample", |_| true);
    assert_eq!(s["unit"], "");
    assert!(s["value"].as_f64().unwrap().abs() <= 1.0, "{s}");
    assert_eq!(s["flags"]["simulated"], true, "{s}");
    assert_eq!(s["status"].as_u64().unwrap() & 64, 64);
    // Log time = sample time; published after sampled; both on this machine's CLOCK_MONOTONIC,
    // a moment ago.
    assert_eq!(time, ns(&s["t_sample"]), "{s}");
    assert!(ns(&s["t_publish"]) >= ns(&s["t_sample"]), "{s}");
    let age = monotonic_ns().saturating_sub(time);
    assert!(age < 5_000_000_000, "sample {age} ns old: {s}");
    let (_, s2) = sample(&mut fox, 2, "a later sensor sample", |b| {
        b["seq"].as_u64() > s["seq"].as_u64()
    });
    assert!(ns(&s2["t_sample"]) > ns(&s["t_sample"]));
    let (_, st) = sample(&mut fox, 3, "the arm's stats", |_| true);
    assert_eq!(st["base_rate_hz"], 200.0, "{st}");
    assert_eq!(st["states"], 6, "{st}");
    assert!(st["ticks"].as_u64().unwrap() > 0, "{st}");

    // Settable states are parameters; read-only ones are not.
    fox.send(json!({"op": "getParameters", "parameterNames": [], "id": "g1"}));
    let all = fox.response("g1");
    for j in 0..6 {
        assert!(param(&all, &format!("arm/j{j}")).is_some(), "{all}");
    }
    assert!(param(&all, "sensors/a").is_none(), "{all}");

    // A parameter set goes through a command frame; the answer is the executor's sample.
    fox.send(json!({"op": "subscribeParameterUpdates", "parameterNames": ["arm/j3"]}));
    fox.send(json!({"op": "setParameters", "id": "s1",
        "parameters": [{"name": "arm/j3", "value": 1.25, "type": "float64"}]}));
    let r = fox.response("s1");
    assert_eq!(param(&r, "arm/j3").unwrap()["value"], 1.25, "{r}");
    let (_, j3) = sample(&mut fox, 1, "j3 at 1.25", |b| b["value"] == 1.25);
    assert_eq!(j3["unit"], "rad");
    assert_eq!(j3["flags"]["rejected"], false);
    // Parameter subscribers hear of it.
    fox.update("arm/j3", 1.25);

    // Out of the limits: refused like `conductor set` without --clamp; nothing is sent.
    fox.send(json!({"op": "setParameters", "id": "s2",
        "parameters": [{"name": "arm/j3", "value": 5.0, "type": "float64"}]}));
    let r = fox.response("s2");
    assert_eq!(param(&r, "arm/j3").unwrap()["value"], 1.25, "{r}");
    let st = fox.status("outside the limits [-2, 2] of arm/j3");
    assert_eq!(st["level"], 2, "an error: {st}");
    // A read-only state cannot be set either.
    fox.send(json!({"op": "setParameters", "id": "s3",
        "parameters": [{"name": "sensors/a", "value": 0.5}]}));
    fox.response("s3");
    fox.status("sensors/a is read-only");
    // The joint still holds 1.25 (samples from later ticks).
    let t_now = monotonic_ns();
    let (_, j3) = sample(&mut fox, 1, "a fresh j3 sample", |b| {
        ns(&b["t_publish"]) > t_now
    });
    assert_eq!(j3["value"], 1.25, "{j3}");
    assert_eq!(
        ok(conductor(&d).args(["get", "arm/j3", "--raw"])).trim(),
        "1.25"
    );

    // The client-publish channel: {"value": x} on a settable state's own topic.
    fox.send(json!({"op": "advertise", "channels": [
        {"id": 7, "topic": "/arm/j2", "encoding": "json", "schemaName": "conductor.LiveSample"},
    ]}));
    fox.publish(7, json!({"value": -0.5}));
    let (_, j2) = sample(&mut fox, 4, "j2 at -0.5", |b| b["value"] == -0.5);
    assert_eq!(j2["flags"]["clamped"], false);
    fox.publish(7, json!({"value": 9}));
    let st = fox.status("9 is outside the limits [-2, 2] of arm/j2");
    assert_eq!(st["level"], 2, "{st}");
    fox.publish(7, json!({"speed": 1}));
    fox.status("expected {\"value\": <number>}");
    let t_now = monotonic_ns();
    let (_, j2) = sample(&mut fox, 4, "a fresh j2 sample", |b| {
        ns(&b["t_publish"]) > t_now
    });
    assert_eq!(j2["value"], -0.5, "{j2}");
    // A topic that is no settable state is told so when advertised.
    fox.send(json!({"op": "advertise", "channels": [
        {"id": 8, "topic": "/sensors/a", "encoding": "json", "schemaName": "x"},
    ]}));
    fox.status("nothing published on /sensors/a will be sent: sensors/a is read-only");
}

#[test]
fn new_states_appear_and_clamp_sends_the_nearest_limit() {
    let d = Domain::unique("view-new").unwrap();
    // The view first, on an empty domain.
    let (_view, url) = view(&d, &["--listen", "127.0.0.1:0", "--clamp"]);
    let mut fox = Fox::connect(&url);
    let leg = hold_sim(
        &d,
        "leg",
        100.0,
        vec![
            state(0, "knee", "rad", true, (-1.5, 2.0), 100.0, "dKnee"),
            state(1, "current", "A", false, (-5.0, 5.0), 100.0, ""),
        ],
    );
    let channels = fox.advertised(&["/leg/knee", "/leg/current", "/leg/stats"]);
    assert_eq!(
        channel(&channels, "/leg/knee")["schemaName"],
        "conductor.LiveSample"
    );
    fox.subscribe(&[(1, channel(&channels, "/leg/knee"))]);
    sample(&mut fox, 1, "a knee sample", |b| b["unit"] == "rad");

    // With --clamp, a value outside the limits is sent as the nearest limit, and said so.
    fox.send(json!({"op": "setParameters", "id": "c1",
        "parameters": [{"name": "leg/knee", "value": 5.0, "type": "float64"}]}));
    let r = fox.response("c1");
    assert_eq!(param(&r, "leg/knee").unwrap()["value"], 2.0, "{r}");
    let st = fox.status("leg/knee <- 2 (clamped from 5");
    assert_eq!(st["level"], 1, "a warning: {st}");
    sample(&mut fox, 1, "the knee at its limit", |b| b["value"] == 2.0);
    // NaN cannot travel as JSON; an integer value is a number like any other.
    fox.send(json!({"op": "setParameters", "id": "c2",
        "parameters": [{"name": "leg/knee", "value": -1}]}));
    let r = fox.response("c2");
    assert_eq!(param(&r, "leg/knee").unwrap()["value"], -1.0, "{r}");
    drop(leg);
}

/// The pids of live processes whose command line has every one of `args`.
fn pids_with(args: &[&str]) -> Vec<i32> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let Ok(cmd) = std::fs::read(e.path().join("cmdline")) else {
            continue;
        };
        let argv: Vec<String> = cmd
            .split(|b| *b == 0)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect();
        if args.iter().all(|a| argv.iter().any(|x| x == a)) {
            out.push(pid);
        }
    }
    out
}

/// A free TCP port on loopback (free when checked; the view binds it next).
fn free_tcp_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn connect_with_retry(url: &str) -> Fox {
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        let addr = url.strip_prefix("ws://").unwrap();
        if TcpStream::connect(addr).is_ok() {
            return Fox::connect(url);
        }
        assert!(Instant::now() < end, "nothing listens on {url}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn a_manifest_view_is_launched_and_restarted_by_the_launcher() {
    let d = Domain::unique("view-launch").unwrap();
    let dir = tempdir("view-launch");
    let port = free_tcp_port();
    let robot =
        std::fs::read_to_string(workspace().join("executors/tests/manifests/two-subsystems.toml"))
            .unwrap();
    let manifest = dir.join("robot.toml");
    std::fs::write(
        &manifest,
        format!("{robot}\n[view]\nlisten = \"127.0.0.1:{port}\"\n"),
    )
    .unwrap();
    let out = ok(conductor(&d).arg("launch").arg(&manifest).arg("--check"));
    assert!(out.contains("a view"), "{out}");
    let launcher = Bg::spawn(
        conductor(&d)
            .arg("launch")
            .arg(&manifest)
            .args(["--no-rt", "--quiet"]),
    );
    let url = format!("ws://127.0.0.1:{port}");
    let mut fox = connect_with_retry(&url);
    fox.advertised(&["/arm/j0", "/sensors/c", "/arm/stats"]);
    drop(fox);

    // The view is the launcher's child, on the manifest's domain; killed, it is restarted.
    let view_args = ["view", "--domain", d.name(), "--listen"];
    let pids = pids_with(&view_args);
    assert_eq!(pids.len(), 1, "one view process: {pids:?}");
    // SAFETY: kill(2) on the view process found above (a grandchild of this test).
    unsafe { libc::kill(pids[0], libc::SIGKILL) };
    let end = Instant::now() + Duration::from_secs(30);
    let mut fox = loop {
        let now = pids_with(&view_args);
        if now.len() == 1 && now[0] != pids[0] {
            break connect_with_retry(&url);
        }
        assert!(Instant::now() < end, "the view was not restarted");
        std::thread::sleep(Duration::from_millis(100));
    };
    let channels = fox.advertised(&["/arm/j3"]);
    fox.subscribe(&[(1, channel(&channels, "/arm/j3"))]);
    sample(&mut fox, 1, "a j3 sample after the restart", |b| {
        b["unit"] == "rad"
    });
    drop(fox);

    // An orderly stop ends the view too.
    let (clean, err) = launcher.interrupt();
    assert!(clean, "{err}");
    assert!(err.contains("and the view stopped"), "{err}");
    assert!(err.contains("restarting the view (restart 1"), "{err}");
    assert!(pids_with(&view_args).is_empty());
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_setpoint_the_executor_refuses_comes_back_as_an_error_with_the_flags() {
    let d = Domain::unique("view-refused").unwrap();
    let dir = tempdir("view-refused");
    let manifest = dir.join("leg.toml");
    std::fs::write(&manifest, TRIPPING_LEG).unwrap();
    let _robot = Bg::spawn(
        conductor(&d)
            .arg("launch")
            .arg(&manifest)
            .args(["--no-rt", "--quiet"]),
    );
    let (_view, url) = view(&d, &["--listen", "127.0.0.1:0"]);
    let mut fox = Fox::connect(&url);
    let channels = fox.advertised(&["/leg/knee", "/leg/knee_enable"]);
    fox.subscribe(&[(1, channel(&channels, "/leg/knee"))]);
    // Brought up and enabled; a first setpoint is taken and arms the watchdog.
    sample(&mut fox, 1, "the knee driving", |b| {
        b["flags"]["disabled"] == false && b["flags"]["tripped"] == false
    });
    fox.send(json!({"op": "setParameters", "id": "t1",
        "parameters": [{"name": "leg/knee", "value": 0.1, "type": "float64"}]}));
    let r = fox.response("t1");
    assert_eq!(param(&r, "leg/knee").unwrap()["value"], 0.1, "{r}");
    assert!(fox.statuses.is_empty(), "{:?}", fox.statuses);
    // Then nobody sends frames: the watchdog trips the motor.
    let (_, tripped) = sample(&mut fox, 1, "the knee tripped", |b| {
        b["flags"]["tripped"] == true
    });
    assert_eq!(tripped["flags"]["watchdog"], true, "{tripped}");
    let held = tripped["value"].as_f64().unwrap();
    assert!(held.abs() < 0.45, "{tripped}");

    // In the limits, so the view sends it; the executor refuses it, and says so in the flags.
    let t_send = monotonic_ns();
    fox.send(json!({"op": "setParameters", "id": "r1",
        "parameters": [{"name": "leg/knee", "value": 0.75, "type": "float64"}]}));
    let r = fox.response("r1");
    let answered = param(&r, "leg/knee").unwrap()["value"].as_f64().unwrap();
    assert!(
        (answered - 0.75).abs() > 0.3,
        "answered with what it holds: {r}"
    );
    let st = fox.status("the executor refused leg/knee <- 0.75: device knee is tripped");
    assert_eq!(st["level"], 2, "{st}");
    assert!(
        st["message"]
            .as_str()
            .unwrap()
            .contains("conductor set leg/knee_enable 1"),
        "{st}"
    );
    let (_, s) = sample(&mut fox, 1, "a sample after the refused frame", |b| {
        ns(&b["t_publish"]) > t_send && b["flags"]["rejected"] == true
    });
    assert_eq!(s["flags"]["tripped"], true, "{s}");
    // The same through the client-publish channel.
    fox.send(json!({"op": "advertise", "channels": [
        {"id": 3, "topic": "/leg/knee", "encoding": "json", "schemaName": "conductor.LiveSample"},
    ]}));
    fox.statuses.clear();
    fox.publish(3, json!({"value": -0.5}));
    fox.status("the executor refused leg/knee <- -0.5: device knee is tripped");
    let _ = std::fs::remove_dir_all(dir);
}

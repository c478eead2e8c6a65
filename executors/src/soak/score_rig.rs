//! The Score board of deploy/score-board.toml as a host-side simulator on a pseudo-terminal,
//! with faults on its link, and the manifest table that points the shipped gateway at it.
//!
//! The board is the firmware's own host-testable logic (`score-board`: [`Board`] with
//! score-core's engine, the RP2040 HAL bookkeeping, the sampler and [`LinkServer`]), driven the
//! way `score/firmware/src/main.rs` drives it: bytes from the host go through
//! [`LinkServer::feed`], the engine ticks at each deadline, then `TableChanged` and the
//! subscribed samples go out as frames. Only the registers are memory ([`RecIo`], which also
//! records every PWM compare value written) and the clock is the host's.
//!
//! What the firmware does, the simulator does:
//!
//! * **Power-on state**: an empty table, every output off (the firmware keeps nothing across a
//!   power cycle). The first power-on gets the bench's configuration ([`CONFIG`]) as typed on
//!   its terminal; an unplug is a power cycle (the Pico is powered by its USB port), so the
//!   board comes back empty and the gateway must restore it.
//! * **Refusals**: those of [`LinkServer`] (stale generation, unknown slot, read-only, the
//!   engine's refusals) — it is the same code.
//! * **A silent host**: the firmware has **no** host watchdog: when nobody writes to the link
//!   its outputs keep their last duty (`link_rx_task` only resets the frame scanner when the
//!   port reconnects). The safe state after a controller dies is the gateway's command
//!   watchdog (`watchdog_ms`), which is what the campaign checks.
//!
//! Faults: each frame the board sends is damaged with the wire's byte probabilities, and so
//! is each chunk of bytes it reads (score_link frames carry a CRC-16: the receiver must drop
//! them); the port is removed (the board powered off) and plugged back.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use conductor_bus::monotonic_ns;
use conductor_devices::sim::fault::{FaultConfig, FaultInjector};
use conductor_protocols::score_link::{encode_reply, Reply, SampleBatch, MAX_FRAME};
use score_board::hal::{BoardHal, MemIo, PinFunction, PortIo};
use score_board::link::LinkServer;
use score_board::out::{FrameOut, TextOut};
use score_board::pwm::SliceRegs;
use score_board::{Board, BoardInfo};
use score_core::hal::HalError;
use score_core::Real;
use serialport::TTYPort;

/// The gateway's subsystem: `score-<board name>` (the firmware's default name).
pub const SUBSYSTEM: &str = "score-rp2040";

/// What the bench's user typed on the board's terminal before the campaign: an ADC channel
/// sampled at 200 Hz (`ADC0` codes, `adc0` volts) and two PWM outputs at 1 kHz that a
/// controller commands (`PWM4`, `PWM6`, duties in %).
pub const CONFIG: [&str; 3] = ["adc 0 200", "pwm 4 1000 0", "pwm 6 1000 0"];

/// The commanded outputs (GPIO numbers = their variables `PWM<n>`).
pub const OUTPUTS: [u8; 2] = [4, 6];

/// The variables whose published values are checked.
pub const WATCHED: [&str; 4] = ["ADC0", "adc0", "PWM4", "PWM6"];

/// The controller sends duties on a 0.5 % grid: a written duty off the grid (beyond one PWM
/// count) came from nowhere.
pub const DUTY_GRID: f64 = 0.5;

const INFO: BoardInfo = BoardInfo {
    firmware: "score-firmware 0.1.0 (soak host board)",
    board: "rp2040",
};

/// How long the history of a variable's values reaches back.
const HISTORY_NS: u64 = 4_000_000_000;

/// What the board did, as seen from inside it.
#[derive(Debug, Default)]
pub struct Record {
    /// Power-ons (the first and each replug).
    pub power_ons: u64,
    /// Handshakes served (`Hello` requests).
    pub hellos: u64,
    /// Power-ons whose empty table was filled again through the link (the gateway's restore).
    pub restores: u64,
    /// Frames sent towards the host.
    pub frames_out: u64,
    /// Of them, damaged on the wire.
    pub damaged_out: u64,
    /// Of the damaged ones, answers to a request (the rest are samples and table changes).
    pub damaged_replies: u64,
    /// Chunks of bytes from the host damaged on the wire.
    pub damaged_in: u64,
    /// Frames from the host the board rejected (bad CRC, bad COBS, too long), all power-ons.
    pub rejected_in: u64,
    /// Frames from the host the board accepted, all power-ons.
    pub accepted_in: u64,
    /// PWM compare values written for the commanded outputs.
    pub writes: u64,
    /// Of them, out of 0–100 % or off the controller's grid.
    pub wrong_writes: u64,
    /// The first few wrong writes, described.
    pub wrong_examples: Vec<String>,
    /// Current duty (%) of each commanded output and since when (ns); 0 while unpowered.
    pub duty: [(f64, u64); 2],
    /// Per watched variable: (from ns, value) whenever its value changed.
    pub history: [VecDeque<(u64, f64)>; 4],
    /// When a commanded output was last given a duty other than 0 (ns): the last command of a
    /// controller that reached the board.
    pub last_nonzero_ns: u64,
    /// Whether the board is powered (plugged).
    pub plugged: bool,
    /// The longest the serving thread overslept a wait (ns).
    pub worst_lag_ns: u64,
    /// The same since the campaign last set it to 0 (ns).
    pub window_lag_ns: u64,
    /// The serving thread's id (its `/proc/self/task/<tid>/schedstat` tells how long it
    /// waited for a CPU).
    pub tid: i32,
}

impl Record {
    fn note_duty(&mut self, out: usize, duty: f64, top: u16) {
        self.writes += 1;
        let count = 100.0 / (top as f64 + 1.0);
        let nearest = (duty / DUTY_GRID).round() * DUTY_GRID;
        let ok = (0.0..=100.0).contains(&duty) && (duty - nearest).abs() <= count + 1e-9;
        if !ok {
            self.wrong_writes += 1;
            if self.wrong_examples.len() < 10 {
                self.wrong_examples
                    .push(format!("PWM{} duty {duty:.4} % (TOP {top})", OUTPUTS[out]));
            }
        }
        let now = monotonic_ns();
        if duty != 0.0 {
            self.last_nonzero_ns = now;
        }
        if self.duty[out].0 != duty {
            self.duty[out] = (duty, now);
        }
    }

    fn note_value(&mut self, var: usize, value: f64, now: u64) {
        let h = &mut self.history[var];
        if h.back()
            .is_none_or(|&(_, v)| v.to_bits() != value.to_bits())
        {
            h.push_back((now, value));
        }
        while h.len() > 2 && h[1].0 + HISTORY_NS < now {
            h.pop_front();
        }
    }

    /// Whether `value` was a value of watched variable `var` at some instant in
    /// `[from_ns, to_ns]`.
    pub fn had(&self, var: usize, value: f64, from_ns: u64, to_ns: u64) -> bool {
        let h = &self.history[var];
        h.iter().enumerate().any(|(i, &(t, v))| {
            let until = h.get(i + 1).map_or(u64::MAX, |n| n.0);
            v.to_bits() == value.to_bits() && t <= to_ns && until >= from_ns
        })
    }

    /// Whether every commanded output is at 0 %.
    pub fn all_off(&self) -> bool {
        self.duty.iter().all(|d| d.0 == 0.0)
    }
}

/// The registers: [`MemIo`], with every compare value of the commanded outputs recorded.
pub struct RecIo {
    mem: MemIo,
    rec: Arc<Mutex<Record>>,
}

impl RecIo {
    fn note(&mut self, s: &SliceRegs) {
        let mut r = lock(&self.rec);
        for (i, &o) in OUTPUTS.iter().enumerate() {
            if o / 2 != s.slice {
                continue;
            }
            let cc = if o % 2 == 0 { s.cc_a } else { s.cc_b };
            let duty = if s.enable {
                cc as f64 * 100.0 / (s.top as f64 + 1.0)
            } else {
                0.0
            };
            r.note_duty(i, duty, s.top);
        }
    }
}

impl PortIo for RecIo {
    fn sys_clock_hz(&self) -> u32 {
        self.mem.sys_clock_hz()
    }
    fn adc_convert(&mut self, ch: u8) -> Result<u16, HalError> {
        self.mem.adc_convert(ch)
    }
    fn pwm_write(&mut self, regs: &SliceRegs) {
        self.mem.pwm_write(regs);
        self.note(regs);
    }
    fn pwm_compare(&mut self, slice: u8, cc_a: u16, cc_b: u16) {
        self.mem.pwm_compare(slice, cc_a, cc_b);
        let s = self.mem.slices[slice as usize];
        self.note(&s);
    }
    fn pin_function(&mut self, pin: u8, f: PinFunction) {
        self.mem.pin_function(pin, f)
    }
    fn pin_read(&mut self, pin: u8) -> bool {
        self.mem.pin_read(pin)
    }
    fn pin_write(&mut self, pin: u8, high: bool) {
        self.mem.pin_write(pin, high)
    }
}

/// The firmware's number type (feature `f32`, the default).
type HostBoard = Board<f32, BoardHal<RecIo>>;

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A pseudo-terminal whose slave the gateway opens through a symlink; dropping it is the
/// unplug (the master closes, the link goes).
struct Port {
    master: TTYPort,
    _slave: TTYPort,
    link: PathBuf,
}

impl Port {
    fn open(link: &Path) -> std::io::Result<Self> {
        let (mut master, slave) = TTYPort::pair().map_err(std::io::Error::from)?;
        // Processes started later (the gateway) must not hold our ends: the gateway would
        // never see the hang-up of an unplug.
        for fd in [master.as_raw_fd(), slave.as_raw_fd()] {
            // SAFETY: fcntl on a descriptor this function owns; no memory is passed.
            if unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) } < 0 {
                return Err(std::io::Error::last_os_error());
            }
        }
        use serialport::SerialPort as _;
        master
            .set_timeout(Duration::from_millis(1))
            .map_err(std::io::Error::from)?;
        let path = slave
            .name()
            .ok_or_else(|| std::io::Error::other("pty without a name"))?;
        let _ = std::fs::remove_file(link);
        std::os::unix::fs::symlink(&path, link)?;
        Ok(Self {
            master,
            _slave: slave,
            link: link.into(),
        })
    }
}

impl Drop for Port {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.link);
    }
}

/// The board on its port, served by a thread of its own.
pub struct BoardSim {
    rec: Arc<Mutex<Record>>,
    plugged: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    link: PathBuf,
}

impl BoardSim {
    /// Powers the board on at `link` (a symlink to its pty) with the wire's byte faults.
    pub fn start(link: &Path, corrupt: f64, drop: f64, seed: u64) -> std::io::Result<Self> {
        let rec = Arc::new(Mutex::new(Record::default()));
        let plugged = Arc::new(AtomicBool::new(true));
        let stop = Arc::new(AtomicBool::new(false));
        let port = Port::open(link)?;
        let (r2, p2, s2, l2) = (
            rec.clone(),
            plugged.clone(),
            stop.clone(),
            link.to_path_buf(),
        );
        let thread = std::thread::Builder::new()
            .name("soak-score-board".into())
            .spawn(move || serve(port, &l2, &r2, &p2, &s2, corrupt, drop, seed))?;
        Ok(Self {
            rec,
            plugged,
            stop,
            thread: Some(thread),
            link: link.into(),
        })
    }

    /// What the board did so far.
    pub fn record(&self) -> MutexGuard<'_, Record> {
        lock(&self.rec)
    }

    /// The path the gateway opens.
    pub fn link(&self) -> &Path {
        &self.link
    }

    /// Pulls the USB cable: the port goes and the board loses power. Returns once done.
    pub fn unplug(&self) {
        self.plugged.store(false, Ordering::SeqCst);
        self.wait_plugged(false);
    }

    /// Plugs it back: a new port at the same path and a board in its power-on state.
    pub fn replug(&self) {
        self.plugged.store(true, Ordering::SeqCst);
        self.wait_plugged(true);
    }

    fn wait_plugged(&self, want: bool) {
        let end = Instant::now() + Duration::from_secs(5);
        while lock(&self.rec).plugged != want && Instant::now() < end {
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Stops the board's thread.
    pub fn stop(mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for BoardSim {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// One powered life of the board: from plug-in (or the first power-on) to unplug.
struct Powered {
    board: Box<HostBoard>,
    server: LinkServer,
    t0: Instant,
    /// The table was empty at power-on and nothing has filled it yet.
    empty_since_power_on: bool,
    /// The ADC input's current code and when it next changes.
    adc_step: u64,
}

impl Powered {
    fn on(rec: &Arc<Mutex<Record>>, first: bool) -> Self {
        let io = RecIo {
            mem: MemIo::default(),
            rec: rec.clone(),
        };
        let mut board: Box<HostBoard> = Box::new(Board::new(BoardHal::new(io), INFO));
        if first {
            for line in CONFIG {
                let mut out = TextOut::<1024>::new(false);
                let ok = board.run_line(line, 0, &mut out, &mut no_extra);
                assert!(ok, "the bench's configuration {line:?}: {}", out.as_str());
            }
        }
        {
            let mut r = lock(rec);
            r.power_ons += 1;
            r.plugged = true;
        }
        Self {
            empty_since_power_on: board.engine.is_empty(),
            board,
            server: LinkServer::new(),
            t0: Instant::now(),
            adc_step: 0,
        }
    }

    fn now_us(&self) -> u64 {
        self.t0.elapsed().as_micros() as u64
    }

    /// The ADC input: a new code every 50 ms (the analogue world moving).
    fn drive_adc(&mut self, now_us: u64) {
        let step = now_us / 50_000;
        if step != self.adc_step || now_us == 0 {
            self.adc_step = step;
            self.board.hal.io.mem.adc[0] = ((step * 397 + 1000) % 4096) as u16;
        }
    }

    fn note_values(&mut self, rec: &Mutex<Record>) {
        let now = monotonic_ns();
        let mut vals = [None; 4];
        for (i, name) in WATCHED.iter().enumerate() {
            vals[i] = self.board.engine.value_of(name).map(|v| v.to_f64());
        }
        let mut r = lock(rec);
        for (i, v) in vals.into_iter().enumerate() {
            if let Some(v) = v {
                r.note_value(i, v, now);
            }
        }
        if self.empty_since_power_on && !self.board.engine.is_empty() {
            self.empty_since_power_on = false;
            r.restores += 1;
        }
    }
}

fn no_extra(_: &str, _: &mut dyn core::fmt::Write) -> Option<bool> {
    None
}

/// Writes `frame` to the host through the wire's faults.
fn send(
    port: &mut Port,
    faults: &mut FaultInjector,
    rec: &Mutex<Record>,
    frame: &[u8],
    reply: bool,
) {
    let mut bytes = frame.to_vec();
    let (f, _) = faults.apply(&mut bytes);
    {
        let mut r = lock(rec);
        r.frames_out += 1;
        if f.damaged() {
            r.damaged_out += 1;
            r.damaged_replies += u64::from(reply);
        }
    }
    // A host that does not read (a gateway being restarted) must not stall the board: the
    // firmware's queue drops what does not fit, so does this after a short wait.
    let end = Instant::now() + Duration::from_millis(20);
    let mut rest = &bytes[..];
    while !rest.is_empty() && Instant::now() < end {
        match port.master.write(rest) {
            Ok(n) => rest = &rest[n..],
            Err(_) => std::thread::sleep(Duration::from_micros(200)),
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn serve(
    port: Port,
    link: &Path,
    rec: &Arc<Mutex<Record>>,
    plugged: &AtomicBool,
    stop: &AtomicBool,
    corrupt: f64,
    drop: f64,
    seed: u64,
) {
    let wire = |seed| {
        FaultInjector::new(FaultConfig {
            corrupt,
            drop,
            seed,
            ..FaultConfig::default()
        })
    };
    // SAFETY: gettid has no preconditions.
    lock(rec).tid = unsafe { libc::gettid() };
    let mut to_host = wire(seed);
    let mut to_board = wire(seed ^ 0x5C0E);
    let mut port = Some(port);
    let mut life = Some(Powered::on(rec, true));
    let mut out = FrameOut::<8192>::new();
    let mut buf = [0u8; 512];
    let mut frame = [0u8; MAX_FRAME];
    let mut stats_base = (0u64, 0u64);
    while !stop.load(Ordering::Relaxed) {
        let want = plugged.load(Ordering::Relaxed);
        if want && port.is_none() {
            match Port::open(link) {
                Ok(p) => {
                    port = Some(p);
                    life = Some(Powered::on(rec, false));
                }
                Err(e) => {
                    eprintln!("soak: score board: replug: {e}");
                    std::thread::sleep(Duration::from_millis(50));
                    continue;
                }
            }
        } else if !want && port.is_some() {
            // Power gone: the table, the outputs and the link with it.
            if let Some(l) = life.take() {
                let s = l.server.stats();
                stats_base.0 += s.bad_crc + s.bad_cobs + s.oversize;
                stats_base.1 += s.frames;
            }
            port = None;
            let mut r = lock(rec);
            r.plugged = false;
            r.duty = [(0.0, monotonic_ns()); 2];
        }
        let (Some(p), Some(l)) = (port.as_mut(), life.as_mut()) else {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        };
        // Read until the next deadline (at most 1 ms: plug requests are seen that often).
        let now = l.now_us();
        let wait_us = l
            .board
            .next_wake()
            .map_or(1000, |t| t.saturating_sub(now).min(1000));
        if wait_us > 0 {
            use serialport::SerialPort as _;
            let _ = p
                .master
                .set_timeout(Duration::from_micros(wait_us.max(100)));
        }
        let before = Instant::now();
        let n = p.master.read(&mut buf).unwrap_or(0);
        let over = before
            .elapsed()
            .saturating_sub(Duration::from_micros(wait_us) + Duration::from_millis(1));
        {
            let mut r = lock(rec);
            r.worst_lag_ns = r.worst_lag_ns.max(over.as_nanos() as u64);
            r.window_lag_ns = r.window_lag_ns.max(over.as_nanos() as u64);
        }
        if n > 0 {
            let mut bytes = buf[..n].to_vec();
            let (f, _) = to_board.apply(&mut bytes);
            if f.damaged() {
                lock(rec).damaged_in += 1;
            }
            out.clear();
            let now = l.now_us();
            l.server
                .feed(&bytes, &mut l.board, now, &mut out, &mut no_extra);
            for f in out.frames() {
                if f.len() > 3 {
                    send(p, &mut to_host, rec, f, true);
                }
            }
            count_hellos(&out, rec);
            l.note_values(rec);
        }
        // The engine task: tick, table changes, samples.
        let now = l.now_us();
        l.drive_adc(now);
        l.board.tick(now);
        l.note_values(rec);
        if let Some(generation) = l.board.take_table_change() {
            if let Ok(n) = encode_reply(0, &Reply::TableChanged { generation }, &mut frame) {
                send(p, &mut to_host, rec, &frame[..n], false);
            }
        }
        let lost = l.board.sampler.lost();
        let mut batches: Vec<Vec<u8>> = Vec::new();
        l.board.collect_samples(now, |t, samples| {
            if let Ok(n) = encode_reply(
                0,
                &Reply::Samples(SampleBatch::new(t, lost, samples)),
                &mut frame,
            ) {
                batches.push(frame[..n].to_vec());
            }
        });
        for b in batches {
            send(p, &mut to_host, rec, &b, false);
        }
        let s = l.server.stats();
        let mut r = lock(rec);
        r.rejected_in = stats_base.0 + s.bad_crc + s.bad_cobs + s.oversize;
        r.accepted_in = stats_base.1 + s.frames;
    }
}

/// Counts the `Hello` replies among the frames just answered (one per gateway handshake).
fn count_hellos<const O: usize>(out: &FrameOut<O>, rec: &Mutex<Record>) {
    use conductor_protocols::score_link::{decode_reply, FrameScanner};
    let mut n = 0;
    let mut sc = FrameScanner::<MAX_FRAME>::new();
    sc.feed(out.as_bytes(), |m| {
        if matches!(decode_reply(m), Ok((_, Reply::Hello(_)))) {
            n += 1;
        }
    });
    if n > 0 {
        lock(rec).hellos += n;
    }
}

/// The gateway table of deploy/score-board.toml with its port pointed at `link`.
pub fn manifest_section(root: &Path, link: &Path) -> std::io::Result<String> {
    let text = std::fs::read_to_string(root.join("deploy/score-board.toml"))?;
    let start = text
        .find("[gateways.")
        .ok_or_else(|| std::io::Error::other("deploy/score-board.toml has no gateway"))?;
    let mut out =
        String::from("\n# deploy/score-board.toml, its port pointed at the soak's board\n");
    for line in text[start..].lines() {
        if line.trim_start().starts_with("port ") || line.trim_start().starts_with("port=") {
            out.push_str(&format!("port = {:?}\n", link.display().to_string()));
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    Ok(out)
}

/// The gateway's `watchdog_ms` in deploy/score-board.toml.
pub fn watchdog_ns(root: &Path) -> std::io::Result<u64> {
    let text = std::fs::read_to_string(root.join("deploy/score-board.toml"))?;
    let v: toml::Value = toml::from_str(&text).map_err(std::io::Error::other)?;
    v.get("gateways")
        .and_then(|g| g.get(SUBSYSTEM))
        .and_then(|g| g.get("watchdog_ms"))
        .and_then(|w| w.as_integer())
        .map(|ms| ms as u64 * 1_000_000)
        .ok_or_else(|| std::io::Error::other("deploy/score-board.toml: no watchdog_ms"))
}

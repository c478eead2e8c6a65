//! One Score session on the host: the engine, the simulated board, the clock, and the
//! host-side commands (`script`, `load`, `save <file>`, `run`, `sim ...`).

use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use score_core::hal::AdcInput;
use score_core::{Engine, Num, Outcome};

use crate::board::{self, SimBoard};

/// How time passes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeMode {
    /// Time stands still between commands; `run s` executes every update due in the next `s`
    /// seconds as fast as the CPU allows. Deterministic: the same script gives the same logs.
    Simulated,
    /// The wall clock (monotonic); updates run when due.
    RealTime,
}

/// Why a host line failed.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The engine refused the command (the table is unchanged).
    #[error("{0}")]
    Score(#[from] score_core::Error),
    /// A file could not be read or written.
    #[error("{path}: {message}")]
    File {
        /// The path.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A line of a script failed; the lines before it have run. Shown as `path:line:column:`
    /// (the column of the token the message is about, as compilers do) or `path:line:`.
    #[error("{path}:{line}:{} {source}", column.map(|c| format!("{c}:")).unwrap_or_default())]
    Script {
        /// The script.
        path: String,
        /// 1-based line number.
        line: usize,
        /// 1-based column (in characters) of the token the error is about, if it has one.
        column: Option<usize>,
        /// The failure.
        source: Box<SessionError>,
    },
    /// `load` found an error in the file; nothing was changed.
    #[error("load: nothing changed: {0}")]
    Load(Box<SessionError>),
    /// A `sim` command was malformed.
    #[error("sim: {0}")]
    Sim(String),
    /// Scripts calling scripts too deeply (probably a loop).
    #[error("script: scripts nest more than {0} deep")]
    TooDeep(usize),
    /// A `run` was stopped by [`Session::set_interrupt`]'s flag (Ctrl-C in the `score` binary);
    /// every update before `at_s` has run, the clock stands at `at_s`.
    #[error("run: interrupted at t = {at_s:.6} s")]
    Interrupted {
        /// Session time when the run stopped, in seconds.
        at_s: f64,
    },
    /// The simulated clock (microseconds in a `u64`) cannot advance that far.
    #[error("run: {seconds} s from t = {now_s:.6} s would pass the end of the simulated clock ({end_s:.0} s)")]
    ClockEnd {
        /// The requested duration.
        seconds: f64,
        /// The clock now, in seconds.
        now_s: f64,
        /// The last instant the clock can hold, in seconds.
        end_s: f64,
    },
}

impl SessionError {
    /// The 1-based column of `line` (the line that failed) that the error is about: the
    /// engine's errors point at a token ([`score_core::Error::column`]).
    pub fn column(&self, line: &str) -> Option<usize> {
        match self {
            SessionError::Score(e) => e.column(line),
            _ => None,
        }
    }
}

/// The lines of a script file: a UTF-8 byte-order mark before the first is dropped.
fn script_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.strip_prefix('\u{feff}')
        .unwrap_or(text)
        .lines()
        .enumerate()
        .map(|(n, l)| (n + 1, l))
}

const MAX_SCRIPT_DEPTH: usize = 8;

/// The engine, its board and clock.
pub struct Session {
    engine: Engine<Num>,
    board: SimBoard,
    mode: TimeMode,
    start: Instant,
    sim_now: u64,
    depth: usize,
    interrupt: Option<Arc<AtomicBool>>,
    /// Print `$> line` before running each line of a script (transcript style).
    pub echo_scripts: bool,
}

impl Session {
    /// A session whose files are relative to `base`.
    pub fn new(mode: TimeMode, base: impl Into<PathBuf>) -> Self {
        Self {
            engine: Engine::new(),
            board: board::sim_board(base),
            mode,
            start: Instant::now(),
            sim_now: 0,
            depth: 0,
            interrupt: None,
            echo_scripts: false,
        }
    }

    /// A flag that stops a `run` in progress when it becomes true (the `score` binary sets it
    /// on SIGINT). The run ends with [`SessionError::Interrupted`] and clears the flag.
    pub fn set_interrupt(&mut self, flag: Arc<AtomicBool>) {
        self.interrupt = Some(flag);
    }

    fn interrupted(&self) -> bool {
        self.interrupt
            .as_ref()
            .is_some_and(|f| f.swap(false, Ordering::Relaxed))
    }

    /// The time mode.
    pub fn mode(&self) -> TimeMode {
        self.mode
    }

    /// The engine (for reading values in tests and tools).
    pub fn engine(&mut self) -> &mut Engine<Num> {
        &mut self.engine
    }

    /// The simulated board.
    pub fn board(&mut self) -> &mut SimBoard {
        &mut self.board
    }

    /// Current time in microseconds (simulated or since the session started).
    pub fn now_us(&self) -> u64 {
        match self.mode {
            TimeMode::Simulated => self.sim_now,
            TimeMode::RealTime => self.start.elapsed().as_micros() as u64,
        }
    }

    /// Real time: runs what is due now; returns the time until the next update.
    pub fn poll(&mut self) -> Option<Duration> {
        if self.mode != TimeMode::RealTime {
            return None;
        }
        let now = self.now_us();
        if self.engine.next_deadline().is_some_and(|d| d <= now) {
            self.engine.tick(now, &mut self.board);
        }
        self.engine
            .next_deadline()
            .map(|d| Duration::from_micros(d.saturating_sub(self.now_us())))
    }

    /// Advances time by `seconds` (checked as `run` checks it: a finite number from 0 to
    /// [`score_core::capacity::MAX_RUN_SECONDS`]): simulated, every update due before the end
    /// runs at its own instant; real time, the session waits and runs updates as they fall due.
    /// The interrupt flag ([`Session::set_interrupt`]) stops it early.
    pub fn advance(&mut self, seconds: f64) -> Result<(), SessionError> {
        if !(0.0..=score_core::capacity::MAX_RUN_SECONDS).contains(&seconds) {
            return Err(score_core::Error::Invalid {
                command: "run",
                token: score_core::error::Token::truncated(&seconds.to_string()),
                expected: score_core::RUN_EXPECTED,
            }
            .into());
        }
        let span = (seconds * 1e6).round() as u64;
        let result = match self.mode {
            TimeMode::Simulated => self.advance_simulated(seconds, span),
            TimeMode::RealTime => {
                let end = Instant::now() + Duration::from_micros(span);
                loop {
                    let wait = self.poll().unwrap_or(Duration::from_millis(10));
                    let left = end.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        break Ok(());
                    }
                    if self.interrupted() {
                        break Err(SessionError::Interrupted {
                            at_s: self.now_us() as f64 / 1e6,
                        });
                    }
                    std::thread::sleep(wait.min(left).min(Duration::from_millis(10)));
                }
            }
        };
        self.board.files.flush();
        result
    }

    fn advance_simulated(&mut self, seconds: f64, span: u64) -> Result<(), SessionError> {
        let end = self
            .sim_now
            .checked_add(span)
            .ok_or(SessionError::ClockEnd {
                seconds,
                now_s: self.sim_now as f64 / 1e6,
                end_s: u64::MAX as f64 / 1e6,
            })?;
        let mut ticks = 0u32;
        while let Some(t) = self.engine.next_deadline() {
            if t >= end {
                break;
            }
            self.sim_now = self.sim_now.max(t);
            self.engine.tick(t, &mut self.board);
            // An atomic load per 1024 instants: nothing next to an update.
            ticks = ticks.wrapping_add(1);
            if ticks.is_multiple_of(1024) && self.interrupted() {
                return Err(SessionError::Interrupted {
                    at_s: self.sim_now as f64 / 1e6,
                });
            }
        }
        self.sim_now = end;
        Ok(())
    }

    /// Runs one line (engine command or host command), writing its output to `out`.
    pub fn line(&mut self, line: &str, out: &mut String) -> Result<(), SessionError> {
        let mut words = line.split_whitespace();
        if words.next() == Some("sim") {
            return self.sim(words.collect::<Vec<_>>().as_slice(), out);
        }
        self.poll();
        self.engine.set_time(self.now_us());
        match self.engine.execute(line, &mut self.board, out)? {
            Outcome::Done => {}
            Outcome::Script(path) => self.script(path, out)?,
            Outcome::Load(path) => self.load(path, out)?,
            Outcome::Save(path) => {
                let mut text = String::new();
                let _ = self.engine.save(&mut text);
                let p = self.board.files.resolve(path);
                std::fs::write(&p, text).map_err(|e| SessionError::File {
                    path: p.display().to_string(),
                    message: e.to_string(),
                })?;
            }
            Outcome::Run(s) => self.advance(s)?,
        }
        Ok(())
    }

    fn read_script(&self, path: &str) -> Result<String, SessionError> {
        let p = self.board.files.resolve(path);
        std::fs::read_to_string(&p).map_err(|e| SessionError::File {
            path: p.display().to_string(),
            message: e.to_string(),
        })
    }

    /// `script <file>`: runs the file's lines; stops at the first failing line.
    pub fn script(&mut self, path: &str, out: &mut String) -> Result<(), SessionError> {
        if self.depth >= MAX_SCRIPT_DEPTH {
            return Err(SessionError::TooDeep(MAX_SCRIPT_DEPTH));
        }
        let text = self.read_script(path)?;
        self.depth += 1;
        let mut result = Ok(());
        for (n, l) in script_lines(&text) {
            if self.echo_scripts && !l.trim().is_empty() {
                let _ = writeln!(out, "{}{}", score_core::PROMPT, l.trim());
            }
            if let Err(e) = self.line(l, out) {
                result = Err(SessionError::Script {
                    path: path.to_string(),
                    line: n,
                    column: e.column(l),
                    source: Box::new(e),
                });
                break;
            }
        }
        self.depth -= 1;
        result
    }

    /// `load <file>`: checks the whole file against an empty table on a dry-run board first;
    /// only if every line passes is the table cleared and the file run for real.
    pub fn load(&mut self, path: &str, out: &mut String) -> Result<(), SessionError> {
        let text = self.read_script(path)?;
        let mut dry: Engine<Num> = Engine::new();
        let mut board = board::dry_run(&self.board);
        let mut sink = String::new();
        for (n, l) in script_lines(&text) {
            let fail = |e: SessionError| {
                SessionError::Load(Box::new(SessionError::Script {
                    path: path.to_string(),
                    line: n,
                    column: e.column(l),
                    source: Box::new(e),
                }))
            };
            match dry.execute(l, &mut board, &mut sink) {
                Ok(Outcome::Done) => {}
                Ok(_) => {
                    return Err(fail(SessionError::Sim(
                        "a loaded file holds definitions only (no script, load, save or run)"
                            .into(),
                    )))
                }
                Err(e) => return Err(fail(e.into())),
            }
        }
        self.engine.clear(&mut self.board);
        for (n, l) in script_lines(&text) {
            self.engine
                .execute(l, &mut self.board, out)
                .map_err(|e| SessionError::Script {
                    path: path.to_string(),
                    line: n,
                    column: e.column(l),
                    source: Box::new(e.into()),
                })?;
        }
        Ok(())
    }

    /// `sim ...`: the simulated board's controls.
    fn sim(&mut self, args: &[&str], out: &mut String) -> Result<(), SessionError> {
        let hw = &mut self.board.hw;
        match args {
            [] | ["show"] => {
                let names = ["0", "1", "2", "3", "A", "B", "T"];
                for (n, v) in names.iter().zip(hw.volts.iter()) {
                    let _ = writeln!(out, "adc {n}: {v:.4} V");
                }
                let _ = writeln!(out, "adc noise: +-{} counts", hw.noise_counts);
                for (i, p) in hw.pwm.iter().enumerate().filter(|(_, p)| p.on) {
                    let inv = if p.inverted { " (complementary)" } else { "" };
                    let _ = writeln!(out, "pwm {i}: {} Hz, duty {:.4} %{inv}", p.freq_hz, p.duty * 100.0);
                }
                let high: Vec<String> = (0..hw.pins.len()).filter(|&i| hw.pins[i]).map(|i| i.to_string()).collect();
                let _ = writeln!(out, "gpio high: {}", if high.is_empty() { "none".into() } else { high.join(" ") });
                let _ = writeln!(out, "time: {:.6} s ({:?})", self.now_us() as f64 / 1e6, self.mode);
            }
            ["adc", ch, v] => {
                let input = match *ch {
                    "A" | "a" => AdcInput::Differential(0),
                    "B" | "b" => AdcInput::Differential(1),
                    "T" | "t" => AdcInput::Temperature,
                    c => AdcInput::Single(c.parse().map_err(|_| SessionError::Sim(format!("'{c}' is not an ADC channel (0-3, A, B, T)")))?),
                };
                let volts: f32 = v.parse().ok().filter(|v: &f32| v.is_finite()).ok_or_else(|| SessionError::Sim(format!("'{v}' is not a voltage")))?;
                hw.set_volts(input, volts).map_err(|e| SessionError::Sim(format!("'{ch}': {e}")))?;
            }
            ["noise", n] => {
                hw.noise_counts = n.parse().map_err(|_| SessionError::Sim(format!("'{n}' is not a count (0-65535)")))?;
            }
            ["gpio", pin, level] => {
                let p: usize = pin.parse().ok().filter(|p| *p < hw.pins.len()).ok_or_else(|| SessionError::Sim(format!("'{pin}' is not a pin")))?;
                hw.pins[p] = match *level {
                    "1" | "high" => true,
                    "0" | "low" => false,
                    l => return Err(SessionError::Sim(format!("'{l}' is not 0 or 1"))),
                };
            }
            _ => {
                return Err(SessionError::Sim(
                    "usage: sim [show] | sim adc <0-3|A|B|T> <volts> | sim noise <counts> | sim gpio <pin> <0|1>".into(),
                ))
            }
        }
        Ok(())
    }
}

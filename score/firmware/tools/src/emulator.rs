//! The rp2040js harness from Rust: start it on the firmware ELF, wait for its two PTYs, and
//! talk to its JSON-lines control channel.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError};
use std::time::Duration;

use serde_json::{json, Value};

/// Wall time allowed for the emulator to boot and enumerate (a loaded CI machine is slow).
pub const START_TIMEOUT: Duration = Duration::from_secs(60);
/// Wall time allowed for one control request.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(30);

/// Something went wrong with the harness.
#[derive(Debug, thiserror::Error)]
pub enum EmuError {
    /// Firmware or harness not installed (the message says how to get them).
    #[error("{0}")]
    Missing(String),
    /// Node could not be started.
    #[error("cannot start node: {0}")]
    Spawn(std::io::Error),
    /// The harness exited or closed its stdout.
    #[error("the emulator harness exited: {0}")]
    Exited(String),
    /// No answer in time.
    #[error("the emulator harness did not answer within {0:?}")]
    Timeout(Duration),
    /// The harness refused a request.
    #[error("the emulator harness refused {request}: {error}")]
    Refused {
        /// The request.
        request: String,
        /// Its error.
        error: String,
    },
}

/// PWM measured at a pin from its edges over whole periods (emulated time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PwmMeasurement {
    /// High time over period (0 or 1 for a constant level).
    pub duty: f64,
    /// Mean period, ns (`None` for a constant level).
    pub period_ns: Option<f64>,
    /// Periods measured.
    pub periods: u64,
}

/// A running emulator. Dropping it kills the harness (and with it the PTYs).
pub struct Emulator {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<Value>,
    next_id: u64,
    /// PTY of the terminal (CDC 0).
    pub term: PathBuf,
    /// PTY of the binary link (CDC 1).
    pub link: PathBuf,
    /// Emulated milliseconds at which the device was ready.
    pub ready_ms: f64,
}

impl Emulator {
    /// Starts the harness on the firmware found by [`crate::paths::firmware_elf`], with the
    /// PTYs in a fresh temporary directory.
    pub fn start() -> Result<Self, EmuError> {
        let elf = crate::paths::firmware_elf().map_err(EmuError::Missing)?;
        Self::start_image(&elf)
    }

    /// Starts the harness on `image` (ELF or UF2), PTYs in a fresh temporary directory.
    pub fn start_image(image: &Path) -> Result<Self, EmuError> {
        let (term, link) = fresh_pty_paths()?;
        Self::start_with(image, &term, &link)
    }

    /// Starts the harness on the default firmware with the PTYs at the given paths (to
    /// restart "the same board" after [`Emulator::kill`]).
    pub fn start_at(term: &Path, link: &Path) -> Result<Self, EmuError> {
        let elf = crate::paths::firmware_elf().map_err(EmuError::Missing)?;
        Self::start_with(&elf, term, link)
    }

    /// Starts the harness on `image` with the PTYs at `term` and `link`.
    pub fn start_with(image: &Path, term: &Path, link: &Path) -> Result<Self, EmuError> {
        let elf = image.to_path_buf();
        let dir = crate::paths::harness_dir().map_err(EmuError::Missing)?;
        let mut child = Command::new("node")
            .arg(dir.join("harness.mjs"))
            .arg(&elf)
            .arg("--term")
            .arg(term)
            .arg("--link")
            .arg(link)
            .current_dir(&dir)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(EmuError::Spawn)?;
        let stdout = child.stdout.take().expect("piped");
        let (tx, rx) = channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if let Ok(v) = serde_json::from_str::<Value>(&line) {
                    if tx.send(v).is_err() {
                        break;
                    }
                }
            }
        });
        let mut emu = Emulator {
            stdin: child.stdin.take(),
            child,
            lines: rx,
            next_id: 1,
            term: term.to_path_buf(),
            link: link.to_path_buf(),
            ready_ms: 0.0,
        };
        loop {
            let v = emu.next_line(START_TIMEOUT)?;
            if v["event"] == "ready" {
                emu.ready_ms = v["emulated_ms"].as_f64().unwrap_or(0.0);
                return Ok(emu);
            }
        }
    }

    fn next_line(&mut self, wait: Duration) -> Result<Value, EmuError> {
        match self.lines.recv_timeout(wait) {
            Ok(v) => Ok(v),
            Err(RecvTimeoutError::Timeout) => Err(EmuError::Timeout(wait)),
            Err(RecvTimeoutError::Disconnected) => Err(EmuError::Exited(
                self.child
                    .try_wait()
                    .ok()
                    .flatten()
                    .map_or("stdout closed".into(), |s| s.to_string()),
            )),
        }
    }

    /// Sends a control request (an object with `cmd`) and returns the reply.
    pub fn request(&mut self, mut req: Value) -> Result<Value, EmuError> {
        let id = self.next_id;
        self.next_id += 1;
        req["id"] = json!(id);
        let text = req.to_string();
        let stdin = self
            .stdin
            .as_mut()
            .ok_or_else(|| EmuError::Exited("stdin closed".into()))?;
        writeln!(stdin, "{text}")
            .and_then(|_| stdin.flush())
            .map_err(|e| EmuError::Exited(e.to_string()))?;
        loop {
            let v = self.next_line(REQUEST_TIMEOUT)?;
            if v["id"] == json!(id) {
                if v["ok"] == json!(true) {
                    return Ok(v);
                }
                return Err(EmuError::Refused {
                    request: text,
                    error: v["error"].as_str().unwrap_or("?").into(),
                });
            }
        }
    }

    /// Puts `volts` on ADC channel `ch` (4 = temperature sensor); returns the 12-bit code the
    /// converter will read (`round(volts / 3.3 · 4095)`).
    pub fn set_adc_volts(&mut self, ch: u8, volts: f64) -> Result<u16, EmuError> {
        let r = self.request(json!({"cmd": "adc", "channel": ch, "volts": volts}))?;
        Ok(r["code"].as_u64().unwrap_or(0) as u16)
    }

    /// Like [`Emulator::set_adc_volts`], also returning the emulated time (ns) of the change.
    pub fn set_adc_volts_timed(&mut self, ch: u8, volts: f64) -> Result<(u16, f64), EmuError> {
        let r = self.request(json!({"cmd": "adc", "channel": ch, "volts": volts}))?;
        Ok((
            r["code"].as_u64().unwrap_or(0) as u16,
            r["nanos"].as_f64().unwrap_or(f64::NAN),
        ))
    }

    /// Sets the raw code ADC channel `ch` converts to.
    pub fn set_adc_code(&mut self, ch: u8, code: u16) -> Result<(), EmuError> {
        self.request(json!({"cmd": "adc", "channel": ch, "value": code}))
            .map(|_| ())
    }

    /// Measures the PWM duty at GPIO `pin` over `periods` whole periods.
    pub fn measure_pwm(&mut self, pin: u8, periods: u32) -> Result<PwmMeasurement, EmuError> {
        let r = self.request(json!({"cmd": "pwm", "pin": pin, "periods": periods}))?;
        Ok(PwmMeasurement {
            duty: r["duty"].as_f64().unwrap_or(f64::NAN),
            period_ns: r["period_ns"].as_f64(),
            periods: r["periods"].as_u64().unwrap_or(0),
        })
    }

    /// Raises (or drops) DTR on the terminal (`"term"`) or link (`"link"`) port, as a host
    /// does when a program opens the port.
    pub fn dtr(&mut self, port: &str, on: bool) -> Result<(), EmuError> {
        self.request(json!({"cmd": "dtr", "port": port, "on": on}))
            .map(|_| ())
    }

    /// Emulated time (ns) and CPU cycles executed.
    pub fn time(&mut self) -> Result<(f64, u64), EmuError> {
        let r = self.request(json!({"cmd": "time"}))?;
        Ok((
            r["nanos"].as_f64().unwrap_or(f64::NAN),
            r["cycles"].as_u64().unwrap_or(0),
        ))
    }

    /// Kills the emulator at once (like pulling the USB cable): the PTYs disappear.
    pub fn kill(&mut self) {
        self.stdin = None;
        let _ = self.child.kill();
        let _ = self.child.wait();
        // socat exits when its TCP peer goes and removes the PTY link; wait for that, so a
        // restart at the same path does not race with the old link.
        for _ in 0..250 {
            if !self.term.exists() && !self.link.exists() {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Two PTY paths in a new temporary directory.
pub fn fresh_pty_paths() -> Result<(PathBuf, PathBuf), EmuError> {
    let dir = std::env::temp_dir().join(format!("score-emu-{}-{}", std::process::id(), unique()));
    std::fs::create_dir_all(&dir).map_err(EmuError::Spawn)?;
    Ok((dir.join("term"), dir.join("link")))
}

fn unique() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    N.fetch_add(1, Ordering::Relaxed)
}

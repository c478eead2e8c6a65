//! The simulated board of the host port: ADC, PWM and GPIO in memory, and real files for
//! `infile` playback and `log` recording.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use score_core::hal::{Adc, AdcInput, Board, DataFiles, Gpio, HalError, Pwm, PwmOutput, StreamId};

/// Number of simulated single-ended ADC channels (thesis: 0-3).
pub const ADC_CHANNELS: u8 = 4;
/// Differential pairs (thesis: A, B).
pub const ADC_PAIRS: u8 = 2;
/// PWM outputs (pairs A-D).
pub const PWM_OUTPUTS: u8 = 8;
/// GPIO pins.
pub const GPIO_PINS: u8 = 32;

/// State of one simulated PWM output.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PwmState {
    /// Configured (running).
    pub on: bool,
    /// Frequency in Hz.
    pub freq_hz: f32,
    /// Duty fraction 0..=1.
    pub duty: f32,
    /// Output inverted (second output of a complementary pair).
    pub inverted: bool,
}

/// Simulated peripherals: a 10-bit, 3.0 V ADC like the thesis' Stellaris board, whose inputs
/// are voltages set by the user (`sim adc`) plus deterministic noise; PWM and GPIO records.
#[derive(Debug, Clone, PartialEq)]
pub struct SimHw {
    /// Voltage at each single-ended input, then the differential pairs, then the temperature
    /// sensor.
    pub volts: [f32; (ADC_CHANNELS + ADC_PAIRS + 1) as usize],
    /// Peak noise in ADC counts (uniform, from a fixed-seed generator: runs repeat exactly).
    pub noise_counts: u16,
    rng: u32,
    /// PWM outputs.
    pub pwm: [PwmState; PWM_OUTPUTS as usize],
    /// Pin levels (inputs as set by `sim gpio`, outputs as driven).
    pub pins: [bool; GPIO_PINS as usize],
    /// Pin directions (true = output).
    pub pin_output: [bool; GPIO_PINS as usize],
}

impl Default for SimHw {
    fn default() -> Self {
        Self {
            // A resistor ladder like the thesis' Fig. 5.1 session; pair A near 0 V.
            volts: [0.97, 2.68, 1.83, 0.98, 0.06, 0.0, 0.7],
            noise_counts: 2,
            rng: 0x5C0E_2011,
            pwm: [PwmState::default(); PWM_OUTPUTS as usize],
            pins: [false; GPIO_PINS as usize],
            pin_output: [false; GPIO_PINS as usize],
        }
    }
}

const FULL_SCALE: u16 = 1023;
const VREF: f32 = 3.0;

impl SimHw {
    fn index(input: AdcInput) -> Option<usize> {
        match input {
            AdcInput::Single(n) if n < ADC_CHANNELS => Some(n as usize),
            AdcInput::Differential(k) if k < ADC_PAIRS => Some((ADC_CHANNELS + k) as usize),
            AdcInput::Temperature => Some((ADC_CHANNELS + ADC_PAIRS) as usize),
            _ => None,
        }
    }

    /// Sets the voltage seen by `input`.
    pub fn set_volts(&mut self, input: AdcInput, v: f32) -> Result<(), HalError> {
        let i = Self::index(input).ok_or(HalError::NoSuchChannel)?;
        self.volts[i] = v;
        Ok(())
    }

    fn noise(&mut self) -> i32 {
        // xorshift32: small, deterministic.
        let mut x = self.rng;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.rng = x;
        let span = 2 * self.noise_counts as u32 + 1;
        (x % span) as i32 - self.noise_counts as i32
    }

    fn outputs(out: PwmOutput) -> Option<(usize, Option<usize>)> {
        match out {
            PwmOutput::Single(n) if n < PWM_OUTPUTS => Some((n as usize, None)),
            PwmOutput::Complementary(k) if 2 * k + 1 < PWM_OUTPUTS => {
                Some((2 * k as usize, Some(2 * k as usize + 1)))
            }
            _ => None,
        }
    }
}

impl Adc for SimHw {
    fn adc_channels(&self) -> u8 {
        ADC_CHANNELS
    }
    fn adc_differential_pairs(&self) -> u8 {
        ADC_PAIRS
    }
    fn adc_has_temperature(&self) -> bool {
        true
    }
    fn adc_full_scale(&self) -> u16 {
        FULL_SCALE
    }
    fn adc_reference_volts(&self) -> f32 {
        VREF
    }
    fn adc_configure(&mut self, input: AdcInput, _rate_hz: f32) -> Result<(), HalError> {
        Self::index(input)
            .map(|_| ())
            .ok_or(HalError::NoSuchChannel)
    }
    fn adc_release(&mut self, _: AdcInput) {}
    fn adc_read(&mut self, input: AdcInput) -> Result<u16, HalError> {
        let i = Self::index(input).ok_or(HalError::NoSuchChannel)?;
        let v = match input {
            AdcInput::Differential(_) => self.volts[i] + VREF / 2.0,
            _ => self.volts[i],
        };
        let code = (v / VREF * FULL_SCALE as f32).round() as i32 + self.noise();
        Ok(code.clamp(0, FULL_SCALE as i32) as u16)
    }
}

impl Pwm for SimHw {
    fn pwm_outputs(&self) -> u8 {
        PWM_OUTPUTS
    }
    fn pwm_configure(&mut self, out: PwmOutput, freq_hz: f32) -> Result<f32, HalError> {
        let (a, b) = Self::outputs(out).ok_or(HalError::NoSuchChannel)?;
        if !(1.0..=1e8).contains(&freq_hz) {
            return Err(HalError::OutOfRange);
        }
        // Outputs 2k and 2k+1 share a timer: the sibling follows the new frequency.
        for i in [Some(a), b].into_iter().flatten() {
            let sibling = i ^ 1;
            self.pwm[sibling].freq_hz = freq_hz;
            self.pwm[i] = PwmState {
                on: true,
                freq_hz,
                duty: 0.0,
                inverted: Some(i) == b,
            };
        }
        Ok(freq_hz)
    }
    fn pwm_set_duty(&mut self, out: PwmOutput, duty: f32) -> f32 {
        let Some((a, b)) = Self::outputs(out) else {
            return 0.0;
        };
        let duty = duty.clamp(0.0, 1.0);
        self.pwm[a].duty = duty;
        if let Some(b) = b {
            self.pwm[b].duty = 1.0 - duty;
        }
        duty
    }
    fn pwm_release(&mut self, out: PwmOutput) {
        if let Some((a, b)) = Self::outputs(out) {
            for i in [Some(a), b].into_iter().flatten() {
                self.pwm[i].on = false;
                self.pwm[i].duty = 0.0;
            }
        }
    }
}

impl Gpio for SimHw {
    fn gpio_pins(&self) -> u8 {
        GPIO_PINS
    }
    fn gpio_configure(&mut self, pin: u8, output: bool) -> Result<(), HalError> {
        let p = self
            .pin_output
            .get_mut(pin as usize)
            .ok_or(HalError::NoSuchChannel)?;
        *p = output;
        Ok(())
    }
    fn gpio_read(&mut self, pin: u8) -> bool {
        self.pins.get(pin as usize).copied().unwrap_or(false)
    }
    fn gpio_write(&mut self, pin: u8, high: bool) {
        if let Some(p) = self.pins.get_mut(pin as usize) {
            *p = high;
        }
    }
    fn gpio_release(&mut self, pin: u8) {
        if let Some(p) = self.pin_output.get_mut(pin as usize) {
            *p = false;
        }
    }
}

enum Slot {
    Input(Vec<f64>),
    Log(Log),
}

/// An open log: its writer, and what the non-finite warning needs.
struct Log {
    w: BufWriter<File>,
    path: PathBuf,
    lines: u64,
    warned: bool,
}

/// `infile`/`log` files, relative to a base directory. Playback files are read whole at `infile`
/// (the thesis caches them); logs are buffered and flushed by [`Files::flush`] and on close.
pub struct Files {
    base: PathBuf,
    slots: Vec<Option<Slot>>,
    /// If set, logs are only checked (directory exists), not created: for dry runs.
    dry: bool,
}

impl Files {
    /// Files relative to `base`.
    pub fn new(base: impl Into<PathBuf>) -> Self {
        Self {
            base: base.into(),
            slots: Vec::new(),
            dry: false,
        }
    }

    /// A copy that opens playback files for checking and never creates logs.
    pub fn dry_run(&self) -> Self {
        Self {
            base: self.base.clone(),
            slots: Vec::new(),
            dry: true,
        }
    }

    /// The base directory.
    pub fn base(&self) -> &Path {
        &self.base
    }

    /// Resolves `path` against the base directory.
    pub fn resolve(&self, path: &str) -> PathBuf {
        self.base.join(path)
    }

    /// Flushes every open log.
    pub fn flush(&mut self) {
        for s in self.slots.iter_mut().flatten() {
            if let Slot::Log(log) = s {
                let _ = log.w.flush();
            }
        }
    }

    fn insert(&mut self, slot: Slot) -> Result<StreamId, HalError> {
        let i = match self.slots.iter().position(Option::is_none) {
            Some(i) => i,
            None if self.slots.len() < u8::MAX as usize => {
                self.slots.push(None);
                self.slots.len() - 1
            }
            None => return Err(HalError::Exhausted),
        };
        self.slots[i] = Some(slot);
        Ok(StreamId(i as u8))
    }

    /// Parses a playback file: one number per line; blank lines are skipped. A log's
    /// non-finite values (`NaN`, `inf`, `-inf`) read back as themselves, so a log plays back
    /// exactly what was recorded.
    pub fn read_numbers(path: &Path) -> Result<Vec<f64>, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let mut data = Vec::new();
        for (n, line) in text.lines().enumerate() {
            let t = line.trim();
            if t.is_empty() {
                continue;
            }
            match t.parse::<f64>() {
                Ok(v) => data.push(v),
                Err(_) => {
                    return Err(format!(
                        "{}:{}: '{t}' is not a number",
                        path.display(),
                        n + 1
                    ))
                }
            }
        }
        Ok(data)
    }
}

impl DataFiles for Files {
    fn open_input(&mut self, path: &str) -> Result<StreamId, HalError> {
        let data = Self::read_numbers(&self.resolve(path)).map_err(|e| {
            eprintln!("infile: {e}");
            HalError::Io
        })?;
        self.insert(Slot::Input(data))
    }
    fn input_len(&self, id: StreamId) -> u32 {
        match self.slots.get(id.0 as usize) {
            Some(Some(Slot::Input(d))) => d.len().min(u32::MAX as usize) as u32,
            _ => 0,
        }
    }
    fn input_sample(&self, id: StreamId, index: u32) -> f64 {
        match self.slots.get(id.0 as usize) {
            Some(Some(Slot::Input(d))) => d.get(index as usize).copied().unwrap_or(0.0),
            _ => 0.0,
        }
    }
    fn open_log(&mut self, path: &str) -> Result<StreamId, HalError> {
        let p = self.resolve(path);
        if self.dry {
            let dir = p
                .parent()
                .filter(|d| !d.as_os_str().is_empty())
                .unwrap_or(Path::new("."));
            return if dir.is_dir() {
                self.insert(Slot::Input(Vec::new()))
            } else {
                Err(HalError::Io)
            };
        }
        let f = File::create(&p).map_err(|e| {
            eprintln!("log: {}: {e}", p.display());
            HalError::Io
        })?;
        self.insert(Slot::Log(Log {
            w: BufWriter::new(f),
            path: p,
            lines: 0,
            warned: false,
        }))
    }
    /// Writes one value; the first non-finite one of each log is also reported on stderr (with
    /// the log's line), since it usually means a division by zero or an overflow upstream.
    fn write_log(&mut self, id: StreamId, text: &str) {
        if let Some(Some(Slot::Log(log))) = self.slots.get_mut(id.0 as usize) {
            let _ = writeln!(log.w, "{text}");
            log.lines += 1;
            // The three texts Display gives non-finite numbers.
            if !log.warned && matches!(text, "NaN" | "inf" | "-inf") {
                log.warned = true;
                eprintln!(
                    "warning: log: {}:{}: the value is {text} (not finite; a division by zero or \
                     an overflow upstream?); infile plays it back as {text}",
                    log.path.display(),
                    log.lines
                );
            }
        }
    }
    fn close(&mut self, id: StreamId) {
        if let Some(slot) = self.slots.get_mut(id.0 as usize) {
            if let Some(Slot::Log(mut log)) = slot.take() {
                let _ = log.w.flush();
            }
        }
    }
}

/// Logs are flushed when the files go (with the session), as on `close`.
impl Drop for Files {
    fn drop(&mut self) {
        self.flush();
    }
}

/// The host's board: simulated peripherals ([`SimHw`], the `hw` field) beside real files
/// ([`Files`], the `files` field).
pub type SimBoard = Board<SimHw, Files>;

/// A board with the default simulated peripherals whose files are relative to `base`.
pub fn sim_board(base: impl Into<PathBuf>) -> SimBoard {
    Board::new(SimHw::default(), Files::new(base))
}

/// A copy of `board` for dry runs: the same peripherals, files only checked.
pub fn dry_run(board: &SimBoard) -> SimBoard {
    Board::new(board.hw.clone(), board.files.dry_run())
}

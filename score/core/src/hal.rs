//! Hardware abstraction: what the engine needs from a board, with no Linux or Embassy types.
//!
//! The engine never owns the hardware: every call that may touch it (`execute`, `tick`, `set`)
//! takes `&mut impl Hal`. A port implements [`Adc`], [`Pwm`], [`Gpio`] and [`DataFiles`] for one
//! struct and gets [`Hal`] for free. [`Clock`] and [`Serial`] are used by the port's main loop
//! (see [`crate::line::LineBuffer`]); the engine itself is given the time in every `tick`.

use core::fmt;

/// Which analogue input an ADC symbol samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdcInput {
    /// Single-ended channel `n` (the thesis' `0`-`3`): volts = raw x vref / full_scale.
    Single(u8),
    /// Differential pair `n` (`A` = 0, `B` = 1). The HAL returns an offset-binary code
    /// (mid-scale = no difference): volts = raw x vref / full_scale - vref / 2.
    Differential(u8),
    /// The on-chip temperature sensor (`T`), read like a single-ended channel.
    Temperature,
}

/// Which PWM output a PWM symbol drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PwmOutput {
    /// Output `n`. Outputs `2k` and `2k+1` share a timer (the thesis' pair `k`), so they share
    /// a frequency on most chips.
    Single(u8),
    /// Complementary pair `k` (`A` = 0, `B` = 1): outputs `2k` (duty) and `2k+1` (inverted).
    Complementary(u8),
}

impl PwmOutput {
    /// True if both drive at least one common pin.
    pub fn overlaps(self, other: PwmOutput) -> bool {
        let pins = |o: PwmOutput| match o {
            PwmOutput::Single(n) => (n as u16, n as u16),
            PwmOutput::Complementary(k) => (2 * k as u16, 2 * k as u16 + 1),
        };
        let (a0, a1) = pins(self);
        let (b0, b1) = pins(other);
        a0 <= b1 && b0 <= a1
    }
}

/// Handle of an `infile`/`log` stream opened by [`DataFiles`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamId(pub u8);

/// Why the hardware refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HalError {
    /// The port has no such channel/pin.
    NoSuchChannel,
    /// The port cannot do this at all (e.g. files on the firmware).
    Unsupported,
    /// The requested value cannot be produced (e.g. a PWM frequency out of the timer's range).
    OutOfRange,
    /// A file could not be opened, read or parsed.
    Io,
    /// No free handle/resource.
    Exhausted,
}

impl fmt::Display for HalError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            HalError::NoSuchChannel => "no such channel on this board",
            HalError::Unsupported => "not supported on this port",
            HalError::OutOfRange => "value out of the hardware's range",
            HalError::Io => "file could not be opened, read or parsed",
            HalError::Exhausted => "no free hardware resource",
        })
    }
}

/// A monotonic microsecond clock.
pub trait Clock {
    /// Microseconds since an arbitrary epoch; never decreases.
    fn now_us(&self) -> u64;
}

/// The analogue-to-digital converter.
pub trait Adc {
    /// Number of single-ended channels (`0..channels`).
    fn adc_channels(&self) -> u8;
    /// Number of differential pairs (`A`, `B`, ...).
    fn adc_differential_pairs(&self) -> u8;
    /// Whether [`AdcInput::Temperature`] exists.
    fn adc_has_temperature(&self) -> bool;
    /// Largest raw code (1023 for 10 bits, 4095 for 12 bits).
    fn adc_full_scale(&self) -> u16;
    /// Voltage that the full-scale code represents.
    fn adc_reference_volts(&self) -> f32;
    /// Prepares `input` for sampling at about `rate_hz` (the engine triggers every read itself).
    fn adc_configure(&mut self, input: AdcInput, rate_hz: f32) -> Result<(), HalError>;
    /// `input` is no longer sampled.
    fn adc_release(&mut self, input: AdcInput);
    /// One conversion: a raw code in `0..=adc_full_scale()`.
    fn adc_read(&mut self, input: AdcInput) -> Result<u16, HalError>;
}

/// The PWM generators.
pub trait Pwm {
    /// Number of single outputs; complementary pairs are `0..pwm_outputs()/2`.
    fn pwm_outputs(&self) -> u8;
    /// Starts `out` at `freq_hz` (duty 0); returns the frequency actually produced.
    fn pwm_configure(&mut self, out: PwmOutput, freq_hz: f32) -> Result<f32, HalError>;
    /// Sets the duty cycle as a fraction in `0..=1`; returns the fraction actually produced
    /// (after quantisation to the timer's resolution).
    fn pwm_set_duty(&mut self, out: PwmOutput, duty: f32) -> f32;
    /// Stops `out` (output low).
    fn pwm_release(&mut self, out: PwmOutput);
}

/// General-purpose digital pins.
pub trait Gpio {
    /// Number of pins (`0..gpio_pins()`).
    fn gpio_pins(&self) -> u8;
    /// Makes `pin` an input (`output == false`) or a push-pull output.
    fn gpio_configure(&mut self, pin: u8, output: bool) -> Result<(), HalError>;
    /// Reads an input pin.
    fn gpio_read(&mut self, pin: u8) -> bool;
    /// Drives an output pin.
    fn gpio_write(&mut self, pin: u8, high: bool);
    /// Returns `pin` to its reset state.
    fn gpio_release(&mut self, pin: u8);
}

/// Files for `infile` playback and `log` recording (the thesis' x86-port features). The default
/// methods say "unsupported", which is right for the firmware.
pub trait DataFiles {
    /// Loads a playback file (one number per line) and returns its handle.
    fn open_input(&mut self, _path: &str) -> Result<StreamId, HalError> {
        Err(HalError::Unsupported)
    }
    /// Number of samples in an open playback file (at least 1).
    fn input_len(&self, _id: StreamId) -> u32 {
        0
    }
    /// Sample `index` (`< input_len`) of a playback file.
    fn input_sample(&self, _id: StreamId, _index: u32) -> f64 {
        0.0
    }
    /// Creates (truncates) a log file and returns its handle.
    fn open_log(&mut self, _path: &str) -> Result<StreamId, HalError> {
        Err(HalError::Unsupported)
    }
    /// Appends one line (`text` has no newline) to a log file.
    fn write_log(&mut self, _id: StreamId, _text: &str) {}
    /// Closes a stream (flushing a log).
    fn close(&mut self, _id: StreamId) {}
}

/// A byte-oriented terminal link (UART, USB CDC).
pub trait Serial {
    /// Next received byte, if any (never blocks).
    fn read_byte(&mut self) -> Option<u8>;
    /// Queues bytes for sending; returns how many were accepted.
    fn write_bytes(&mut self, bytes: &[u8]) -> usize;
}

/// Everything the engine touches; blanket-implemented.
pub trait Hal: Adc + Pwm + Gpio + DataFiles {}
impl<T: Adc + Pwm + Gpio + DataFiles> Hal for T {}

/// A board put together from two parts: peripherals `P` (its [`Adc`], [`Pwm`] and [`Gpio`]) and
/// a file store `F` (its [`DataFiles`]), so a port or a test that keeps them apart (simulated
/// peripherals beside real files, a dummy board beside in-memory files) gets [`Hal`] without
/// forwarding every method itself.
///
/// ```
/// use score_core::hal::{Board, DummyHal, PlaybackHal};
/// use score_core::Engine;
/// // The dummy's ADC (reading code 1023 of 1023 at 3.0 V) beside a played-back signal.
/// let dummy = DummyHal { adc_code: 1023, ..DummyHal::default() };
/// let mut hal = Board::new(dummy, PlaybackHal::new([0.25]));
/// let mut score: Engine<f64> = Engine::new();
/// let mut out = String::new();
/// for line in ["adc 0 100", "infile e 100 e.txt", "defexp sum adc0 e +"] {
///     score.execute(line, &mut hal, &mut out).unwrap();
/// }
/// assert_eq!(score.value_of("sum"), Some(3.0 + 0.25));
/// ```
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Board<P, F> {
    /// ADC, PWM and GPIO.
    pub hw: P,
    /// `infile` and `log`.
    pub files: F,
}

impl<P, F> Board<P, F> {
    /// `hw` with `files`.
    pub const fn new(hw: P, files: F) -> Self {
        Self { hw, files }
    }
}

impl<P: Adc, F> Adc for Board<P, F> {
    fn adc_channels(&self) -> u8 {
        self.hw.adc_channels()
    }
    fn adc_differential_pairs(&self) -> u8 {
        self.hw.adc_differential_pairs()
    }
    fn adc_has_temperature(&self) -> bool {
        self.hw.adc_has_temperature()
    }
    fn adc_full_scale(&self) -> u16 {
        self.hw.adc_full_scale()
    }
    fn adc_reference_volts(&self) -> f32 {
        self.hw.adc_reference_volts()
    }
    fn adc_configure(&mut self, input: AdcInput, rate_hz: f32) -> Result<(), HalError> {
        self.hw.adc_configure(input, rate_hz)
    }
    fn adc_release(&mut self, input: AdcInput) {
        self.hw.adc_release(input)
    }
    fn adc_read(&mut self, input: AdcInput) -> Result<u16, HalError> {
        self.hw.adc_read(input)
    }
}

impl<P: Pwm, F> Pwm for Board<P, F> {
    fn pwm_outputs(&self) -> u8 {
        self.hw.pwm_outputs()
    }
    fn pwm_configure(&mut self, out: PwmOutput, freq_hz: f32) -> Result<f32, HalError> {
        self.hw.pwm_configure(out, freq_hz)
    }
    fn pwm_set_duty(&mut self, out: PwmOutput, duty: f32) -> f32 {
        self.hw.pwm_set_duty(out, duty)
    }
    fn pwm_release(&mut self, out: PwmOutput) {
        self.hw.pwm_release(out)
    }
}

impl<P: Gpio, F> Gpio for Board<P, F> {
    fn gpio_pins(&self) -> u8 {
        self.hw.gpio_pins()
    }
    fn gpio_configure(&mut self, pin: u8, output: bool) -> Result<(), HalError> {
        self.hw.gpio_configure(pin, output)
    }
    fn gpio_read(&mut self, pin: u8) -> bool {
        self.hw.gpio_read(pin)
    }
    fn gpio_write(&mut self, pin: u8, high: bool) {
        self.hw.gpio_write(pin, high)
    }
    fn gpio_release(&mut self, pin: u8) {
        self.hw.gpio_release(pin)
    }
}

impl<P, F: DataFiles> DataFiles for Board<P, F> {
    fn open_input(&mut self, path: &str) -> Result<StreamId, HalError> {
        self.files.open_input(path)
    }
    fn input_len(&self, id: StreamId) -> u32 {
        self.files.input_len(id)
    }
    fn input_sample(&self, id: StreamId, index: u32) -> f64 {
        self.files.input_sample(id, index)
    }
    fn open_log(&mut self, path: &str) -> Result<StreamId, HalError> {
        self.files.open_log(path)
    }
    fn write_log(&mut self, id: StreamId, text: &str) {
        self.files.write_log(id, text)
    }
    fn close(&mut self, id: StreamId) {
        self.files.close(id)
    }
}

/// A board that accepts every configuration and reads a fixed code: for tests, fuzzing and docs.
/// Four single-ended channels, two differential pairs, a temperature sensor (10-bit, 3.0 V like
/// the thesis' board), eight PWM outputs, eight pins, no files. Every ADC read returns
/// [`adc_code`](Self::adc_code) (mid-scale, 512, by default) and every input pin reads
/// [`pin_level`](Self::pin_level) (low by default).
#[derive(Debug, Clone, PartialEq)]
pub struct DummyHal {
    /// Last duty fraction set per output (single outputs; pairs write their first output).
    pub duty: [f32; 8],
    /// The code every ADC conversion returns.
    pub adc_code: u16,
    /// The level every input pin reads.
    pub pin_level: bool,
}

impl Default for DummyHal {
    fn default() -> Self {
        Self {
            duty: [0.0; 8],
            adc_code: 512,
            pin_level: false,
        }
    }
}

impl Adc for DummyHal {
    fn adc_channels(&self) -> u8 {
        4
    }
    fn adc_differential_pairs(&self) -> u8 {
        2
    }
    fn adc_has_temperature(&self) -> bool {
        true
    }
    fn adc_full_scale(&self) -> u16 {
        1023
    }
    fn adc_reference_volts(&self) -> f32 {
        3.0
    }
    fn adc_configure(&mut self, _: AdcInput, _: f32) -> Result<(), HalError> {
        Ok(())
    }
    fn adc_release(&mut self, _: AdcInput) {}
    fn adc_read(&mut self, _: AdcInput) -> Result<u16, HalError> {
        Ok(self.adc_code)
    }
}

impl Pwm for DummyHal {
    fn pwm_outputs(&self) -> u8 {
        8
    }
    fn pwm_configure(&mut self, _: PwmOutput, freq_hz: f32) -> Result<f32, HalError> {
        Ok(freq_hz)
    }
    fn pwm_set_duty(&mut self, out: PwmOutput, duty: f32) -> f32 {
        let i = match out {
            PwmOutput::Single(n) => n as usize,
            PwmOutput::Complementary(k) => 2 * k as usize,
        };
        if let Some(d) = self.duty.get_mut(i) {
            *d = duty;
        }
        duty
    }
    fn pwm_release(&mut self, _: PwmOutput) {}
}

impl Gpio for DummyHal {
    fn gpio_pins(&self) -> u8 {
        8
    }
    fn gpio_configure(&mut self, _: u8, _: bool) -> Result<(), HalError> {
        Ok(())
    }
    fn gpio_read(&mut self, _: u8) -> bool {
        self.pin_level
    }
    fn gpio_write(&mut self, _: u8, _: bool) {}
    fn gpio_release(&mut self, _: u8) {}
}

impl DataFiles for DummyHal {}

/// A board with no peripherals that plays one in-memory signal through `infile`: whatever the
/// file name, `infile` opens [`signal`](Self::signal) (the engine loops it, one sample per
/// update). No ADC inputs, PWM outputs or pins (configuring one is refused with
/// [`HalError::NoSuchChannel`]); `log` is unsupported. For benchmarks and tests of algorithms
/// fed by a recorded signal, such as the thesis' Fig. 5.20 PID ([`crate::FIG_5_20_PID`]), on the
/// host and in the firmware alike: `S` is anything that lends a `[f64]` (an array, a slice, a
/// `Vec`), so no heap is needed.
///
/// ```
/// use score_core::{hal::PlaybackHal, Engine};
/// let mut hal = PlaybackHal::new([0.5, -0.25]);
/// let mut score: Engine<f64> = Engine::new();
/// let mut out = String::new();
/// score.execute("infile e 1000 any-name", &mut hal, &mut out).unwrap();
/// let seen: Vec<f64> = (0..4u64)
///     .map(|k| {
///         score.tick(k * 1000, &mut hal);
///         score.value_of("e").unwrap()
///     })
///     .collect();
/// assert_eq!(seen, [0.5, -0.25, 0.5, -0.25]);
/// assert!(score.execute("adc 0 100", &mut hal, &mut out).is_err());
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct PlaybackHal<S> {
    /// The samples `infile` plays, in order.
    pub signal: S,
}

impl<S: AsRef<[f64]>> PlaybackHal<S> {
    /// A board playing `signal`.
    pub const fn new(signal: S) -> Self {
        Self { signal }
    }
}

/// No inputs; the converter's scale is a nominal 12-bit, 3.3 V one.
impl<S> Adc for PlaybackHal<S> {
    fn adc_channels(&self) -> u8 {
        0
    }
    fn adc_differential_pairs(&self) -> u8 {
        0
    }
    fn adc_has_temperature(&self) -> bool {
        false
    }
    fn adc_full_scale(&self) -> u16 {
        4095
    }
    fn adc_reference_volts(&self) -> f32 {
        3.3
    }
    fn adc_configure(&mut self, _: AdcInput, _: f32) -> Result<(), HalError> {
        Err(HalError::NoSuchChannel)
    }
    fn adc_release(&mut self, _: AdcInput) {}
    fn adc_read(&mut self, _: AdcInput) -> Result<u16, HalError> {
        Err(HalError::NoSuchChannel)
    }
}

impl<S> Pwm for PlaybackHal<S> {
    fn pwm_outputs(&self) -> u8 {
        0
    }
    fn pwm_configure(&mut self, _: PwmOutput, _: f32) -> Result<f32, HalError> {
        Err(HalError::NoSuchChannel)
    }
    fn pwm_set_duty(&mut self, _: PwmOutput, duty: f32) -> f32 {
        duty
    }
    fn pwm_release(&mut self, _: PwmOutput) {}
}

impl<S> Gpio for PlaybackHal<S> {
    fn gpio_pins(&self) -> u8 {
        0
    }
    fn gpio_configure(&mut self, _: u8, _: bool) -> Result<(), HalError> {
        Err(HalError::NoSuchChannel)
    }
    fn gpio_read(&mut self, _: u8) -> bool {
        false
    }
    fn gpio_write(&mut self, _: u8, _: bool) {}
    fn gpio_release(&mut self, _: u8) {}
}

impl<S: AsRef<[f64]>> DataFiles for PlaybackHal<S> {
    fn open_input(&mut self, _path: &str) -> Result<StreamId, HalError> {
        Ok(StreamId(0))
    }
    fn input_len(&self, _: StreamId) -> u32 {
        self.signal.as_ref().len().min(u32::MAX as usize) as u32
    }
    fn input_sample(&self, _: StreamId, index: u32) -> f64 {
        self.signal
            .as_ref()
            .get(index as usize)
            .copied()
            .unwrap_or(0.0)
    }
}

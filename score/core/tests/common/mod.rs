//! Test board: the dummy HAL's peripherals plus in-memory playback and log files.
#![allow(dead_code)]

use score_core::hal::*;
use score_core::{Engine, Num, Outcome};

/// [`DummyHal`]'s peripherals (reading ADC code 0 and high pins unless told otherwise) with
/// named in-memory playback inputs and logs.
pub struct MemBoard {
    pub hw: DummyHal,
    pub inputs: Vec<(String, Vec<f64>)>,
    pub open: Vec<Option<usize>>,
    pub logs: Vec<(String, Vec<String>)>,
    pub log_open: Vec<Option<usize>>,
}

impl Default for MemBoard {
    fn default() -> Self {
        Self {
            hw: DummyHal {
                adc_code: 0,
                pin_level: true,
                ..DummyHal::default()
            },
            inputs: Vec::new(),
            open: Vec::new(),
            logs: Vec::new(),
            log_open: Vec::new(),
        }
    }
}

impl MemBoard {
    /// Every ADC conversion returns `code`.
    pub fn with_adc_code(mut self, code: u16) -> Self {
        self.hw.adc_code = code;
        self
    }
    pub fn with_input(mut self, path: &str, data: Vec<f64>) -> Self {
        self.inputs.push((path.into(), data));
        self
    }
    pub fn log(&self, path: &str) -> Vec<f64> {
        let (_, lines) = self
            .logs
            .iter()
            .rev()
            .find(|(p, _)| p == path)
            .expect("log exists");
        lines.iter().map(|l| l.parse().expect("number")).collect()
    }
}

impl Adc for MemBoard {
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
    fn adc_configure(&mut self, i: AdcInput, rate_hz: f32) -> Result<(), HalError> {
        self.hw.adc_configure(i, rate_hz)
    }
    fn adc_release(&mut self, i: AdcInput) {
        self.hw.adc_release(i)
    }
    fn adc_read(&mut self, i: AdcInput) -> Result<u16, HalError> {
        self.hw.adc_read(i)
    }
}

impl Pwm for MemBoard {
    fn pwm_outputs(&self) -> u8 {
        self.hw.pwm_outputs()
    }
    fn pwm_configure(&mut self, o: PwmOutput, f: f32) -> Result<f32, HalError> {
        self.hw.pwm_configure(o, f)
    }
    fn pwm_set_duty(&mut self, o: PwmOutput, d: f32) -> f32 {
        self.hw.pwm_set_duty(o, d)
    }
    fn pwm_release(&mut self, o: PwmOutput) {
        self.hw.pwm_release(o)
    }
}

impl Gpio for MemBoard {
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

impl DataFiles for MemBoard {
    fn open_input(&mut self, path: &str) -> Result<StreamId, HalError> {
        let i = self
            .inputs
            .iter()
            .position(|(p, _)| p == path)
            .ok_or(HalError::Io)?;
        self.open.push(Some(i));
        Ok(StreamId((self.open.len() - 1) as u8))
    }
    fn input_len(&self, id: StreamId) -> u32 {
        self.open[id.0 as usize].map_or(0, |i| self.inputs[i].1.len() as u32)
    }
    fn input_sample(&self, id: StreamId, index: u32) -> f64 {
        self.open[id.0 as usize].map_or(0.0, |i| self.inputs[i].1[index as usize])
    }
    fn open_log(&mut self, path: &str) -> Result<StreamId, HalError> {
        self.logs.push((path.into(), Vec::new()));
        self.open.push(None);
        self.log_open.resize(self.open.len(), None);
        self.log_open[self.open.len() - 1] = Some(self.logs.len() - 1);
        Ok(StreamId((self.open.len() - 1) as u8))
    }
    fn write_log(&mut self, id: StreamId, text: &str) {
        if let Some(Some(i)) = self.log_open.get(id.0 as usize) {
            self.logs[*i].1.push(text.to_string());
        }
    }
    fn close(&mut self, id: StreamId) {
        if let Some(slot) = self.open.get_mut(id.0 as usize) {
            *slot = None;
        }
        if let Some(slot) = self.log_open.get_mut(id.0 as usize) {
            *slot = None;
        }
    }
}

/// Runs lines, panicking with the message on error; returns the output.
pub fn run(e: &mut Engine<Num>, hal: &mut MemBoard, lines: &str) -> String {
    let mut out = String::new();
    for line in lines.lines() {
        match e.execute(line, hal, &mut out) {
            Ok(Outcome::Done) => {}
            Ok(o) => panic!("unexpected outcome {o:?} for {line}"),
            Err(err) => panic!("{line}: {err}"),
        }
    }
    out
}

/// Simulated time: runs every due update with deadline < `until_us`.
pub fn run_until(e: &mut Engine<Num>, hal: &mut MemBoard, until_us: u64) {
    while let Some(t) = e.next_deadline() {
        if t >= until_us {
            break;
        }
        e.tick(t, hal);
    }
}

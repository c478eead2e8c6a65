//! [`BoardHal`]: score-core's HAL for the RP2040, with all bookkeeping (pins, slices, pairs)
//! done here and only register access left to the firmware through [`PortIo`].

use score_core::hal::{Adc, AdcInput, DataFiles, Gpio, HalError, Pwm, PwmOutput};

use crate::adc::{self, CHANNELS, FULL_SCALE, PAIRS, TEMPERATURE_CHANNEL, VREF};
use crate::pins::{PinTable, PinUse, DIGITAL_PINS};
use crate::pwm::{self, PwmBank, SliceRegs, OUTPUTS};

/// What a pin's pad and function select should become.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PinFunction {
    /// Reset state: no function, input buffer off.
    Off,
    /// Driven by its PWM slice.
    Pwm,
    /// Software-controlled input.
    Input,
    /// Software-controlled output, starting low.
    Output,
}

/// The registers the firmware touches; everything else is decided by [`BoardHal`].
pub trait PortIo {
    /// System clock in Hz (the PWM counters' clock).
    fn sys_clock_hz(&self) -> u32;
    /// One 12-bit conversion of ADC channel `ch` (0-3 = GPIO 26-29, 4 = temperature sensor).
    fn adc_convert(&mut self, ch: u8) -> Result<u16, HalError>;
    /// Writes a slice's divider, TOP, compares, inversions and enable (a new configuration).
    fn pwm_write(&mut self, regs: &SliceRegs);
    /// Writes only the compare values of a running slice (a duty change: the counter must
    /// not be disturbed; the hardware applies them at the next wrap).
    fn pwm_compare(&mut self, slice: u8, cc_a: u16, cc_b: u16);
    /// Sets a pin's function.
    fn pin_function(&mut self, pin: u8, f: PinFunction);
    /// Level of a pin.
    fn pin_read(&mut self, pin: u8) -> bool;
    /// Drives an output pin.
    fn pin_write(&mut self, pin: u8, high: bool);
}

/// Score's view of the RP2040: four ADC channels, pairs `A`/`B` in software, the temperature
/// sensor; sixteen PWM outputs (pairs `A`-`H`); GPIO 0-25.
pub struct BoardHal<P: PortIo> {
    /// The registers.
    pub io: P,
    pins: PinTable,
    pwm: PwmBank,
}

impl<P: PortIo> BoardHal<P> {
    /// Everything stopped.
    pub const fn new(io: P) -> Self {
        Self {
            io,
            pins: PinTable::new(),
            pwm: PwmBank::new(),
        }
    }

    /// The PWM bookkeeping (for reports and tests).
    pub fn pwm_bank(&self) -> &PwmBank {
        &self.pwm
    }

    /// The pin table.
    pub fn pins(&self) -> &PinTable {
        &self.pins
    }
}

impl<P: PortIo> Adc for BoardHal<P> {
    fn adc_channels(&self) -> u8 {
        CHANNELS
    }
    fn adc_differential_pairs(&self) -> u8 {
        PAIRS
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
        match input {
            AdcInput::Single(n) if n < CHANNELS => Ok(()),
            AdcInput::Differential(k) if k < PAIRS => Ok(()),
            AdcInput::Temperature => Ok(()),
            _ => Err(HalError::NoSuchChannel),
        }
    }
    fn adc_release(&mut self, _: AdcInput) {}
    fn adc_read(&mut self, input: AdcInput) -> Result<u16, HalError> {
        match input {
            AdcInput::Single(n) if n < CHANNELS => self.io.adc_convert(n),
            AdcInput::Temperature => self.io.adc_convert(TEMPERATURE_CHANNEL),
            AdcInput::Differential(k) => {
                let (p, n) = adc::pair_channels(k).ok_or(HalError::NoSuchChannel)?;
                let pos = self.io.adc_convert(p)?;
                let neg = self.io.adc_convert(n)?;
                Ok(adc::differential_code(pos, neg))
            }
            AdcInput::Single(_) => Err(HalError::NoSuchChannel),
        }
    }
}

impl<P: PortIo> Pwm for BoardHal<P> {
    fn pwm_outputs(&self) -> u8 {
        OUTPUTS
    }
    fn pwm_configure(&mut self, out: PwmOutput, freq_hz: f32) -> Result<f32, HalError> {
        let pins = pwm::pins(out)?;
        // Check the frequency before taking the pins, so a refusal changes nothing.
        pwm::timing(self.io.sys_clock_hz(), freq_hz)?;
        self.pins.claim(pins, PinUse::Pwm)?;
        let (f, regs) = self.pwm.configure(out, self.io.sys_clock_hz(), freq_hz)?;
        self.io.pwm_write(&regs);
        for &p in pins {
            self.io.pin_function(p, PinFunction::Pwm);
        }
        Ok(f as f32)
    }
    fn pwm_set_duty(&mut self, out: PwmOutput, duty: f32) -> f32 {
        let (d, regs) = self.pwm.set_duty(out, duty);
        if let Some(r) = regs {
            self.io.pwm_compare(r.slice, r.cc_a, r.cc_b);
        }
        d
    }
    fn pwm_release(&mut self, out: PwmOutput) {
        if let Some(r) = self.pwm.release(out) {
            self.io.pwm_write(&r);
        }
        if let Ok(pins) = pwm::pins(out) {
            for &p in pins {
                self.io.pin_function(p, PinFunction::Off);
            }
            self.pins.release(pins);
        }
    }
}

impl<P: PortIo> Gpio for BoardHal<P> {
    fn gpio_pins(&self) -> u8 {
        DIGITAL_PINS
    }
    fn gpio_configure(&mut self, pin: u8, output: bool) -> Result<(), HalError> {
        if pin >= DIGITAL_PINS {
            return Err(HalError::NoSuchChannel);
        }
        let what = if output {
            PinUse::Output
        } else {
            PinUse::Input
        };
        self.pins.claim(&[pin], what)?;
        self.io.pin_function(
            pin,
            if output {
                PinFunction::Output
            } else {
                PinFunction::Input
            },
        );
        Ok(())
    }
    fn gpio_read(&mut self, pin: u8) -> bool {
        matches!(self.pins.get(pin), PinUse::Input | PinUse::Output) && self.io.pin_read(pin)
    }
    fn gpio_write(&mut self, pin: u8, high: bool) {
        if self.pins.get(pin) == PinUse::Output {
            self.io.pin_write(pin, high);
        }
    }
    fn gpio_release(&mut self, pin: u8) {
        if matches!(self.pins.get(pin), PinUse::Input | PinUse::Output) {
            self.io.pin_function(pin, PinFunction::Off);
            self.pins.release(&[pin]);
        }
    }
}

/// The firmware has no files: `infile`, `log`, `load`, `save <file>` say so.
impl<P: PortIo> DataFiles for BoardHal<P> {}

/// A [`PortIo`] in memory, for tests: ADC codes to return, registers and pins as written.
#[derive(Debug, Clone, Default)]
pub struct MemIo {
    /// Code returned per ADC channel (0-3, 4 = temperature).
    pub adc: [u16; 5],
    /// Last registers written per slice.
    pub slices: [SliceRegs; 8],
    /// Function per pin.
    pub function: [Option<PinFunction>; 30],
    /// Level per pin.
    pub level: [bool; 30],
}

impl PortIo for MemIo {
    fn sys_clock_hz(&self) -> u32 {
        125_000_000
    }
    fn adc_convert(&mut self, ch: u8) -> Result<u16, HalError> {
        self.adc
            .get(ch as usize)
            .copied()
            .ok_or(HalError::NoSuchChannel)
    }
    fn pwm_write(&mut self, regs: &SliceRegs) {
        self.slices[regs.slice as usize] = *regs;
    }
    fn pwm_compare(&mut self, slice: u8, cc_a: u16, cc_b: u16) {
        let s = &mut self.slices[slice as usize];
        s.cc_a = cc_a;
        s.cc_b = cc_b;
    }
    fn pin_function(&mut self, pin: u8, f: PinFunction) {
        self.function[pin as usize] = Some(f);
    }
    fn pin_read(&mut self, pin: u8) -> bool {
        self.level[pin as usize]
    }
    fn pin_write(&mut self, pin: u8, high: bool) {
        self.level[pin as usize] = high;
    }
}

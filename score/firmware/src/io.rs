//! The registers behind `score_board::hal::PortIo`: ADC conversions, PWM slices, GPIO pads.
//! Every decision (which slice, which divider, who owns a pin) was made by `score-board`.

use embassy_rp::adc::{Adc, Blocking, Channel};
use embassy_rp::gpio::{Flex, Level};
use embassy_rp::pac;
use embassy_rp::pac::pwm::vals::Divmode;
use embassy_rp::peripherals::{
    PWM_SLICE0, PWM_SLICE1, PWM_SLICE2, PWM_SLICE3, PWM_SLICE4, PWM_SLICE5, PWM_SLICE6, PWM_SLICE7,
};
use embassy_rp::Peri;
use score_board::hal::{PinFunction, PortIo};
use score_board::pins::DIGITAL_PINS;
use score_board::pwm::SliceRegs;
use score_core::hal::HalError;

/// Function select values of the RP2040's IO bank (datasheet §2.19.2).
const FUNCSEL_PWM: u8 = 4;
const FUNCSEL_SIO: u8 = 5;

/// The eight PWM slices, held so nothing else in the firmware can take them.
pub type Slices = (
    Peri<'static, PWM_SLICE0>,
    Peri<'static, PWM_SLICE1>,
    Peri<'static, PWM_SLICE2>,
    Peri<'static, PWM_SLICE3>,
    Peri<'static, PWM_SLICE4>,
    Peri<'static, PWM_SLICE5>,
    Peri<'static, PWM_SLICE6>,
    Peri<'static, PWM_SLICE7>,
);

/// The RP2040's peripherals as Score uses them.
pub struct RpIo {
    /// The converter (blocking reads: one conversion is 2 µs).
    pub adc: Adc<'static, Blocking>,
    /// ADC channels 0-3 (GPIO 26-29), then the temperature sensor.
    pub channels: [Channel<'static>; 5],
    /// GPIO 0-25.
    pub pins: [Flex<'static>; DIGITAL_PINS as usize],
    /// Owned, programmed through the PAC.
    pub _slices: Slices,
    /// `clk_sys` in Hz.
    pub sys_hz: u32,
}

impl PortIo for RpIo {
    fn sys_clock_hz(&self) -> u32 {
        self.sys_hz
    }

    fn adc_convert(&mut self, ch: u8) -> Result<u16, HalError> {
        let c = self
            .channels
            .get_mut(ch as usize)
            .ok_or(HalError::NoSuchChannel)?;
        self.adc.blocking_read(c).map_err(|_| HalError::Io)
    }

    fn pwm_write(&mut self, r: &SliceRegs) {
        let ch = pac::PWM.ch(r.slice as usize);
        ch.csr().modify(|w| w.set_en(false));
        ch.div().write(|w| {
            w.set_int(r.div_int);
            w.set_frac(r.div_frac);
        });
        ch.top().write(|w| w.set_top(r.top));
        ch.cc().write(|w| {
            w.set_a(r.cc_a);
            w.set_b(r.cc_b);
        });
        ch.csr().write(|w| {
            w.set_divmode(Divmode::DIV);
            w.set_ph_correct(false);
            w.set_a_inv(r.a_inv);
            w.set_b_inv(r.b_inv);
            w.set_en(r.enable);
        });
    }

    fn pwm_compare(&mut self, slice: u8, cc_a: u16, cc_b: u16) {
        pac::PWM.ch(slice as usize).cc().write(|w| {
            w.set_a(cc_a);
            w.set_b(cc_b);
        });
    }

    fn pin_function(&mut self, pin: u8, f: PinFunction) {
        let Some(p) = self.pins.get_mut(pin as usize) else {
            return;
        };
        let ctrl = pac::IO_BANK0.gpio(pin as usize).ctrl();
        match f {
            PinFunction::Pwm => ctrl.write(|w| w.set_funcsel(FUNCSEL_PWM)),
            PinFunction::Off | PinFunction::Input => {
                ctrl.write(|w| w.set_funcsel(FUNCSEL_SIO));
                p.set_as_input();
            }
            PinFunction::Output => {
                ctrl.write(|w| w.set_funcsel(FUNCSEL_SIO));
                p.set_level(Level::Low);
                p.set_as_output();
            }
        }
    }

    fn pin_read(&mut self, pin: u8) -> bool {
        self.pins.get(pin as usize).is_some_and(|p| p.is_high())
    }

    fn pin_write(&mut self, pin: u8, high: bool) {
        if let Some(p) = self.pins.get_mut(pin as usize) {
            p.set_level(if high { Level::High } else { Level::Low });
        }
    }
}

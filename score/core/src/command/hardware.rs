//! Commands that configure peripherals and files: adc, pwm, gpio, defpwm, defgpio, rate,
//! infile, log.

use core::fmt::Write;

use crate::capacity::{MAX_NAME_LEN, MAX_PATH_LEN, MAX_STREAMS, MAX_SYMBOLS};
use crate::engine::{Engine, Stream};
use crate::error::{name as mk_name, tok, Error, Result};
use crate::hal::{AdcInput, Hal, PwmOutput};
use crate::lexer::parse_number;
use crate::num::Real;
use crate::symbol::{Family, Kind, Symbol, Task};
use crate::text::ShortStr;
use crate::VarId;

use super::args::{
    adc_input, channel_name_num, channel_suffix, hal_err, join, parse_rate, pwm_freq, pwm_output,
    pwm_suffix, Args,
};
use super::define::placeholder;

/// Hardware a variable holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Hw {
    Adc(AdcInput),
    Pwm(PwmOutput),
    Pin(u8),
    Stream(u8),
}

pub(super) fn hardware<N>(k: &Kind<N>) -> Option<Hw> {
    match *k {
        Kind::AdcRaw { input, .. } => Some(Hw::Adc(input)),
        Kind::PwmFixed { out, .. } | Kind::PwmFollow { out, .. } => Some(Hw::Pwm(out)),
        Kind::GpioIn { pin } | Kind::GpioOut { pin, .. } => Some(Hw::Pin(pin)),
        Kind::Infile { stream, .. } | Kind::Log { stream, .. } => Some(Hw::Stream(stream)),
        _ => None,
    }
}

impl<N: Real> Engine<N> {
    pub(super) fn pwm_owner(&self, out: PwmOutput, except: Option<VarId>) -> Option<VarId> {
        (0..MAX_SYMBOLS).map(|i| VarId(i as u8)).find(|&id| {
            Some(id) != except
                && matches!(self.sym(id).map(|s| s.kind),
                    Some(Kind::PwmFixed { out: o, .. }) | Some(Kind::PwmFollow { out: o, .. }) if o.overlaps(out))
        })
    }

    pub(super) fn pin_owner(&self, pin: u8, except: Option<VarId>) -> Option<VarId> {
        (0..MAX_SYMBOLS).map(|i| VarId(i as u8)).find(|&id| {
            Some(id) != except
                && matches!(self.sym(id).map(|s| s.kind),
                    Some(Kind::GpioIn { pin: p }) | Some(Kind::GpioOut { pin: p, .. }) if p == pin)
        })
    }

    pub(super) fn note_frequency(out: &mut impl Write, name: &str, requested: f32, actual: f32) {
        if (actual - requested).abs() > requested * 1e-4 {
            let _ = writeln!(out, "note: {name} runs at {actual} Hz, the nearest to {requested} Hz this timer can make");
        }
    }

    pub(super) fn cmd_pwm(
        &mut self,
        a: &mut Args<'_, '_>,
        hal: &mut impl Hal,
        out: &mut impl Write,
    ) -> Result<()> {
        let t_ch = a.next("channel")?;
        let o = pwm_output("pwm", t_ch, hal)?;
        let freq = pwm_freq(a)?;
        let t_duty = a.next("duty")?;
        a.end()?;
        let duty = parse_number::<N>(t_duty)
            .filter(|d| *d >= N::ZERO && *d <= N::from_u32(100))
            .ok_or(Error::Invalid {
                command: "pwm",
                token: tok(t_duty),
                expected: "a duty cycle in percent (0-100)",
            })?;
        let name = join("PWM", pwm_suffix(o).as_str());
        let target = self.check_target("pwm", name.as_str(), Family::Pwm)?;
        if let Some(owner) = self.pwm_owner(o, target) {
            return Err(Error::Busy {
                command: "pwm",
                token: tok(t_ch),
                owner: mk_name(self.name_of(owner)),
            });
        }
        self.check_refs("pwm", name.as_str(), target, &[], false)?;
        let actual = hal
            .pwm_configure(o, freq)
            .map_err(|e| hal_err("pwm", t_ch, e))?;
        let applied = hal.pwm_set_duty(o, (duty.to_f64() / 100.0) as f32);
        Self::note_frequency(out, name.as_str(), freq, actual);
        let value = N::from_f64(applied as f64 * 100.0);
        self.commit(name.as_str(), &[], None, value, hal, |_, _| {
            Kind::PwmFixed { out: o, freq }
        });
        Ok(())
    }

    pub(super) fn cmd_defpwm(
        &mut self,
        a: &mut Args<'_, '_>,
        hal: &mut impl Hal,
        out: &mut impl Write,
    ) -> Result<()> {
        let name = a.name("varname")?;
        let src = a.name("basename")?;
        let rate = a.rate("refreshFreq")?;
        let t_ch = a.next("channel")?;
        let o = pwm_output("defpwm", t_ch, hal)?;
        let freq = pwm_freq(a)?;
        a.end()?;
        let target = self.check_target("defpwm", name, Family::Def)?;
        if let Some(owner) = self.pwm_owner(o, target) {
            return Err(Error::Busy {
                command: "defpwm",
                token: tok(t_ch),
                owner: mk_name(self.name_of(owner)),
            });
        }
        self.check_refs("defpwm", name, target, &[src], false)?;
        let actual = hal
            .pwm_configure(o, freq)
            .map_err(|e| hal_err("defpwm", t_ch, e))?;
        Self::note_frequency(out, name, freq, actual);
        self.commit(name, &[src], Some(rate), N::ZERO, hal, |e, _| {
            Kind::PwmFollow {
                src: e.resolve(src),
                out: o,
                freq,
            }
        });
        Ok(())
    }

    pub(super) fn parse_pin(
        &self,
        a: &mut Args<'_, '_>,
        hal: &impl Hal,
    ) -> Result<(u8, &'static str)> {
        let t = a.next("pin")?;
        match t.parse::<u8>() {
            Ok(p) if p < hal.gpio_pins() => Ok((p, "")),
            _ => Err(Error::Invalid {
                command: a.cmd,
                token: tok(t),
                expected: "a GPIO pin number of this board",
            }),
        }
    }

    pub(super) fn cmd_gpio_in(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
        let t_pin = a.toks.first().copied().unwrap_or("");
        let (pin, _) = self.parse_pin(a, hal)?;
        let rate = a.rate("frequency")?;
        a.end()?;
        let name = join("GPIO", channel_name_num(pin).as_str());
        let target = self.check_target("gpio", name.as_str(), Family::Gpio)?;
        if let Some(owner) = self.pin_owner(pin, target) {
            return Err(Error::Busy {
                command: "gpio",
                token: tok(t_pin),
                owner: mk_name(self.name_of(owner)),
            });
        }
        self.check_refs("gpio", name.as_str(), target, &[], false)?;
        hal.gpio_configure(pin, false)
            .map_err(|e| hal_err("gpio", t_pin, e))?;
        let v = if hal.gpio_read(pin) { N::ONE } else { N::ZERO };
        self.commit(name.as_str(), &[], Some(rate), v, hal, |_, _| {
            Kind::GpioIn { pin }
        });
        Ok(())
    }

    pub(super) fn cmd_defgpio(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
        let name = a.name("varname")?;
        let src = a.name("basename")?;
        let rate = a.rate("refreshFreq")?;
        let t_pin = a.toks.get(a.pos).copied().unwrap_or("");
        let (pin, _) = self.parse_pin(a, hal)?;
        a.end()?;
        let target = self.check_target("defgpio", name, Family::Def)?;
        if let Some(owner) = self.pin_owner(pin, target) {
            return Err(Error::Busy {
                command: "defgpio",
                token: tok(t_pin),
                owner: mk_name(self.name_of(owner)),
            });
        }
        self.check_refs("defgpio", name, target, &[src], false)?;
        hal.gpio_configure(pin, true)
            .map_err(|e| hal_err("defgpio", t_pin, e))?;
        self.commit(name, &[src], Some(rate), N::ZERO, hal, |e, _| {
            Kind::GpioOut {
                src: e.resolve(src),
                pin,
            }
        });
        Ok(())
    }

    pub(super) fn cmd_adc(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
        let t_ch = a.next("channel")?;
        let input = adc_input("adc", t_ch, hal)?;
        let rate = a.rate("frequency")?;
        a.end()?;
        let mut suffix = ShortStr::<4>::new();
        channel_suffix(&mut suffix, input);
        let raw_name = join("ADC", suffix.as_str());
        let mut lower = [0u8; 4];
        let sfx = suffix.as_str().as_bytes();
        for (d, c) in lower.iter_mut().zip(sfx) {
            *d = c.to_ascii_lowercase();
        }
        let volts_name = join(
            "adc",
            core::str::from_utf8(&lower[..sfx.len()]).unwrap_or(""),
        );
        let raw = self.check_target("adc", raw_name.as_str(), Family::Adc)?;
        let volts = self.check_target("adc", volts_name.as_str(), Family::Adc)?;
        let hz = rate as f32 / 1000.0;
        // Existing channel: a new sampling rate.
        if let Some(Kind::AdcRaw { .. }) = raw.and_then(|r| self.sym(r)).map(|s| s.kind) {
            hal.adc_configure(input, hz)
                .map_err(|e| hal_err("adc", t_ch, e))?;
            if let Some(s) = raw.and_then(|r| self.syms[r.0 as usize].as_mut()) {
                s.task = Some(Task::new(rate));
            }
            self.rebuild();
            return Ok(());
        }
        let needed = raw.is_none() as usize + volts.is_none() as usize;
        if self.len() + needed > MAX_SYMBOLS {
            return Err(Error::Full {
                command: "adc",
                what: "variables",
                capacity: MAX_SYMBOLS,
            });
        }
        hal.adc_configure(input, hz)
            .map_err(|e| hal_err("adc", t_ch, e))?;
        let code = hal.adc_read(input).unwrap_or(0);
        let v = Self::volts(input, code, hal);
        let slot = |e: &mut Self, n: &str| match e.lookup(n) {
            Some(id) => id,
            None => {
                let i = e.free_slot().unwrap_or(MAX_SYMBOLS - 1);
                e.syms[i] = Some(placeholder(n));
                VarId(i as u8)
            }
        };
        let rid = slot(self, raw_name.as_str());
        let vid = slot(self, volts_name.as_str());
        self.syms[rid.0 as usize] = Some(Symbol {
            name: raw_name,
            kind: Kind::AdcRaw { input, volts: vid },
            task: Some(Task::new(rate)),
        });
        self.values[rid.0 as usize] = N::from_u32(code as u32);
        self.syms[vid.0 as usize] = Some(Symbol {
            name: volts_name,
            kind: Kind::AdcVolts { raw: rid },
            task: None,
        });
        self.values[vid.0 as usize] = v;
        self.rebuild();
        Ok(())
    }

    pub(super) fn cmd_rate(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
        let n = a.next("varname")?;
        let rate = a.rate("frequency")?;
        a.end()?;
        let mut id = self.lookup(n).ok_or(Error::UnknownVariable {
            command: "rate",
            token: tok(n),
        })?;
        if let Some(Kind::AdcVolts { raw }) = self.sym(id).map(|s| s.kind) {
            id = raw;
        }
        let sym = self.sym(id).copied().ok_or(Error::UnknownVariable {
            command: "rate",
            token: tok(n),
        })?;
        let Some(mut task) = sym.task else {
            return Err(Error::Invalid {
                command: "rate",
                token: tok(n),
                expected:
                    "a periodic variable (bare expressions, constants and pwm duties have no rate)",
            });
        };
        if let Kind::AdcRaw { input, .. } = sym.kind {
            hal.adc_configure(input, rate as f32 / 1000.0)
                .map_err(|e| hal_err("rate", n, e))?;
        }
        task.set_rate(rate);
        if let Some(s) = &mut self.syms[id.0 as usize] {
            s.task = Some(task);
        }
        self.rebuild();
        Ok(())
    }

    pub(super) fn check_path(&self, cmd: &'static str, path: &str) -> Result<usize> {
        if path.len() > MAX_PATH_LEN {
            return Err(Error::Invalid {
                command: cmd,
                token: tok(path),
                expected: "a file name of at most 63 bytes",
            });
        }
        self.streams
            .iter()
            .position(|s| s.is_none())
            .ok_or(Error::Full {
                command: cmd,
                what: "open files",
                capacity: MAX_STREAMS,
            })
    }

    pub(super) fn cmd_infile(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
        let name = a.name("varname")?;
        let rate = a.rate("frequency")?;
        let path = a.next("filename")?;
        a.end()?;
        let target = self.check_target("infile", name, Family::Infile)?;
        self.check_refs("infile", name, target, &[], false)?;
        let slot = self.check_path("infile", path)?;
        let id = hal
            .open_input(path)
            .map_err(|e| hal_err("infile", path, e))?;
        let len = hal.input_len(id);
        if len == 0 {
            hal.close(id);
            return Err(Error::Invalid {
                command: "infile",
                token: tok(path),
                expected: "a file with at least one number",
            });
        }
        let first = N::from_f64(hal.input_sample(id, 0));
        self.streams[slot] = Some(Stream {
            id,
            path: ShortStr::truncated(path),
        });
        self.commit(name, &[], Some(rate), first, hal, |_, _| Kind::Infile {
            stream: slot as u8,
            len,
            cursor: 0,
        });
        Ok(())
    }

    pub(super) fn cmd_log(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
        // `log name var hz file` or `log var hz file`; three tokens whose second is not a rate but
        // whose third is are the named form missing its file.
        let rest = &a.toks[a.pos..];
        let named = rest.len() >= 4
            || (rest.len() == 3 && parse_rate(rest[1]).is_none() && parse_rate(rest[2]).is_some());
        let (name, src) = if named {
            (join("", a.name("logname")?), a.name("varname")?)
        } else {
            let src = a.name("varname")?;
            if src.len() + 1 > MAX_NAME_LEN {
                return Err(Error::Invalid {
                    command: "log",
                    token: tok(src),
                    expected: "a variable name of at most 14 characters (or give the log a name)",
                });
            }
            (join("L", src), src)
        };
        let rate = a.rate("frequency")?;
        let path = a.next("filename")?;
        a.end()?;
        let name = name.as_str();
        let target = self.check_target("log", name, Family::Log)?;
        self.check_refs("log", name, target, &[src], false)?;
        let slot = self.check_path("log", path)?;
        let id = hal.open_log(path).map_err(|e| hal_err("log", path, e))?;
        self.streams[slot] = Some(Stream {
            id,
            path: ShortStr::truncated(path),
        });
        self.commit(name, &[src], Some(rate), N::ZERO, hal, |e, _| Kind::Log {
            src: e.resolve(src),
            stream: slot as u8,
        });
        Ok(())
    }
}

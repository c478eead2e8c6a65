//! Argument reading and channel/name helpers.

use core::fmt::Write;

use crate::capacity::{MAX_NAME_LEN, MAX_RATE_HZ, MIN_RATE_MILLIHZ};
use crate::error::{name as mk_name, tok, ChannelRange, Error, Result};
use crate::expr::{self};
use crate::hal::{AdcInput, Hal, HalError, PwmOutput};
use crate::lexer::parse_number;
use crate::num::Real;
use crate::text::ShortStr;

/// Argument cursor over one command's tokens.
pub(super) struct Args<'t, 'a> {
    pub cmd: &'static str,
    pub usage: &'static str,
    pub toks: &'t [&'a str],
    pub pos: usize,
}

pub(super) const NAME_EXPECTED: &str =
    "a variable name (a letter or _, then letters, digits or _; at most 15 characters)";
pub(super) const RATE_EXPECTED: &str = "a frequency in Hz between 0.001 and 100000";

impl<'a> Args<'_, 'a> {
    pub(super) fn next(&mut self, expected: &'static str) -> Result<&'a str> {
        let t = self.toks.get(self.pos).copied().ok_or(Error::Missing {
            command: self.cmd,
            expected,
            usage: self.usage,
        })?;
        self.pos += 1;
        Ok(t)
    }

    pub(super) fn opt(&mut self) -> Option<&'a str> {
        let t = self.toks.get(self.pos).copied();
        self.pos += t.is_some() as usize;
        t
    }

    pub(super) fn remaining(&self) -> usize {
        self.toks.len() - self.pos.min(self.toks.len())
    }

    pub(super) fn name(&mut self, expected: &'static str) -> Result<&'a str> {
        let t = self.next(expected)?;
        if expr::is_name(t) {
            Ok(t)
        } else {
            Err(Error::Invalid {
                command: self.cmd,
                token: tok(t),
                expected: NAME_EXPECTED,
            })
        }
    }

    pub(super) fn number<N: Real>(&mut self, expected: &'static str) -> Result<N> {
        let t = self.next(expected)?;
        parse_number::<N>(t).ok_or(Error::Invalid {
            command: self.cmd,
            token: tok(t),
            expected,
        })
    }

    /// A rate in millihertz.
    pub(super) fn rate(&mut self, expected: &'static str) -> Result<u32> {
        let t = self.next(expected)?;
        parse_rate(t).ok_or(Error::Invalid {
            command: self.cmd,
            token: tok(t),
            expected: RATE_EXPECTED,
        })
    }

    pub(super) fn operand<N: Real>(
        &mut self,
        expected: &'static str,
    ) -> Result<(Option<N>, &'a str)> {
        let t = self.next(expected)?;
        if let Some(v) = parse_number::<N>(t) {
            Ok((Some(v), t))
        } else if expr::is_name(t) {
            Ok((None, t))
        } else {
            Err(Error::Invalid {
                command: self.cmd,
                token: tok(t),
                expected: "a number or a variable name",
            })
        }
    }

    pub(super) fn end(&self) -> Result<()> {
        match self.toks.get(self.pos) {
            None => Ok(()),
            Some(t) => Err(Error::Extra {
                command: self.cmd,
                token: tok(t),
                usage: self.usage,
            }),
        }
    }
}

pub(super) fn parse_rate(t: &str) -> Option<u32> {
    let hz = parse_number::<f64>(t)?;
    let mhz = libm::round(hz * 1000.0);
    (mhz >= MIN_RATE_MILLIHZ as f64 && hz <= MAX_RATE_HZ as f64).then_some(mhz as u32)
}

/// Channel suffix used in generated names (`0`, `A`, `T`).
pub(super) fn channel_suffix(buf: &mut ShortStr<4>, input: AdcInput) {
    let mut s = [0u8; 4];
    let text: &str = match input {
        AdcInput::Single(n) => {
            let mut w = crate::text::BufWriter::new(&mut s);
            let _ = write!(w, "{n}");
            let len = w.as_str().len();
            core::str::from_utf8(&s[..len]).unwrap_or("")
        }
        AdcInput::Differential(k) => {
            s[0] = b'A' + k;
            core::str::from_utf8(&s[..1]).unwrap_or("")
        }
        AdcInput::Temperature => "T",
    };
    *buf = ShortStr::truncated(text);
}

pub(super) fn pwm_suffix(out: PwmOutput) -> ShortStr<4> {
    match out {
        PwmOutput::Single(n) => channel_name_num(n),
        PwmOutput::Complementary(k) => {
            ShortStr::truncated(core::str::from_utf8(&[b'A' + k]).unwrap_or("?"))
        }
    }
}

pub(super) fn channel_name_num(n: u8) -> ShortStr<4> {
    let mut s = [0u8; 4];
    let mut w = crate::text::BufWriter::new(&mut s);
    let _ = write!(w, "{n}");
    ShortStr::truncated(w.as_str())
}

pub(super) fn join(prefix: &str, suffix: &str) -> crate::error::Name {
    let mut buf = [0u8; MAX_NAME_LEN];
    let mut w = crate::text::BufWriter::new(&mut buf);
    let _ = write!(w, "{prefix}{suffix}");
    mk_name(w.as_str())
}

/// Parses a channel token: digits = single, one letter = pair (`T` = temperature for the ADC).
pub(super) fn parse_channel(t: &str, temperature_letter: bool) -> Option<(bool, u8, bool)> {
    if let Ok(n) = t.parse::<u8>() {
        return Some((false, n, false));
    }
    let b = t.as_bytes();
    if b.len() == 1 && b[0].is_ascii_alphabetic() {
        let up = b[0].to_ascii_uppercase();
        if temperature_letter && up == b'T' {
            return Some((false, 0, true));
        }
        return Some((true, up - b'A', false));
    }
    None
}

pub(super) fn adc_input(cmd: &'static str, t: &str, hal: &impl Hal) -> Result<AdcInput> {
    let range = ChannelRange::new(
        hal.adc_channels(),
        hal.adc_differential_pairs(),
        hal.adc_has_temperature(),
    );
    let input = match parse_channel(t, true) {
        Some((_, _, true)) if range.temperature() => Some(AdcInput::Temperature),
        Some((false, n, false)) if n < range.singles() => Some(AdcInput::Single(n)),
        Some((true, k, false)) if k < range.pairs() => Some(AdcInput::Differential(k)),
        _ => None,
    };
    input.ok_or(Error::Channel {
        command: cmd,
        token: tok(t),
        what: "an ADC channel",
        range,
    })
}

pub(super) fn pwm_output(cmd: &'static str, t: &str, hal: &impl Hal) -> Result<PwmOutput> {
    let n = hal.pwm_outputs();
    let range = ChannelRange::new(n, n / 2, false);
    let out = match parse_channel(t, false) {
        Some((false, c, _)) if c < n => Some(PwmOutput::Single(c)),
        Some((true, k, _)) if k < n / 2 => Some(PwmOutput::Complementary(k)),
        _ => None,
    };
    out.ok_or(Error::Channel {
        command: cmd,
        token: tok(t),
        what: "a PWM output",
        range,
    })
}

pub(super) fn hal_err(command: &'static str, t: &str, error: HalError) -> Error {
    match error {
        HalError::Unsupported => Error::Unsupported {
            command,
            what: "the hardware or file system is missing",
        },
        error => Error::Hardware {
            command,
            token: tok(t),
            error,
        },
    }
}

pub(super) const PWM_FREQ: &str = "a PWM frequency in Hz (above 0, at most 100000000)";

pub(super) fn pwm_freq(args: &mut Args<'_, '_>) -> Result<f32> {
    let t = args.next("frequency")?;
    match parse_number::<f64>(t) {
        Some(f) if f > 0.0 && f <= 1e8 => Ok(f as f32),
        _ => Err(Error::Invalid {
            command: args.cmd,
            token: tok(t),
            expected: PWM_FREQ,
        }),
    }
}

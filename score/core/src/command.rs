//! Command execution: parse a line completely, check everything, then change the table.
//! A command that returns an error has changed neither the table nor (except for a HAL call that
//! itself failed) the hardware.

use core::fmt::Write;

use crate::capacity::{
    MAX_NAME_LEN, MAX_PATH_LEN, MAX_RATE_HZ, MAX_STREAMS, MAX_SYMBOLS, MIN_RATE_MILLIHZ,
};
use crate::engine::{Engine, Menu, Stream};
use crate::error::{name as mk_name, tok, ChannelRange, Error, NameList, Result};
use crate::expr::{self, Class, Op};
use crate::hal::{AdcInput, Hal, HalError, PwmOutput};
use crate::help;
use crate::lexer::{parse_number, Tokens};
use crate::num::Real;
use crate::symbol::{Family, Kind, Operand, Symbol, Task, Trapezoid, TwoPoint};
use crate::text::ShortStr;
use crate::VarId;

/// What the port must do after a successful command. File and time commands are carried out by
/// the port, which owns files and the clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Outcome<'a> {
    /// Nothing more.
    Done,
    /// `script <file>`: run the file's lines.
    Script(&'a str),
    /// `load <file>`: replace the table by the file's script (atomically: keep the old table if
    /// a line fails).
    Load(&'a str),
    /// `save <file>`: write [`Engine::save`] to the file.
    Save(&'a str),
    /// `run <seconds>`: advance time.
    Run(f64),
}

/// Argument cursor over one command's tokens.
struct Args<'t, 'a> {
    cmd: &'static str,
    usage: &'static str,
    toks: &'t [&'a str],
    pos: usize,
}

const NAME_EXPECTED: &str =
    "a variable name (a letter or _, then letters, digits or _; at most 15 characters)";
const RATE_EXPECTED: &str = "a frequency in Hz between 0.001 and 100000";

impl<'a> Args<'_, 'a> {
    fn next(&mut self, expected: &'static str) -> Result<&'a str> {
        let t = self.toks.get(self.pos).copied().ok_or(Error::Missing {
            command: self.cmd,
            expected,
            usage: self.usage,
        })?;
        self.pos += 1;
        Ok(t)
    }

    fn opt(&mut self) -> Option<&'a str> {
        let t = self.toks.get(self.pos).copied();
        self.pos += t.is_some() as usize;
        t
    }

    fn remaining(&self) -> usize {
        self.toks.len() - self.pos.min(self.toks.len())
    }

    fn name(&mut self, expected: &'static str) -> Result<&'a str> {
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

    fn number<N: Real>(&mut self, expected: &'static str) -> Result<N> {
        let t = self.next(expected)?;
        parse_number::<N>(t).ok_or(Error::Invalid {
            command: self.cmd,
            token: tok(t),
            expected,
        })
    }

    /// A rate in millihertz.
    fn rate(&mut self, expected: &'static str) -> Result<u32> {
        let t = self.next(expected)?;
        parse_rate(t).ok_or(Error::Invalid {
            command: self.cmd,
            token: tok(t),
            expected: RATE_EXPECTED,
        })
    }

    fn operand<N: Real>(&mut self, expected: &'static str) -> Result<(Option<N>, &'a str)> {
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

    fn end(&self) -> Result<()> {
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

fn parse_rate(t: &str) -> Option<u32> {
    let hz = parse_number::<f64>(t)?;
    let mhz = libm::round(hz * 1000.0);
    (mhz >= MIN_RATE_MILLIHZ as f64 && hz <= MAX_RATE_HZ as f64).then_some(mhz as u32)
}

/// Hardware a variable holds.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Hw {
    Adc(AdcInput),
    Pwm(PwmOutput),
    Pin(u8),
    Stream(u8),
}

fn hardware<N>(k: &Kind<N>) -> Option<Hw> {
    match *k {
        Kind::AdcRaw { input, .. } => Some(Hw::Adc(input)),
        Kind::PwmFixed { out, .. } | Kind::PwmFollow { out, .. } => Some(Hw::Pwm(out)),
        Kind::GpioIn { pin } | Kind::GpioOut { pin, .. } => Some(Hw::Pin(pin)),
        Kind::Infile { stream, .. } | Kind::Log { stream, .. } => Some(Hw::Stream(stream)),
        _ => None,
    }
}

/// Channel suffix used in generated names (`0`, `A`, `T`).
fn channel_suffix(buf: &mut ShortStr<4>, input: AdcInput) {
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

fn pwm_suffix(out: PwmOutput) -> ShortStr<4> {
    match out {
        PwmOutput::Single(n) => channel_name_num(n),
        PwmOutput::Complementary(k) => {
            ShortStr::truncated(core::str::from_utf8(&[b'A' + k]).unwrap_or("?"))
        }
    }
}

fn channel_name_num(n: u8) -> ShortStr<4> {
    let mut s = [0u8; 4];
    let mut w = crate::text::BufWriter::new(&mut s);
    let _ = write!(w, "{n}");
    ShortStr::truncated(w.as_str())
}

fn join(prefix: &str, suffix: &str) -> crate::error::Name {
    let mut buf = [0u8; MAX_NAME_LEN];
    let mut w = crate::text::BufWriter::new(&mut buf);
    let _ = write!(w, "{prefix}{suffix}");
    mk_name(w.as_str())
}

/// Parses a channel token: digits = single, one letter = pair (`T` = temperature for the ADC).
fn parse_channel(t: &str, temperature_letter: bool) -> Option<(bool, u8, bool)> {
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

fn adc_input(cmd: &'static str, t: &str, hal: &impl Hal) -> Result<AdcInput> {
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

fn pwm_output(cmd: &'static str, t: &str, hal: &impl Hal) -> Result<PwmOutput> {
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

fn hal_err(command: &'static str, t: &str, error: HalError) -> Error {
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

const PWM_FREQ: &str = "a PWM frequency in Hz (above 0, at most 100000000)";

fn pwm_freq(args: &mut Args<'_, '_>) -> Result<f32> {
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

impl<N: Real> Engine<N> {
    /// Executes one command line. Output (listings, echoes, notes) goes to `out`; an error is
    /// returned, not printed, and leaves the table exactly as it was. Never panics on any input.
    pub fn execute<'a>(
        &mut self,
        line: &'a str,
        hal: &mut impl Hal,
        out: &mut impl Write,
    ) -> Result<Outcome<'a>> {
        let tokens = Tokens::split(line)?;
        let toks = tokens.as_slice();
        let Some((&word, rest)) = toks.split_first() else {
            return Ok(Outcome::Done);
        };
        let spec = help::spec(word).ok_or(Error::UnknownCommand { token: tok(word) })?;
        let mut a = Args {
            cmd: spec.name,
            usage: spec.usage,
            toks: rest,
            pos: 0,
        };
        // Writes to `out` are best effort: a full terminal must not undo a finished command.
        match spec.name {
            "help" => {
                let topic = a.opt();
                a.end()?;
                match topic {
                    None => {
                        let _ = help::write_menu(out, self.menu);
                        let _ = writeln!(out, "{}", crate::capacity::CAPACITIES);
                    }
                    Some(t) => {
                        let c = help::spec(t).ok_or(Error::Invalid {
                            command: "help",
                            token: tok(t),
                            expected: "a command name (type 'help' for the list)",
                        })?;
                        let _ = help::write_command(out, c);
                    }
                }
            }
            "var" | "main" => {
                a.end()?;
                self.menu = if spec.name == "var" {
                    Menu::Var
                } else {
                    Menu::Main
                };
                let _ = writeln!(out);
                let _ = help::write_menu(out, self.menu);
            }
            "capacities" => {
                a.end()?;
                let _ = writeln!(out, "{}", crate::capacity::CAPACITIES);
                let _ = writeln!(
                    out,
                    "table memory: {} bytes ({} used of {} symbols, {} of {} expression tokens)",
                    core::mem::size_of::<Self>(),
                    self.len(),
                    MAX_SYMBOLS,
                    self.ops_used,
                    crate::capacity::MAX_EXPR_OPS
                );
            }
            "printvars" => {
                a.end()?;
                self.print_vars(out);
            }
            "printv" => {
                let n = a.next("varname")?;
                a.end()?;
                let id = self.lookup(n).ok_or(Error::UnknownVariable {
                    command: "printv",
                    token: tok(n),
                })?;
                self.print_var(id, out);
            }
            "show" => {
                let n = a.next("varname")?;
                a.end()?;
                let id = self.lookup(n).ok_or(Error::UnknownVariable {
                    command: "show",
                    token: tok(n),
                })?;
                self.show(id, out);
            }
            "save" => {
                let path = a.opt();
                a.end()?;
                match path {
                    Some(p) => return Ok(Outcome::Save(p)),
                    None => {
                        let _ = self.save(out);
                    }
                }
            }
            "load" | "script" => {
                let p = a.next("filename")?;
                a.end()?;
                return Ok(if spec.name == "load" {
                    Outcome::Load(p)
                } else {
                    Outcome::Script(p)
                });
            }
            "run" => {
                let t = a.next("seconds")?;
                a.end()?;
                let s = parse_number::<f64>(t)
                    .filter(|s| *s >= 0.0)
                    .ok_or(Error::Invalid {
                        command: "run",
                        token: tok(t),
                        expected: "a duration in seconds (0 or more)",
                    })?;
                return Ok(Outcome::Run(s));
            }
            "clear" => {
                a.end()?;
                self.clear(hal);
            }
            "adc" => self.cmd_adc(&mut a, hal)?,
            "pwm" => self.cmd_pwm(&mut a, hal, out)?,
            "gpio" => self.cmd_gpio_in(&mut a, hal)?,
            "defexp" => self.cmd_defexp(&mut a, hal, out)?,
            "defscale" | "defsat" | "defint" | "defdiff" | "defwind" | "deflpf" | "defpid" => {
                self.cmd_block(&mut a, hal)?
            }
            "defpwm" => self.cmd_defpwm(&mut a, hal, out)?,
            "defgpio" => self.cmd_defgpio(&mut a, hal)?,
            "set" => {
                let n = a.next("varname")?;
                let t = a.next("value")?;
                a.end()?;
                let id = self.lookup(n).ok_or(Error::UnknownVariable {
                    command: "set",
                    token: tok(n),
                })?;
                let v = parse_number::<N>(t).ok_or(Error::Invalid {
                    command: "set",
                    token: tok(t),
                    expected: "a number",
                })?;
                self.set(id, v, hal)?;
            }
            "del" => {
                let n = a.next("varname")?;
                a.end()?;
                let id = self.lookup(n).ok_or(Error::UnknownVariable {
                    command: "del",
                    token: tok(n),
                })?;
                self.delete(id, hal)?;
            }
            "rate" => self.cmd_rate(&mut a, hal)?,
            "infile" => self.cmd_infile(&mut a, hal)?,
            "log" => self.cmd_log(&mut a, hal)?,
            _ => return Err(Error::UnknownCommand { token: tok(word) }),
        }
        Ok(Outcome::Done)
    }

    /// [`Engine::execute`], also printing an error as `error: <message>` to `out`.
    pub fn command<'a>(
        &mut self,
        line: &'a str,
        hal: &mut impl Hal,
        out: &mut impl Write,
    ) -> Result<Outcome<'a>> {
        let r = self.execute(line, hal, out);
        if let Err(e) = &r {
            let _ = writeln!(out, "error: {e}");
        }
        r
    }

    // ----- definitions -------------------------------------------------------------------

    /// Checks that `name` may be (re)defined by a command of `family`; returns its slot if it
    /// exists (a placeholder or a variable of the same family).
    fn check_target(
        &self,
        command: &'static str,
        name: &str,
        family: Family,
    ) -> Result<Option<VarId>> {
        let Some(id) = self.lookup(name) else {
            return Ok(None);
        };
        let kind = self.sym(id).map(|s| s.kind).unwrap_or(Kind::Placeholder);
        match kind.family() {
            Family::Placeholder => Ok(Some(id)),
            f if f == family => Ok(Some(id)),
            _ => Err(Error::NameTaken {
                command,
                name: mk_name(name),
                what: kind.what(),
            }),
        }
    }

    /// Capacity and cycle checks for a definition of `name` reading `refs`.
    fn check_refs(
        &self,
        command: &'static str,
        name: &str,
        target: Option<VarId>,
        refs: &[&str],
        lazy: bool,
    ) -> Result<()> {
        let mut needed = target.is_none() as usize;
        for (i, r) in refs.iter().enumerate() {
            if *r != name && self.lookup(r).is_none() && !refs[..i].contains(r) {
                needed += 1;
            }
        }
        if self.len() + needed > MAX_SYMBOLS {
            return Err(Error::Full {
                command,
                what: "variables",
                capacity: MAX_SYMBOLS,
            });
        }
        if lazy {
            for r in refs {
                let cyc = *r == name
                    || match (self.lookup(r), target) {
                        (Some(d), Some(x)) => self.view[d.0 as usize].contains(x.0 as usize),
                        _ => false,
                    };
                if cyc {
                    return Err(Error::Cycle {
                        command,
                        name: mk_name(name),
                        via: mk_name(r),
                    });
                }
            }
        }
        Ok(())
    }

    fn free_slot(&self) -> Option<usize> {
        self.syms.iter().position(|s| s.is_none())
    }

    /// Creates placeholders for unknown `refs`, puts `kind` (built once all names resolve) in
    /// `name`'s slot, releases what the old definition held, and rebuilds the graph. Infallible:
    /// every check has been done.
    fn commit(
        &mut self,
        name: &str,
        refs: &[&str],
        task: Option<u32>,
        value: N,
        hal: &mut impl Hal,
        build: impl FnOnce(&mut Self, VarId) -> Kind<N>,
    ) -> VarId {
        let id = match self.lookup(name) {
            Some(id) => id,
            None => {
                let i = self.free_slot().unwrap_or(MAX_SYMBOLS - 1);
                self.syms[i] = Some(placeholder(name));
                VarId(i as u8)
            }
        };
        for r in refs {
            if self.lookup(r).is_none() {
                if let Some(i) = self.free_slot() {
                    self.syms[i] = Some(placeholder(r));
                }
            }
        }
        let old = self.syms[id.0 as usize]
            .map(|s| s.kind)
            .unwrap_or(Kind::Placeholder);
        if let Kind::Expr { start, len } = old {
            self.remove_ops(start as usize, len as usize);
        }
        let kind = build(self, id);
        if let Some(hw) = hardware(&old) {
            // A new definition on the same (or an overlapping) output has already reconfigured it.
            let superseded = match (hw, hardware(&kind)) {
                (Hw::Pwm(a), Some(Hw::Pwm(b))) => a.overlaps(b),
                (a, b) => Some(a) == b,
            };
            if !superseded {
                self.release(hw, hal);
            }
        }
        self.syms[id.0 as usize] = Some(Symbol {
            name: mk_name(name),
            kind,
            value,
            task: task.map(Task::new),
        });
        self.collect_placeholders();
        self.rebuild();
        id
    }

    fn resolve(&self, name: &str) -> VarId {
        self.lookup(name).unwrap_or(VarId(0))
    }

    fn cmd_defexp(
        &mut self,
        a: &mut Args<'_, '_>,
        hal: &mut impl Hal,
        out: &mut impl Write,
    ) -> Result<()> {
        let name = a.name("varname")?;
        let toks = &a.toks[a.pos..];
        if toks.is_empty() {
            return Err(Error::Missing {
                command: "defexp",
                expected: "a postfix expression",
                usage: a.usage,
            });
        }
        expr::validate::<N>("defexp", toks)?;
        let target = self.check_target("defexp", name, Family::Def)?;
        let mut refs = [""; crate::capacity::MAX_EXPR_TOKENS];
        let mut nrefs = 0;
        for t in toks {
            if let Some(Class::Name(n)) = expr::classify::<N>(t) {
                refs[nrefs] = n;
                nrefs += 1;
            }
        }
        let refs = &refs[..nrefs];
        let constant = match toks {
            [t] => parse_number::<N>(t),
            _ => None,
        };
        if let Some(v) = constant {
            self.check_refs("defexp", name, target, &[], false)?;
            self.commit(name, &[], None, v, hal, |_, _| Kind::Const);
        } else {
            self.check_refs("defexp", name, target, refs, true)?;
            let old_len = match target.and_then(|t| self.sym(t)).map(|s| s.kind) {
                Some(Kind::Expr { len, .. }) => len as usize,
                _ => 0,
            };
            if self.ops_used - old_len + toks.len() > crate::capacity::MAX_EXPR_OPS {
                return Err(Error::Full {
                    command: "defexp",
                    what: "expression tokens",
                    capacity: crate::capacity::MAX_EXPR_OPS,
                });
            }
            self.commit(name, refs, None, N::ZERO, hal, |e, _| {
                let start = e.ops_used;
                for t in toks {
                    let op = match expr::classify::<N>(t) {
                        Some(Class::Lit(v)) => Op::Lit(v),
                        Some(Class::Name(n)) => Op::Var(e.resolve(n)),
                        Some(Class::Bin(b)) => Op::Bin(b),
                        Some(Class::Un(u)) => Op::Un(u),
                        None => Op::Lit(N::ZERO),
                    };
                    e.ops[e.ops_used] = op;
                    e.ops_used += 1;
                }
                Kind::Expr {
                    start: start as u16,
                    len: toks.len() as u16,
                }
            });
        }
        if let Some(id) = self.lookup(name) {
            self.write_tree(id, out);
        }
        Ok(())
    }

    fn cmd_block(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
        let cmd = a.cmd;
        let name = a.name("varname")?;
        let src = a.name("basename")?;
        let target = self.check_target(cmd, name, Family::Def)?;
        match cmd {
            "defscale" => {
                let lo_in: N = a.number("the lower input bound a")?;
                let t_b = a.toks.get(a.pos).copied().unwrap_or("");
                let hi_in: N = a.number("the upper input bound b")?;
                let lo: N = a.number("the lower output bound c")?;
                let hi: N = a.number("the upper output bound d")?;
                a.end()?;
                if hi_in == lo_in {
                    return Err(Error::Invalid {
                        command: cmd,
                        token: tok(t_b),
                        expected: "an input bound different from a (the interval [a,b] is empty)",
                    });
                }
                self.check_refs(cmd, name, target, &[src], true)?;
                self.commit(name, &[src], None, N::ZERO, hal, |e, _| Kind::Scale {
                    src: e.resolve(src),
                    a: lo_in,
                    b: hi_in,
                    c: lo,
                    d: hi,
                });
            }
            "defsat" => {
                let lo: N = a.number("the lower limit")?;
                let t_hi = a.toks.get(a.pos).copied().unwrap_or("");
                let hi: N = a.number("the upper limit")?;
                a.end()?;
                if hi < lo {
                    return Err(Error::Invalid {
                        command: cmd,
                        token: tok(t_hi),
                        expected: "an upper limit at least the lower limit",
                    });
                }
                self.check_refs(cmd, name, target, &[src], true)?;
                self.commit(name, &[src], None, N::ZERO, hal, |e, _| Kind::Sat {
                    src: e.resolve(src),
                    lo,
                    hi,
                });
            }
            "defint" | "defdiff" => {
                let rate = a.rate("refreshFreq")?;
                a.end()?;
                self.check_refs(cmd, name, target, &[src], false)?;
                let int = cmd == "defint";
                self.commit(name, &[src], Some(rate), N::ZERO, hal, |e, _| {
                    let src = e.resolve(src);
                    if int {
                        Kind::Int {
                            src,
                            st: Trapezoid::default(),
                        }
                    } else {
                        Kind::Diff {
                            src,
                            st: TwoPoint::default(),
                        }
                    }
                });
            }
            "defwind" => {
                let rate = a.rate("refreshFreq")?;
                let gain: N = a.number("the anti-windup gain (a number)")?;
                let pre = a.name("presat (the control before saturation)")?;
                let post = a.name("postsat (the control after saturation)")?;
                a.end()?;
                let refs = [src, pre, post];
                self.check_refs(cmd, name, target, &refs, false)?;
                self.commit(name, &refs, Some(rate), N::ZERO, hal, |e, _| Kind::Wind {
                    src: e.resolve(src),
                    gain,
                    pre: e.resolve(pre),
                    post: e.resolve(post),
                    st: Trapezoid::default(),
                });
            }
            "deflpf" => {
                let rate = a.rate("refreshFreq")?;
                let t = a.toks.get(a.pos).copied().unwrap_or("");
                let fc: N = a.number("the cutoff frequency in Hz")?;
                a.end()?;
                if fc <= N::ZERO {
                    return Err(Error::Invalid {
                        command: cmd,
                        token: tok(t),
                        expected: "a cutoff frequency above 0 Hz",
                    });
                }
                self.check_refs(cmd, name, target, &[src], false)?;
                self.commit(name, &[src], Some(rate), N::ZERO, hal, |e, _| Kind::Lpf {
                    src: e.resolve(src),
                    cutoff_hz: fc,
                    last_t: None,
                });
            }
            _ => {
                // defpid
                let rate = a.rate("refreshFreq")?;
                let kp = a.operand::<N>("kp (a number or variable)")?;
                let ki = a.operand::<N>("ki (a number or variable)")?;
                let kd = a.operand::<N>("kd (a number or variable)")?;
                let limits = match a.remaining() {
                    0 => None,
                    1 => {
                        a.pos += 1;
                        return Err(Error::Missing {
                            command: cmd,
                            expected: "the upper output limit",
                            usage: a.usage,
                        });
                    }
                    _ => {
                        let lo: N = a.number("the lower output limit")?;
                        let t_hi = a.toks.get(a.pos).copied().unwrap_or("");
                        let hi: N = a.number("the upper output limit")?;
                        if hi < lo {
                            return Err(Error::Invalid {
                                command: cmd,
                                token: tok(t_hi),
                                expected: "an upper limit at least the lower limit",
                            });
                        }
                        Some((lo, hi))
                    }
                };
                a.end()?;
                let mut refs = [src, "", "", ""];
                let mut n = 1;
                for (v, t) in [kp, ki, kd] {
                    if v.is_none() {
                        refs[n] = t;
                        n += 1;
                    }
                }
                let refs = &refs[..n];
                self.check_refs(cmd, name, target, refs, false)?;
                self.commit(name, refs, Some(rate), N::ZERO, hal, |e, _| {
                    let op = |(v, t): (Option<N>, &str)| match v {
                        Some(v) => Operand::Lit(v),
                        None => Operand::Var(e.resolve(t)),
                    };
                    Kind::Pid {
                        src: e.resolve(src),
                        kp: op(kp),
                        ki: op(ki),
                        kd: op(kd),
                        limits,
                        int: Trapezoid::default(),
                        der: TwoPoint::default(),
                    }
                });
            }
        }
        Ok(())
    }

    fn pwm_owner(&self, out: PwmOutput, except: Option<VarId>) -> Option<VarId> {
        (0..MAX_SYMBOLS).map(|i| VarId(i as u8)).find(|&id| {
            Some(id) != except
                && matches!(self.sym(id).map(|s| s.kind),
                    Some(Kind::PwmFixed { out: o, .. }) | Some(Kind::PwmFollow { out: o, .. }) if o.overlaps(out))
        })
    }

    fn pin_owner(&self, pin: u8, except: Option<VarId>) -> Option<VarId> {
        (0..MAX_SYMBOLS).map(|i| VarId(i as u8)).find(|&id| {
            Some(id) != except
                && matches!(self.sym(id).map(|s| s.kind),
                    Some(Kind::GpioIn { pin: p }) | Some(Kind::GpioOut { pin: p, .. }) if p == pin)
        })
    }

    fn note_frequency(out: &mut impl Write, name: &str, requested: f32, actual: f32) {
        if (actual - requested).abs() > requested * 1e-4 {
            let _ = writeln!(out, "note: {name} runs at {actual} Hz, the nearest to {requested} Hz this timer can make");
        }
    }

    fn cmd_pwm(
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

    fn cmd_defpwm(
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

    fn parse_pin(&self, a: &mut Args<'_, '_>, hal: &impl Hal) -> Result<(u8, &'static str)> {
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

    fn cmd_gpio_in(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
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

    fn cmd_defgpio(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
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

    fn cmd_adc(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
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
        let v = self.volts(input, code, hal);
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
            value: N::from_u32(code as u32),
            task: Some(Task::new(rate)),
        });
        self.syms[vid.0 as usize] = Some(Symbol {
            name: volts_name,
            kind: Kind::AdcVolts { raw: rid },
            value: v,
            task: None,
        });
        self.rebuild();
        Ok(())
    }

    fn cmd_rate(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
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
        task.mhz = rate;
        task.frac = 0;
        if let Some(s) = &mut self.syms[id.0 as usize] {
            s.task = Some(task);
        }
        self.rebuild();
        Ok(())
    }

    fn check_path(&self, cmd: &'static str, path: &str) -> Result<usize> {
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

    fn cmd_infile(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
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

    fn cmd_log(&mut self, a: &mut Args<'_, '_>, hal: &mut impl Hal) -> Result<()> {
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

    // ----- writable values, deletion ------------------------------------------------------

    /// Sets a writable variable: a constant, the duty (%) of a `pwm` output, or the accumulated
    /// value of an integral (`defint`/`defwind`). Others are refused with
    /// [`Error::NotWritable`]; the table is unchanged on error.
    pub fn set(&mut self, id: VarId, value: N, hal: &mut impl Hal) -> Result<()> {
        let sym = *self.sym(id).ok_or(Error::UnknownVariable {
            command: "set",
            token: tok("?"),
        })?;
        if !value.is_finite() {
            return Err(Error::Invalid {
                command: "set",
                token: tok("value"),
                expected: "a finite number",
            });
        }
        let mut kind = sym.kind;
        let stored = match &mut kind {
            Kind::Const => value,
            Kind::PwmFixed { out, .. } => {
                if value < N::ZERO || value > N::from_u32(100) {
                    let mut b = [0u8; 24];
                    let mut w = crate::text::BufWriter::new(&mut b);
                    let _ = write!(w, "{value}");
                    return Err(Error::Invalid {
                        command: "set",
                        token: tok(w.as_str()),
                        expected: "a duty cycle in percent (0-100)",
                    });
                }
                let applied = hal.pwm_set_duty(*out, (value.to_f64() / 100.0) as f32);
                N::from_f64(applied as f64 * 100.0)
            }
            Kind::Int { st, .. } | Kind::Wind { st, .. } => {
                st.acc = value;
                value
            }
            k => {
                return Err(Error::NotWritable {
                    name: sym.name,
                    what: k.what(),
                })
            }
        };
        if let Some(s) = &mut self.syms[id.0 as usize] {
            s.kind = kind;
            s.value = stored;
        }
        Ok(())
    }

    /// Deletes a variable (both of an ADC pair), releasing its hardware or file. Refused with
    /// [`Error::InUse`] while other variables read it.
    pub fn delete(&mut self, id: VarId, hal: &mut impl Hal) -> Result<()> {
        let sym = *self.sym(id).ok_or(Error::UnknownVariable {
            command: "del",
            token: tok("?"),
        })?;
        let partner = match sym.kind {
            Kind::AdcRaw { volts, .. } => Some(volts),
            Kind::AdcVolts { raw } => Some(raw),
            _ => None,
        };
        let mut users = NameList::default();
        for who in [Some(id), partner].into_iter().flatten() {
            self.users(who, |u| {
                if Some(u) != partner && u != id {
                    users.push(self.name_of(u));
                }
            });
        }
        if users.total() > 0 {
            return Err(Error::InUse {
                name: sym.name,
                users,
            });
        }
        for who in [Some(id), partner].into_iter().flatten() {
            self.remove(who, hal);
        }
        self.collect_placeholders();
        self.rebuild();
        Ok(())
    }

    /// Deletes every variable, releasing all hardware and files.
    pub fn clear(&mut self, hal: &mut impl Hal) {
        for i in 0..MAX_SYMBOLS {
            self.remove(VarId(i as u8), hal);
        }
        self.rebuild();
    }

    fn remove(&mut self, id: VarId, hal: &mut impl Hal) {
        let Some(sym) = self.syms[id.0 as usize] else {
            return;
        };
        if let Kind::Expr { start, len } = sym.kind {
            self.remove_ops(start as usize, len as usize);
        }
        if let Some(hw) = hardware(&sym.kind) {
            self.release(hw, hal);
        }
        self.syms[id.0 as usize] = None;
    }

    fn release(&mut self, hw: Hw, hal: &mut impl Hal) {
        match hw {
            Hw::Adc(input) => hal.adc_release(input),
            Hw::Pwm(out) => hal.pwm_release(out),
            Hw::Pin(pin) => hal.gpio_release(pin),
            Hw::Stream(slot) => {
                if let Some(s) = self.streams.get_mut(slot as usize).and_then(|s| s.take()) {
                    hal.close(s.id);
                }
            }
        }
    }

    fn remove_ops(&mut self, start: usize, len: usize) {
        let end = (start + len).min(self.ops_used);
        self.ops.copy_within(end..self.ops_used, start);
        self.ops_used -= end - start;
        for s in self.syms.iter_mut().flatten() {
            if let Kind::Expr { start: st, .. } = &mut s.kind {
                if *st as usize > start {
                    *st -= (end - start) as u16;
                }
            }
        }
    }

    /// Removes placeholders nothing refers to any more.
    fn collect_placeholders(&mut self) {
        for i in 0..MAX_SYMBOLS {
            if matches!(self.syms[i].map(|s| s.kind), Some(Kind::Placeholder))
                && !self.has_users(VarId(i as u8))
            {
                self.syms[i] = None;
            }
        }
    }
}

fn placeholder<N: Real>(name: &str) -> Symbol<N> {
    Symbol {
        name: mk_name(name),
        kind: Kind::Placeholder,
        value: N::ZERO,
        task: None,
    }
}

//! Command execution: parse a line completely, check everything, then change the table.
//! A command that returns an error has changed neither the table nor (except for a HAL call that
//! itself failed) the hardware.
//!
//! `mod.rs` dispatches; `args` reads arguments; `define` checks and commits definitions;
//! `hardware` holds the commands that configure peripherals and files; `edit` sets, deletes
//! and releases.

mod args;
mod define;
mod edit;
mod hardware;

use core::fmt::Write;

use crate::capacity::{MAX_RUN_SECONDS, MAX_SYMBOLS};
use crate::engine::{Engine, Menu};
use crate::error::{tok, Error, Result};
use crate::hal::Hal;
use crate::help;
use crate::lexer::{parse_number, Tokens};
use crate::num::Real;
use crate::symbol::{Kind, SymSet};
use crate::VarId;

use args::Args;

/// What `run` expects, in its error message and in the ports' own option checks.
pub const RUN_EXPECTED: &str = "a duration in seconds from 0 to 1e9";

/// Parses the argument of `run` (and a port's `--run` option): a finite number of seconds in
/// `0..=`[`MAX_RUN_SECONDS`]. `inf`, `nan`, negative and larger values are refused with the
/// same message as `run`.
pub fn run_seconds(token: &str) -> Result<f64> {
    parse_number::<f64>(token)
        .filter(|s| (0.0..=MAX_RUN_SECONDS).contains(s))
        .map(|s| s + 0.0) // -0 is 0
        .ok_or(Error::Invalid {
            command: "run",
            token: tok(token),
            expected: RUN_EXPECTED,
        })
}

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
        let placeholders_before = self.placeholders();
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
                    self.tokens_used(),
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
                return Ok(Outcome::Run(run_seconds(t)?));
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
        self.note_new_placeholders(placeholders_before, out);
        Ok(Outcome::Done)
    }

    /// The slots holding placeholders (names used before their definition).
    fn placeholders(&self) -> SymSet {
        let mut set = SymSet::EMPTY;
        for (i, s) in self.syms.iter().enumerate() {
            if matches!(s, Some(s) if matches!(s.kind, Kind::Placeholder)) {
                set.insert(i);
            }
        }
        set
    }

    /// A name used before it is defined reads 0 (the thesis defines gains after their use), so
    /// a misspelt input would silently read 0: say so for every name a command has just made a
    /// placeholder, with the defined name it most resembles.
    fn note_new_placeholders(&self, before: SymSet, out: &mut impl Write) {
        let now = self.placeholders();
        for i in 0..MAX_SYMBOLS {
            if !now.contains(i) || before.contains(i) {
                continue;
            }
            let name = self.name_of(VarId(i as u8));
            let _ = write!(
                out,
                "note: '{name}' is not defined yet; it reads 0 until it is"
            );
            let similar =
                self.syms.iter().flatten().find(|s| {
                    !matches!(s.kind, Kind::Placeholder) && similar(s.name.as_str(), name)
                });
            let _ = match similar {
                Some(s) => writeln!(out, " (did you mean '{}'?)", s.name),
                None => writeln!(out),
            };
        }
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
}

/// Names a typo apart: equal ignoring case, or, both of three characters or more, one edit
/// apart (a character changed, added, removed, or two neighbours swapped), like `adcO` for
/// `adc0`.
fn similar(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.eq_ignore_ascii_case(b) {
        return true;
    }
    if a.len() < 3 || b.len() < 3 {
        return false;
    }
    let prefix = a.iter().zip(b).take_while(|(x, y)| x == y).count();
    let (a, b) = (&a[prefix..], &b[prefix..]);
    match (a.len(), b.len()) {
        (n, m) if n == m => {
            a[1..] == b[1..] || (n >= 2 && a[0] == b[1] && a[1] == b[0] && a[2..] == b[2..])
        }
        (n, m) if n == m + 1 => a[1..] == *b,
        (n, m) if n + 1 == m => *a == b[1..],
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::similar;

    #[test]
    fn similar_names_are_one_typo_apart() {
        for (a, b) in [
            ("adcO", "adc0"),
            ("Kp", "kp"),
            ("Isgnl", "Isgn"),
            ("sgnl", "sngl"),
            ("PID", "PIDx"),
        ] {
            assert!(similar(a, b) && similar(b, a), "{a} {b}");
        }
        for (a, b) in [
            ("adc0", "adc12"),
            ("Kp", "Kd"),
            ("abc", "cba"),
            ("ab", "abcd"),
            ("x", "y"),
        ] {
            assert!(!similar(a, b), "{a} {b}");
        }
    }
}

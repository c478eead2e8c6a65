//! The command reference: menus and `help` texts (thesis Fig. 5.1, 5.16).

use core::fmt::{self, Write};

use crate::engine::Menu;

/// One command of the language.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandSpec {
    /// The command word.
    pub name: &'static str,
    /// The menu whose listing shows it (every command works in both menus).
    pub menu: Menu,
    /// One line for the menu listing.
    pub summary: &'static str,
    /// Synopsis.
    pub usage: &'static str,
    /// Full `help <cmd>` text (after the synopsis).
    pub detail: &'static str,
}

const fn c(
    name: &'static str,
    menu: Menu,
    summary: &'static str,
    usage: &'static str,
    detail: &'static str,
) -> CommandSpec {
    CommandSpec {
        name,
        menu,
        summary,
        usage,
        detail,
    }
}

use Menu::{Main, Var};

/// Every command, in menu-listing order.
pub const COMMANDS: &[CommandSpec] = &[
    c("var", Main, "Switch to the variables menu", "var", "Lists the variable commands; they work from either menu."),
    c("adc", Main, "Configure the ADC Module", "adc channel frequency",
      "Format of the command is:\nadc channel frequency\n\n\
       channel(0-3,A,B): The channel to sample. Codes 0-3 indicate the numbered\n\
       ADCs and A, B are the differential ADCs.\n\
       T is the temperature sensor, where the board has one.\n\
       frequency(1-100000): Desired sampling frequency\n\
       Creates ADCn (raw code) and adcn (volts: 0..vref single-ended, -vref/2..vref/2 differential).\n\
       Repeating the command changes the sampling frequency."),
    c("pwm", Main, "Configure a PWM output", "pwm channel frequency duty",
      "channel: output number (0, 1, ...) or complementary pair letter (A = outputs 0/1, B = 2/3).\n\
       frequency: PWM frequency in Hz (outputs 2k and 2k+1 share a timer and a frequency).\n\
       duty(0-100): duty cycle in percent.\n\
       Creates the settable variable PWMn (the duty actually produced)."),
    c("gpio", Main, "Sample a digital input pin", "gpio pin frequency",
      "Creates GPIOn, 0 or 1, read at the given frequency (Hz)."),
    c("capacities", Main, "Show the fixed capacities of this build", "capacities",
      "Symbols, expression sizes, line length, streams, number type and table memory."),
    c("script", Main, "Run a file of commands (host port)", "script filename",
      "Runs each line of the file as if typed; stops at the first error."),
    c("save", Main, "Print or save the configuration as a script", "save [filename]",
      "Writes the command lines that recreate the variable table (constants with their current\n\
       values). Without a file name the script is printed."),
    c("load", Main, "Replace the configuration by a saved script (host port)", "load filename",
      "Clears the table and runs the file; if any line fails, the previous table is kept."),
    c("clear", Main, "Delete every variable", "clear", "Releases all hardware and files the variables used."),
    c("run", Main, "Advance time (host port)", "run seconds",
      "Simulated time: runs every update due in the next `seconds` as fast as possible.\n\
       Real time: waits `seconds` while the variables update.\n\
       `seconds` is 0 to 1e9; Ctrl-C stops a run where it is (host)."),
    c("main", Var, "Return to the main menu", "main", "Lists the hardware commands; they work from either menu."),
    c("printv", Var, "Print value of a variable", "printv varname", "Prints 'name - value'."),
    c("printvars", Var, "Print the variable table", "printvars",
      "Print the symbolic variable table along with its current values."),
    c("help", Var, "Display list of commands", "help [cmdname]",
      "Without an argument, lists the commands of the current menu; with one, explains it."),
    c("defexp", Var, "Define a variable as a postfix expression", "defexp varname postfix...",
      "Postfix (reverse Polish) expression of numbers, variables and the operators\n\
       + - * / min max (two operands) and neg abs sqrt sin cos exp (one operand).\n\
       Example: defexp PID Pterm Iterm + Dterm +\n\
       A single number defines a constant that 'set' can change. Evaluated on demand.\n\
       Variables may be used before they are defined (they read 0 until then)."),
    c("defscale", Var, "Linearly scale a variable, with hard limits", "defscale varname basename a b c d",
      "Maps basename from [a,b] to [c,d] and hard-limits the result to [c,d]."),
    c("defsat", Var, "Saturate a variable", "defsat varname basename low high",
      "basename limited to [low, high]."),
    c("defint", Var, "Trapezoid integral of a variable", "defint varname basename refreshFreq",
      "Inext = Icurrent + (t2 - t1) (x1 + x2) / 2, updated refreshFreq times a second."),
    c("defwind", Var, "Anti-windup integral", "defwind varname basename refreshFreq gain presat postsat",
      "Integrates basename + gain (postsat - presat) (thesis Fig. 5.11): while the output is\n\
       saturated the difference bleeds the integral back instead of letting it wind up."),
    c("defdiff", Var, "Two-point derivative of a variable", "defdiff varname basename refreshFreq",
      "dx/dt = (x2 - x1) / (t2 - t1), updated refreshFreq times a second."),
    c("deflpf", Var, "First-order low-pass filter", "deflpf varname basename refreshFreq cutoffHz",
      "y += dt / (tau + dt) (x - y), tau = 1 / (2 pi cutoffHz)."),
    c("defpid", Var, "PID controller in one line", "defpid varname error refreshFreq kp ki kd [low high]",
      "kp e + ki I(e) + kd D(e) with the defint/defdiff methods; gains are numbers or variables.\n\
       With limits the output is clamped and the integral is held while it would push further\n\
       into saturation."),
    c("defpwm", Var, "Drive a PWM output from a variable",
      "defpwm (varname) (basename) (refreshFreq) (channel) (frequency)",
      "At refreshFreq the duty cycle (percent, clamped to 0-100) is set to basename's value.\n\
       channel and frequency as for 'pwm'."),
    c("defgpio", Var, "Drive a digital output from a variable", "defgpio varname basename refreshFreq pin",
      "The pin is high while basename >= 0.5."),
    c("set", Var, "Set a constant, a PWM duty or an integral", "set varname value",
      "Changes a constant (defexp name number), the duty of a 'pwm' output, or resets an integral."),
    c("del", Var, "Delete a variable", "del varname",
      "Refused while other variables use it (the message lists them). Deleting either ADC\n\
       variable deletes the pair."),
    c("rate", Var, "Change the update frequency of a periodic variable", "rate varname frequency", ""),
    c("show", Var, "Show a variable's definition, rate and users", "show varname", ""),
    c("infile", Var, "Play back a file as a variable (host port)", "infile varname frequency filename",
      "The file holds one number per line; each update presents the next one, looping at the end."),
    c("log", Var, "Record a variable to a file (host port)", "log [logname] varname frequency filename",
      "Writes the value frequency times a second, one value per line. The log itself is a\n\
       variable (default name L<varname>) that 'del' stops."),
];

/// The spec of a command word.
pub fn spec(name: &str) -> Option<&'static CommandSpec> {
    COMMANDS.iter().find(|c| c.name == name)
}

/// Prints the listing of `menu` (thesis Fig. 5.1).
pub(crate) fn write_menu(out: &mut dyn Write, menu: Menu) -> fmt::Result {
    writeln!(out, "Available commands")?;
    writeln!(
        out,
        "(Type 'help cmdname' for more information on a command)"
    )?;
    writeln!(out, "------------------")?;
    // The thesis lists these four first in the variables menu.
    let first: &[&str] = match menu {
        Menu::Var => &["main", "printv", "printvars", "help"],
        Menu::Main => &["var", "help"],
    };
    for name in first {
        if let Some(c) = spec(name) {
            writeln!(out, "{} : {}", c.name, c.summary)?;
        }
    }
    for c in COMMANDS
        .iter()
        .filter(|c| c.menu == menu && !first.contains(&c.name))
    {
        writeln!(out, "{} : {}", c.name, c.summary)?;
    }
    Ok(())
}

/// Prints `help cmd`.
pub(crate) fn write_command(out: &mut dyn Write, c: &CommandSpec) -> fmt::Result {
    writeln!(out, "{}", c.summary)?;
    if c.detail.starts_with("Format") {
        writeln!(out, "{}", c.detail)
    } else {
        writeln!(out, "{}", c.usage)?;
        if !c.detail.is_empty() {
            writeln!(out, "{}", c.detail)?;
        }
        Ok(())
    }
}

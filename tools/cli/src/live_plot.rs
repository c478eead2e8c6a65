//! `conductor echo --plot`: a live terminal chart (Unicode braille, `textplots`) of the matching
//! states over the last `--window` seconds, with a legend line per state giving its newest
//! value, its flags now and how many samples in the window carried each flag.
//!
//! On a terminal the screen is redrawn 10 times a second, the lines in the states' colours;
//! otherwise (a pipe, a file) a plain frame is printed every second and once at the end.

use std::collections::VecDeque;
use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

use conductor_bus::{monotonic_ns, status, StateSubscriber};
use textplots::{Chart, ColorPlot, LabelBuilder, LabelFormat, Plot, Shape};

use crate::cli::EchoArgs;
use crate::error::{CliError, Result};
use crate::out;
use crate::plot::PALETTE;

/// One plotted state.
pub struct Plotted {
    /// `subsystem/state`.
    pub name: String,
    /// Units (may be empty).
    pub units: String,
    /// Its samples.
    pub sub: StateSubscriber,
    /// `(t_sample_ns, value, status)` within the window, oldest first.
    window: VecDeque<(u64, f64, u32)>,
}

impl Plotted {
    /// A state to plot.
    pub fn new(name: String, units: String, sub: StateSubscriber) -> Self {
        Self {
            name,
            units,
            sub,
            window: VecDeque::new(),
        }
    }
}

/// Columns and rows of the terminal on stdout, if it is one.
fn terminal_size() -> Option<(u16, u16)> {
    // SAFETY: TIOCGWINSZ fills a `winsize` we own; the fd is stdout, open for our lifetime.
    unsafe {
        let mut ws: libc::winsize = std::mem::zeroed();
        (libc::ioctl(libc::STDOUT_FILENO, libc::TIOCGWINSZ, &mut ws) == 0 && ws.ws_col > 0)
            .then_some((ws.ws_col, ws.ws_row))
    }
}

/// One frame: a title, the chart and a legend line per state. `now_ns` is the chart's right
/// edge; `colour` draws the lines and legend marks in the states' colours (ANSI true colour).
pub fn frame(
    states: &[Plotted],
    now_ns: u64,
    window_s: f64,
    (cols, rows): (u16, u16),
    colour: bool,
) -> String {
    let x = |t: u64| -((now_ns.saturating_sub(t)) as f64 * 1e-9) as f32;
    let lines: Vec<Vec<(f32, f32)>> = states
        .iter()
        .map(|s| {
            s.window
                .iter()
                .filter(|p| p.1.is_finite())
                .map(|p| (x(p.0), p.1 as f32))
                .collect()
        })
        .collect();
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for &(_, y) in lines.iter().flatten() {
        lo = lo.min(y);
        hi = hi.max(y);
    }
    if lo > hi {
        (lo, hi) = (-1.0, 1.0);
    } else if hi - lo < 1e-6 {
        (lo, hi) = (lo - 1.0, hi + 1.0);
    } else {
        let pad = (hi - lo) * 0.05;
        (lo, hi) = (lo - pad, hi + pad);
    }
    // Braille: 2 dots per column, 4 per row; room for the y labels and the legend.
    let width = (u32::from(cols).saturating_sub(14) * 2).max(32);
    let legend = states.len() as u32 + 3;
    let height = (u32::from(rows).saturating_sub(legend) * 4).clamp(12, 160);
    let shapes: Vec<Shape> = lines.iter().map(|l| Shape::Lines(l)).collect();
    let mut chart = Chart::new_with_y_range(width, height, -(window_s as f32), 0.0, lo, hi);
    let mut c = chart.y_label_format(LabelFormat::Custom(Box::new(|v| format!("{v:.3}"))));
    for (i, s) in shapes.iter().enumerate() {
        c = if colour {
            let (r, g, b) = PALETTE[i % PALETTE.len()];
            c.linecolorplot(s, textplots_rgb(r, g, b))
        } else {
            c.lineplot(s)
        };
    }
    c.axis();
    c.figures();
    let mut text = format!(
        "{} state(s), last {} s (x: seconds before now; y: value)\n{c}",
        states.len(),
        out::value(window_s)
    );
    for (i, s) in states.iter().enumerate() {
        let mark = if colour {
            let (r, g, b) = PALETTE[i % PALETTE.len()];
            format!("\x1b[38;2;{r};{g};{b}m━━\x1b[0m")
        } else {
            format!("[{}]", i + 1)
        };
        let newest = s.window.back();
        let value = newest.map_or("-".into(), |p| out::value(p.1));
        let now = newest.map_or("-".into(), |p| out::flags(p.2));
        // How many samples in the window carried each flag.
        let mut counts = Vec::new();
        for bit in (0..32).map(|b| 1u32 << b) {
            let n = s.window.iter().filter(|p| p.2 & bit != 0).count();
            if n > 0 {
                let name = status::names(bit).next().unwrap_or("unknown");
                counts.push(format!("{name} {n}/{}", s.window.len()));
            }
        }
        text += &format!(
            "{mark} {}  {value}{}{}  flags: {now}{}\n",
            s.name,
            if s.units.is_empty() { "" } else { " " },
            s.units,
            if counts.is_empty() {
                String::new()
            } else {
                format!("  (in window: {})", counts.join(", "))
            }
        );
    }
    text
}

fn textplots_rgb(r: u8, g: u8, b: u8) -> rgb::RGB8 {
    rgb::RGB8 { r, g, b }
}

/// Runs until `--duration`, `--count` frames, or Ctrl-C; returns the number of frames drawn.
pub fn run(mut states: Vec<Plotted>, args: &EchoArgs) -> Result<u64> {
    if !(args.window > 0.0 && args.window.is_finite()) {
        return Err(CliError::Usage(format!(
            "--window must be positive, got {}",
            args.window
        )));
    }
    let tty = std::io::stdout().is_terminal();
    let every = Duration::from_millis(if tty { 100 } else { 1000 });
    let window_ns = (args.window * 1e9) as u64;
    let end = args
        .duration
        .map(|d| Instant::now() + Duration::from_secs_f64(d.max(0.0)));
    let stdout = std::io::stdout();
    let mut frames = 0u64;
    let mut last = Instant::now();
    loop {
        let now_ns = monotonic_ns();
        for s in &mut states {
            while let Some(x) = s.sub.receive()? {
                s.window.push_back((x.t_sample_ns, x.value, x.status));
            }
            while s.window.front().is_some_and(|p| p.0 + window_ns < now_ns) {
                s.window.pop_front();
            }
        }
        let done = end.is_some_and(|t| Instant::now() >= t) || conductor_bus::shutdown::requested();
        if last.elapsed() >= every || (done && !tty) {
            last = Instant::now();
            let size = terminal_size().unwrap_or((100, 30));
            let mut text = frame(&states, now_ns, args.window, size, tty);
            if tty {
                // Home and clear, then the frame.
                text.insert_str(0, "\x1b[H\x1b[2J");
            } else {
                text.push('\n');
            }
            let mut lock = stdout.lock();
            if lock
                .write_all(text.as_bytes())
                .and_then(|()| lock.flush())
                .is_err()
            {
                return Ok(frames); // the reader went away
            }
            frames += 1;
        }
        if done || args.count.is_some_and(|c| frames >= c) {
            return Ok(frames);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

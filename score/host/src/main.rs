//! `score`: the Score terminal on a PC.
//!
//! Interactive (a line editor when stdin is a terminal, plain lines otherwise) in real time by
//! default; `--script FILE` runs a file in simulated time, then `--run SECONDS` advances it.

use std::io::{BufRead, IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use clap::Parser;
use score_host::{Session, TimeMode};
use signal_hook::consts::SIGINT;

#[derive(Parser, Debug)]
#[command(
    name = "score",
    version,
    about = "Score signal-variable terminal (host port)"
)]
struct Cli {
    /// Run this file of commands, then exit (after --run).
    #[arg(long, value_name = "FILE")]
    script: Option<PathBuf>,
    /// After the script, advance time by this many seconds (0 to 1e9, as the `run` command).
    #[arg(long, value_name = "SECONDS", value_parser = run_seconds, allow_hyphen_values = true)]
    run: Option<f64>,
    /// Simulated time (default for --script).
    #[arg(long, conflicts_with = "realtime")]
    simulated: bool,
    /// Real time (default for interactive sessions).
    #[arg(long)]
    realtime: bool,
    /// Do not echo script lines or print the banner.
    #[arg(long, short)]
    quiet: bool,
    /// Directory for infile/log/script/save paths (default: the current directory).
    #[arg(long, value_name = "DIR", default_value = ".")]
    dir: PathBuf,
}

/// `--run`: checked exactly as the `run` command checks its argument.
fn run_seconds(s: &str) -> Result<f64, String> {
    score_core::run_seconds(s).map_err(|e| e.to_string())
}

/// SIGINT (Ctrl-C) while a command runs stops a `run` at the current instant (the session
/// continues); while the session waits for input it ends the program (status 130), as usual.
fn on_sigint(session: &mut Session) -> Arc<AtomicBool> {
    let interrupt = Arc::new(AtomicBool::new(false));
    let idle = Arc::new(AtomicBool::new(true));
    // Registration fails only for forbidden signals; SIGINT is not one.
    let _ = signal_hook::flag::register_conditional_shutdown(SIGINT, 130, idle.clone());
    let _ = signal_hook::flag::register(SIGINT, interrupt.clone());
    session.set_interrupt(interrupt);
    idle
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let batch = cli.script.is_some();
    let mode = if cli.realtime || (!batch && !cli.simulated) {
        TimeMode::RealTime
    } else {
        TimeMode::Simulated
    };
    let mut session = Session::new(mode, &cli.dir);
    session.echo_scripts = !cli.quiet;
    let idle = on_sigint(&mut session);
    if let Some(path) = &cli.script {
        idle.store(false, Ordering::Relaxed);
        let mut out = String::new();
        let path = path.to_string_lossy().into_owned();
        let r = session.script(&path, &mut out);
        print!("{out}");
        let r = r.and_then(|()| cli.run.map_or(Ok(()), |s| session.advance(s)));
        if let Err(e) = r {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
        return ExitCode::SUCCESS;
    }
    if !cli.quiet {
        let mut banner = String::new();
        let _ = score_core::write_banner(&mut banner);
        println!("{banner}");
    }
    if let Some(s) = cli.run {
        idle.store(false, Ordering::Relaxed);
        if let Err(e) = session.advance(s) {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
        idle.store(true, Ordering::Relaxed);
    }
    repl(session, cli.quiet, idle)
}

/// Runs lines until end of input or `quit`; real-time sessions tick on a second thread.
fn repl(session: Session, quiet: bool, idle: Arc<AtomicBool>) -> ExitCode {
    let realtime = session.mode() == TimeMode::RealTime;
    let session = Arc::new(Mutex::new(session));
    let stop = Arc::new(AtomicBool::new(false));
    let ticker = realtime.then(|| {
        let (s, stop) = (session.clone(), stop.clone());
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                let wait = s.lock().map(|mut s| s.poll()).unwrap_or(None);
                std::thread::sleep(
                    wait.unwrap_or(Duration::from_millis(10))
                        .min(Duration::from_millis(10)),
                );
            }
        })
    });
    let mut failed = false;
    let terminal = std::io::stdin().is_terminal();
    // `echo`: print `$> line` first (piped input), once the line is taken in hand, so that
    // Ctrl-C after the echo interrupts the command rather than ending the program.
    let mut handle = |line: &str, echo: bool| -> bool {
        idle.store(false, Ordering::Relaxed);
        if echo {
            println!("{}{}", score_core::PROMPT, line.trim());
        }
        let cmd = line.trim();
        if cmd == "quit" || cmd == "exit" {
            return false;
        }
        let mut out = String::new();
        let r = session.lock().map(|mut s| s.line(line, &mut out));
        idle.store(true, Ordering::Relaxed);
        print!("{out}");
        match r {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                failed = true;
                // A caret under the token the error is about, below the line as typed (a
                // terminal) or as echoed after the prompt (trimmed).
                let col = e.column(line).filter(|_| terminal || !quiet);
                if let Some(col) = col {
                    let shift = if terminal {
                        0
                    } else {
                        line.len() - line.trim_start().len()
                    };
                    let pad = score_core::PROMPT.len() + (col - 1).saturating_sub(shift);
                    println!("{:pad$}^", "");
                }
                println!("error: {e}");
            }
            Err(_) => return false,
        }
        let _ = std::io::stdout().flush();
        true
    };
    if terminal {
        match rustyline::DefaultEditor::new() {
            Ok(mut ed) => {
                while let Ok(line) = ed.readline(score_core::PROMPT) {
                    let _ = ed.add_history_entry(line.as_str());
                    if !handle(&line, false) {
                        break;
                    }
                }
            }
            Err(e) => eprintln!("line editor unavailable: {e}"),
        }
    } else {
        for line in std::io::stdin().lock().lines() {
            let Ok(line) = line else { break };
            if !handle(&line, !quiet) {
                break;
            }
        }
    }
    stop.store(true, Ordering::Relaxed);
    if let Some(t) = ticker {
        let _ = t.join();
    }
    if failed && !terminal {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

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
    /// After the script, advance time by this many seconds.
    #[arg(long, value_name = "SECONDS")]
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
    if let Some(path) = &cli.script {
        let mut out = String::new();
        let path = path.to_string_lossy().into_owned();
        let r = session.script(&path, &mut out);
        print!("{out}");
        if let Err(e) = r {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
        if let Some(s) = cli.run {
            session.advance(s);
        }
        return ExitCode::SUCCESS;
    }
    if !cli.quiet {
        let mut banner = String::new();
        let _ = score_core::write_banner(&mut banner);
        println!("{banner}");
    }
    if let Some(s) = cli.run {
        session.advance(s);
    }
    repl(session, cli.quiet)
}

/// Runs lines until end of input or `quit`; real-time sessions tick on a second thread.
fn repl(session: Session, quiet: bool) -> ExitCode {
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
    let mut handle = |line: &str| -> bool {
        let cmd = line.trim();
        if cmd == "quit" || cmd == "exit" {
            return false;
        }
        let mut out = String::new();
        let r = session.lock().map(|mut s| s.line(line, &mut out));
        print!("{out}");
        match r {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                failed = true;
                println!("error: {e}");
            }
            Err(_) => return false,
        }
        let _ = std::io::stdout().flush();
        true
    };
    if std::io::stdin().is_terminal() {
        match rustyline::DefaultEditor::new() {
            Ok(mut ed) => {
                while let Ok(line) = ed.readline(score_core::PROMPT) {
                    let _ = ed.add_history_entry(line.as_str());
                    if !handle(&line) {
                        break;
                    }
                }
            }
            Err(e) => eprintln!("line editor unavailable: {e}"),
        }
    } else {
        for line in std::io::stdin().lock().lines() {
            let Ok(line) = line else { break };
            if !quiet {
                println!("{}{}", score_core::PROMPT, line.trim());
            }
            if !handle(&line) {
                break;
            }
        }
    }
    stop.store(true, Ordering::Relaxed);
    if let Some(t) = ticker {
        let _ = t.join();
    }
    if failed && !std::io::stdin().is_terminal() {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

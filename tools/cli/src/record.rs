//! `conductor record`: states to an MCAP file (layout in [`crate::recording`]).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, IsTerminal, Write};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use conductor_bus::{monotonic_ns, Bus, StateSubscriber, ABI_VERSION};
use indicatif::{ProgressBar, ProgressStyle};

use crate::cli::RecordArgs;
use crate::error::{CliError, Result};
use crate::recording::{self, Message};
use crate::select;

/// Per-subscriber queue: at 1 kHz this covers a quarter second of the recorder not running.
const QUEUE: usize = 256;

/// What a recording contains.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordReport {
    /// Messages written.
    pub messages: u64,
    /// `(state, samples written, samples lost)` per channel.
    pub per_state: Vec<(String, u64, u64)>,
    /// `duration` or `signal`.
    pub stopped_by: &'static str,
}

struct Track {
    name: String,
    sub: StateSubscriber,
    channel: u16,
    written: u64,
}

fn unix_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

fn progress(args: &RecordArgs) -> Option<ProgressBar> {
    if args.no_progress || !std::io::stderr().is_terminal() {
        return None;
    }
    let bar = match args.duration {
        Some(d) => ProgressBar::new((d * 1000.0) as u64).with_style(
            ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {percent}% {msg}")
                .ok()?
                .progress_chars("=> "),
        ),
        None => ProgressBar::new_spinner()
            .with_style(ProgressStyle::with_template("{spinner} {elapsed_precise} {msg}").ok()?),
    };
    Some(bar)
}

/// Records until `--duration` or Ctrl-C/SIGTERM; the file is finalised (summary, indexes,
/// footer) either way.
pub fn run(bus: &Bus, args: &RecordArgs) -> Result<RecordReport> {
    if let Some(d) = args.duration {
        if !(d > 0.0 && d.is_finite()) {
            return Err(CliError::Usage(format!(
                "--duration must be positive, got {d}"
            )));
        }
    }
    let manifest = match &args.manifest {
        Some(p) => Some((
            p.display().to_string(),
            std::fs::read_to_string(p).map_err(|e| CliError::io(p, e))?,
        )),
        None => None,
    };
    let states = select::states_wait(bus, &args.pattern, args.wait)?;
    let mut tracks = Vec::with_capacity(states.len());
    let path = &args.output;
    let file = File::create(path).map_err(|e| CliError::io(path, e))?;
    let mcap_err = |e: mcap::McapError| CliError::mcap(path, e);
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .chunk_size(Some(1 << 20))
        .profile(recording::PROFILE)
        .library(concat!("conductor-cli ", env!("CARGO_PKG_VERSION")))
        .create(BufWriter::new(file))
        .map_err(mcap_err)?;
    let schema = w
        .add_schema(
            recording::SCHEMA_NAME,
            recording::SCHEMA_ENCODING,
            recording::SCHEMA.as_bytes(),
        )
        .map_err(mcap_err)?;
    for info in &states {
        let name = info.qualified_name();
        let channel = w
            .add_channel(
                schema,
                &recording::topic(&info.subsystem, &info.name),
                recording::MESSAGE_ENCODING,
                &recording::channel_metadata(info),
            )
            .map_err(mcap_err)?;
        tracks.push(Track {
            sub: StateSubscriber::with_buffer(bus, &name, QUEUE)?,
            name,
            channel,
            written: 0,
        });
    }
    let started_mono = monotonic_ns();
    let started_unix = unix_ns();
    w.write_metadata(&mcap::records::Metadata {
        name: recording::META_START.into(),
        metadata: BTreeMap::from([
            ("domain".into(), bus.domain().name().into()),
            ("pattern".into(), args.pattern.clone()),
            ("abi".into(), ABI_VERSION.to_string()),
            ("states".into(), states.len().to_string()),
            (
                "recorder".into(),
                concat!("conductor-cli ", env!("CARGO_PKG_VERSION")).into(),
            ),
            // log_time is CLOCK_MONOTONIC; this pair maps it to wall-clock time.
            ("start_monotonic_ns".into(), started_mono.to_string()),
            ("start_unix_ns".into(), started_unix.to_string()),
        ]),
    })
    .map_err(mcap_err)?;
    if let Some((p, text)) = &manifest {
        w.write_metadata(&mcap::records::Metadata {
            name: recording::META_MANIFEST.into(),
            metadata: BTreeMap::from([("path".into(), p.clone()), ("toml".into(), text.clone())]),
        })
        .map_err(mcap_err)?;
    }
    eprintln!(
        "recording {} state(s) of domain {:?} to {}",
        tracks.len(),
        bus.domain().name(),
        path.display()
    );

    let bar = progress(args);
    let start = Instant::now();
    let end = args.duration.map(|d| start + Duration::from_secs_f64(d));
    let mut body = Vec::with_capacity(160);
    let mut messages = 0u64;
    let mut last_draw = start;
    let stopped_by = loop {
        for t in &mut tracks {
            while let Some(s) = t.sub.receive()? {
                body.clear();
                serde_json::to_writer(&mut body, &Message::of(&s))
                    .expect("a Message always serialises");
                w.write_to_known_channel(
                    &mcap::records::MessageHeader {
                        channel_id: t.channel,
                        sequence: s.seq as u32,
                        log_time: s.t_sample_ns,
                        publish_time: s.t_publish_ns,
                    },
                    &body,
                )
                .map_err(mcap_err)?;
                t.written += 1;
                messages += 1;
            }
        }
        let now = Instant::now();
        if end.is_some_and(|e| now >= e) {
            break "duration";
        }
        if conductor_bus::shutdown::requested() {
            break "signal";
        }
        if let Some(b) = &bar {
            if now - last_draw > Duration::from_millis(100) {
                last_draw = now;
                b.set_message(format!("{messages} messages"));
                b.set_position((now - start).as_millis() as u64);
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    };
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let per_state: Vec<(String, u64, u64)> = tracks
        .iter()
        .map(|t| (t.name.clone(), t.written, t.sub.missed()))
        .collect();
    let mut summary = BTreeMap::from([
        ("stopped_by".to_string(), stopped_by.to_string()),
        (
            "duration_s".into(),
            format!("{:.6}", start.elapsed().as_secs_f64()),
        ),
        ("messages".into(), messages.to_string()),
    ]);
    for (name, written, missed) in &per_state {
        summary.insert(format!("{name}.messages"), written.to_string());
        summary.insert(format!("{name}.lost"), missed.to_string());
    }
    w.write_metadata(&mcap::records::Metadata {
        name: recording::META_SUMMARY.into(),
        metadata: summary,
    })
    .map_err(mcap_err)?;
    w.finish().map_err(mcap_err)?;
    let file = w
        .into_inner()
        .into_inner()
        .map_err(|e| CliError::io(path, e.into_error()))?;
    file.sync_all().map_err(|e| CliError::io(path, e))?;
    let lost: u64 = per_state.iter().map(|p| p.2).sum();
    let mut err = std::io::stderr().lock();
    let _ = writeln!(
        err,
        "recorded {messages} messages on {} channel(s) in {:.2} s to {} (stopped by {stopped_by}; {lost} samples lost)",
        per_state.len(),
        start.elapsed().as_secs_f64(),
        path.display()
    );
    Ok(RecordReport {
        messages,
        per_state,
        stopped_by,
    })
}

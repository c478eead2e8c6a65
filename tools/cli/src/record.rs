//! `conductor record`: states to an MCAP file (layout in [`crate::recording`]).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, IsTerminal, Write};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use conductor_bus::{monotonic_ns, Bus, StateSubscriber, ABI_VERSION};
use indicatif::{ProgressBar, ProgressStyle};

use crate::cli::RecordArgs;
use crate::error::{CliError, Result};
use crate::recording;
use crate::select;

/// Per-subscriber queue: at 1 kHz this covers a quarter second of the recorder not running.
const QUEUE: usize = 256;

/// How often the open chunk is closed and synced to the disk: what a killed recorder loses.
const FLUSH_EVERY: Duration = Duration::from_secs(1);

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
/// footer) either way. Exactly the samples published within the window are written (see the
/// summary's `window_*` metadata); a chunk is closed and synced every second.
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
    // A second handle on the file, to sync what each flush wrote while the writer owns it.
    let sync = file.try_clone().map_err(|e| CliError::io(path, e))?;
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
                &info.metadata_strings(),
            )
            .map_err(mcap_err)?;
        tracks.push(Track {
            sub: StateSubscriber::with_buffer(bus, &name, QUEUE)?,
            name,
            channel,
            written: 0,
        });
    }
    // The recording window opens here (see below): the start metadata states it.
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
            // log_time is CLOCK_MONOTONIC; this pair maps it to wall-clock time. The monotonic
            // one is also where the window opens: no sample published before it is written.
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
    // The window is exact by publish time: a sample is written when it was published at or
    // after `window_start` and before `window_end` (the duration's end, or the moment a stop
    // was seen). Samples published before the start (each subscriber is handed the newest
    // sample when it connects, and more queue up while the file is set up) are left out.
    let window_start = started_mono;
    let mut window_end = args
        .duration
        .map_or(u64::MAX, |d| window_start + (d * 1e9).round() as u64);
    let mut body = Vec::with_capacity(160);
    let mut messages = 0u64;
    let mut before = 0u64;
    let mut last_draw = start;
    let mut last_flush = start;
    let mut stopped_by = None;
    loop {
        for t in &mut tracks {
            while let Some(s) = t.sub.receive()? {
                if s.t_publish_ns < window_start {
                    before += 1;
                    continue;
                }
                if s.t_publish_ns >= window_end {
                    continue;
                }
                body.clear();
                recording::write_message(&mut body, &recording::message_of(&s));
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
        if stopped_by.is_some() {
            // That drain after the end took in every sample published before it.
            break;
        }
        let now = Instant::now();
        if monotonic_ns() >= window_end {
            stopped_by = Some("duration");
        } else if conductor_bus::shutdown::requested() {
            window_end = monotonic_ns();
            stopped_by = Some("signal");
        }
        if stopped_by.is_some() {
            // A publisher stamps t_publish_ns just before it sends: let one that stamped a time
            // inside the window finish sending before the last drain.
            std::thread::sleep(Duration::from_millis(5));
            continue;
        }
        if now - last_flush >= FLUSH_EVERY {
            // Close the chunk and push it to the disk, so that a recorder killed (SIGKILL,
            // power loss) loses at most this interval: the file reads up to the last chunk.
            last_flush = now;
            w.flush().map_err(mcap_err)?;
            sync.sync_data().map_err(|e| CliError::io(path, e))?;
        }
        if let Some(b) = &bar {
            if now - last_draw > Duration::from_millis(100) {
                last_draw = now;
                b.set_message(format!("{messages} messages"));
                b.set_position((now - start).as_millis() as u64);
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let stopped_by = stopped_by.expect("the loop ends only once stopped");
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
        // The publish-time window [start, end) of the written samples, CLOCK_MONOTONIC ns.
        ("window_start_monotonic_ns".into(), window_start.to_string()),
        ("window_end_monotonic_ns".into(), window_end.to_string()),
        ("published_before_start".into(), before.to_string()),
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

//! The command-line grammar (clap derive). Every subcommand's options live here, so `--help`,
//! the shell completions and the README describe one thing.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

const EXAMPLES: &str = "\
Examples:
  conductor launch deploy/minihubo-right-leg.toml one executor per subsystem, supervised
  conductor list                                  every state of the domain with its metadata
  conductor get leg/knee                          latest sample of one state
  conductor set leg/knee 0.5                      send a setpoint (refused outside the limits)
  conductor echo 'leg/*' --rate 10                print a subsystem's states, 10 lines/s each
  conductor top                                   executor health, refreshed every second
  conductor record '*' -o run.mcap --duration 30  record every state to MCAP (open in Foxglove)
  conductor replay run.mcap --domain replay       publish a recording as live states
  conductor udp-gateway --base-port 2827          plain-text SET/GET/SMP per state (thesis §2.5.2)
  conductor plot run.mcap 'leg/*' -o leg.png      joint plot of recorded states
  conductor bench --quick                         stress test beside cyclictest, ~1 minute
  conductor bench --scaling                       CPU and latency against states, subscribers, executors
  conductor bridge --export 'leg/*' --listen tcp/0.0.0.0:7447   states to other hosts over Zenoh
  conductor completions bash > /etc/bash_completion.d/conductor

The domain comes from --domain, else $CONDUCTOR_DOMAIN, else \"default\".
State names are `subsystem/state`, or a bare state name when it is unique in the domain.
Patterns are globs (`*`, `?`, `[..]`) over `subsystem/state` (or over the state name when the
pattern has no `/`).";

/// `conductor`: inspect, command, record and replay the states of a Conductor robot.
#[derive(Debug, Parser)]
#[command(name = "conductor", version, about, after_help = EXAMPLES)]
pub struct Cli {
    /// Domain to work in (like ROS_DOMAIN_ID) [default: $CONDUCTOR_DOMAIN or "default"].
    #[arg(long, global = true, value_name = "NAME")]
    pub domain: Option<String>,
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Validate a manifest and run one real-time executor per subsystem (and one process per
    /// gateway) until Ctrl-C/SIGTERM.
    #[command(
        after_help = "Every manifest error is reported with file, line and column before \
anything starts. Executors and gateways that crash are restarted with back-off; the robot does not
wait for a gateway's board. SIGINT/SIGTERM stop them in order (devices go to their safe state).

Examples:\n  conductor launch deploy/minihubo-right-leg.toml\n  conductor launch robot.toml --check\n  conductor launch robot.toml --only leg --no-rt"
    )]
    Launch(LaunchArgs),
    /// Runs one executor (what `launch` spawns per subsystem; see `conductor-executor --help`).
    #[command(name = "__executor", hide = true, disable_help_flag = true)]
    Executor {
        /// The executor's own arguments.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
    /// Runs one Score gateway (what `launch` spawns per `[gateways.<name>]` of kind "score"; see
    /// `score-gateway --help`).
    #[command(name = "__score-gateway", hide = true, disable_help_flag = true)]
    ScoreGateway {
        /// The gateway's own arguments.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
    /// List every state: units, rate, writable, limits, device, writer process, age.
    #[command(after_help = "Example:\n  conductor list 'leg/*'")]
    List(ListArgs),
    /// Print the latest sample of one state.
    #[command(after_help = "Examples:\n  conductor get leg/knee\n  conductor get knee --raw")]
    Get(GetArgs),
    /// Send one setpoint to a writable state, through a command frame.
    #[command(
        allow_negative_numbers = true,
        after_help = "Values outside the state's limits are refused unless --clamp is given,
then they are clamped to the nearest limit before sending. NaN and inf are always refused.

Then it waits (up to --wait) for a sample of the state from a tick after the frame: when that
sample says the executor refused the setpoint (REJECTED), it exits with status 1 saying why (the
device is tripped or disabled: the error names the state that enables it again). With --wait 0,
or when no such sample comes in time, a note says the verdict was not checked.

Examples:\n  conductor set leg/knee 0.5\n  conductor set leg/knee -3 --clamp"
    )]
    Set(SetArgs),
    /// Print samples of the states matching a name or glob, optionally rate-limited.
    #[command(
        after_help = "Examples:\n  conductor echo leg/knee\n  conductor echo 'leg/*' --rate 5 --count 50\n  conductor echo 'leg/*' --plot --window 5"
    )]
    Echo(EchoArgs),
    /// Executor health per subsystem: rate, lateness, misses, stale states, devices, buses,
    /// refused setpoints.
    #[command(
        after_help = "Columns: HZ achieved tick rate; P99_US tick lateness p99 (µs); MISS deadlines
missed; STALE stale/all states; DEV devices enabled/all (- when it has none); TRIP devices tripped
now (they refuse setpoints until enabled again); FAULT devices reporting a fault now; BUS_ERR bus
errors; OUTAGE times a bus vanished; LATE replies that came after their request was given up;
REFUSED setpoints refused because their device was disabled or tripped; AGE of the stats message.
--wide names them in full (RATE_HZ, LATE_P99_US, MISSES, ENABLED, TRIPPED, FAULTED, OUTAGES,
LATE_REPLIES) and adds TARGET_HZ, LATE_P50_US, LATE_MAX_US, LINKS_DOWN (buses down now), FRAMES,
REJECTED (setpoints rejected for any reason), CLAMPED, WATCHDOG (watchdog trips), FAULTS (fault
transitions) and RT (fifo@<cpu>, fifo or no).

Examples:\n  conductor top\n  conductor top --once --wide"
    )]
    Top(TopArgs),
    /// Record states to an MCAP file (one channel per state, JSON, zstd chunks, indexed).
    #[command(
        after_help = "Ctrl-C (SIGINT) or SIGTERM stops the recording and finalises the file.

Examples:\n  conductor record '*' -o run.mcap\n  conductor record 'leg/*' -o walk.mcap --duration 30 --manifest robot.toml"
    )]
    Record(RecordArgs),
    /// Publish a recording as live states (flagged REPLAYED), at its own pace or scaled.
    #[command(
        after_help = "Replayed states are read-only and indexed in recording order; replay
into another domain than the robot's (the names would clash).

Examples:\n  conductor --domain replay replay run.mcap\n  conductor --domain replay replay run.mcap --rate-scale 0.5 --loop"
    )]
    Replay(ReplayArgs),
    /// Serve each state on its own UDP port: plain-text `SET <v>`, `GET`, `SMP`, `INFO`.
    #[command(
        name = "udp-gateway",
        after_help = "Port of the i-th selected state (in `conductor list` order) = base port + i.
Replies: `SET v` -> `OK <sent>` or `OK <sent> CLAMPED`; `GET` -> `<value>`;
`SMP` -> `<value> <t_sample_ns> <seq> <status>` of the next fresh sample;
`INFO` -> `<state> <units|-> <rw|ro> <min> <max> <rate_hz>`; anything else -> `ERR <reason>`.

Examples:\n  conductor udp-gateway\n  conductor udp-gateway 'leg/*' --base-port 4000 --bind 0.0.0.0"
    )]
    UdpGateway(UdpArgs),
    /// Live view in Foxglove or Lichtblick: a Foxglove WebSocket server with every state, the
    /// executors' stats, and settable states as parameters.
    #[command(
        after_help = "Open ws://127.0.0.1:8765 in Foxglove (Open connection > Foxglove WebSocket)
or Lichtblick. Each state is a channel /<subsystem>/<state> (JSON: value, unit, status, flags,
t_sample, t_publish, seq, tick; log time = sample time, CLOCK_MONOTONIC), each executor's health
/<subsystem>/stats. New states appear as they are discovered. Settable states are parameters
named <subsystem>/<state>, and take {\"value\": x} published on their own topic; both go
through the checks of `conductor set` (NaN/inf and read-only refused; outside the limits refused,
or clamped with --clamp) and report the executor's verdict (refused, clamped) as a status.
It only subscribes: it never blocks or slows an executor. Loopback only unless --listen says
otherwise; anything else lets the network command the robot.

Examples:\n  conductor view\n  conductor view --listen 0.0.0.0:8765\n  conductor view --listen 127.0.0.1:0 --clamp"
    )]
    View(ViewArgs),
    /// Join this domain's bus to Zenoh: export states to other hosts, import theirs as local
    /// mirror states, carry commands back to the owning executor.
    #[command(after_help = BRIDGE_HELP)]
    Bridge(BridgeArgs),
    /// Plot recorded states against time into a PNG (or SVG) image.
    #[command(
        after_help = "Examples:\n  conductor plot run.mcap 'leg/*' -o leg.png --title 'Robot Joint State'\n  conductor plot run.mcap 'leg/*' -o leg.png --flags"
    )]
    Plot(PlotArgs),
    /// Benchmark suite: the thesis' stress test at 50 Hz–10 kHz beside cyclictest and the IPC
    /// floor; writes a Markdown table, JSON and plots.
    #[command(
        after_help = "For every rate and number of states: tick lateness p50/p99/p99.9/max
beside cyclictest's at the same rate, priority and CPU (with ratios), misses, executor CPU use,
hardware sample -> external subscriber and controller command -> hardware write latencies, the
thesis' error sin(t) - value (Fig. 3.1 plots); plus the raw iceoryx2 ping-pong floor. Installs
rt-tests (cyclictest) with apt-get when it is missing, unless --no-install. A full run takes
about 5 minutes; --quick about one. Run it on a quiet machine.

Examples:\n  conductor bench\n  conductor bench --quick -o /tmp/bench\n  conductor bench --rates 1000,2000,5000 --states 3 --seconds 5\n  conductor bench --scaling -o /tmp/scaling"
    )]
    Bench(BenchArgs),
    /// Fault campaign on the simulated robots of deploy/ (byte faults, unplugs, executor and
    /// controller kills, stalls, floods), checked from outside; one table, JSON, exit 1 when a
    /// check failed. `conductor soak --help` for its options.
    #[command(
        disable_help_flag = true,
        after_help = "Examples:\n  conductor soak --duration 10m --json soak.json\n  conductor soak --duration 5m --faults controller-kill,controller-stop"
    )]
    Soak {
        /// The campaign's own arguments (see `conductor soak --help`).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
    /// The stress test's helper processes (logger, probe; see `conductor-stress --help`).
    #[command(name = "__stress", hide = true, disable_help_flag = true)]
    Stress {
        /// The tool's own arguments.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
    /// Raw Zenoh publisher/subscriber of the bridge benchmark.
    #[command(name = "__bridge-bench", hide = true, disable_help_flag = true)]
    BridgeBench {
        /// The helper's own arguments.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
    /// The receiving side of the IPC ping-pong (its role comes from the environment).
    #[command(name = "__pingpong", hide = true)]
    PingPong,
    /// Print a shell completion script.
    #[command(after_help = "Example:\n  conductor completions zsh > ~/.zfunc/_conductor")]
    Completions {
        /// Shell to generate for.
        shell: clap_complete::Shell,
    },
}

const BRIDGE_HELP: &str = "\
Exported states go out as Zenoh key expressions conductor/<domain>/<subsystem>/<state> (the bus
ABI bytes plus host and sequence); imported ones appear as local states of the same names (or
under --prefix) that every tool reads unchanged. Only states given to --commands accept remote
setpoints; they pass the owning executor's checks and watchdog. A link quiet for 2 heartbeats
marks imported states STALE; they resume when it returns. Peer-to-peer with explicit endpoints
and multicast scouting off unless told otherwise; TLS, routers and access control: deploy/bridge.md.
Flags add to the configuration read from --config or from --manifest's [bridge] table.

Examples:
  robot:        conductor bridge --host robot --listen tcp/0.0.0.0:7447 --export 'leg/*' --commands 'leg/knee'
  workstation:  conductor bridge --host ws --connect tcp/192.168.1.10:7447 --import default
  conductor bridge --config bridge.toml";

/// `conductor bridge`.
#[derive(Debug, Args)]
pub struct BridgeArgs {
    /// A bridge.toml (see deploy/bridge.md).
    #[arg(long, value_name = "FILE", conflicts_with = "manifest")]
    pub config: Option<PathBuf>,
    /// A robot manifest: its `[bridge]` table (what `conductor launch` uses).
    #[arg(long, value_name = "FILE")]
    pub manifest: Option<PathBuf>,
    /// This bridge's host name on Zenoh [default: the machine's host name].
    #[arg(long, value_name = "NAME")]
    pub host: Option<String>,
    /// Zenoh endpoint to listen on (repeatable), e.g. tcp/0.0.0.0:7447.
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Zenoh endpoint to connect to (repeatable), e.g. tcp/192.168.1.10:7447.
    #[arg(long, value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Export the states matching this glob (repeatable).
    #[arg(long, value_name = "GLOB")]
    pub export: Vec<String>,
    /// Exported states that accept remote commands (repeatable glob).
    #[arg(long, value_name = "GLOB")]
    pub commands: Vec<String>,
    /// Export at most this rate per state (Hz) [default: every sample].
    #[arg(long, value_name = "HZ")]
    pub rate_hz: Option<f64>,
    /// Import the states of this remote domain (repeatable).
    #[arg(long, value_name = "DOMAIN")]
    pub import: Vec<String>,
    /// Mirror subsystem name prefix for --import.
    #[arg(long, default_value = "", value_name = "PREFIX")]
    pub prefix: String,
    /// Heartbeat period (ms) [default: 50].
    #[arg(long, value_name = "MS")]
    pub heartbeat_ms: Option<u64>,
    /// Busy-wait of the export thread before each expected tick (µs, 0 = off; at most 1000):
    /// less latency for up to this × tick rate of a CPU [default: 0].
    #[arg(long, value_name = "US")]
    pub spin_us: Option<u64>,
    /// CPUs the bridge runs on, e.g. `1,2` [default: all but the CPUs the manifest pins its
    /// executors to].
    #[arg(long, value_name = "CPUS", value_delimiter = ',')]
    pub cpus: Vec<usize>,
    /// A Zenoh JSON5 configuration applied first (TLS, access control).
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

/// `conductor list`.
#[derive(Debug, Args)]
pub struct ListArgs {
    /// Only states matching this glob.
    pub pattern: Option<String>,
    /// How long to wait for each state's latest sample, for the AGE column (seconds).
    #[arg(long, default_value_t = 0.3, value_name = "S")]
    pub wait: f64,
}

/// `conductor get`.
#[derive(Debug, Args)]
pub struct GetArgs {
    /// `subsystem/state` or a unique state name.
    pub state: String,
    /// Print only the value (shortest decimal that reads back exactly).
    #[arg(long)]
    pub raw: bool,
    /// Give up when no sample arrives within this many seconds.
    #[arg(long, default_value_t = 2.0, value_name = "S")]
    pub timeout: f64,
}

/// `conductor set`.
#[derive(Debug, Args)]
pub struct SetArgs {
    /// `subsystem/state` or a unique state name.
    pub state: String,
    /// The setpoint, in the state's units.
    pub value: f64,
    /// Clamp an out-of-limit value to the nearest limit instead of refusing it.
    #[arg(long)]
    pub clamp: bool,
    /// How long to wait for a sample from a tick after the frame, which carries the executor's
    /// verdict (seconds; 0 = don't wait, don't check).
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub wait: f64,
}

/// `conductor echo`.
#[derive(Debug, Args)]
pub struct EchoArgs {
    /// A state name or a glob.
    pub pattern: String,
    /// At most this many lines per second per state (by sample time); default: every sample.
    #[arg(long, value_name = "HZ")]
    pub rate: Option<f64>,
    /// Stop after this many lines.
    #[arg(long, value_name = "N")]
    pub count: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long, value_name = "S")]
    pub duration: Option<f64>,
    /// One JSON object per line instead of columns.
    #[arg(long)]
    pub json: bool,
    /// Wait this long for a matching state to appear (seconds).
    #[arg(long, default_value_t = 5.0, value_name = "S")]
    pub wait: f64,
    /// A live chart in the terminal instead of lines: the last --window seconds of every
    /// matching state, with its value and flags (--count then counts frames).
    #[arg(long, conflicts_with_all = ["json", "rate"])]
    pub plot: bool,
    /// Seconds of history the --plot chart shows.
    #[arg(long, default_value_t = 10.0, value_name = "S", requires = "plot")]
    pub window: f64,
}

/// `conductor top`.
#[derive(Debug, Args)]
pub struct TopArgs {
    /// Seconds between refreshes.
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub interval: f64,
    /// Print this many tables, then exit.
    #[arg(long, value_name = "N", conflicts_with = "once")]
    pub count: Option<u64>,
    /// Print one table and exit (same as --count 1).
    #[arg(long)]
    pub once: bool,
    /// How long to wait for the first stats of each executor (seconds).
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub wait: f64,
    /// Every figure, with full column names (about 220 columns) instead of the health summary.
    #[arg(long, short)]
    pub wide: bool,
}

/// `conductor record`.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// States to record: a name or a glob (`'*'` for all).
    pub pattern: String,
    /// Output MCAP file.
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long, value_name = "S")]
    pub duration: Option<f64>,
    /// Manifest to store in the file's metadata.
    #[arg(long, value_name = "FILE")]
    pub manifest: Option<PathBuf>,
    /// Wait this long for a matching state to appear (seconds).
    #[arg(long, default_value_t = 5.0, value_name = "S")]
    pub wait: f64,
    /// Never draw a progress bar (it is drawn only when stderr is a terminal anyway).
    #[arg(long)]
    pub no_progress: bool,
}

/// `conductor replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// MCAP file written by `conductor record`.
    pub file: PathBuf,
    /// Playback speed: 2 = twice as fast, 0.5 = half speed.
    #[arg(long, default_value_t = 1.0, value_name = "X")]
    pub rate_scale: f64,
    /// Start over at the end, until Ctrl-C.
    #[arg(long = "loop")]
    pub repeat: bool,
    /// Only states matching this glob.
    #[arg(long, value_name = "GLOB")]
    pub states: Option<String>,
    /// Before the first sample, wait (up to 10 s) until every replayed state has this many
    /// subscribers.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub wait_subscribers: usize,
    /// Never draw a progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

/// `conductor udp-gateway`.
#[derive(Debug, Args)]
pub struct UdpArgs {
    /// States to serve (glob; default all).
    pub pattern: Option<String>,
    /// Port of the first state; state i (in `conductor list` order) gets base + i.
    #[arg(long, default_value_t = 2827, value_name = "PORT")]
    pub base_port: u16,
    /// Address to bind; anything other than loopback exposes the robot to the network.
    #[arg(long, default_value = "127.0.0.1", value_name = "ADDR")]
    pub bind: std::net::IpAddr,
    /// Longest wait for a fresh sample when answering SMP (seconds).
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub smp_timeout: f64,
    /// Wait this long for a matching state to appear (seconds).
    #[arg(long, default_value_t = 5.0, value_name = "S")]
    pub wait: f64,
}

/// `conductor view`.
#[derive(Debug, Args)]
pub struct ViewArgs {
    /// Address and port of the WebSocket server; anything other than loopback exposes the robot
    /// (and its settable states) to the network. Port 0 picks a free one (printed).
    #[arg(long, default_value = "127.0.0.1:8765", value_name = "ADDR")]
    pub listen: std::net::SocketAddr,
    /// Send the nearest limit for a value outside a state's limits (as `conductor set --clamp`)
    /// instead of refusing it.
    #[arg(long)]
    pub clamp: bool,
}

/// `conductor plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// MCAP file written by `conductor record`.
    pub file: PathBuf,
    /// States to plot (names or globs).
    #[arg(required = true)]
    pub states: Vec<String>,
    /// Output image: `.png` or `.svg`.
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
    /// Plot title (default: the file name).
    #[arg(long)]
    pub title: Option<String>,
    /// Y-axis label (default: the states' common units).
    #[arg(long)]
    pub ylabel: Option<String>,
    /// Image width in pixels.
    #[arg(long, default_value_t = 1200)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 700)]
    pub height: u32,
    /// Add a panel below, on the same time axis: when each state's flags (clamped, rejected,
    /// stale, tripped, ...) were set, one row per state and flag.
    #[arg(long)]
    pub flags: bool,
}

/// `conductor bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// About one minute: fewer rates (100 Hz, 1 kHz), 3 s per run, fewer ping-pongs.
    #[arg(long)]
    pub quick: bool,
    /// Output directory (report.md, report.json, *.png).
    #[arg(short, long, default_value = "bench-out", value_name = "DIR")]
    pub out: PathBuf,
    /// Rates in Hz [default: 50,100,500,1000,5000,10000; --quick: 100,1000].
    #[arg(long, value_delimiter = ',', value_name = "HZ,...")]
    pub rates: Vec<f64>,
    /// Numbers of sine states [default: 3,41].
    #[arg(long, value_delimiter = ',', value_name = "N,...")]
    pub states: Vec<usize>,
    /// How the stress test's readers take the states: `states` (a subscriber per state, woken by
    /// the tick event), `snapshot` (the subsystem's snapshot, woken by its event) or both
    /// (default: a run of each). `--scaling` uses the first.
    #[arg(long, value_delimiter = ',', value_name = "READER,...", value_parser = parse_reader)]
    pub readers: Vec<conductor_benches::suite::Reader>,
    /// Logged seconds per run [default: 15, the span of Fig. 3.1; --quick: 3].
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// CPU of the executor and cyclictest [default: the last one].
    #[arg(long, value_name = "N")]
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority of the executor and cyclictest.
    #[arg(long, default_value_t = 80, value_name = "P")]
    pub priority: i32,
    /// Round trips per IPC ping-pong path [default: 50000; --quick: 5000].
    #[arg(long, value_name = "N")]
    pub ipc_samples: Option<usize>,
    /// Do not run cyclictest.
    #[arg(long)]
    pub no_cyclictest: bool,
    /// Do not install rt-tests when cyclictest is missing.
    #[arg(long)]
    pub no_install: bool,
    /// Never draw a progress bar (it is drawn only when stderr is a terminal anyway).
    #[arg(long)]
    pub no_progress: bool,
    /// Only the scaling curves: executor CPU per tick and sample → controller latency against
    /// states (1–1000), subscribers per state (0–16) and executors per host (1–4) at 1 kHz,
    /// with fitted per-unit costs (--quick: fewer points, 1 s each).
    #[arg(long, conflicts_with = "bridge")]
    pub scaling: bool,
    /// Only the bridge benchmark: latency through `conductor bridge` vs raw Zenoh vs the local
    /// bus, and a load run (CPU % of each bridge, drops); over two network namespaces as root.
    #[arg(long)]
    pub bridge: bool,
    /// States of the bridge load run.
    #[arg(long, default_value_t = 1000, value_name = "N")]
    pub bridge_states: usize,
    /// Rate of the bridge load run (Hz).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ")]
    pub bridge_rate: f64,
    /// Samples per latency path of the bridge benchmark [default: 5000; --quick: 1000].
    #[arg(long, value_name = "N")]
    pub bridge_samples: Option<usize>,
    /// Run the bridge benchmark over loopback even as root.
    #[arg(long)]
    pub bridge_loopback: bool,
    /// The exporting bridge's `--spin-us` in the bridge benchmark [default: the bridge's].
    #[arg(long, value_name = "US")]
    pub bridge_spin_us: Option<u64>,
    /// In the bridge benchmark, leave the publisher and the exporting bridge wherever the
    /// scheduler puts them [default: the publisher, standing for an executor, on the first CPU
    /// and the exporting bridge on the others].
    #[arg(long)]
    pub bridge_unpinned: bool,
}

/// `conductor launch`.
#[derive(Debug, Args)]
pub struct LaunchArgs {
    /// The manifest (TOML).
    pub manifest: PathBuf,
    /// Launch only these subsystems and gateways (repeatable).
    #[arg(long = "only", value_name = "SUBSYSTEM")]
    pub only: Vec<String>,
    /// Run without real-time set-up (normal scheduling, no pinning, no memory lock).
    #[arg(long)]
    pub no_rt: bool,
    /// No live summary line per subsystem.
    #[arg(long, short)]
    pub quiet: bool,
    /// Seconds between summaries [default: 1 on a terminal, 10 otherwise].
    #[arg(long, value_name = "SECONDS")]
    pub summary_secs: Option<f64>,
    /// Only validate the manifest and exit (status 2 if invalid).
    #[arg(long)]
    pub check: bool,
}

fn parse_reader(s: &str) -> Result<conductor_benches::suite::Reader, String> {
    conductor_benches::suite::Reader::parse(s)
        .ok_or_else(|| format!("{s:?}: expected `states` or `snapshot`"))
}

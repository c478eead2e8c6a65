//! How the launcher treats the manifest's gateways, with stand-in gateway programs (`sh`
//! scripts: the real Score gateway against the emulator is tested in tools/cli/tests/gateway.rs):
//! one that cannot run and one that keeps crashing are given up while the executor runs on; a
//! gateway's `ready` line makes it ready and `--only` can launch a gateway alone; a missing
//! gateway program and a gateway that already runs stop the launch before it starts.

mod support;

use std::time::Duration;

use conductor_bus::{Bus, StateSubscriber};
use conductor_executor::launcher::{Launch, LaunchError, LaunchOptions, ProcessKind};
use support::*;

/// A simulated subsystem `sim` and gateways named `names` (the port is never opened: the
/// programs here are stand-ins).
fn manifest(tag: &str, names: &[&str]) -> std::path::PathBuf {
    let mut text = String::from(
        "system = \"gwsup\"\n\
         [subsystems.sim]\nrate_hz = 100\nhardware.wave.kind = \"sine\"\n\
         protocols.p = { kind = \"sim\", hardware = \"wave\" }\n\
         devices.d = { kind = \"sim\", protocol = \"p\", id = 1 }\nstates.s.device = \"d\"\n",
    );
    for n in names {
        text.push_str(&format!(
            "[gateways.{n}]\nkind = \"score\"\nport = \"/dev/null-{tag}-{n}\"\n"
        ));
    }
    temp_manifest(tag, &text)
}

/// `options` with `sh -c script` as the gateway program; the script's `$4` is the gateway's
/// name (its arguments start `--port P --subsystem NAME`).
fn with_script(mut opts: LaunchOptions, script: &str) -> LaunchOptions {
    opts.gateway = "sh".into();
    opts.gateway_args = vec!["-c".into(), script.into(), "sh".into()];
    opts
}

#[test]
fn gateways_that_cannot_run_or_keep_crashing_are_given_up_while_the_robot_runs() {
    let (d, _guard) = private_domain("gwgiveup");
    let mut opts = with_script(
        options(&d),
        "echo \"gateway $4 fails\" >&2; [ \"$4\" = cannot ] && exit 2; exit 1",
    );
    opts.backoff = Duration::from_millis(10);
    opts.backoff_max = Duration::from_millis(20);
    opts.max_restarts = 2;
    let launch = Launch::start(&manifest("giveup", &["cannot", "crashy"]), opts).unwrap();
    let gave_up = |name: &str| {
        launch
            .executors()
            .into_iter()
            .find(|e| e.subsystem == name && e.failed.is_some())
    };
    let cannot = eventually(10, "cannot given up", || gave_up("cannot"));
    let crashy = eventually(10, "crashy given up", || gave_up("crashy"));
    assert_eq!(
        (cannot.kind, cannot.restarts, cannot.pid),
        (ProcessKind::Gateway, 0, None)
    );
    let why = cannot.failed.unwrap();
    assert!(why.contains("cannot run (exit status 2)"), "{why}");
    // Two restarts are tolerated within the window; the third crash gives up.
    assert_eq!((crashy.restarts, crashy.pid), (2, None));
    let why = crashy.failed.unwrap();
    assert!(
        why.contains("crashed 3 times") && why.contains("exit status 1"),
        "{why}"
    );

    // The executor was never disturbed and still publishes.
    let bus = Bus::open(&d, "test").unwrap();
    let mut s = StateSubscriber::new(&bus, "sim/s").unwrap();
    eventually(5, "sim/s sample", || s.receive().unwrap());
    let sim = launch.executors().into_iter().next().unwrap();
    assert_eq!(
        (sim.subsystem.as_str(), sim.ready, sim.restarts),
        ("sim", true, 0)
    );
    drop((s, bus));

    launch.stop();
    match launch.wait() {
        Err(LaunchError::Unclean { failures }) => {
            assert_eq!(failures.len(), 2, "{failures:?}");
            assert!(
                failures[0].starts_with("gateway cannot: given up"),
                "{failures:?}"
            );
            assert!(
                failures[1].starts_with("gateway crashy: given up"),
                "{failures:?}"
            );
        }
        other => panic!("unexpected: {other:?}"),
    }
}

#[test]
fn a_gateway_is_ready_when_its_ready_line_comes_and_can_be_launched_alone() {
    let (d, _guard) = private_domain("gwready");
    // Ready after a pause (the launch does not wait for it), then runs until SIGTERM.
    let opts = with_script(
        options(&d),
        "trap 'exit 0' TERM; sleep 0.3; echo \"ready $4 2 states\"; \
         while :; do sleep 0.02; done",
    );
    let mut opts = opts;
    opts.only = vec!["board".into()];
    let launch = Launch::start(&manifest("ready", &["board", "other"]), opts).unwrap();
    let all = launch.executors();
    assert_eq!(all.len(), 1, "only the gateway: {all:?}");
    assert_eq!((all[0].kind, all[0].ready), (ProcessKind::Gateway, false));
    let ready = eventually(10, "board ready", || {
        launch.executors().into_iter().find(|e| e.ready)
    });
    assert_eq!(ready.pid, all[0].pid, "the same process, not a restart");
    launch.stop();
    let report = launch.wait().unwrap();
    assert_eq!(report.subsystems.len(), 1);
    let r = &report.subsystems[0];
    assert_eq!(
        (r.subsystem.as_str(), r.kind, r.restarts, r.exit_code),
        ("board", ProcessKind::Gateway, 0, Some(0))
    );
}

#[test]
fn a_missing_gateway_program_or_a_running_gateway_stops_the_launch() {
    let (d, _guard) = private_domain("gwmissing");
    let m = manifest("missing", &["board"]);
    let mut opts = options(&d);
    opts.gateway = "/nonexistent/score-gateway".into();
    match Launch::start(&m, opts) {
        Err(e @ LaunchError::SpawnGateway { .. }) => {
            let text = e.to_string();
            assert!(
                text.contains("\"board\"") && text.contains("/nonexistent/score-gateway"),
                "{text}"
            );
        }
        other => panic!("unexpected: {other:?}"),
    }
    // A live node named like the gateway's: it already runs in this domain.
    let bus = Bus::open(&d, "gateway/board").unwrap();
    match Launch::start(&m, with_script(options(&d), "exit 0")) {
        Err(LaunchError::AlreadyRunning { subsystem, pid, .. }) => {
            assert_eq!(subsystem, "board");
            assert_eq!(pid, std::process::id().to_string());
        }
        other => panic!("unexpected: {other:?}"),
    }
    drop(bus);
}

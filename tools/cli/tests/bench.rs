//! `conductor bench --quick` end to end: it runs the whole suite (IPC ping-pong, cyclictest when
//! installed, the stress test at every quick rate with 3 and 41 states, each read by per-state
//! subscribers and by the snapshot, beside its executor-shaped floor) and writes a well-formed
//! report: JSON that parses with every row, PNGs with the right signature and size, and a
//! Markdown table row per configured rate and state count. The figures themselves are not
//! checked: they depend on the machine. The executor sleeps to its deadlines (no spin), so the
//! SCHED_FIFO thread never spins during the test; it takes about 30 s.

use std::collections::BTreeSet;
use std::path::Path;

mod support;

use conductor_benches::suite::{cyclictest, plots, Reader, QUICK_RATES, STATES};
use serde_json::Value;

/// Width and height from a PNG's IHDR chunk, after checking the signature.
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(b.len() > 33, "{}: too short for a PNG", path.display());
    assert_eq!(
        &b[..8],
        b"\x89PNG\r\n\x1a\n",
        "{}: not a PNG",
        path.display()
    );
    assert_eq!(&b[12..16], b"IHDR", "{}: first chunk", path.display());
    let be = |i: usize| u32::from_be_bytes(b[i..i + 4].try_into().unwrap());
    (be(16), be(20))
}

/// The first three cells (rate, states, reader) of every body row of each Markdown table whose
/// header starts with `| rate Hz | states |`: one set per table.
fn table_rows(md: &str) -> Vec<Vec<(String, String, String)>> {
    let mut tables = Vec::new();
    let mut current: Option<Vec<(String, String, String)>> = None;
    for line in md.lines() {
        if line.starts_with("| rate Hz | states |") {
            current = Some(Vec::new());
            continue;
        }
        match (&mut current, line.starts_with('|')) {
            (Some(_), true) if line.starts_with("|---") => {}
            (Some(rows), true) => {
                let cells: Vec<&str> = line.split('|').map(str::trim).collect();
                rows.push((
                    cells[1].to_string(),
                    cells[2].to_string(),
                    cells[3].to_string(),
                ));
            }
            (Some(_), false) => tables.push(current.take().unwrap()),
            (None, _) => {}
        }
    }
    tables.extend(current);
    tables
}

fn quantiles_ok(v: &Value, what: &str) {
    for k in ["count", "p50_ns", "p99_ns", "p999_ns", "max_ns"] {
        assert!(v[k].is_u64(), "{what}.{k} is not a count/ns: {v}");
    }
    assert!(v["count"].as_u64().unwrap() > 0, "{what}: nothing measured");
}

#[test]
fn quick_bench_writes_a_table_json_and_plots() {
    let (out, run) = support::bench("bench", &["--quick", "--no-install"]);

    // JSON: parses, and holds a row for every configured rate × state count.
    let text = std::fs::read_to_string(out.join("report.json")).unwrap();
    let j: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        (j["schema"].as_u64(), j["mode"].as_str()),
        (Some(3), Some("suite"))
    );
    assert_eq!(j["quick"], true);
    let rates: Vec<f64> = j["rates_hz"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r.as_f64().unwrap())
        .collect();
    assert_eq!(rates, QUICK_RATES);
    let ipc = j["ipc"].as_array().unwrap();
    assert_eq!(ipc.len(), 4, "four ping-pong paths");
    for r in ipc {
        quantiles_ok(&r["one_way"], r["path"].as_str().unwrap());
    }
    // The publish paths' cost in this run, and the executor's per-state cost beside it per rate
    // and reader.
    let publish = j["publish_cost"].as_array().unwrap();
    let paths: Vec<&str> = publish
        .iter()
        .map(|p| p["path"].as_str().unwrap())
        .collect();
    let four = ["raw", "state", "state-clock-per-state", "staged"];
    assert_eq!(
        paths,
        [four, four].concat(),
        "with one subscriber per state, then none"
    );
    for p in publish {
        assert!(p["per_state_ns"].as_f64().unwrap() > 0.0, "{p}");
    }
    let per_state = j["per_state_cost"].as_array().unwrap();
    assert_eq!(
        per_state.len(),
        QUICK_RATES.len() * Reader::ALL.len(),
        "{per_state:?}"
    );
    for r in per_state {
        assert_eq!(
            r["states"],
            serde_json::json!([STATES[0], STATES[1]]),
            "{r}"
        );
        assert!(r["over_raw"].is_f64(), "{r}");
    }
    // A row per rate × state count × reader (a subscriber per state, or the snapshot).
    let stress = j["stress"].as_array().unwrap();
    let per_rate = STATES.len() * Reader::ALL.len();
    assert_eq!(stress.len(), QUICK_RATES.len() * per_rate);
    for (i, row) in stress.iter().enumerate() {
        let rate = QUICK_RATES[i / per_rate];
        let states = STATES[i % per_rate / Reader::ALL.len()];
        let reader = Reader::ALL[i % Reader::ALL.len()].name();
        assert_eq!(row["rate_hz"].as_f64(), Some(rate));
        assert_eq!(row["states"].as_u64(), Some(states as u64));
        assert_eq!(row["reader"].as_str(), Some(reader));
        let what = format!("{rate} Hz × {states}, read by {reader}");
        // Beside each run, its floor of the same shape, and the ratio to it.
        quantiles_ok(&row["shape_floor"], &format!("{what} shape floor"));
        assert!(
            row["sample_to_subscriber_over_shape_floor"]["p50"].is_f64(),
            "{what}: {row}"
        );
        quantiles_ok(&row["lateness"], &format!("{what} lateness"));
        quantiles_ok(
            &row["sample_to_subscriber"],
            &format!("{what} sample→subscriber"),
        );
        quantiles_ok(
            &row["command"]["to_write"],
            &format!("{what} command→write"),
        );
        for k in ["ticks", "misses", "samples", "lost", "late_steps"] {
            assert!(row[k].is_u64(), "{what}: {k} = {}", row[k]);
        }
        // Misses over time: one count per second of the window, summing to the total.
        let by_second: Vec<u64> = row["misses_by_second"]
            .as_array()
            .unwrap_or_else(|| panic!("{what}: misses_by_second"))
            .iter()
            .map(|m| m.as_u64().unwrap())
            .collect();
        assert_eq!(by_second.len(), 3, "{what}: a 3 s window in 1 s slices");
        assert_eq!(
            by_second.iter().sum::<u64>(),
            row["misses"].as_u64().unwrap()
        );
        for k in ["thesis_error_max", "thesis_error_rms", "pipeline_error_max"] {
            assert!(row[k].is_f64(), "{what}: {k} = {}", row[k]);
        }
        assert!(row["cpu_percent"].is_f64(), "{what}: CPU use from /proc");
    }
    // cyclictest beside every rate when it is installed, else a note saying why not.
    if cyclictest::locate().is_some() {
        let ct = j["cyclictest"].as_array().unwrap();
        assert_eq!(ct.len(), QUICK_RATES.len(), "{}", j["cyclictest_note"]);
        for c in ct {
            quantiles_ok(&c["latency"], "cyclictest");
        }
        for row in stress {
            assert!(row["lateness_over_cyclictest"]["p50"].is_f64(), "{row}");
        }
    } else {
        assert!(j["cyclictest_note"].is_string());
    }

    // Plots: every one listed exists as a PNG of the suite's size, lateness and error per rate.
    let listed: BTreeSet<String> = j["plots"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap().to_string())
        .collect();
    let mut expected: BTreeSet<String> = QUICK_RATES
        .iter()
        .flat_map(|r| [format!("lateness-{r}hz.png"), format!("error-{r}hz.png")])
        .collect();
    expected.insert("error-all-rates.png".into());
    assert_eq!(listed, expected);
    for p in &listed {
        assert_eq!(png_size(&out.join(p)), (plots::WIDTH, plots::HEIGHT), "{p}");
    }

    // Markdown: the three per-run tables, each with a row per rate and state count.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let tables = table_rows(&md);
    assert_eq!(tables.len(), 3, "lateness, end to end, thesis:\n{md}");
    let want: Vec<(String, String, String)> = QUICK_RATES
        .iter()
        .flat_map(|r| {
            STATES.iter().flat_map(move |s| {
                Reader::ALL
                    .iter()
                    .map(move |x| (r.to_string(), s.to_string(), x.name().to_string()))
            })
        })
        .collect();
    for t in &tables {
        assert_eq!(t, &want, "{md}");
    }
    assert!(
        md.contains("| raw-busy |") && md.contains("| raw-event |"),
        "{md}"
    );
    // The Markdown is also what the command prints.
    assert_eq!(String::from_utf8_lossy(&run.stdout).trim(), md.trim());
    let _ = std::fs::remove_dir_all(&out);
}

/// `conductor bench --bridge --quick` over loopback: raw Zenoh read three ways, the bridge path
/// read three ways, the local bus twice, and a load run, all in one well-formed report. The
/// figures are not checked (they depend on the machine), only that each path was measured and
/// that the load run's counts add up.
#[test]
fn quick_bridge_bench_measures_every_path_and_counts_the_load() {
    let (out, _) = support::bench(
        "bench-bridge",
        &[
            "--bridge",
            "--quick",
            "--bridge-loopback",
            "--bridge-states",
            "50",
            "--seconds",
            "1",
        ],
    );
    let r: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("bridge.json")).unwrap()).unwrap();
    assert!(r["link"].as_str().unwrap().starts_with("loopback"), "{r}");
    // A's side placed as a launched manifest places it: the publisher (an executor) on the
    // first CPU, the exporting bridge on the others.
    let cpus = conductor_bus::rt::usable_cpus();
    let placement = r["placement"].as_str();
    if cpus.len() > 1 {
        let rest: Vec<String> = cpus[1..].iter().map(|c| c.to_string()).collect();
        assert_eq!(
            placement,
            Some(
                format!(
                    "publisher on CPU {}, exporting bridge on CPU(s) {}",
                    cpus[0],
                    rest.join(", ")
                )
                .as_str()
            ),
            "{r}"
        );
    } else {
        assert_eq!(placement, None, "{r}");
    }
    for path in [
        "zenoh_us",
        "zenoh_woken_us",
        "zenoh_poll_us",
        "bridge_on_bus_us",
        "bridge_woken_us",
        "bridge_us",
        "local_woken_us",
        "local_us",
    ] {
        let (p50, p99) = (r[path][0].as_f64(), r[path][1].as_f64());
        assert!(
            matches!((p50, p99), (Some(a), Some(b)) if a > 0.0 && a <= b),
            "{path} not measured: {}",
            r[path]
        );
    }
    let (published, received) = (
        r["published"].as_u64().unwrap(),
        r["received"].as_u64().unwrap(),
    );
    assert!(
        published > 0 && received > 0 && received <= published,
        "load run: {received} of {published}"
    );
    let md = std::fs::read_to_string(out.join("bridge.md")).unwrap();
    for row in [
        "raw Zenoh pub/sub: reader woken by the channel",
        "bridge: reader on B busy-polling",
    ] {
        assert!(md.contains(row), "no {row:?} row in\n{md}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

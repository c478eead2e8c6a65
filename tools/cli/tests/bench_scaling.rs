//! `conductor bench --scaling --quick` end to end: it runs the quick sweeps (states, subscribers
//! per state, executors per host; real executors, real reader processes, each run in a fresh
//! iceoryx2 domain) and writes a well-formed report: a JSON point per planned configuration
//! with its measured figures, every sweep's least-squares fits equal to a fit recomputed here
//! from that sweep's points, the six PNG curves, and a Markdown table per sweep. The figures
//! themselves are not checked (they are the machine's); executors sleep to their deadlines, so
//! nothing spins. It takes about 20 s. A file of its own so that it never runs beside the
//! suite's test (test binaries run one after another).

use std::path::Path;

mod support;

use conductor_benches::suite::scaling::{
    Plan, BASE_STATES, QUICK_EXECUTORS, QUICK_STATES, QUICK_SUBSCRIBERS,
};
use conductor_benches::suite::{fit, plots};
use serde_json::Value;

fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(b.len() > 33, "{}: too short for a PNG", path.display());
    assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n", "{}", path.display());
    assert_eq!(&b[12..16], b"IHDR", "{}", path.display());
    let be = |i: usize| u32::from_be_bytes(b[i..i + 4].try_into().unwrap());
    (be(16), be(20))
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

/// Checks a JSON fit against the fit of `pts`.
fn fit_matches(json: &Value, pts: &[(f64, f64)], what: &str) {
    let want = fit::fit_line(pts).unwrap_or_else(|| panic!("{what}: no fit of {pts:?}"));
    let got = |k: &str| {
        json[k]
            .as_f64()
            .unwrap_or_else(|| panic!("{what}.{k}: {json}"))
    };
    assert!(
        close(got("slope"), want.slope),
        "{what}: {json} vs {want:?}"
    );
    assert!(
        close(got("intercept"), want.intercept),
        "{what}: {json} vs {want:?}"
    );
    assert_eq!(json["points"].as_u64(), Some(pts.len() as u64), "{what}");
}

#[test]
fn quick_scaling_writes_points_fits_and_curves() {
    let (out, run) = support::bench("scaling", &["--scaling", "--quick"]);

    let j: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(
        (j["schema"].as_u64(), j["mode"].as_str()),
        (Some(3), Some("scaling"))
    );
    assert_eq!(j["quick"], true);

    // A point per planned configuration, each with its measured figures.
    let points = j["points"].as_array().unwrap();
    let plan = Plan::new(true).points();
    let got: Vec<(usize, usize, usize)> = points
        .iter()
        .map(|p| {
            let n = |k: &str| p[k].as_u64().unwrap() as usize;
            (n("states"), n("subscribers"), n("executors"))
        })
        .collect();
    assert_eq!(got, plan);
    for p in points {
        assert!(p["ticks"].as_u64().unwrap() > 0, "{p}");
        assert!(p["cpu_us_per_tick"].as_f64().unwrap() > 0.0, "{p}");
        assert!(p["lateness"]["count"].as_u64().unwrap() > 0, "{p}");
        let readers = p["subscribers"].as_u64().unwrap();
        if readers == 0 {
            assert!(p["sample_to_controller"].is_null(), "{p}");
        } else {
            let q = &p["sample_to_controller"];
            assert!(q["count"].as_u64().unwrap() > 0, "{p}");
            assert!(q["p99_ns"].as_u64().unwrap() >= q["p50_ns"].as_u64().unwrap());
            // The other readers read the same states: together about (readers − 1) times the
            // logger's samples, well above zero when there are any.
            assert_eq!(p["other_samples"].as_u64().unwrap() > 0, readers > 1, "{p}");
        }
    }

    // The sweeps: their points in order, and fits computed from exactly those points.
    let sweeps = j["sweeps"].as_array().unwrap();
    let names: Vec<&str> = sweeps.iter().map(|s| s["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["states", "subscribers", "executors"]);
    let xs: [(&str, Vec<usize>, f64); 3] = [
        ("states", QUICK_STATES.to_vec(), 1.0),
        (
            "subscribers",
            QUICK_SUBSCRIBERS.to_vec(),
            BASE_STATES as f64,
        ),
        ("executors", QUICK_EXECUTORS.to_vec(), 1.0),
    ];
    for (s, (key, want_x, per)) in sweeps.iter().zip(xs) {
        let idx: Vec<usize> = s["points"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i.as_u64().unwrap() as usize)
            .collect();
        let x: Vec<usize> = idx
            .iter()
            .map(|&i| points[i][key].as_u64().unwrap() as usize)
            .collect();
        assert_eq!(x, want_x, "{key}");
        let cpu: Vec<(f64, f64)> = idx
            .iter()
            .map(|&i| {
                (
                    points[i][key].as_f64().unwrap(),
                    points[i]["cpu_us_per_tick"].as_f64().unwrap(),
                )
            })
            .collect();
        fit_matches(&s["cpu_fit"], &cpu, &format!("{key} CPU"));
        let unit = s["unit_cost_us"].as_f64().unwrap();
        assert!(close(unit, s["cpu_fit"]["slope"].as_f64().unwrap() / per));
        let lat: Vec<(f64, f64)> = idx
            .iter()
            .filter(|&&i| !points[i]["sample_to_controller"].is_null())
            .map(|&i| {
                (
                    points[i][key].as_f64().unwrap(),
                    points[i]["sample_to_controller"]["p50_ns"]
                        .as_f64()
                        .unwrap()
                        / 1e3,
                )
            })
            .collect();
        fit_matches(&s["latency_p50_fit"], &lat, &format!("{key} latency"));
    }

    // The curves.
    let listed = conductor_testkit::json_strings(&j["plots"]);
    let want: Vec<String> = ["states", "subscribers", "executors"]
        .iter()
        .flat_map(|s| [format!("cpu-vs-{s}.png"), format!("latency-vs-{s}.png")])
        .collect();
    assert_eq!(listed, want);
    for p in &listed {
        assert_eq!(png_size(&out.join(p)), (plots::WIDTH, plots::HEIGHT), "{p}");
    }

    // Markdown: a table per sweep with a row per point, the fits, and what was printed.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let tables = md
        .lines()
        .filter(|l| l.starts_with("| states | subscribers | executors |"))
        .count();
    assert_eq!(tables, 3, "{md}");
    for unit in [
        "µs per state per tick",
        "µs per subscriber per state per tick",
        "µs per extra executor per tick",
    ] {
        assert!(md.contains(unit), "{unit}:\n{md}");
    }
    assert_eq!(String::from_utf8_lossy(&run.stdout).trim(), md.trim());
    let _ = std::fs::remove_dir_all(&out);
}

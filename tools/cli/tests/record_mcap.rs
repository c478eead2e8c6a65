//! `record` for 5 s at 1 kHz, then the official MCAP Python reader and jsonschema check the
//! file. Its own test binary, so that no other test competes for the 2 CPUs while it records.

mod support;

use support::*;

#[test]
fn record_5s_at_1khz_reads_with_the_official_mcap_package() {
    let (d, _leg) = domain_with_leg("rec", 1000.0, leg);
    let dir = tempdir("rec");
    let file = dir.join("run.mcap");
    let manifest = dir.join("robot.toml");
    let manifest_text = "[subsystem.leg]\nrate_hz = 1000\n";
    std::fs::write(&manifest, manifest_text).unwrap();
    ok(record(&d, &["leg/*", "--duration", "5"], &file)
        .arg("--manifest")
        .arg(&manifest));

    let r = check_with_python(&file);
    assert_eq!(r["profile"], "conductor");
    assert_eq!(
        r["schemas_ok"],
        serde_json::json!({"conductor.StateSample": true})
    );
    assert_eq!(r["compression"], serde_json::json!(["zstd"]));
    assert!(r["chunks"].as_u64().unwrap() >= 1);
    assert_eq!(r["message_indexes"], true);
    let channels = r["channels"].as_object().unwrap();
    let topics: Vec<&String> = channels.keys().collect();
    assert_eq!(topics, ["/leg/current", "/leg/hip", "/leg/knee"]);
    for (topic, c) in channels {
        let count = c["count"].as_u64().unwrap();
        // 5 s at 1 kHz; within 1 % (the acceptance criterion).
        assert!(count.abs_diff(5000) <= 50, "{topic}: {count} messages");
        // No sample lost between the first and the last recorded.
        let span = c["last_seq"].as_u64().unwrap() - c["first_seq"].as_u64().unwrap() + 1;
        assert_eq!(span, count, "{topic}");
        assert_eq!(c["monotonic"], true, "{topic}");
        assert_eq!(c["log_time_is_t_sample"], true, "{topic}");
        assert_eq!(c["invalid"], 0, "{topic}");
        assert_eq!(c["encoding"], "jsonschema");
        assert_eq!(c["message_encoding"], "json");
        let first_t = c["first_t"].as_u64().unwrap();
        let last_t = c["last_t"].as_u64().unwrap();
        let rate = (count - 1) as f64 / ((last_t - first_t) as f64 * 1e-9);
        assert!((rate - 1000.0).abs() < 10.0, "{topic}: {rate} Hz");
    }
    let knee = &channels["/leg/knee"]["metadata"];
    for (k, v) in [
        ("subsystem", "leg"),
        ("state", "knee"),
        ("units", "rad"),
        ("index", "0"),
        ("writable", "true"),
        ("min", "-1.5"),
        ("max", "2"),
        ("rate_hz", "1000"),
        ("device", "dKnee"),
    ] {
        assert_eq!(knee[k], v, "{k}: {knee}");
    }
    let md = &r["metadata"];
    assert_eq!(md["conductor"]["domain"], d.name());
    assert_eq!(md["conductor.manifest"]["toml"], manifest_text);
    assert_eq!(md["conductor.summary"]["stopped_by"], "duration");
    for s in ["leg/knee", "leg/hip", "leg/current"] {
        assert_eq!(md["conductor.summary"][format!("{s}.lost")], "0");
    }
    // The summary's statistics agree with what the reader counted.
    let stats: u64 = r["statistics"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_u64().unwrap())
        .sum();
    let counted: u64 = channels
        .values()
        .map(|c| c["count"].as_u64().unwrap())
        .sum();
    assert_eq!(stats, counted);
    let _ = std::fs::remove_dir_all(&dir);
}
